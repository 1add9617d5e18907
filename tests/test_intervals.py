"""HAC intervals and the residual whiteness test (sysid.identification.intervals), and how a fit reports them."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobra_model import CobraModel, ModelParameters
from integrators.simulator import Simulator
from sysid.generators.dataset import RunPlan, record
from sysid.identification.intervals import (Whiteness, bartlett_bandwidth, check_blocks, long_run_covariance, prewhiten,
                             sandwich_covariance, whiteness)
from sysid.identification.lsq import fit_lsq
from sysid.identification.objective import Objective, Simulated, Weights, current_rows, residual_blocks, residual_vector


def ar1(rng: np.random.Generator, rho: float, shape: tuple[int, ...]) -> np.ndarray:
    """Stationary AR(1) series along axis 0, unit variance."""
    e = rng.normal(size=shape)
    out = np.empty(shape)
    out[0] = e[0]
    for t in range(1, shape[0]):
        out[t] = rho * out[t - 1] + np.sqrt(1 - rho * rho) * e[t]
    return out


def slope_coverage(rho: float, draws: int = 400, runs: int = 4, samples: int = 50,
                   channels: int = 2) -> tuple[float, float]:
    """Coverage of the true slope by the naive and the HAC 95 % intervals of the regression
    ``y = beta x + u``, ``x`` and ``u`` both AR(1) with ``rho`` in every (run, channel) series."""
    rng = np.random.default_rng(7)
    beta = 1.5
    m = runs * samples * channels
    blocks = [np.arange(k * samples * channels, (k + 1) * samples * channels).reshape(samples, channels)
              for k in range(runs)]
    naive = hac = 0
    for _ in range(draws):
        x = np.concatenate([ar1(rng, rho, (samples, channels)).ravel() for _ in range(runs)])
        u = np.concatenate([ar1(rng, rho, (samples, channels)).ravel() for _ in range(runs)])
        y = beta * x + u
        J = x[:, None]                                  # residual r(b) = b x - y
        inv = np.array([[1.0 / (x @ x)]])
        b = float(x @ y) * inv[0, 0]
        r = b * x - y
        std_naive = np.sqrt(float(r @ r) / (m - 1) * inv[0, 0])
        std_hac = np.sqrt(sandwich_covariance(J, r, blocks, inv).cov[0, 0])
        naive += abs(b - beta) <= 1.96 * std_naive
        hac += abs(b - beta) <= 1.96 * std_hac
    return naive / draws, hac / draws


def test_hac_interval_covers_under_autocorrelation_where_the_naive_one_does_not():
    """AR(1) regressor and error with rho = 0.7: the naive variance is low by about
    (1 + 0.49) / (1 - 0.49) = 2.9, i.e. nominal 95 % intervals cover about 75 %. Over 400
    draws a coverage's standard error is about 1.1 points, so the bounds are 4 to 6 of them
    away from those values."""
    naive, hac = slope_coverage(0.7)
    assert naive < 0.82
    assert 0.90 <= hac <= 0.99


def test_hac_interval_keeps_nominal_coverage_with_white_errors():
    naive, hac = slope_coverage(0.0)
    assert 0.91 <= naive <= 0.99 and 0.91 <= hac <= 0.99   # nominal 0.95, standard error 1.1 points


def test_white_scores_get_the_gauss_newton_variance_back():
    """With white residuals the bandwidth falls to one lag and the sandwich equals
    sigma^2 (J^T J)^-1 up to its sampling error (about 1 / sqrt(runs x samples) here)."""
    rng = np.random.default_rng(3)
    m, d = 4000, 2
    J = rng.normal(size=(m, d))
    r = rng.normal(size=m)
    blocks = [np.arange(k * 1000, (k + 1) * 1000).reshape(500, 2) for k in range(4)]
    inv = np.linalg.inv(J.T @ J)
    est = sandwich_covariance(J, r, blocks, inv, sample_hz=10.0)
    gn = inv * float(r @ r) / (m - d)
    assert est.bandwidth < 2.0 and est.bandwidth_s == pytest.approx(est.bandwidth / 10.0)
    assert np.diag(est.cov) == pytest.approx(np.diag(gn), rel=0.15)


def test_bandwidth_grows_with_persistence():
    rng = np.random.default_rng(0)
    white = [rng.normal(size=(100, 2)) for _ in range(3)]
    slow = [ar1(rng, 0.8, (100, 2)) for _ in range(3)]
    assert bartlett_bandwidth(white) < 2.0 < bartlett_bandwidth(slow) <= 100


def test_long_run_covariance_of_a_constant_series_counts_its_lags():
    """A constant series s_t = 1 over T samples: G_l = T - l, and Bartlett weights 1 - l / b."""
    s = [np.ones((10, 1))]
    assert long_run_covariance(s, 1.0)[0, 0] == pytest.approx(10.0)
    expected = 10 + 2 * sum((1 - lag / 3.0) * (10 - lag) for lag in (1, 2))
    assert long_run_covariance(s, 3.0)[0, 0] == pytest.approx(expected)


def test_prewhitening_recovers_the_autoregression():
    rng = np.random.default_rng(1)
    series = [ar1(rng, 0.6, (400, 1)) for _ in range(5)]
    innovations, A = prewhiten(series)
    assert A[0, 0] == pytest.approx(0.6, abs=0.05)
    assert [len(e) for e in innovations] == [399] * 5
    lead, lag = np.concatenate([e[1:] for e in innovations]), np.concatenate([e[:-1] for e in innovations])
    assert abs(float(np.sum(lead * lag) / np.sum(lag * lag))) < 0.05     # the innovations are white


def test_blocks_must_index_the_residuals_once():
    with pytest.raises(ValueError, match="overlap"):
        check_blocks(10, [np.arange(6).reshape(3, 2), np.arange(4, 8).reshape(2, 2)])
    with pytest.raises(ValueError, match="outside"):
        check_blocks(4, [np.arange(6).reshape(3, 2)])
    with pytest.raises(ValueError, match="2-D integer"):
        check_blocks(6, [np.arange(6.0)])


def series_blocks(runs: int, samples: int, channels: int) -> list[np.ndarray]:
    n = samples * channels
    return [np.arange(k * n, (k + 1) * n).reshape(samples, channels) for k in range(runs)]


def test_whiteness_accepts_white_and_flags_autocorrelated_residuals():
    rng = np.random.default_rng(11)
    blocks = series_blocks(3, 60, 13)
    white = whiteness(rng.normal(size=3 * 60 * 13), blocks)
    assert isinstance(white, Whiteness) and white.white and white.verdict.startswith("white")
    assert white.series == 39 and white.lags == 10 and white.dof == 390
    assert abs(white.lag1) < 0.05
    # AR(1) with rho = 0.6 in every channel series (as a model mismatch leaves them)
    r = np.concatenate([ar1(rng, 0.6, (60, 13)).ravel() for _ in range(3)])
    red = whiteness(r, blocks)
    assert not red.white and red.p_value < 1e-6 and red.lag1 == pytest.approx(0.6, abs=0.1)
    assert "NOT white" in red.verdict and "understate" in red.verdict
    assert red.to_json_dict()["white"] is False


def test_whiteness_calls_weak_significant_correlation_white_enough():
    """rho = 0.05 over 100 000 residuals is detectable but changes an interval by 5 %."""
    rng = np.random.default_rng(2)
    blocks = series_blocks(10, 400, 25)
    r = np.concatenate([ar1(rng, 0.05, (400, 25)).ravel() for _ in range(10)])
    w = whiteness(r, blocks)
    assert w.p_value < 0.01 and w.white and w.verdict.startswith("white enough")


def test_whiteness_skips_missing_samples():
    """Residuals marked missing (motion-capture gaps) are not read: whatever a gap holds, the
    test gives the same statistic; read as data, a filler with structure is structure."""
    rng = np.random.default_rng(4)
    blocks = series_blocks(2, 200, 2)
    r = rng.normal(size=800)
    gaps = np.zeros(800, dtype=bool)
    gaps[blocks[0][50:90, :].ravel()] = True
    zeros, ramp = r.copy(), r.copy()
    zeros[gaps] = 0.0
    ramp[gaps] = np.linspace(5.0, 10.0, int(gaps.sum()))  # a slow ramp, 5-10 noise deviations
    masked = whiteness(zeros, blocks, missing=gaps)
    assert masked.white and masked.series == 4 and masked.verdict.startswith("white (")
    other_filler = whiteness(ramp, blocks, missing=gaps)
    assert (other_filler.statistic, other_filler.p_value, other_filler.lag1) == \
        (masked.statistic, masked.p_value, masked.lag1)
    read = whiteness(ramp, blocks)
    assert not read.white and read.lag1 > 0.2


@pytest.fixture(scope="module")
def short_objective() -> Objective:
    truth = ModelParameters.nominal().with_values(mu_c=0.25)
    model = CobraModel.load()
    rng = np.random.default_rng(9)
    runs = [record(Simulator(model, truth), RunPlan("a", 0.5, 2.0, (0.2, -0.1), 0.4, "train"), rng, model)]
    return Objective(runs, truth.with_values(mu_c=0.27).with_frozen(free=["mu_c"]))


def test_residual_blocks_follow_the_residual_vector(short_objective):
    """Every (run, sample, channel) index of residual_blocks picks that channel's residual."""
    spec = short_objective.spec
    tg = spec.targets[0]
    S = len(tg.t_samples)
    head_marks = np.arange(2 * S, dtype=float).reshape(S, 2)
    joint_marks = 1000 + np.arange(11 * S, dtype=float).reshape(S, 11)
    w = spec.weights
    sim = Simulated([np.where(np.isfinite(tg.head_xy), tg.head_xy, 0.0) + head_marks * w.head_scale_m],
                    [tg.q + joint_marks * w.joint_scale_rad], [np.zeros_like(tg.q)])
    r = residual_vector(spec, sim)
    (block,) = short_objective.residual_blocks()
    assert block.shape == (S, 13)
    seen = np.isfinite(tg.head_xy).all(axis=1)
    assert np.allclose(r[block[seen, :2]], head_marks[seen])
    assert np.allclose(r[block[:, 2:]], joint_marks)
    gaps = short_objective.head_gaps()
    assert gaps.shape == r.shape and np.array_equal(gaps[block[:, 0]], ~seen) and not gaps[block[:, 2:]].any()


def test_current_channels_follow_the_joints_in_the_residual_vector(short_objective):
    """With the current fitted, each run's block has 11 more columns, after the joints."""
    spec = dataclasses.replace(short_objective.spec, weights=Weights(use_current=True))
    tg = dataclasses.replace(spec.targets[0], current=np.zeros_like(spec.targets[0].q))
    spec = dataclasses.replace(spec, targets=(tg,))
    S = len(tg.t_samples)
    current_marks = 5000 + np.arange(11 * S, dtype=float).reshape(S, 11)
    sim = Simulated([np.where(np.isfinite(tg.head_xy), tg.head_xy, 0.0)], [tg.q],
                    [current_marks * spec.weights.current_scale_a])
    r = residual_vector(spec, sim)
    (block,) = residual_blocks(spec)
    assert block.shape == (S, 24) and r.size == 24 * S
    assert np.allclose(r[block[:, 13:]], current_marks) and np.allclose(r[block[:, 2:13]], 0.0)
    assert current_rows(spec)[block[:, 13:]].all() and not current_rows(spec)[block[:, :13]].any()


def test_fit_reports_whiteness_and_both_intervals(short_objective):
    result = fit_lsq(short_objective, max_iterations=3, horizons_s=())
    w = result.residual_whiteness
    assert isinstance(w, Whiteness) and w.verdict and w.series == 13 and 0.0 <= w.p_value <= 1.0
    assert "HAC" in result.interval_method and "start-pose" in result.interval_method
    (rep,) = result.report
    # the runs were made at mu_c = 0.25 (the fit started at 0.27; 2 s of encoder and mocap noise
    # leave an interval about +-0.001 wide): both intervals hold it
    assert rep.name == "mu_c" and rep.value == pytest.approx(0.25, abs=0.002)
    assert rep.ci_low <= 0.25 <= rep.ci_high and rep.ci_low_iid <= 0.25 <= rep.ci_high_iid
