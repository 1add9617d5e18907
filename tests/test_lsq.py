"""Least-squares identification: recovery on data with the reference dataset's measurement noise."""
from __future__ import annotations

import numpy as np
import pytest

from cobra_model import CobraModel, ModelParameters
from cobra_model.errors import InputError
from integrators.simulator import Simulator
from sysid.generators.dataset import RunPlan, record
from sysid.identification.executor import LocalExecutor, RayExecutor
from sysid.identification.lsq import fit_lsq, uncertainty
from sysid.identification.objective import Objective

TRUTH = ModelParameters.nominal().with_values(mu_c=0.22, mu_s=0.34, joint_damping=0.25, motor_km=0.0095)


def measured_runs(truth: ModelParameters, plans) -> list:
    """Runs 'measured' like the reference dataset: 50 Hz quantised encoders, noisy mocap with dropouts."""
    model = CobraModel.load()
    sim = Simulator(model, truth)
    rng = np.random.default_rng(5)
    return [record(sim, p, rng, model) for p in plans]


@pytest.fixture(scope="module")
def noisy_runs():
    plans = [RunPlan("a", 0.5, 4.0, (0.0, 0.0), 0.3, "train"), RunPlan("b", 0.65, 4.0, (0.5, -0.2), 2.0, "train")]
    return measured_runs(TRUTH, plans)


@pytest.mark.slow
def test_lsq_recovers_parameters_within_two_percent(noisy_runs):
    """Guess off by 30-50 %; every parameter flagged identifiable must come back within 2 %."""
    free = ["mu_c", "joint_damping", "motor_km"]
    guess = TRUTH.with_values(mu_c=0.22 * 1.45, joint_damping=0.25 * 0.6, motor_km=0.0095 * 1.3).with_frozen(free=free)
    result = fit_lsq(Objective(noisy_runs, guess), max_iterations=15)
    assert result.status.name.startswith("CONVERGED")
    assert result.cost < 0.05 * result.initial_cost
    assert sorted(r.name for r in result.report) == sorted(free)
    for r in result.report:
        assert r.identifiable, r
        assert r.value == pytest.approx(TRUTH.value(r.name), rel=0.02), r
        assert r.ci_low <= TRUTH.value(r.name) <= r.ci_high, r   # the interval holds the truth
    assert [entry.iteration for entry in result.log] == sorted(entry.iteration for entry in result.log)
    # the continuation: 1.5 s, then 3 s, then the whole 4 s runs
    horizons = [entry.horizon_s for entry in result.log]
    assert horizons == sorted(horizons) and horizons[0] == pytest.approx(1.5, abs=0.03) and horizons[-1] > 3.9
    # the path a benchmark plots: the start, then one point per accepted step, ending at the fit
    iterates = result.extra["iterates"]
    assert len(iterates) == 1 + sum(entry.accepted for entry in result.log)
    np.testing.assert_allclose(iterates[0][2].as_vector(), guess.as_vector(), rtol=1e-12)
    np.testing.assert_array_equal(iterates[-1][2].as_vector(), result.params.as_vector())
    seconds = [sec for sec, _, _ in iterates]
    assert seconds[0] == 0.0 and seconds == sorted(seconds) and seconds[-1] <= result.seconds


def test_horizons_must_increase(noisy_runs):
    with pytest.raises(InputError, match="horizons_s"):
        fit_lsq(Objective(noisy_runs, TRUTH.with_frozen(free=["mu_c"])), horizons_s=(3.0, 1.5))


def test_flat_directions_and_bounds_are_flagged():
    p = ModelParameters.nominal().with_frozen(free=["mu_c", "k1", "v_s"])
    rng = np.random.default_rng(0)
    J = rng.normal(size=(50, 3))
    assert p.free_names == ("k1", "mu_c", "v_s")     # table order
    J[:, 0] = 0.0                                  # k1 does not change the residuals at all
    z = p.to_unit()
    z[2] = 1.0                                     # v_s on its upper bound
    found = uncertainty(p, p.from_unit(z), J, rng.normal(size=50) * 0.1, z)
    report, sv = found.report, found.singular_values
    by = {r.name: r for r in report}
    assert by["mu_c"].identifiable and np.isfinite(by["mu_c"].ci_low)
    assert not by["k1"].identifiable and "flat direction" in by["k1"].reason
    assert not by["v_s"].identifiable and by["v_s"].at_bound
    assert sv[-1] < 1e-12 * sv[0]


def test_objective_is_the_same_in_process_and_in_local_processes(noisy_runs):
    p = TRUTH.with_frozen(free=["mu_c", "joint_damping"])
    assert p.free_names == ("joint_damping", "mu_c")          # vectors follow the table order
    X = np.array([[0.25, 0.22], [0.2, 0.3], [0.1, 0.25]])
    inline = Objective(noisy_runs[:1], p).residuals(X)
    ex = LocalExecutor(2)
    try:
        pooled = Objective(noisy_runs[:1], p, executor=ex).residuals(X)
    finally:
        ex.close()
    assert np.allclose(inline, pooled, atol=1e-9)
    assert np.sum(inline[0] ** 2) < np.sum(inline[1] ** 2)     # truth fits better than a wrong guess


def test_an_objective_runs_on_the_threads_it_is_given_or_the_default(noisy_runs, monkeypatch):
    p = TRUTH.with_frozen(free=["mu_c"])
    monkeypatch.setenv("COBRA_THREADS", "3")
    assert Objective(noisy_runs[:1], p).spec.threads == 3
    assert Objective(noisy_runs[:1], p, threads=1).spec.threads == 1
    with pytest.raises(InputError, match="an objective needs threads >= 1 .*got 0"):
        Objective(noisy_runs[:1], p, threads=0)


@pytest.mark.slow
def test_objective_on_ray_matches_local(noisy_runs):
    ray = pytest.importorskip("ray")
    p = TRUTH.with_frozen(free=["mu_c"])
    X = np.array([[0.22], [0.3]])
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        on_ray = Objective(noisy_runs[:1], p, executor=RayExecutor()).residuals(X)
    finally:
        ray.shutdown()
    assert np.allclose(on_ray, Objective(noisy_runs[:1], p).residuals(X), atol=1e-9)


def test_a_set_on_the_edge_mu_s_equal_mu_c_survives_the_unit_round_trip():
    """A fit that ends on mu_s = mu_c (the diagnosis matrix's MuJoCo frictionloss case near its
    limit) used to come back from the unit-interval transforms with mu_s one ulp below mu_c, and
    the next fit refused its own start. At 0.4477... the plain round trip loses that ulp; the
    relation itself stays strict."""
    mu = 0.44773651375733614
    p = ModelParameters.nominal().with_values(mu_c=mu, mu_s=mu).with_frozen(free=["mu_c", "mu_s"])
    back = p.from_unit(p.to_unit())
    assert back.mu_s >= back.mu_c and back.mu_s == pytest.approx(mu, rel=1e-14)
    with pytest.raises(InputError, match=r"'mu_s' = .* must be >= 'mu_c'"):
        ModelParameters.nominal().with_values(mu_c=mu, mu_s=np.nextafter(mu, 0.0))


def test_unit_points_a_constrained_step_lands_on_are_valid_sets():
    """The LM's steps end on bounds and on mu_s = mu_c; each such unit point must map to a valid
    set, or the step is rejected as if it raised the cost and the fit stalls before the bound
    (it did: k1 = exp(log 5e4) = 50000.00000000001 N/m was 'outside its bounds' 12 times in one
    MuJoCo base fit, and mu_s landed ulps below mu_c 6 times)."""
    p = ModelParameters.nominal().with_frozen(free=["k1", "mu_c", "mu_s"])
    k1 = p["k1"]
    assert p.from_unit(np.array([1.0, 0.3, 0.3])).k1 == k1.max  # log-scaled, at its upper bound
    assert p.from_unit(np.array([0.0, 0.3, 0.3])).k1 == k1.min
    pc, ps = p["mu_c"], p["mu_s"]
    for mu in np.linspace(max(pc.min, ps.min), min(pc.max, ps.max), 37):
        zc, zs = pc.to_unit_interval(mu), ps.to_unit_interval(mu)
        for dz in (0.0, -np.spacing(zs), -4 * np.spacing(zs)):  # on the edge, and round-off below it
            back = p.from_unit(np.array([0.5, zc, zs + dz]))
            assert back.mu_s >= back.mu_c and back.mu_s == pytest.approx(mu, rel=1e-12)
    with pytest.raises(InputError, match=r"'mu_s' = .* must be >= 'mu_c'"):  # a real violation still raises
        p.from_unit(np.array([0.5, pc.to_unit_interval(0.3), ps.to_unit_interval(0.29)]))


class _LinearObjective:
    """An objective whose residuals are linear in the unit coordinates: its Gauss-Newton model
    is exact, so the trust region should only ever grow."""

    def __init__(self, params: ModelParameters, target: np.ndarray):
        from types import SimpleNamespace
        self.params, self.target, self.evaluations = params, target, 0
        self.spec = SimpleNamespace(targets=[SimpleNamespace(duration=1.0)])

    def residuals(self, X: np.ndarray, divergence: str = "raise") -> np.ndarray:
        self.evaluations += len(X)
        Z = np.array([self.params.update_from_vector(x).to_unit() for x in np.atleast_2d(X)])
        return np.repeat(10.0 * (Z - self.target), 3, axis=1)


@pytest.mark.parametrize("radius, first_steps", [(0.1, [0.1, 0.2]), (1.0, [0.36])])
def test_the_trust_region_starts_small_and_grows_where_the_model_predicts_well(radius, first_steps):
    from sysid.identification.lockstep import run
    from sysid.identification.lsq import _levenberg_marquardt
    params = ModelParameters.nominal().with_frozen(free=["k1"])
    z0 = params.to_unit()
    objective = _LinearObjective(params, z0 + 0.36)
    lm = run(_levenberg_marquardt(objective, z0, max_iterations=8, budget_seconds=None, fd_step=1e-2,
                                  trust_radius=radius, cost_tol=1e-9, step_tol=1e-9, progress=None,
                                  first_iteration=0, evaluations_before=0, t_start=0.0))
    steps = [e.step_norm for e in lm.log if e.accepted]
    # from 0.1 of the range, doubled after each step the model predicted; whole range: one step
    assert steps[:len(first_steps)] == pytest.approx(first_steps, rel=1e-3)
    assert lm.z == pytest.approx(z0 + 0.36, abs=1e-3)


def test_a_probe_that_diverges_is_taken_on_the_stable_side_or_leaves_its_column_zero():
    """The Jacobian's probes: a diverged one (NaN residuals, ``divergence="mask"``) is retaken
    at ``z - h_j``, with its step reversed; when that one diverges too, the column is zero."""
    from sysid.identification.lsq import probe_residuals

    params = ModelParameters.nominal().with_frozen(free=["joint_damping", "motor_km", "k1"])
    z = params.to_unit()
    r = np.array([1.0, 2.0])
    h = np.array([0.01, 0.01, -0.01])

    def evaluate(Z, divergence):      # the request, as the fit's driver would receive it
        return np.array(Z), divergence

    steps = probe_residuals(evaluate, params, z, r, h)
    probes = next(steps)
    assert probes[1] == "mask" and np.allclose(probes[0], z[None, :] + np.diag([0.01, 0.01, -0.01]))
    back = steps.send(np.array([[1.5, 2.5], [np.nan, np.nan], [np.nan, 0.0]]))   # coordinates 1 and 2 diverged
    assert back[1] == "mask" and np.allclose(back[0], z - np.array([0.0, 0.01, 0.0]))
    back2 = steps.send(np.array([[0.5, 1.5]]))          # coordinate 1 is stable on the other side
    assert np.allclose(back2[0], z + np.array([0.0, 0.0, 0.01]))
    with pytest.raises(StopIteration) as done:
        steps.send(np.array([[np.nan, np.nan]]))          # coordinate 2 diverges on both sides
    rows = done.value.value
    assert np.array_equal(rows, [[1.5, 2.5], [0.5, 1.5], [1.0, 2.0]])
    assert np.array_equal(h, [0.01, -0.01, -0.01])
    J = ((rows - r[None, :]) / h[:, None]).T
    assert np.allclose(J[:, 1], [50.0, 50.0]) and np.array_equal(J[:, 2], [0.0, 0.0])
