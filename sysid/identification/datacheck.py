"""A check of the data before a fit may start: what is wrong with the runs, what they cannot pin down.

Two kinds of finding, in the shape of the data checks identification tools make before they
fit (Isaac Sim's actuator identification refuses to start on data that cannot fit):

- **Per run** (:func:`inspect_run`, no simulation): gaps in the sample rate, motion-capture
  dropouts of the head, joints that sit at their URDF limits or stay flat while their command
  moves, and runs too short for the fit's first horizon stage.
- **Identifiability of the free parameters** (:func:`check_runs`): one forward finite-difference
  Jacobian of the residuals in the parameters' unit coordinates, made exactly as
  :func:`sysid.identification.lsq.fit_lsq` makes its Jacobians (:func:`sysid.identification.lsq.forward_steps`,
  :data:`sysid.identification.lsq.FD_STEP`, every perturbed vector in one batched
  :meth:`sysid.identification.objective.Objective.residuals` call), on each run's first ``horizon_s``
  seconds. Its singular values give the numerical rank and condition number; its columns say how
  strongly each parameter moves the residuals (its excitation); its flat directions say which
  parameters move them in nearly the same way. :func:`analyse_jacobian` names the parameters
  that cannot be pinned down, each with a one-sentence reason, and picks the fewest to freeze.

:func:`apply` freezes them in a parameter set. The ``cobra check`` command prints the report;
``cobra fit`` and ``cobra diagnose`` run it before fitting (``--no-check`` skips it).

Residual units are those of :class:`sysid.identification.objective.Weights`: by default 1 residual unit is
1 cm of head path or 0.01 rad of joint angle at one 10 Hz sample.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from cobra_model.errors import InputError
from cobra_model.model import CobraModel
from cobra_model.parameters import ModelParameters
from cobra_model.run import Run
from integrators.simulator import SimSettings, SimulationDiverged
from sysid.identification.lockstep import Evaluate, run
from sysid.identification.lsq import DEFAULT_HORIZONS_S, FD_STEP, forward_steps, retake_diverged
from sysid.identification.objective import Objective, Weights

#: A sample interval longer than this multiple of the run's median interval is a gap. A logger
#: at a steady rate jitters by a few percent; 1.5x is a skipped sample at the least.
GAP_FACTOR = 1.5
#: A run shorter than this [s] is too short: it is the first horizon stage of
#: :func:`sysid.identification.lsq.fit_lsq`, below which a head path barely depends on the ground parameters.
MIN_DURATION_S = DEFAULT_HORIZONS_S[0]
#: A head dropout longer than this [s] is a problem: a quarter of the fastest gait's period
#: (0.65 Hz), over which the head path bends noticeably. Shorter ones, in all under
#: :data:`DROPOUT_FRACTION` of a run, are routine (the reference dataset's longest is 0.16 s, at
#: most 5.3 % of a run): the objective leaves those head samples out and loses little.
DROPOUT_LONG_S = 0.5
#: A run missing the head in more than this fraction of its samples has a dropout problem.
DROPOUT_FRACTION = 0.1
#: A joint sample within this distance [rad] (about 1.1 deg, a dozen encoder counts of the
#: XH540's 4096 per turn) of a URDF joint limit is at the limit.
LIMIT_MARGIN_RAD = 0.02
#: A joint whose measured peak-to-peak is below this fraction of its commanded peak-to-peak is
#: flat. A position-controlled servo that tracks at all keeps most of its swing (the fitted
#: reference data: amplitude ratios 0.8-1.0); half of it lost is a clamp, a stall or a broken
#: encoder.
FLAT_RATIO = 0.5
#: Commanded peak-to-peak [rad] below which a joint is not judged flat (a joint commanded to stay
#: still is allowed to stay still; 0.1 rad is 65 encoder counts, far above quantisation).
MIN_COMMAND_SWING_RAD = 0.1
#: A singular value of the unit-coordinate Jacobian below this fraction of the largest is a flat
#: direction: the threshold :func:`sysid.identification.lsq.fit_lsq` uses for its identifiability flags, so the
#: check and the fit's report agree on what is flat.
FLAT_RELATIVE = 1e-4
#: A component above this magnitude (of a unit right singular vector) loads a flat direction, as
#: in :func:`sysid.identification.lsq.fit_lsq`'s report.
FLAT_LOADING = 0.3
#: A parameter whose residual sensitivity (its Jacobian column norm) is below this fraction of
#: the largest one's is not excited. Equal to :data:`FLAT_RELATIVE`: such a column alone makes a
#: flat direction, so the two criteria name it alike and this one gives the plainer reason.
EXCITATION_RELATIVE = 1e-4
#: A parameter whose residual sensitivity is below this many residual units per unit coordinate
#: (moving it across its whole range, in the linear picture) is not excited whatever the other
#: parameters do: 1e-2 residual units is 0.1 mm of head path or 0.1 mrad of joint angle over all
#: samples together, a fifteenth of one encoder count. This is what judges a parameter free alone.
ABSOLUTE_SENSITIVITY = 1e-2
#: Components above this magnitude of a flat direction's singular vector name the partners a
#: frozen parameter is confused with (below it a parameter barely takes part).
PARTNER_LOADING = 0.1


# ----------------------------------------------------------------------------------------------
# Per-run findings.


@dataclass(frozen=True)
class SampleGap:
    """One sample interval longer than :data:`GAP_FACTOR` x the run's median interval.

    Attributes:
        t_s: time of the last sample before the gap [s] (the run's own clock).
        interval_s: the interval from it to the next sample [s].
    """

    t_s: float
    interval_s: float


@dataclass(frozen=True)
class Dropouts:
    """Motion-capture dropouts: runs of NaN in ``head_x``/``head_y``.

    Attributes:
        count: number of separate dropouts.
        longest_s: the longest one [s], from its first missing sample to the next sample that
            has the head (or past the run's end by one median interval).
        longest_at_s: time of the longest one's first missing sample [s].
        fraction: fraction of the run's samples without the head, in [0, 1].
        joint_only: no sample has the head (a run recorded without motion capture): not a
            dropout; its head channel is simply left out of fits and comparisons.
    """

    count: int = 0
    longest_s: float = 0.0
    longest_at_s: float = float("nan")
    fraction: float = 0.0
    joint_only: bool = False

    @property
    def minor(self) -> bool:
        """Routine: none longer than :data:`DROPOUT_LONG_S`, under :data:`DROPOUT_FRACTION` in all."""
        return self.longest_s <= DROPOUT_LONG_S and self.fraction <= DROPOUT_FRACTION

    def describe(self) -> str:
        """One clause in words."""
        return (f"{self.count} motion-capture dropout{'s' if self.count > 1 else ''} of the head "
                f"(head_x/head_y NaN), longest {self.longest_s:.2f} s at {self.longest_at_s:.2f} s, "
                f"{100 * self.fraction:.1f} % of the samples")


@dataclass(frozen=True)
class JointSaturation:
    """A joint that is at its URDF limit, or that stays flat while its command moves.

    Attributes:
        joint: joint number, 1..11 from the head.
        kind: ``"limit"`` (samples within :data:`LIMIT_MARGIN_RAD` of a limit) or ``"flat"``
            (measured peak-to-peak below :data:`FLAT_RATIO` of the commanded one).
        measured_swing_rad: measured peak-to-peak [rad].
        commanded_swing_rad: commanded peak-to-peak [rad].
        at_limit_fraction: fraction of the samples at a limit (``"limit"``; else 0).
        at_limit_first_s: time of the first sample at a limit [s] (``"limit"``; else NaN).
        limit_rad: the limit it reaches [rad] (``"limit"``; else NaN).
    """

    joint: int
    kind: str
    measured_swing_rad: float
    commanded_swing_rad: float
    at_limit_fraction: float = 0.0
    at_limit_first_s: float = float("nan")
    limit_rad: float = float("nan")

    def describe(self) -> str:
        """One clause in words."""
        if self.kind == "limit":
            return (f"joint {self.joint} at its limit {self.limit_rad:+.3f} rad for "
                    f"{100 * self.at_limit_fraction:.1f} % of the samples (first at {self.at_limit_first_s:.2f} s)")
        return (f"joint {self.joint} keeps under half its commanded swing: it swings {self.measured_swing_rad:.3f} "
                f"rad of {self.commanded_swing_rad:.3f} rad "
                f"({100 * self.measured_swing_rad / self.commanded_swing_rad:.0f} %; a clamp, a stall, a broken "
                "encoder, or a gait faster than the servo follows)")


@dataclass(frozen=True)
class RunFindings:
    """What is wrong with one run, found without simulating it.

    Attributes:
        name: the run's file (or ``run N`` for a run not read from a file).
        duration_s: ``t[-1] - t[0]`` [s].
        samples: number of samples.
        median_dt_s: median sample interval [s] (NaN for one sample).
        too_short: shorter than the minimum duration the check was given.
        min_duration_s: that minimum [s].
        gaps: the sample-rate gaps, in time order.
        dropouts: the head's motion-capture dropouts.
        saturated: joints at a limit or flat, by joint number.
        motion_profile: the recording's servo Profile Velocity and Profile Acceleration (raw
            register values, from the sidecar's ``bus.servo``) when either is not 0, else None:
            the servos then ramped to each goal, which the simulated servo (a step to each
            goal) does not.
    """

    name: str
    duration_s: float
    samples: int
    median_dt_s: float
    too_short: bool
    min_duration_s: float = MIN_DURATION_S
    gaps: tuple[SampleGap, ...] = ()
    dropouts: Dropouts = field(default_factory=Dropouts)
    saturated: tuple[JointSaturation, ...] = ()
    motion_profile: tuple[int, int] | None = None

    @property
    def clean(self) -> bool:
        """Nothing found."""
        return not (self.too_short or self.gaps or self.dropouts.count or self.saturated or self.motion_profile)

    @property
    def has_problems(self) -> bool:
        """Something found beyond minor dropouts (:attr:`Dropouts.minor`)."""
        return bool(self.too_short or self.gaps or self.saturated or self.motion_profile
                    or (self.dropouts.count and not self.dropouts.minor))

    @property
    def saturated_joints(self) -> tuple[int, ...]:
        """Joint numbers with any saturation finding, increasing."""
        return tuple(sorted({s.joint for s in self.saturated}))

    def problems(self, *, minor_dropouts: bool = True) -> list[str]:
        """One line per kind of finding, each naming the run (minor dropouts only if ``minor_dropouts``)."""
        out = []
        if self.too_short:
            out.append(f"{self.name}: too short: {self.duration_s:.2f} s, the fit's first horizon is "
                       f"{self.min_duration_s:g} s")
        if self.gaps:
            shown = ", ".join(f"{g.t_s:.2f} s ({g.interval_s:.3f} s)" for g in self.gaps[:5])
            more = f" and {len(self.gaps) - 5} more" if len(self.gaps) > 5 else ""
            out.append(f"{self.name}: {len(self.gaps)} gap{'s' if len(self.gaps) > 1 else ''} in the sample rate "
                       f"(intervals over {GAP_FACTOR:g} x the median {self.median_dt_s:.4g} s) at {shown}{more}")
        d = self.dropouts
        if d.count and (minor_dropouts or not d.minor):
            out.append(f"{self.name}: {d.describe()}")
        for s in self.saturated:
            out.append(f"{self.name}: {s.describe()}")
        if self.motion_profile:
            out.append(f"{self.name}: recorded with a servo motion profile (Profile Velocity "
                       f"{self.motion_profile[0]}, Profile Acceleration {self.motion_profile[1]}): the servos "
                       f"ramped to each goal, the simulated servo steps to it; the model lags less than the "
                       f"robot did (record with both at 0 to compare like with like)")
        return out

    def to_json_dict(self) -> dict[str, Any]:
        return {"name": self.name, "duration_s": self.duration_s, "samples": self.samples,
                "median_dt_s": _finite(self.median_dt_s), "too_short": self.too_short,
                "gap_count": len(self.gaps),
                "gaps": [{"t_s": g.t_s, "interval_s": g.interval_s} for g in self.gaps],
                "dropouts": {"count": self.dropouts.count, "longest_s": self.dropouts.longest_s,
                             "longest_at_s": _finite(self.dropouts.longest_at_s),
                             "fraction": self.dropouts.fraction, "joint_only": self.dropouts.joint_only},
                "saturated_joints": [{"joint": s.joint, "kind": s.kind,
                                      "measured_swing_rad": s.measured_swing_rad,
                                      "commanded_swing_rad": s.commanded_swing_rad,
                                      "at_limit_fraction": s.at_limit_fraction,
                                      "at_limit_first_s": _finite(s.at_limit_first_s),
                                      "limit_rad": _finite(s.limit_rad)} for s in self.saturated],
                "motion_profile": None if self.motion_profile is None else
                {"profile_velocity": self.motion_profile[0], "profile_acceleration": self.motion_profile[1]}}


def joint_limits(model: CobraModel | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(lower, upper) position limits [rad] of joints 1..11 from the URDF (Pinocchio's model)."""
    model = model or CobraModel.load()
    pm = model.pin_model
    idx = [pm.joints[pm.getJointId(name)].idx_q for name in model.joint_names]
    return np.asarray(pm.lowerPositionLimit)[idx].copy(), np.asarray(pm.upperPositionLimit)[idx].copy()


def inspect_run(run: Run, name: str | None = None, *, limits: tuple[np.ndarray, np.ndarray] | None = None,
                min_duration_s: float = MIN_DURATION_S) -> RunFindings:
    """Gaps, dropouts, saturated joints and length of one run (no simulation).

    Args:
        run: a validated run.
        name: how messages name it (default: its source file, else ``"run"``).
        limits: (lower, upper) joint limits [rad], (11,) each (default: :func:`joint_limits`).
        min_duration_s: shorter runs are too short [s].

    Returns:
        RunFindings; thresholds are :data:`GAP_FACTOR`, :data:`LIMIT_MARGIN_RAD`,
        :data:`FLAT_RATIO` and :data:`MIN_COMMAND_SWING_RAD` (see their notes).
    """
    name = name or str(run.source or "run")
    t = run.t
    dt = np.diff(t)
    median = float(np.median(dt)) if dt.size else float("nan")
    gaps = tuple(SampleGap(float(t[i]), float(dt[i])) for i in np.flatnonzero(dt > GAP_FACTOR * median))
    lower, upper = limits if limits is not None else joint_limits()
    saturated = []
    for j in range(run.q.shape[1]):
        q, q_ref = run.q[:, j], run.q_ref[:, j]
        swing, commanded = float(np.ptp(q)), float(np.ptp(q_ref))
        low = np.isfinite(lower[j]) & (q <= lower[j] + LIMIT_MARGIN_RAD)
        high = np.isfinite(upper[j]) & (q >= upper[j] - LIMIT_MARGIN_RAD)
        at = low | high
        if at.any():
            first = int(np.flatnonzero(at)[0])
            saturated.append(JointSaturation(j + 1, "limit", swing, commanded, float(at.mean()), float(t[first]),
                                             float(lower[j] if low[first] else upper[j])))
        if commanded >= MIN_COMMAND_SWING_RAD and swing < FLAT_RATIO * commanded:
            saturated.append(JointSaturation(j + 1, "flat", swing, commanded))
    return RunFindings(name, run.duration, run.n_samples, median, run.duration < min_duration_s, min_duration_s,
                       gaps, _dropouts(t, run.head_pos, median), tuple(saturated), _motion_profile(run.meta))


def _motion_profile(meta: Mapping[str, Any]) -> tuple[int, int] | None:
    """The sidecar's servo Profile Velocity and Acceleration (``bus.servo``, as ``cobra record``
    writes it) when either is set (not 0); None when both are 0 or the sidecar does not say."""
    bus = meta.get("bus")
    servo = bus.get("servo") if isinstance(bus, Mapping) else None
    if not isinstance(servo, Mapping):
        return None
    velocity, acceleration = servo.get("profile_velocity", 0), servo.get("profile_acceleration", 0)
    if not all(isinstance(x, (int, float)) for x in (velocity, acceleration)) or (velocity, acceleration) == (0, 0):
        return None
    return int(velocity), int(acceleration)


def _dropouts(t: np.ndarray, head_pos: np.ndarray, median_dt: float) -> Dropouts:
    missing = np.isnan(head_pos[:, 0]) | np.isnan(head_pos[:, 1])
    if not missing.any():
        return Dropouts()
    if missing.all():
        return Dropouts(fraction=1.0, joint_only=True)
    edges = np.diff(np.concatenate([[0], missing.astype(int), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)   # ends: first sample after
    step = median_dt if math.isfinite(median_dt) else 0.0
    lengths = np.array([t[e] - t[s] if e < t.size else t[-1] - t[s] + step for s, e in zip(starts, ends)])
    k = int(np.argmax(lengths))
    return Dropouts(int(starts.size), float(lengths[k]), float(t[starts[k]]), float(missing.mean()))


# ----------------------------------------------------------------------------------------------
# Identifiability.


@dataclass(frozen=True)
class ParameterCheck:
    """How well the runs pin down one free parameter.

    Attributes:
        name, unit, value: the parameter (value in its unit).
        sensitivity: its Jacobian column norm [residual units per unit coordinate]: how far a
            move across its whole range moves the residuals, in the linear picture.
        excitation: ``sensitivity`` relative to the largest parameter's, in [0, 1].
        flat_loading: its largest component in a flat direction of the whole Jacobian (0 when
            there is none); above :data:`FLAT_LOADING` it takes part in that direction.
        frozen: the check freezes it.
        reason: why it cannot be pinned down, one clause ("" when it can).
    """

    name: str
    unit: str
    value: float
    sensitivity: float
    excitation: float
    flat_loading: float
    frozen: bool
    reason: str = ""

    def sentence(self) -> str:
        """``"name: reason"``, or ``"name: identifiable"``."""
        return f"{self.name}: {self.reason or 'identifiable'}"


@dataclass(frozen=True)
class Identifiability:
    """What one unit-coordinate Jacobian of the residuals says about the free parameters.

    Attributes:
        horizon_s: the horizon it was made on [s] (each run's first ``horizon_s``).
        run_count: number of runs.
        residual_count: number of residuals (rows).
        singular_values: singular values of the whole Jacobian, decreasing.
        rank: numerical rank: singular values above :data:`FLAT_RELATIVE` x the largest.
        condition_number: largest over smallest singular value (inf when one is zero).
        parameters: one entry per free parameter, in table order.
    """

    horizon_s: float
    run_count: int
    residual_count: int
    singular_values: tuple[float, ...]
    rank: int
    condition_number: float
    parameters: tuple[ParameterCheck, ...]

    @property
    def frozen_names(self) -> tuple[str, ...]:
        """The parameters to freeze, in table order."""
        return tuple(p.name for p in self.parameters if p.frozen)

    def __getitem__(self, name: str) -> ParameterCheck:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(name)

    def summary(self) -> str:
        """One line: horizon, size, rank and condition number."""
        d = len(self.parameters)
        return (f"identifiability on the first {self.horizon_s:g} s of {self.run_count} run"
                f"{'s' if self.run_count != 1 else ''} ({self.residual_count} residuals, {d} free "
                f"parameter{'s' if d != 1 else ''}): rank {self.rank} of {d}, condition number "
                f"{self.condition_number:.3g} (in the parameters' unit coordinates)")

    def excitation_line(self) -> str:
        """One line: every parameter's excitation, largest first."""
        ranked = sorted(self.parameters, key=lambda p: -p.excitation)
        return "excitation (residual sensitivity relative to the largest): " + ", ".join(
            f"{p.name} {p.excitation:.2g}" for p in ranked)

    def to_json_dict(self) -> dict[str, Any]:
        return {"horizon_s": _finite(self.horizon_s), "run_count": self.run_count,
                "residual_count": self.residual_count,
                "singular_values": list(self.singular_values), "rank": self.rank,
                "condition_number": _finite(self.condition_number),
                "parameters": {p.name: {"unit": p.unit, "value": p.value, "sensitivity": p.sensitivity,
                                        "excitation": p.excitation, "flat_loading": p.flat_loading,
                                        "frozen": p.frozen, "reason": p.reason or "identifiable"}
                               for p in self.parameters}}


def unit_jacobian(objective: Objective, *, fd_step: float = FD_STEP) -> np.ndarray:
    """Forward finite-difference Jacobian (m, d) of the objective's residuals in unit coordinates.

    Made exactly as :func:`sysid.identification.lsq.fit_lsq` makes one: steps from
    :func:`sysid.identification.lsq.forward_steps` (inward at an upper bound, away from ``mu_s = mu_c``), the
    base and every perturbed parameter vector simulated in one batched
    :meth:`Objective.residuals` call, at the objective's parameter set; a probe that diverges is
    retaken on the other side (:func:`sysid.identification.lsq.retake_diverged`).

    Raises:
        SimulationDiverged: the simulation at the parameter set diverges, or a parameter's
            probes diverge on both sides of it (named: its slope cannot be measured).
    """
    params = objective.params
    z = params.to_unit()
    h = forward_steps(params, z, fd_step)

    def as_x(Z: np.ndarray) -> np.ndarray:
        return np.array([params.from_unit(zz).as_vector() for zz in np.atleast_2d(Z)])

    R = objective.residuals(as_x(np.vstack([z, z[None, :] + np.diag(h)])), "mask")
    if np.isnan(R[0]).any():
        objective.residuals(as_x(z))  # raises, naming the time and what diverged
    rows = run(retake_diverged(lambda Z, divergence: Evaluate(objective, as_x(Z), divergence), params, z, h, R[1:]))
    unstable = [params.free_names[j] for j in np.flatnonzero(np.isnan(rows).any(axis=1))]
    if unstable:
        raise SimulationDiverged(f"the simulation diverges when {_and(unstable)} is stepped by {fd_step:g} of its "
                                 "range either way from its value: its effect on these runs cannot be measured; "
                                 "start from other values")
    return ((rows - R[0][None, :]) / h[:, None]).T


def analyse_jacobian(J: np.ndarray, params: ModelParameters, *, horizon_s: float = float("nan"),
                     run_count: int = 0, flat_relative: float = FLAT_RELATIVE,
                     excitation_relative: float = EXCITATION_RELATIVE,
                     absolute_sensitivity: float = ABSOLUTE_SENSITIVITY) -> Identifiability:
    """Rank, conditioning, excitation and the parameters to freeze, from one Jacobian.

    First every parameter whose column norm is below ``absolute_sensitivity`` or below
    ``excitation_relative`` x the largest is *not excited* and frozen. Then, while the Jacobian
    of the parameters left has a singular value below ``flat_relative`` x the largest singular
    value of the whole Jacobian, the parameter with the largest component in that flat direction
    is frozen (removing the column most aligned with the direction lifts its singular value the
    most), its reason naming the partners it is confused with. So of two parameters that enter
    only as a product one is frozen and the other stays free.

    Args:
        J: (m, d) residual Jacobian in the unit coordinates of ``params``' free parameters.
        params: the parameter set (its free parameters are the columns, in table order).
        horizon_s, run_count: what ``J`` was made on (reported only).
        flat_relative, excitation_relative, absolute_sensitivity: thresholds (module constants).

    Raises:
        InputError: ``J`` does not have one column per free parameter.
    """
    names = params.free_names
    J = np.asarray(J, dtype=float)
    if J.ndim != 2 or J.shape[1] != len(names):
        raise InputError(f"Jacobian of shape {J.shape} does not have one column per free parameter "
                         f"({', '.join(names)})")
    d = len(names)
    norms = np.linalg.norm(J, axis=0)
    top = float(norms.max()) if d else 0.0
    excitation = norms / top if top > 0 else np.zeros(d)
    s_all = np.linalg.svd(J, compute_uv=False) if J.size else np.zeros(0)
    s0 = float(s_all[0]) if s_all.size else 0.0
    flat_all = s_all < flat_relative * s0 if s0 > 0 else np.ones(s_all.size, dtype=bool)
    loading = np.zeros(d)
    if s0 > 0 and flat_all.any():
        _, _, Vt = np.linalg.svd(J, full_matrices=False)
        loading = np.abs(Vt[flat_all]).max(axis=0)
    elif s0 == 0:
        loading = np.ones(d)
    reasons: dict[int, str] = {}
    for j in range(d):
        p = params[names[j]]
        if norms[j] < absolute_sensitivity:
            reasons[j] = (f"not excited by these runs: moving it across its whole range [{p.min:.4g}, {p.max:.4g}]"
                          f"{_unit(p.unit)} changes the residuals by {norms[j]:.2g} residual units (below "
                          f"{absolute_sensitivity:g})")
        elif norms[j] < excitation_relative * top:
            reasons[j] = (f"not excited by these runs: its residual sensitivity is {excitation[j]:.2g} of the "
                          f"largest parameter's ({names[int(np.argmax(norms))]})")
    keep = [j for j in range(d) if j not in reasons]
    while len(keep) > 1 and s0 > 0:
        _, s, Vt = np.linalg.svd(J[:, keep], full_matrices=False)
        if s[-1] >= flat_relative * s0:
            break
        v = np.abs(Vt[-1])
        i = int(np.argmax(v))
        order = [k for k in np.argsort(-v, kind="stable") if k != i]
        partners = [names[keep[k]] for k in order if v[k] > PARTNER_LOADING] or [names[keep[order[0]]]]
        how = (f"in nearly the same way as {partners[0]}" if len(partners) == 1
               else f"nearly as a combination of {_and(partners)} does")
        reasons[keep[i]] = (f"moves the residuals {how} (flat direction, singular value {s[-1] / s0:.2g} of the "
                            f"largest)")
        del keep[i]
    rank = int(np.sum(~flat_all)) if s0 > 0 else 0
    cond = float(s_all[0] / s_all[-1]) if s_all.size and s_all[-1] > 0 else float("inf")
    checks = tuple(ParameterCheck(n, params[n].unit, params.value(n), float(norms[j]), float(excitation[j]),
                                  float(loading[j]), j in reasons, reasons.get(j, ""))
                   for j, n in enumerate(names))
    return Identifiability(float(horizon_s), int(run_count), int(J.shape[0]), tuple(float(x) for x in s_all),
                           rank, cond, checks)


# ----------------------------------------------------------------------------------------------
# The report.


@dataclass(frozen=True)
class DataCheck:
    """The data check: per-run findings, identifiability, and what is fatal.

    Attributes:
        runs: findings of the runs the fit would train on (in order).
        held_out: findings of held-out runs (data only: they take no part in the Jacobian).
        identifiability: the Jacobian's verdict, or None when it was not made (a fatal problem
            found before it).
        fatal: problems no freezing can cure, one line each; empty when the data can be fitted.
    """

    runs: tuple[RunFindings, ...]
    held_out: tuple[RunFindings, ...] = ()
    identifiability: Identifiability | None = None
    fatal: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """The data can be fitted (possibly with :attr:`frozen_names` frozen)."""
        return not self.fatal

    @property
    def frozen_names(self) -> tuple[str, ...]:
        """The free parameters the runs cannot pin down, to freeze (table order)."""
        return self.identifiability.frozen_names if self.identifiability else ()

    def reason(self, name: str) -> str:
        """Why ``name`` is frozen (its one clause)."""
        if self.identifiability is None:
            raise KeyError(name)
        return self.identifiability[name].reason

    def messages(self, *, parameters: bool = True) -> list[str]:
        """Human lines: each run's problems (minor dropouts summed up in one line), the
        identifiability summary and (``parameters``) one sentence per parameter that cannot be
        pinned down, then any fatal problem."""
        every = self.runs + self.held_out
        total = len(every)
        lines = [f"data check: {total} run{'s' if total != 1 else ''}, "
                 f"{sum(f.has_problems for f in every)} with problems"]
        lines += [line for f in self.runs for line in f.problems(minor_dropouts=False)]
        lines += [f"held out {line}" for f in self.held_out for line in f.problems(minor_dropouts=False)]
        minor = [f for f in every if f.dropouts.count and f.dropouts.minor]
        if minor:
            worst = max(minor, key=lambda f: f.dropouts.longest_s)
            runs = f"{len(minor)} run{'s' if len(minor) > 1 else ''}"
            lines.append(f"minor motion-capture dropouts of the head in {runs} "
                         f"(none over {DROPOUT_LONG_S:g} s, each run under {100 * DROPOUT_FRACTION:.0f} % of its "
                         f"samples): longest {worst.dropouts.longest_s:.2f} s in {worst.name}, at most "
                         f"{100 * max(f.dropouts.fraction for f in minor):.1f} % of a run")
        joint_only = [f.name for f in every if f.dropouts.joint_only]
        if joint_only:
            lines.append(f"joint-only run{'s' if len(joint_only) > 1 else ''} (no head pose in any sample, recorded "
                         f"without motion capture; the head channel is left out): {', '.join(joint_only)}")
        ident = self.identifiability
        if ident is not None:
            lines.append(ident.summary())
            lines.append(ident.excitation_line())
            if parameters:
                lines += [f"cannot be pinned down: {p.sentence()}" for p in ident.parameters if p.frozen]
                if not ident.frozen_names:
                    lines.append("every free parameter can be pinned down by these runs")
        lines += [f"FATAL: {f}" for f in self.fatal]
        return lines

    def to_json_dict(self) -> dict[str, Any]:
        return {"ok": self.ok, "fatal": list(self.fatal), "frozen": list(self.frozen_names),
                "reasons": {n: self.reason(n) for n in self.frozen_names},
                "runs": [f.to_json_dict() for f in self.runs],
                "held_out": [f.to_json_dict() for f in self.held_out],
                "identifiability": self.identifiability.to_json_dict() if self.identifiability else None,
                "messages": self.messages()}


def check_runs(runs: Sequence[Run], params: ModelParameters, *, horizon_s: float = 3.0, threads: int = 1,
               held_out: Sequence[Run] = (), weights: Weights | None = None, settings: SimSettings | None = None,
               min_duration_s: float = MIN_DURATION_S, names: Sequence[str] | None = None) -> DataCheck:
    """Check runs before fitting the free parameters of ``params`` on them.

    Per run (:func:`inspect_run`): gaps, dropouts, saturated joints, too-short runs. Then one
    unit-coordinate Jacobian (:func:`unit_jacobian`) of the objective
    ``Objective(runs, params, weights, settings, threads=threads)`` truncated to each run's
    first ``horizon_s`` seconds, and its analysis (:func:`analyse_jacobian`). 3 s is the
    continuation's second stage in :func:`sysid.identification.lsq.fit_lsq`: long enough for the ground to
    shape the head path, short enough that the Jacobian costs about a second per 10 run-seconds
    and parameter, and that the residuals are still nearly linear in the parameters.

    Fatal (:attr:`DataCheck.ok` False): no runs; no run at least ``min_duration_s`` long (then
    no Jacobian is made); every free parameter unidentifiable.

    Args:
        runs: the training runs.
        params: parameter set; its free parameters are judged.
        horizon_s: horizon of the Jacobian [s] (> 0).
        threads: threads of the batched evaluation (1 when other work shares the cores).
        held_out: runs inspected for data findings only.
        weights, settings: of the objective (defaults: :class:`Weights`, :class:`SimSettings`).
        min_duration_s: shorter runs are too short [s].
        names: how messages name the runs (default: their source files, else ``run N``).

    Raises:
        InputError: ``horizon_s`` not positive, or no free parameter in ``params``.
        SimulationDiverged: the nominal simulation of a run diverges, or a parameter's probes
            diverge on both sides of its value (:func:`unit_jacobian`).
    """
    if not (horizon_s > 0 and math.isfinite(horizon_s)):
        raise InputError(f"horizon must be a positive number of seconds, got {horizon_s}")
    if not params.free_names:
        raise InputError("every parameter is frozen: nothing to check")
    limits = joint_limits()
    names = list(names) if names is not None else [str(r.source) if r.source else f"run {i + 1}"
                                                     for i, r in enumerate(runs)]
    found = tuple(inspect_run(r, n, limits=limits, min_duration_s=min_duration_s) for r, n in zip(runs, names))
    held = tuple(inspect_run(r, str(r.source) if r.source else f"held-out run {i + 1}", limits=limits,
                             min_duration_s=min_duration_s) for i, r in enumerate(held_out))
    if not runs:
        return DataCheck(found, held, None, ("no training runs given",))
    if all(f.too_short for f in found):
        lengths = ", ".join(f"{f.name} {f.duration_s:.2f} s" for f in found)
        return DataCheck(found, held, None, (f"no run is long enough to fit (at least {min_duration_s:g} s): "
                                             f"{lengths}",))
    objective = Objective(list(runs), params, weights or Weights(), settings,
                          threads=threads).truncated(horizon_s)
    J = unit_jacobian(objective)
    ident = analyse_jacobian(J, params, horizon_s=min(horizon_s, max(f.duration_s for f in found)),
                             run_count=len(runs))
    fatal: tuple[str, ...] = ()
    if len(ident.frozen_names) == len(params.free_names):
        fatal = (_nothing_left(ident),)
    return DataCheck(found, held, ident, fatal)


def apply(check: DataCheck, params: ModelParameters) -> ModelParameters:
    """``params`` with the parameters the check could not pin down frozen (at their values).

    Raises:
        InputError: freezing them would leave nothing free (names every parameter and why), or
            the check names a parameter ``params`` does not have.
    """
    names = check.frozen_names
    if not names:
        return params
    if not [n for n in params.free_names if n not in names]:
        raise InputError(_nothing_left(check.identifiability))
    return params.with_frozen(frozen=names)


def _nothing_left(ident: Identifiability | None) -> str:
    parts = "; ".join(p.sentence() for p in ident.parameters if p.frozen) if ident else ""
    return f"no free parameter can be pinned down by these runs: {parts}"


def _finite(x: float) -> float | None:
    """JSON has no NaN or infinity: those become null."""
    return float(x) if math.isfinite(x) else None


def _unit(unit: str) -> str:
    return "" if unit in ("", "1") else f" {unit}"


def _and(items: Sequence[str]) -> str:
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"
