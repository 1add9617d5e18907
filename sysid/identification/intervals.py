"""Parameter intervals that allow for autocorrelated residuals, and a residual whiteness test.

The Gauss-Newton covariance ``sigma^2 (J^T J)^-1`` assumes every residual is an independent
draw. The identification residuals are time series: per run, per channel (head x, head y, 11
joints), one sample every ``1 / Weights.sample_hz`` seconds. Whatever lasts longer than one
sample (motion-capture error that wanders, a missing effect) correlates neighbouring residuals,
and the Gauss-Newton interval is then too narrow by about ``sqrt(1 + 2 sum_k rho_k)``.

:func:`sandwich_covariance` replaces it with the heteroscedasticity and autocorrelation
consistent (HAC) sandwich of Newey and West (1987),

    cov = m / (m - d)  (J^T J)^-1  Omega  (J^T J)^-1,
    Omega = sum_runs [ G_0 + sum_{l >= 1} w_l (G_l + G_l^T) ],
    G_l = sum_t s_t s_{t-l}^T,   s_t = sum_channels J_{t,c}^T r_{t,c},

(with the prewhitening below) over the *scores* ``s_t`` (what sample time ``t`` of a run
contributes to the gradient ``J^T r``). Choices, and why:

- **One score series per run, summed over its channels.** Runs are separate experiments with
  independent noise, so there is no covariance between runs. Within a run the channels share
  one robot: a mismatch that bends the head path also bends the joints at the same moment, so
  the channels of one run are summed per sample time before the autocovariances are taken
  (Driscoll and Kraay, 1998). This keeps the cross-channel covariances that separate
  per-channel series would drop, and costs nothing when the channels are independent.
- **Bartlett weights** ``w_l = 1 - l / b`` for ``l < b``: they keep ``Omega`` positive
  semi-definite (Newey and West, 1987).
- **VAR(1) prewhitening** (Andrews and Monahan, 1992): the kernel estimate is taken of the
  innovations ``e_t = s_t - A s_{t-1}`` of a first-order vector autoregression fitted to the
  scores (pooled over runs), then recoloured, ``Omega = (I - A)^-1 Omega_e (I - A)^-T``. A
  run is a few dozen samples long, and a kernel estimate over so few samples of a persistent
  series (a drift lasting several samples) is biased low by the lags it down-weights or cuts
  off; the autoregression carries that persistence at every lag instead. ``A``'s singular
  values are capped at :data:`RHO_CAP` (as Andrews and Monahan do) so that ``I - A`` stays
  invertible. With white scores ``A`` is near zero and nothing changes.
- **Bandwidth** ``b`` by Andrews' (1991) AR(1) plug-in rule for the Bartlett kernel,
  ``b = 1.1447 (alpha T)^(1/3)``, ``alpha`` from first-order autoregressions of every
  component of the (prewhitened) scores, pooled over runs, and ``T`` the mean run length in
  samples: it minimises the asymptotic mean squared error of ``Omega``, grows with the
  measured correlation and falls to one lag (no autocorrelation terms) when the series is
  white, so that white residuals get the Gauss-Newton interval back. ``b`` is capped at ``T``.
- ``m / (m - d)``: the usual small-sample factor for ``d`` fitted parameters (as in
  ``sigma^2 = r.r / (m - d)``).

:func:`whiteness` is the pooled Ljung-Box (1978) test on every channel series of every run,
each normalised by its own root mean square. Residuals that are not white mean the model
leaves structure in them; then no interval computed from the residuals alone is trustworthy:
the fitted values are the best compromise of a wrong model, and the HAC interval accounts for
autocorrelation of stationary noise only.

Measured (``benchmarks/interval_coverage.py``, ``benchmarks/results/coverage.md``): on this
project's simulated runs with the reference dataset's measurement noise the residuals at the
default 10 Hz are close to white (lag-1 autocorrelation within +-0.07), the bandwidth falls to
one sample and both intervals cover 90-95 % over 20 recoveries. The HAC interval is for
residuals that are not white, as in the AR(1) regression of ``tests/test_intervals.py``
(there the naive interval covers 74 %, the HAC interval 93 %).

Units: ``J`` and ``r`` in the objective's residual units per unit coordinate (see
:mod:`sysid.identification.lsq`); covariances come back in squared unit coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy import stats

#: Ljung-Box significance level below which the residuals are declared not white: 1 %, so that
#: a fit on residuals that are white is wrongly warned about once in a hundred fits.
WHITENESS_ALPHA = 0.01
#: Mean lag-1 autocorrelation of the residual series above which a significant Ljung-Box test
#: counts as "not white". Ljung-Box alone flags correlations far too weak to matter once there
#: are thousands of residuals (quantised encoders on a slow joint are enough). An AR(1) error
#: with rho = 0.1 widens the interval of a sum by sqrt((1 + rho) / (1 - rho)) = 1.105, so a
#: 95 % interval that ignored it would still cover 92.5 %: weaker correlation does not change
#: what an interval means by more than a coverage check of tens of fits can resolve.
MIN_LAG1 = 0.1
#: Largest first-order autocorrelation magnitude the bandwidth rule uses, and largest singular
#: value of the prewhitening autoregression: Andrews' ``alpha`` and ``(I - A)^-1`` diverge as
#: rho -> 1 (a unit root has no finite long-run variance); 0.97 is Andrews and Monahan's bound.
RHO_CAP = 0.97


def check_blocks(m: int, blocks: Sequence[np.ndarray]) -> None:
    """Raise ValueError unless ``blocks`` are 2-D integer index arrays into a vector of ``m``
    residuals, each index used at most once."""
    seen = np.zeros(m, dtype=bool)
    for b in blocks:
        b = np.asarray(b)
        if b.ndim != 2 or not np.issubdtype(b.dtype, np.integer):
            raise ValueError(f"a residual block must be a 2-D integer array (samples, channels), got {b.dtype} "
                             f"of shape {b.shape}")
        if b.size and (b.min() < 0 or b.max() >= m):
            raise ValueError(f"a residual block indexes outside the {m} residuals")
        if seen[b.ravel()].any() or len(np.unique(b)) != b.size:
            raise ValueError("residual blocks overlap")
        seen[b.ravel()] = True


def scores(J: np.ndarray, r: np.ndarray, blocks: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Per run, the ``(S, d)`` score series ``s_t = sum_c J[i_tc]^T r[i_tc]``.

    Args:
        J: ``(m, d)`` residual Jacobian.
        r: ``(m,)`` residuals.
        blocks: per run, ``(S, C)`` indices of its residuals: row = sample time, column =
            channel (:func:`sysid.identification.objective.residual_blocks`).
    """
    return [np.einsum("tcd,tc->td", J[b], r[b]) for b in map(np.asarray, blocks)]


def bartlett_bandwidth(series: Sequence[np.ndarray]) -> float:
    """Andrews' (1991) AR(1) plug-in bandwidth [samples] of the Bartlett kernel.

    Args:
        series: per run, an ``(S, d)`` multivariate time series (the scores).

    Returns:
        ``b = 1.1447 (alpha T)^(1/3)``, capped at the mean length ``T``, with
        ``alpha = sum_a 4 rho_a^2 s_a^4 / ((1 - rho_a)^6 (1 + rho_a)^2) / sum_a s_a^4 / (1 - rho_a)^4``
        over the components ``a`` whose AR(1) fit ``x_t = rho_a x_{t-1} + e`` (pooled over the
        runs) has innovation variance ``s_a^2 > 0``.
    """
    series = [np.asarray(s, dtype=float) for s in series if len(s) > 1]
    if not series:
        return 1.0
    T = float(np.mean([len(s) for s in series]))
    lead = np.concatenate([s[1:] for s in series])
    lag = np.concatenate([s[:-1] for s in series])
    den = np.sum(lag * lag, axis=0)
    ok = den > 0
    if not ok.any():
        return 1.0
    rho = np.clip(np.sum(lead * lag, axis=0)[ok] / den[ok], -RHO_CAP, RHO_CAP)
    innov = np.mean((lead[:, ok] - rho * lag[:, ok]) ** 2, axis=0)
    keep = innov > 0
    if not keep.any():
        return 1.0
    rho, s4 = rho[keep], innov[keep] ** 2
    alpha = np.sum(4 * rho ** 2 * s4 / ((1 - rho) ** 6 * (1 + rho) ** 2)) / np.sum(s4 / (1 - rho) ** 4)
    return float(min(max(1.1447 * (alpha * T) ** (1.0 / 3.0), 1.0), T))


def long_run_covariance(series: Sequence[np.ndarray], bandwidth: float) -> np.ndarray:
    """Newey-West estimate ``sum_runs [G_0 + sum_l w_l (G_l + G_l^T)]`` with Bartlett weights
    ``w_l = 1 - l / bandwidth`` (``l < bandwidth``) of the variance of the summed series.

    Args:
        series: per run, an ``(S, d)`` time series; runs are taken as independent.
        bandwidth: ``b`` [samples]; ``b <= 1`` keeps only ``G_0`` (no autocorrelation).
    """
    d = np.asarray(series[0]).shape[1]
    out = np.zeros((d, d))
    for s in series:
        if len(s) == 0:
            continue
        s = np.asarray(s, dtype=float)
        out += s.T @ s
        for lag in range(1, min(int(np.ceil(bandwidth)), len(s))):
            w = 1.0 - lag / bandwidth
            g = s[lag:].T @ s[:-lag]
            out += w * (g + g.T)
    return out


def prewhiten(series: Sequence[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray]:
    """Innovations of a VAR(1) fitted to ``series`` pooled over runs, and its coefficients.

    Args:
        series: per run, an ``(S, d)`` time series.

    Returns:
        per run the ``(S - 1, d)`` innovations ``e_t = s_t - A s_{t-1}`` (t >= 1), and the
        ``(d, d)`` matrix ``A`` (least squares over every run's consecutive pairs, singular
        values capped at :data:`RHO_CAP`; zero when there are too few pairs to fit it).
    """
    series = [np.asarray(s, dtype=float) for s in series]
    d = series[0].shape[1]
    pairs = [s for s in series if len(s) > 1]
    A = np.zeros((d, d))
    if sum(len(s) - 1 for s in pairs) > d:
        lead = np.concatenate([s[1:] for s in pairs])
        lag = np.concatenate([s[:-1] for s in pairs])
        A = np.linalg.lstsq(lag, lead, rcond=None)[0].T
        U, sv, Vt = np.linalg.svd(A)
        A = (U * np.minimum(sv, RHO_CAP)) @ Vt
    return [s[1:] - s[:-1] @ A.T for s in pairs], A


@dataclass(frozen=True)
class SandwichEstimate:
    """The HAC covariance of the unit coordinates and how it was obtained.

    Attributes:
        cov: ``(d, d)`` covariance [squared unit coordinates].
        bandwidth: Bartlett bandwidth used [samples].
        bandwidth_s: the same in seconds (samples / sample rate), NaN when the rate is unknown.
        persistence: largest singular value of the prewhitening autoregression ``A`` (0: none).
    """

    cov: np.ndarray
    bandwidth: float
    bandwidth_s: float = float("nan")
    persistence: float = 0.0


def sandwich_covariance(J: np.ndarray, r: np.ndarray, blocks: Sequence[np.ndarray], JtJ_pinv: np.ndarray, *,
                        bandwidth: float | None = None, prewhitened: bool = True,
                        sample_hz: float | None = None) -> SandwichEstimate:
    """HAC sandwich covariance ``(J^T J)^-1 Omega (J^T J)^-1`` (module docstring).

    Args:
        J: ``(m, d)`` residual Jacobian in unit coordinates.
        r: ``(m,)`` residuals at the fit.
        blocks: per run, ``(S, C)`` residual indices (row = sample time, column = channel);
            residuals in no block are left out of ``Omega``.
        JtJ_pinv: ``(d, d)`` (pseudo-)inverse of ``J^T J`` (flat directions zeroed by the caller).
        bandwidth: Bartlett bandwidth [samples]; default :func:`bartlett_bandwidth` of the
            (prewhitened) scores.
        prewhitened: VAR(1) prewhitening of the scores (:func:`prewhiten`); False gives the
            plain Newey-West estimate.
        sample_hz: residual sample rate [Hz], only to report the bandwidth in seconds.

    Raises:
        ValueError: if the blocks are not index arrays into ``r`` (:func:`check_blocks`).
    """
    m, d = J.shape
    check_blocks(m, blocks)
    s = scores(J, r, blocks)
    A = np.zeros((d, d))
    if prewhitened:
        s, A = prewhiten(s)
    b = bartlett_bandwidth(s) if bandwidth is None else float(bandwidth)
    omega = long_run_covariance(s, b)
    if prewhitened:
        recolour = np.linalg.inv(np.eye(d) - A)
        omega = recolour @ omega @ recolour.T
    cov = JtJ_pinv @ omega @ JtJ_pinv * (m / max(m - d, 1))
    return SandwichEstimate(0.5 * (cov + cov.T), b, b / sample_hz if sample_hz else float("nan"),
                            float(np.linalg.norm(A, 2)) if A.any() else 0.0)


@dataclass(frozen=True)
class Whiteness:
    """Pooled Ljung-Box test of the residuals' channel series.

    Attributes:
        statistic: ``Q = sum_series T (T + 2) sum_{k=1}^{h} rho_k^2 / (T - k)``.
        dof: degrees of freedom of its chi-squared law under whiteness (lags x series).
        p_value: probability of a ``Q`` at least this large if the residuals were white.
        lags: ``h``, lags per series.
        lag1: mean lag-1 autocorrelation over the series (0 when white, near 1 for a slow drift).
        series: number of channel series tested.
        white: ``p_value >= alpha`` or ``lag1 <= MIN_LAG1`` (:data:`MIN_LAG1`).
        verdict: one sentence for reports.
    """

    statistic: float
    dof: int
    p_value: float
    lags: int
    lag1: float
    series: int
    white: bool
    verdict: str

    def console_line(self) -> str:
        """``residuals: <verdict>``, prefixed ``WARNING:`` when the residuals are not white."""
        return f"{'' if self.white else 'WARNING: '}residuals: {self.verdict}"

    def to_json_dict(self) -> dict:
        return {"statistic": self.statistic, "dof": self.dof, "p_value": self.p_value, "lags": self.lags,
                "lag1_autocorrelation": self.lag1, "series": self.series, "white": self.white,
                "verdict": self.verdict}

    @classmethod
    def from_json_dict(cls, data: dict) -> "Whiteness":
        """Inverse of :meth:`to_json_dict`."""
        return cls(float(data["statistic"]), int(data["dof"]), float(data["p_value"]), int(data["lags"]),
                   float(data["lag1_autocorrelation"]), int(data["series"]), bool(data["white"]), str(data["verdict"]))


def _autocorrelation(x: np.ndarray, lags: int) -> tuple[np.ndarray, int]:
    """Autocorrelations at lags 1..``lags`` of ``x`` about zero, with NaN as missing samples, and
    the count of samples present. Each lag averages over the pairs present, normalised by the
    mean square. Not demeaned: residuals of a right model have zero mean, so an offset is
    structure to detect (and demeaning would bias every autocorrelation by -1/T)."""
    present = np.isfinite(x)
    n = int(present.sum())
    y = np.where(present, x, 0.0)
    var = float(np.sum(y * y)) / max(n, 1)
    out = np.zeros(lags)
    if var <= 0:
        return out, 0
    for k in range(1, lags + 1):
        both = present[k:] & present[:-k]
        if both.any():
            out[k - 1] = float(np.sum(y[k:] * y[:-k])) / int(both.sum()) / var
    return out, n


def whiteness(r: np.ndarray, blocks: Sequence[np.ndarray], *, lags: int | None = None,
              alpha: float = WHITENESS_ALPHA, min_lag1: float = MIN_LAG1,
              missing: np.ndarray | None = None) -> Whiteness:
    """Ljung-Box test of every channel series of every run, pooled: ``Q ~ chi2(h x series)``.

    The residuals count as not white when the test rejects at ``alpha`` *and* the mean lag-1
    autocorrelation exceeds ``min_lag1`` (the correlation is then both real and large enough
    to matter, :data:`MIN_LAG1`).

    Each series is normalised by its own root mean square (the test is scale free, so head [cm]
    and joint [0.01 rad] channels count alike) and not demeaned (:func:`_autocorrelation`); the
    series are taken as independent under whiteness, so their statistics add.

    Args:
        r: ``(m,)`` residuals.
        blocks: per run, ``(S, C)`` residual indices (row = sample time, column = channel).
        lags: ``h``; default ``min(10, T // 5)`` for the mean series length ``T``, at least 1
            (Hyndman and Athanasopoulos' rule for non-seasonal series: enough lags to see a
            correlation time of several samples, few enough that each is estimated from many
            pairs).
        alpha: significance level of the verdict.
        min_lag1: mean lag-1 autocorrelation a significant result must exceed.
        missing: ``(m,)`` booleans, residuals that are not measurements (motion-capture gaps,
            stored as 0): left out of the autocorrelations.

    Raises:
        ValueError: if the blocks are not index arrays into ``r`` (:func:`check_blocks`).
    """
    check_blocks(r.size, blocks)
    x = np.where(missing, np.nan, r) if missing is not None else np.asarray(r, dtype=float)
    blocks = [np.asarray(b) for b in blocks]
    T_mean = float(np.mean([len(b) for b in blocks])) if blocks else 0.0
    h = lags if lags is not None else max(1, min(10, int(T_mean) // 5))
    Q, n_series, lag1 = 0.0, 0, []
    for b in blocks:
        for c in range(b.shape[1]):
            rho, n = _autocorrelation(x[b[:, c]], h)
            if n <= h + 1:
                continue
            k = np.arange(1, h + 1)
            Q += n * (n + 2) * float(np.sum(rho ** 2 / (n - k)))
            n_series += 1
            lag1.append(rho[0])
    dof = h * n_series
    p = float(stats.chi2.sf(Q, dof)) if dof else float("nan")
    mean1 = float(np.mean(lag1)) if lag1 else float("nan")
    white = bool(not dof or p >= alpha or mean1 <= min_lag1)
    stats_text = f"Ljung-Box p = {p:.2g} over {n_series} series, mean lag-1 autocorrelation {mean1:.2f}"
    if not dof:
        verdict = "not tested: no residual series long enough"
    elif p >= alpha:
        verdict = f"white ({stats_text}): consistent with independent noise"
    elif white:
        verdict = (f"white enough ({stats_text}: detectable but at most {min_lag1:g} at lag 1, too weak to "
                   "change what the intervals mean)")
    else:
        verdict = (f"NOT white ({stats_text}): the intervals understate the uncertainty. The residuals keep "
                   "structure over time that the model does not explain (a missing effect, a bad start, or "
                   "measurement noise more coloured than the HAC interval allows for); with a wrong model the "
                   "fitted values are its best compromise, not the physical parameters")
    return Whiteness(float(Q), int(dof), p, int(h), mean1, n_series, white, verdict)
