"""The discrepancy workflow names the effect that is there, and nothing when none is.

Short runs made by this simulator with parameter error (``mu_c``, ``joint_damping`` and
``motor_km`` 9-60 % off, as in ``benchmarks/diagnose_accuracy.py``) and one library effect (or two)
hidden at the benchmark's realistic magnitude: two training runs (0.5 and 0.65 Hz) and one held-out run
(0.5 Hz) of 3 s from random poses, measured like the reference dataset (quantised encoders, mocap
noise and dropouts). Seed 21 is not one the screening was developed on (the benchmark's is 3).
"""
from __future__ import annotations

import numpy as np
import pytest

from cobra_model import CobraModel, ModelParameters
from integrators.simulator import Simulator
from sysid.generators.dataset import RunPlan, record
from sysid.discrepancy.diagnose import DiagnoseConfig, diagnose
from sysid.discrepancy.effects import EffectLibrary
from benchmarks._robot import with_error

LIBRARY = EffectLibrary()
#: Each effect's realistic magnitude (SI units of its parameter), as benchmarks/diagnose_accuracy.py hides it.
MAGNITUDES = {e.name: e.realistic for e in LIBRARY}
FREE = ["mu_c", "joint_damping", "motor_km"]
SEED = 21
DURATION_S = 3.0
#: Held-out final head error [m] that the measured start pose alone can leave (see the test).
HEAD_FLOOR_M = 0.005


def diagnosed(effect: str | None, *also: str, seed: int = SEED, progress=lambda message: None):
    """The diagnosis of runs with ``effect`` (and the effects ``also``) hidden, looking for as many;
    ``seed`` draws the runs' starts and noise, ``progress`` gets the workflow's messages."""
    truth = with_error()
    if effect is not None:
        truth = LIBRARY.transform(truth, {e: MAGNITUDES[e] for e in (effect, *also)}, frozen=True)
    model = CobraModel.load()
    sim = Simulator(model, truth)
    rng = np.random.default_rng(seed)
    plans = [RunPlan(f"r{i}", f, DURATION_S, (rng.uniform(-1, 1), rng.uniform(-1, 1)), rng.uniform(0, 2 * np.pi), "train")
             for i, f in enumerate((0.5, 0.65, 0.5))]
    runs = [record(sim, p, rng, model) for p in plans]
    return diagnose(runs[:2], runs[2:], params=ModelParameters.nominal().with_frozen(free=FREE),
                    config=DiagnoseConfig(max_effects=1 + len(also)), progress=progress)


@pytest.mark.slow
@pytest.mark.parametrize("effect", list(MAGNITUDES))
def test_the_hidden_effect_is_named_first(effect):
    d = diagnosed(effect)
    assert d.effects, f"nothing named; candidates: {[c.to_json() for c in d.rounds[0][:3]]}"
    assert d.effects[0].name == effect
    assert not d.structural
    # at its hidden value: within 10 % (3 s runs, quantised encoders; a torque limit's value is
    # seen only where the demand exceeds it, and comes out 1-4 % high in the matrix's runs)
    assert d.effects[0].value == pytest.approx(MAGNITUDES[effect], rel=0.1)
    # naming it more than halves the held-out cost (what the workflow judges by: head and joints)
    assert d.effects[0].held_out_cost_reduction > 0.5
    # and the held-out head error halves, unless the base fit already left it at the floor that
    # the measured start pose sets (0.2 deg of heading over a 3 s run's ~0.6 m path: 2 mm, plus
    # the 0.5 mm mocap noise): a torque limit is largely absorbed by the actuator parameters in
    # the head path (measured 1.4 mm before, 2.5 mm after), its evidence is in the joints
    before, after = d.gap_before.head_final_error_m, d.gap_after.head_final_error_m
    assert after < max(0.5 * before, HEAD_FLOOR_M)


@pytest.mark.slow
def test_nothing_is_named_when_only_parameters_are_off():
    d = diagnosed(None)
    assert d.effects == [] and d.structural == []
    assert d.verdict.startswith("no library effect explains the gap")


@pytest.mark.slow
def test_each_of_two_named_effects_is_reported_as_the_final_model_holds_it():
    """The second round refits the first effect's parameter with the rest: what the diagnosis
    reports for each effect (value, interval) is the final model's, the one a user is given."""
    d = diagnosed("actuator_delay", "encoder_offset")
    assert sorted(e.name for e in d.effects) == ["actuator_delay", "encoder_offset"]
    for e in d.effects:
        assert e.value == d.params_after.value(e.parameter)
        low, high = e.ci95
        assert low <= e.value <= high and low <= MAGNITUDES[e.name] <= high   # the interval holds the truth
        # recovered within 10 % of the hidden value (3 s runs, quantised encoders)
        assert e.value == pytest.approx(MAGNITUDES[e.name], rel=0.1)


@pytest.mark.slow
def test_two_effects_that_bend_each_others_screening_are_both_named():
    """Twice the lateral ground friction and a 0.8 kg payload hidden together, on the runs of
    the confusion matrix's pair of development seed 32 (``benchmarks/diagnose_matrix.py``: the
    same design). Each effect's short screening refit mimics the other, and which candidates
    pass there turns on the last bits (OpenBLAS's kernels): on Haswell's none passes and the
    payload, which the training runs support most, gets its second look on the whole runs
    (``sysid.discrepancy.diagnose.second_look``); on SkylakeX's a torque limit that was not
    hidden passes first and the payload next, and refitted on the whole runs the payload fits
    the training runs better (``contested``). Either way the payload is named first, the
    anisotropy in the next round, and both come out at their values."""
    d = diagnosed("anisotropic_ground_friction", "link_mass_error", seed=32)
    assert [e.name for e in d.effects] == ["link_mass_error", "anisotropic_ground_friction"]
    for e in d.effects:  # each 95 % interval (the final model's, both refitted together) holds the value hidden
        assert e.ci95[0] <= MAGNITUDES[e.name] <= e.ci95[1]
        assert e.value == pytest.approx(MAGNITUDES[e.name], rel=0.02)
    assert d.gap_after.head_final_error_m < 0.1 * d.gap_before.head_final_error_m


@pytest.mark.slow
def test_an_effect_named_after_another_is_refitted_as_if_both_had_been_modelled_from_the_start():
    """A 0.02 rad backlash and a 0.8 kg payload hidden together, on the runs of the confusion
    matrix's pair of development seed 38: the payload is named first, on a model whose fit bent
    its parameters to mimic the backlash still missing. From there the backlash screened at half
    its value and a joint friction that was not hidden passed beside it, and the friction was
    named. The refit after naming also starts from the base fit's start with both effects at
    their values (``sysid.discrepancy.diagnose.final_refit``), as if both had been modelled from
    the beginning: the backlash is named, and both come out at their values."""
    d = diagnosed("backlash", "link_mass_error", seed=38)
    assert [e.name for e in d.effects] == ["link_mass_error", "backlash"]
    for e in d.effects:  # each within 2 % (the backlash's 95 % interval, 0.0200-0.0201 rad, misses 0.02 by 34 urad)
        assert e.value == pytest.approx(MAGNITUDES[e.name], rel=0.02)
    assert d.gap_after.head_final_error_m < 0.1 * d.gap_before.head_final_error_m


@pytest.mark.slow
def test_a_gear_play_and_a_ground_anisotropy_hidden_together_are_both_named():
    """A 0.02 rad backlash and twice the lateral ground friction hidden together, on the runs of
    the confusion matrix's pair of development seed 36. With the backlash a dead zone on the loop's
    error (before the gear play), its refit alone bent the ground and the motor to mimic the
    anisotropy and only the partnered look (``sysid.discrepancy.diagnose.partnered_look``) named
    the two; as gear play the anisotropy is named in the first round and the backlash in the
    second, each at its value (measured 2.010 and 0.01997 rad)."""
    d = diagnosed("backlash", "anisotropic_ground_friction", seed=36)
    assert sorted(e.name for e in d.effects) == ["anisotropic_ground_friction", "backlash"]
    for e in d.effects:  # each 95 % interval holds the value hidden, and the value is within 2 %
        assert e.ci95[0] <= MAGNITUDES[e.name] <= e.ci95[1]
        assert e.value == pytest.approx(MAGNITUDES[e.name], rel=0.02)
    assert d.gap_after.head_final_error_m < 0.1 * d.gap_before.head_final_error_m


@pytest.mark.slow
def test_a_candidate_whose_screening_diverges_is_left_out_and_the_others_are_screened(monkeypatch):
    """A candidate whose screening refit no simulation follows (a payload on a ground fitted
    without it can sink the head through a soft ground) is reported as not screened, is not a
    candidate of that round, and the diagnosis goes on: the effect hidden is still named."""
    import sysid.discrepancy.diagnose as diagnose_module
    from integrators.simulator import SimulationDiverged
    screen_refit = diagnose_module._screen_refit

    def payload_sinks(start, *args, **kwargs):
        if "link_mass_error" in start.free_names:
            raise SimulationDiverged("t = 0.4 s: the head sank 3 cm into the ground")
        return (yield from screen_refit(start, *args, **kwargs))

    monkeypatch.setattr(diagnose_module, "_screen_refit", payload_sinks)
    messages: list[str] = []
    d = diagnosed("actuator_delay", progress=messages.append)
    assert any("link_mass_error: its screening's simulation diverged (t = 0.4 s: the head sank 3 cm" in m
               and m.endswith("not screened") for m in messages)
    screened = {c.name for c in d.rounds[0]}
    assert "link_mass_error" not in screened
    assert screened == {e.name for e in LIBRARY} - {"link_mass_error"}
    assert [e.name for e in d.effects] == ["actuator_delay"]
    assert d.effects[0].value == pytest.approx(MAGNITUDES["actuator_delay"], rel=0.1)
