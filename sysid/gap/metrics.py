"""Sim-to-real gap metrics between two runs (paper Eq. 7 and 8 and the sliding-window correlation).

All functions are pure and take :class:`cobra_model.run.Run` objects, typically a measured run
(hardware, OptiTrack) and a simulated run of the same command. Two runs are first put on a common
time base (:func:`resample_to`); then

* the *external* gap (Eq. 7) is the ground-plane (world ``x``, ``y``) distance between the head
  positions, over time and at the last time both runs have motion capture;
* the *actuated* gap is the per-joint RMS difference of the measured joint angles;
* the *internal* gap (Eq. 8) compares the CPG variables (amplitude, frequency, phase) of a sine
  ``q_k(t) = A sin(2 pi f t + phi) + c`` fitted to each joint of each run;
* the sliding-window Pearson correlation between joint trajectories, averaged over the joints
  with its min-max band (the paper's correlation figure).

Differences are always ``b - a`` (``simulated - measured`` in :func:`compare_runs`). Motion-capture
gaps are NaN and every metric ignores them. Units: m, rad, Hz, s.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from cobra_model.errors import InputError
from cobra_model.resample import resample_run
from cobra_model.run import NUM_JOINTS, Run

#: Default sliding-correlation window [s]: about one gait cycle at the paper's middle gait
#: frequency of 0.5 Hz, long enough that a window of a sine-tracking joint has a well-defined
#: correlation, short enough to show when during the run the tracking degrades.
DEFAULT_WINDOW_S = 2.0
#: Longest motion-capture dropout [samples] bridged by linear interpolation when resampling.
MAX_MOCAP_GAP_SAMPLES = 2


def wrap_angle(angle: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) [rad] wrapped to ``(-pi, pi]``."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2.0 * np.pi)


# ---------------------------------------------------------------------------------------------
# Sine fit (CPG variables of one joint).


@dataclass(frozen=True)
class SineFit:
    """Least-squares fit ``y(t) = amplitude * sin(2 pi frequency t + phase) + offset``.

    Attributes:
        amplitude: A >= 0 [rad].
        frequency: f [Hz]; NaN for a constant signal.
        phase: phi [rad] at ``t = 0`` of the run's clock, wrapped to ``(-pi, pi]``; NaN for a
            constant signal.
        offset: c [rad].
        rmse: RMS of the fit residual [rad].
    """

    amplitude: float
    frequency: float
    phase: float
    offset: float
    rmse: float

    def as_dict(self) -> dict[str, float]:
        """The fields as a plain dict (for JSON)."""
        return {
            "amplitude": self.amplitude,
            "frequency": self.frequency,
            "phase": self.phase,
            "offset": self.offset,
            "rmse": self.rmse,
        }


def _periodogram_peak(t: np.ndarray, y: np.ndarray) -> float:
    """Frequency [Hz] of the largest zero-padded FFT peak of ``y`` resampled uniformly."""
    n = t.size
    tu = np.linspace(t[0], t[-1], n)
    yu = np.interp(tu, t, y)
    yu = (yu - yu.mean()) * np.hanning(n)
    n_fft = 8 * (1 << int(np.ceil(np.log2(n))))
    power = np.abs(np.fft.rfft(yu, n_fft)) ** 2
    freqs = np.fft.rfftfreq(n_fft, d=tu[1] - tu[0])
    # Below one cycle over the record there is no periodicity to speak of.
    power[freqs < 1.0 / (t[-1] - t[0])] = 0.0
    return float(freqs[int(np.argmax(power))])


def _linear_fit(tc: np.ndarray, y: np.ndarray, freqs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each frequency, the least-squares ``(a, b, c)`` of ``a sin + b cos + c`` and its SSE.

    Vectorised over the frequencies with 3x3 normal equations. ``freqs`` (F,) [Hz]; returns
    coefficients (F, 3) and the residual sums of squares (F,).
    """
    phase = 2.0 * np.pi * np.outer(freqs, tc)
    basis = np.stack([np.sin(phase), np.cos(phase), np.ones_like(phase)], axis=1)  # (F, 3, N)
    gram = np.einsum("fin,fjn->fij", basis, basis)
    rhs = np.einsum("fin,n->fi", basis, y)
    coef = np.linalg.solve(gram, rhs[..., None])[..., 0]
    sse = np.maximum(y @ y - np.einsum("fi,fi->f", coef, rhs), 0.0)
    return coef, sse


def fit_sine(t: np.ndarray, y: np.ndarray, *, freq_guess: float | None = None) -> SineFit:
    """Fit ``y = A sin(2 pi f t + phi) + c`` to samples ``y`` (N,) at times ``t`` (N,) [s].

    The frequency starts at ``freq_guess`` [Hz] or at the peak of a zero-padded periodogram, is
    refined on a grid of linear fits within one frequency bin (1 / record length), then all four
    parameters are refined by :func:`scipy.optimize.least_squares`. NaN samples are ignored.
    Reliable for three or more cycles in the record. A constant signal gives amplitude 0 and NaN
    frequency and phase.

    Raises:
        InputError: on mismatched shapes, fewer than 5 finite samples or a non-positive
            ``freq_guess``.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    if t.ndim != 1 or t.shape != y.shape:
        raise InputError(
            f"fit_sine: t and y must be 1-D of equal length, got {t.shape} and {y.shape}"
        )
    if freq_guess is not None and not freq_guess > 0:
        raise InputError(f"fit_sine: freq_guess must be > 0 Hz, got {freq_guess!r}")
    keep = np.isfinite(t) & np.isfinite(y)
    t, y = t[keep], y[keep]
    if t.size < 5:
        raise InputError(f"fit_sine: need at least 5 finite samples, got {t.size}")
    order = np.argsort(t, kind="stable")
    t, y = t[order], y[order]
    span = t[-1] - t[0]
    if span <= 0 or np.ptp(y) <= 1e-12 * max(1.0, float(np.abs(y).max())):
        offset = float(y.mean())
        rmse = float(np.sqrt(np.mean((y - offset) ** 2)))
        return SineFit(0.0, float("nan"), float("nan"), offset, rmse)

    # Centre time for conditioning; the phase is moved back to t = 0 at the end.
    t_mid = 0.5 * (t[0] + t[-1])
    tc = t - t_mid
    f0 = float(freq_guess) if freq_guess is not None else _periodogram_peak(t, y)
    grid = f0 + np.linspace(-1.0, 1.0, 41) / span
    grid = grid[grid > 0]
    coef, sse = _linear_fit(tc, y, grid)
    best = int(np.argmin(sse))

    def residual(p: np.ndarray) -> np.ndarray:
        ph = 2.0 * np.pi * p[3] * tc
        return p[0] * np.sin(ph) + p[1] * np.cos(ph) + p[2] - y

    def jacobian(p: np.ndarray) -> np.ndarray:
        ph = 2.0 * np.pi * p[3] * tc
        s, c = np.sin(ph), np.cos(ph)
        return np.column_stack([s, c, np.ones_like(tc), 2.0 * np.pi * tc * (p[0] * c - p[1] * s)])

    sol = least_squares(
        residual,
        np.append(coef[best], grid[best]),
        jac=jacobian,
        bounds=([-np.inf, -np.inf, -np.inf, 0.0], np.inf),
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
    )
    a, b, c, f = sol.x
    phase_mid = np.arctan2(b, a)
    return SineFit(
        amplitude=float(np.hypot(a, b)),
        frequency=float(f),
        phase=float(wrap_angle(phase_mid - 2.0 * np.pi * f * t_mid)),
        offset=float(c),
        rmse=float(np.sqrt(np.mean(sol.fun**2))),
    )


# ---------------------------------------------------------------------------------------------
# Common time base.


def _describe(run: Run, label: str) -> str:
    name = f"{label} ({run.source.name})" if run.source is not None else label
    return (
        f"{name}: {run.n_samples} samples, {1e3 * run.dt_median:.4g} ms median step, "
        f"[{run.t[0]:.6g}, {run.t[-1]:.6g}] s"
    )


def resample_to(
    run_a: Run, run_b: Run, *, labels: Sequence[str] = ("a", "b")
) -> tuple[Run, Run, str]:
    """Put two runs on one time base: the coarser run's sample times inside the overlap.

    The coarser run (larger median step; ``run_a`` on a tie) keeps its samples inside the overlap
    of the two time spans; the other run is interpolated linearly onto those times (quaternions by
    nlerp). Motion-capture dropouts of the interpolated run longer than
    :data:`MAX_MOCAP_GAP_SAMPLES` samples stay NaN. ``labels`` name the runs in the note.

    Returns:
        ``(a, b, note)``: both runs on the common times, and a human-readable note of what was
        resampled.

    Raises:
        InputError: if the runs overlap in fewer than 2 samples of the coarser run.
    """
    label_a, label_b = labels
    if run_a.t.shape == run_b.t.shape and np.array_equal(run_a.t, run_b.t):
        note = (
            f"{label_a} and {label_b} share the same {run_a.n_samples} sample times in "
            f"[{run_a.t[0]:.6g}, {run_a.t[-1]:.6g}] s; no resampling"
        )
        return run_a, run_b, note
    lo = max(run_a.t[0], run_b.t[0])
    hi = min(run_a.t[-1], run_b.t[-1])
    a_is_coarse = not run_b.dt_median > run_a.dt_median
    coarse, fine = (run_a, run_b) if a_is_coarse else (run_b, run_a)
    coarse_label, fine_label = (label_a, label_b) if a_is_coarse else (label_b, label_a)
    inside = (coarse.t >= lo) & (coarse.t <= hi)
    if inside.sum() < 2:
        raise InputError(
            f"cannot compare runs: they overlap in fewer than 2 samples "
            f"({_describe(run_a, label_a)}; {_describe(run_b, label_b)})"
        )
    coarse_common = coarse.select(inside)
    fine_common = resample_run(fine, coarse_common.t, max_gap_samples=MAX_MOCAP_GAP_SAMPLES)
    note = (
        f"common time base: the {coarse_common.n_samples} samples of {coarse_label} in the overlap "
        f"[{coarse_common.t[0]:.6g}, {coarse_common.t[-1]:.6g}] s; {fine_label} interpolated "
        f"linearly onto them (motion-capture gaps over {MAX_MOCAP_GAP_SAMPLES} samples left NaN) "
        f"- {_describe(run_a, label_a)}; {_describe(run_b, label_b)}"
    )
    if a_is_coarse:
        return coarse_common, fine_common, note
    return fine_common, coarse_common, note


# ---------------------------------------------------------------------------------------------
# External gap: ground-plane position errors (Eq. 7).


def _nan_mean(x: np.ndarray) -> float:
    finite = np.isfinite(x)
    return float(x[finite].mean()) if finite.any() else float("nan")


@dataclass(frozen=True)
class PathError:
    """Ground-plane distance between two tracks of one body on a common time base.

    Attributes:
        t: (M,) common times [s].
        distance: (M,) ``sqrt(dx^2 + dy^2)`` in the world x-y plane [m]; NaN where either track
            is missing.
        mean: mean of the finite distances [m]; NaN if none.
        final: distance at the last time both tracks have data [m] (Eq. 7); NaN if none.
        final_t: that time [s]; NaN if none.
    """

    t: np.ndarray
    distance: np.ndarray
    mean: float
    final: float
    final_t: float


@dataclass(frozen=True)
class HeadError(PathError):
    """:class:`PathError` of the head, plus one per other body tracked in both runs.

    Attributes:
        body_errors: body name -> :class:`PathError`, for bodies present in both runs.
    """

    body_errors: Mapping[str, PathError] = field(default_factory=dict)


def _path_error(t: np.ndarray, pos_a: np.ndarray, pos_b: np.ndarray) -> PathError:
    distance = np.hypot(pos_b[:, 0] - pos_a[:, 0], pos_b[:, 1] - pos_a[:, 1])
    finite = np.flatnonzero(np.isfinite(distance))
    last = int(finite[-1]) if finite.size else None
    return PathError(
        t=t,
        distance=distance,
        mean=_nan_mean(distance),
        final=float(distance[last]) if last is not None else float("nan"),
        final_t=float(t[last]) if last is not None else float("nan"),
    )


def head_error(a: Run, b: Run) -> HeadError:
    """Ground-plane head position error between two runs (paper Eq. 7), and of the other bodies.

    The runs are put on a common time base with :func:`resample_to`.
    """
    a, b, _ = resample_to(a, b)
    head = _path_error(a.t, a.head_pos, b.head_pos)
    bodies = {
        name: _path_error(a.t, a.bodies[name], b.bodies[name])
        for name in a.bodies
        if name in b.bodies
    }
    return HeadError(
        t=head.t,
        distance=head.distance,
        mean=head.mean,
        final=head.final,
        final_t=head.final_t,
        body_errors=bodies,
    )


# ---------------------------------------------------------------------------------------------
# Actuated gap: joint trajectories.


def joint_rmse(a: Run, b: Run) -> np.ndarray:
    """Per-joint RMS of ``q_b - q_a`` on the common time base, (11,) [rad]. NaN samples ignored."""
    a, b, _ = resample_to(a, b)
    d2 = (b.q - a.q) ** 2
    finite = np.isfinite(d2)
    count = finite.sum(axis=0)
    total = np.where(finite, d2, 0.0).sum(axis=0)
    return np.where(count > 0, np.sqrt(total / np.maximum(count, 1)), np.nan)


def joint_l2(a: Run, b: Run) -> np.ndarray:
    """Per-joint L2 norm of ``q_b - q_a`` over time, ``sqrt(integral d^2 dt)``, (11,) [rad sqrt(s)].

    Trapezoidal rule on the common time base; the paper's "L2 norm of joint trajectory
    differences". Unlike :func:`joint_rmse` it grows with the run's duration.
    """
    a, b, _ = resample_to(a, b)
    d2 = (b.q - a.q) ** 2
    return np.sqrt(np.trapezoid(d2, a.t, axis=0))


# ---------------------------------------------------------------------------------------------
# Internal gap: CPG variables (Eq. 8).


def cpg_error(a: Run, b: Run, *, labels: Sequence[str] = ("a", "b")) -> list[dict[str, Any]]:
    """Per joint, the sine fits of ``q`` of both runs and their differences (paper Eq. 8).

    Both fits use the common time base, so phases refer to the same clock.

    Returns:
        11 dicts, joint 1..11 from the head: ``"joint"`` (int), ``"amplitude"`` [rad],
        ``"frequency"`` [Hz] and ``"phase"`` [rad, wrapped to (-pi, pi]] as differences ``b - a``,
        and the fits of each run (:meth:`SineFit.as_dict`) under ``labels[0]`` and ``labels[1]``.
    """
    a, b, _ = resample_to(a, b)
    label_a, label_b = labels
    out: list[dict[str, Any]] = []
    for j in range(NUM_JOINTS):
        fa = fit_sine(a.t, a.q[:, j])
        fb = fit_sine(b.t, b.q[:, j])
        out.append(
            {
                "joint": j + 1,
                "amplitude": fb.amplitude - fa.amplitude,
                "frequency": fb.frequency - fa.frequency,
                "phase": float(wrap_angle(fb.phase - fa.phase)),
                label_a: fa.as_dict(),
                label_b: fb.as_dict(),
            }
        )
    return out


# ---------------------------------------------------------------------------------------------
# Sliding-window correlation.


def _window_sums(x: np.ndarray, window: int) -> np.ndarray:
    """Sums of ``x`` (N, J) over each run of ``window`` consecutive rows, (N - window + 1, J)."""
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    return c[window:] - c[:-window]


def window_correlation(x: np.ndarray, y: np.ndarray, window: int) -> np.ndarray:
    """Pearson correlation of ``x`` and ``y`` (N, J) per joint over every sliding window.

    Window ``i`` covers rows ``i .. i + window - 1``. Computed from cumulative sums (columns are
    centred first to limit cancellation). A window containing a NaN, or in which either signal has
    zero variance (to rounding), gives NaN.

    Returns:
        (N - window + 1, J) correlations in [-1, 1].

    Raises:
        InputError: on mismatched or non-2-D shapes, or ``window`` outside ``2 .. N``.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    if x.ndim != 2 or x.shape != y.shape:
        raise InputError(
            f"window_correlation: x and y must be (N, J) arrays of one shape, "
            f"got {x.shape} and {y.shape}"
        )
    n = x.shape[0]
    if not 2 <= window <= n:
        raise InputError(f"window_correlation: window must be in 2..{n} samples, got {window}")
    missing = np.isnan(x) | np.isnan(y)
    counts = np.maximum((~missing).sum(axis=0), 1)
    x0 = np.where(missing, 0.0, x)
    y0 = np.where(missing, 0.0, y)
    x0 = np.where(missing, 0.0, x0 - x0.sum(axis=0) / counts)
    y0 = np.where(missing, 0.0, y0 - y0.sum(axis=0) / counts)
    sx, sy = _window_sums(x0, window), _window_sums(y0, window)
    var_x = _window_sums(x0 * x0, window) - sx * sx / window
    var_y = _window_sums(y0 * y0, window) - sy * sy / window
    cov = _window_sums(x0 * y0, window) - sx * sy / window
    # Rounding of the cumulative sums leaves |error| ~ eps * N * max(x^2) in each window sum.
    eps = np.finfo(float).eps
    tol_x = 16.0 * eps * n * np.max(x0 * x0, axis=0)
    tol_y = 16.0 * eps * n * np.max(y0 * y0, axis=0)
    ok = (var_x > tol_x) & (var_y > tol_y) & (_window_sums(missing.astype(float), window) < 0.5)
    denom = np.sqrt(np.where(ok, var_x * var_y, 1.0))
    return np.where(ok, np.clip(cov / denom, -1.0, 1.0), np.nan)


def correlation_summary(corr: np.ndarray) -> dict[str, Any]:
    """Average a (W, J) window-correlation array over the joints, with its min-max band.

    Returns:
        ``mean_curve``, ``min_curve``, ``max_curve`` (W,) over the joints (NaN where every joint
        is NaN); ``mean`` the time average of ``mean_curve``; ``min`` and ``max`` the extremes of
        the band over the whole run (NaN if nothing is finite).
    """
    corr = np.asarray(corr, dtype=float)
    finite = np.isfinite(corr)
    count = finite.sum(axis=1)
    some = count > 0
    total = np.where(finite, corr, 0.0).sum(axis=1)
    mean_curve = np.where(some, total / np.maximum(count, 1), np.nan)
    min_curve = np.where(some, np.where(finite, corr, np.inf).min(axis=1), np.nan)
    max_curve = np.where(some, np.where(finite, corr, -np.inf).max(axis=1), np.nan)
    return {
        "mean": _nan_mean(mean_curve),
        "min": float(min_curve[some].min()) if some.any() else float("nan"),
        "max": float(max_curve[some].max()) if some.any() else float("nan"),
        "mean_curve": mean_curve,
        "min_curve": min_curve,
        "max_curve": max_curve,
    }


# ---------------------------------------------------------------------------------------------
# Report.


def _json_float(x: float) -> float | None:
    """A float for JSON: NaN and infinities (no data) become ``None`` (JSON ``null``)."""
    x = float(x)
    return x if np.isfinite(x) else None


def _json_values(value: float | Mapping[str, float]) -> float | None | dict[str, float | None]:
    """:func:`_json_float` of a float or of each value of a mapping of floats."""
    if isinstance(value, Mapping):
        return {key: _json_float(v) for key, v in value.items()}
    return _json_float(value)


def _scalars(summary: Mapping[str, Any]) -> dict[str, float | None]:
    return {key: _json_float(summary[key]) for key in ("mean", "min", "max")}


@dataclass(frozen=True)
class GapReport:
    """The sim-to-real gap between a measured and a simulated run.

    Attributes:
        head: head (and other bodies') ground-plane errors [m].
        joint_rmse: (11,) per-joint RMS of ``q_simulated - q_measured`` [rad].
        cpg: :func:`cpg_error` output, fits labelled ``"measured"`` and ``"simulated"``.
        correlation: window-correlation summaries (:func:`correlation_summary`) under
            ``"measured_vs_simulated"``, ``"measured_vs_command"``, ``"simulated_vs_command"``
            (``q`` against the run's own ``q_ref``).
        correlation_t: (W,) centre time of each correlation window [s].
        window_s: requested correlation window [s].
        window_samples: the window in samples of the common time base.
        resampled: note of how the runs were put on a common time base.
    """

    head: HeadError
    joint_rmse: np.ndarray
    cpg: Sequence[Mapping[str, Any]]
    correlation: Mapping[str, Mapping[str, Any]]
    correlation_t: np.ndarray
    window_s: float
    window_samples: int
    resampled: str

    def to_json_dict(self) -> dict[str, Any]:
        """The report as JSON-ready values; NaN (no data, e.g. no motion capture) is ``None``."""
        cpg = [
            {
                key: value if key == "joint" else _json_values(value)
                for key, value in entry.items()
            }
            for entry in self.cpg
        ]
        window = _scalars(self.correlation["measured_vs_simulated"])
        window.update(
            window_s=float(self.window_s),
            window_samples=int(self.window_samples),
            measured_vs_command=_scalars(self.correlation["measured_vs_command"]),
            simulated_vs_command=_scalars(self.correlation["simulated_vs_command"]),
        )
        return {
            "head_omitted": self.head_omitted,
            "head_final_error_m": _json_float(self.head.final),
            "head_mean_error_m": _json_float(self.head.mean),
            "joint_rmse_rad": {
                "per_joint": [_json_float(v) for v in self.joint_rmse],
                "mean": _json_float(self.mean_joint_rmse),
            },
            "cpg_error": cpg,
            "window_correlation": window,
            "body_final_error_m": {
                name: _json_float(err.final) for name, err in self.head.body_errors.items()
            },
            "resampled": self.resampled,
        }

    @property
    def mean_window_correlation(self) -> float:
        """Time-and-joint mean of the measured-vs-simulated sliding-window correlation."""
        return float(self.correlation["measured_vs_simulated"]["mean"])

    @property
    def mean_joint_rmse(self) -> float:
        """Mean over the joints of the per-joint RMS error [rad] (NaN joints left out)."""
        return _nan_mean(self.joint_rmse)

    @property
    def head_omitted(self) -> str | None:
        """Why there are no head metrics (no common sample has a head pose in both runs, as in a
        joint-only run recorded without motion capture), or None when there are."""
        if np.isfinite(self.head.distance).any():
            return None
        return ("no sample has a head pose in both runs (a joint-only run, e.g. recorded without "
                "motion capture): head metrics omitted, joint metrics only")

    def format_table(self) -> str:
        """A plain-text table of the report (m, rad, Hz)."""

        def num(x: float, fmt: str = "{:9.4f}") -> str:
            return fmt.format(x) if np.isfinite(x) else f"{'n/a':>9}"

        lines = ["Sim-to-real gap (differences are simulated - measured)"]
        if self.head_omitted:
            lines.append(f"  {self.head_omitted}")
        else:
            lines += [
                f"  {'head final error (x-y)':<28}{num(self.head.final)} m"
                f"  at t = {num(self.head.final_t, '{:.3f}')} s",
                f"  {'head mean error (x-y)':<28}{num(self.head.mean)} m",
            ]
        for name, err in self.head.body_errors.items():
            lines.append(f"  {name + ' final error (x-y)':<28}{num(err.final)} m")
        lines.append("")
        lines.append(
            f"{'joint':>5} {'rmse[rad]':>9} {'A_meas':>9} {'A_sim':>9} {'dA[rad]':>9} "
            f"{'f_meas':>9} {'f_sim':>9} {'df[Hz]':>9} {'dphi[rad]':>9}"
        )
        for rmse, entry in zip(self.joint_rmse, self.cpg):
            meas, sim = entry["measured"], entry["simulated"]
            lines.append(
                f"{entry['joint']:>5} {num(rmse)} {num(meas['amplitude'])} {num(sim['amplitude'])} "
                f"{num(entry['amplitude'])} {num(meas['frequency'])} {num(sim['frequency'])} "
                f"{num(entry['frequency'])} {num(entry['phase'])}"
            )
        lines.append(f"{'mean':>5} {num(_nan_mean(self.joint_rmse))}")
        lines.append("")
        lines.append(
            f"window correlation ({self.window_s:g} s = {self.window_samples} samples), "
            "mean [min, max] over windows and joints:"
        )
        for key, summary in self.correlation.items():
            lines.append(
                f"  {key.replace('_', ' '):<22} {num(summary['mean'], '{:.4f}')} "
                f"[{num(summary['min'], '{:.4f}')}, {num(summary['max'], '{:.4f}')}]"
            )
        lines.append("")
        lines.append(f"resampled: {self.resampled}")
        return "\n".join(lines)


def compare_runs(measured: Run, simulated: Run, *, window_s: float = DEFAULT_WINDOW_S) -> GapReport:
    """All gap metrics between a measured and a simulated run of the same command.

    ``window_s`` [s] is the sliding-correlation window; it is rounded to whole samples of the
    common time base and clipped to ``3 .. N`` samples.

    Raises:
        InputError: if ``window_s`` is not positive or the runs do not overlap in time.
    """
    if not window_s > 0:
        raise InputError(f"compare_runs: window_s must be > 0 s, got {window_s!r}")
    labels = ("measured", "simulated")
    a, b, note = resample_to(measured, simulated, labels=labels)
    n = a.n_samples
    if n < 5:
        raise InputError(f"compare_runs: need at least 5 common samples, got {n} ({note})")
    window = int(min(max(round(window_s / a.dt_median), 3), n))
    correlation = {
        "measured_vs_simulated": correlation_summary(window_correlation(a.q, b.q, window)),
        "measured_vs_command": correlation_summary(window_correlation(a.q_ref, a.q, window)),
        "simulated_vs_command": correlation_summary(window_correlation(b.q_ref, b.q, window)),
    }
    centres = 0.5 * (a.t[: n - window + 1] + a.t[window - 1 :])
    return GapReport(
        head=head_error(a, b),
        joint_rmse=joint_rmse(a, b),
        cpg=cpg_error(a, b, labels=labels),
        correlation=correlation,
        correlation_t=centres,
        window_s=float(window_s),
        window_samples=window,
        resampled=note,
    )
