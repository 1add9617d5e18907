"""Independent computations stepped together (sysid.identification.lockstep): their batches
shared, their results bit-for-bit those of running them one after the other."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobra_model import CobraModel, ModelParameters
from cobra_model.errors import InputError
from integrators.simulator import Simulator
from sysid.discrepancy.diagnose import _cost_steps, _screen_refit, screening_start
from sysid.discrepancy.effects import EffectLibrary
from sysid.generators.dataset import RunPlan, record
from sysid.identification.lockstep import Evaluate, run, run_together
from sysid.identification.objective import Objective, Weights, simulate_together
from benchmarks._robot import with_error

LIBRARY = EffectLibrary()
FREE = ["mu_c", "joint_damping", "motor_km"]
NOMINAL = ModelParameters.nominal().with_frozen(free=FREE)
TRUTH = LIBRARY.transform(with_error(NOMINAL),
                          {"backlash": 0.02}, frozen=True)


@pytest.fixture(scope="module")
def runs() -> tuple[list, list]:
    """Two 2 s training runs and a 2 s held-out run made with a backlash the nominal model lacks."""
    model = CobraModel.load()
    sim = Simulator(model, TRUTH)
    rng = np.random.default_rng(5)
    plans = [RunPlan("a", 0.5, 2.0, (0.0, 0.0), 0.3, "train"), RunPlan("b", 0.65, 2.0, (0.4, -0.2), 2.0, "train"),
             RunPlan("c", 0.35, 2.0, (0.1, 0.3), 1.0, "validation")]
    made = [record(sim, p, rng, model) for p in plans]
    return made[:2], made[2:]


def computations(train: list, held: list) -> list:
    """Different free sets, contact parameters and run sets: screening starts (one needs the torque
    demand), refits from effect-augmented starts and a grid of costs."""
    backlash = LIBRARY.transform(NOMINAL, {"backlash": 0.01})
    delay = LIBRARY.transform(NOMINAL, {"actuator_delay": 0.02})
    grid = np.array([NOMINAL.with_values(mu_c=v).as_vector() for v in (0.15, 0.2, 0.3)])
    return [screening_start(LIBRARY["torque_saturation"], NOMINAL, NOMINAL, train, LIBRARY),
            screening_start(LIBRARY["backlash"], NOMINAL, NOMINAL, train, LIBRARY),
            _screen_refit(backlash, train, held, 2, Weights()),
            _screen_refit(delay, train, held, 2, Weights()),
            _cost_steps(Objective(held, NOMINAL), grid)]


def same(a, b) -> bool:
    """Bit-for-bit equality of the computations' results (parameter sets, fits, cost arrays)."""
    if isinstance(a, tuple):
        return all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, ModelParameters):
        return a.free_names == b.free_names and np.array_equal(a.as_vector(), b.as_vector())
    if isinstance(a, np.ndarray):
        return np.array_equal(a, b)
    return (same(a.params, b.params) and a.cost == b.cost and a.evaluations == b.evaluations
            and [dataclasses.astuple(e)[:7] for e in a.log] == [dataclasses.astuple(e)[:7] for e in b.log])


@pytest.mark.slow
def test_computations_stepped_together_give_exactly_their_results_alone(runs):
    """Fits, screening starts and cost grids of different effects and free sets, run in
    lock-step, return bit-for-bit what each returns run on its own (each environment steps as
    it would in a batch of its own), with the same evaluation counts."""
    train, held = runs
    alone = [run(c) for c in computations(train, held)]
    order = []
    together = run_together(computations(train, held), finished=order.append)
    assert sorted(order) == list(range(len(alone)))
    for a, b in zip(alone, together):
        assert same(a, b)
    # the screening found the hidden backlash, the refit from it moved: the comparison is not vacuous
    assert alone[1].value("backlash") > 0.0
    assert alone[2][0].params.value("backlash") != 0.01


def test_a_diverging_request_gets_its_own_error_and_the_others_their_residuals(runs):
    """In a shared batch, a request whose row diverges gets the error it would get alone (naming
    what blew up); a request with an invalid row gets its InputError; the others their residuals,
    exactly as alone."""
    train, _ = runs
    short = [r.slice_time(float(r.t[0]), float(r.t[0]) + 1.0) for r in train]
    every = ModelParameters.nominal().with_frozen(free=list(ModelParameters.nominal().names))
    objective = Objective(short, every)
    wild = every.from_unit(np.array([1.0 if name in ("joint_damping", "motor_km", "k2", "mu_c", "mu_s",
                                                      "friction_cone", "contact_rounding") else 0.0
                                     for name in every.free_names])).as_vector()
    healthy = Objective(short, NOMINAL)
    x = NOMINAL.as_vector()[None]

    def ask(request: Evaluate):
        try:
            return (yield request)
        except (RuntimeError, InputError) as exc:
            return exc

    got = run_together([ask(Evaluate(objective, wild[None])), ask(Evaluate(healthy, x)),
                        ask(Evaluate(healthy, np.array([[1.0, 2.0]]))), ask(Evaluate(objective, wild[None], "mask"))])
    assert isinstance(got[0], RuntimeError) and "diverged" in str(got[0]) and "environment" in str(got[0])
    assert np.array_equal(got[1], healthy.residuals(x))
    assert isinstance(got[2], InputError) and "expected 3" in str(got[2])
    assert np.isnan(got[3]).all()


def test_objectives_that_cannot_share_a_batch_are_refused(runs):
    """Another sample rate records at another period: simulate_together refuses the pair and
    says what must match; run_together evaluates them in separate batches."""
    train, _ = runs
    a = Objective(train, NOMINAL)
    b = Objective(train, NOMINAL, Weights(sample_hz=20.0))
    x = NOMINAL.as_vector()[None]
    with pytest.raises(InputError, match="sample rate"):
        simulate_together([(a.spec, x), (b.spec, x)])

    def ask(objective: Objective):
        return (yield Evaluate(objective, x))

    ra, rb = run_together([ask(a), ask(b)])
    assert np.array_equal(ra, a.residuals(x)) and np.array_equal(rb, b.residuals(x))


def test_runs_and_horizons_of_different_lengths_share_a_batch_and_keep_their_residuals(runs):
    """Each environment runs for its own run's length (not the batch's longest) and a run's samples
    read only its own records: a run of 2 s beside one cut to 1.2 s, and a 0.7 s horizon beside
    whole runs, give exactly the residuals each has alone."""
    train, held = runs
    uneven = Objective([train[0], held[0].slice_time(held[0].t[0], held[0].t[0] + 1.2)], NOMINAL)
    x = np.stack([NOMINAL.as_vector(), NOMINAL.as_vector() * np.array([1.1, 1.3, 0.95])])
    alone = [Objective([r], NOMINAL).residuals(x) for r in uneven.runs]
    assert np.array_equal(uneven.residuals(x), np.concatenate(alone, axis=1))
    short = Objective(train, NOMINAL).truncated(0.7)

    def ask(objective: Objective):
        return (yield Evaluate(objective, x))

    got = run_together([ask(uneven), ask(short)])
    assert np.array_equal(got[0], uneven.residuals(x)) and np.array_equal(got[1], short.residuals(x))


def test_a_computation_that_diverges_leaves_its_alternatives(runs):
    """Computations run side by side as alternatives (a refit's starts): one whose simulation
    diverges gives None through ``unless_diverged`` and the others their results, stepped
    together as before; left bare, its divergence is the error it always was."""
    from integrators.simulator import SimulationDiverged
    from sysid.identification.lockstep import unless_diverged
    from sysid.identification.lsq import fit_lsq_steps

    train, _ = runs

    def diverging():
        yield Evaluate(Objective(train, NOMINAL), NOMINAL.as_vector()[None, :])
        raise SimulationDiverged("at t = 0.1920 s contact point head:front penetrated 3.05 cm into the ground")

    alone = run(fit_lsq_steps(Objective(train, NOMINAL), max_iterations=1))
    gone, fit = run_together([unless_diverged(diverging()),
                              unless_diverged(fit_lsq_steps(Objective(train, NOMINAL), max_iterations=1))])
    assert gone is None and fit.cost == alone.cost
    with pytest.raises(SimulationDiverged, match="penetrated"):
        run_together([diverging(), fit_lsq_steps(Objective(train, NOMINAL), max_iterations=1)])
