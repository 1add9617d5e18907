"""The base fit on MuJoCo's stiff contact (2 ms time constant, no effect added): the soft-constraint
law chosen on validation runs and within issue 16's bounds, and what the compliant law can say of
such a ground (the shapes of the ends, the sliding friction, a stiffness on its bound)."""
from __future__ import annotations

import pytest

from cobra_model import design
from cobra_model.parameters import ModelParameters
from sysid.generators.mujoco_recording import stiff_contact
from sysid.identification.contact_choice import choose_contact_law
from sysid.identification.objective import SENSOR_NOISE
from mujoco_fit_cases import fit, gaps_of, runs_of, validation_runs

pytestmark = pytest.mark.slow
mujoco = pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def stiff_case(cobra):
    """On MuJoCo's stiff contact (2 ms): the compliant and the soft-constraint (pyramid) laws fitted
    from every shape of the ends (and, for the soft law, a soft and the stiffest ground), each
    start screened on the first 1.5 s and only the lowest fitted on the whole runs; one law chosen
    on three validation runs, as in ``test_mujoco_fit.py``'s ``case``."""
    train, hold, options = runs_of(cobra, stiff_contact)
    valid = validation_runs(cobra, options)
    choice = choose_contact_law(train, valid, ModelParameters.nominal(), laws=("compliant", "soft_constraint"),
                                fit=fit, whole_run_fits=1)
    return choice, gaps_of(hold, {f.law: f.fit.params for f in choice.fits})


def test_on_mujocos_stiff_contact_the_held_out_head_error_is_within_5_cm(stiff_case):
    """Issue 16's bound on MuJoCo's stiff contact (2 ms time constant), with the law chosen on
    validation runs: the soft-constraint law, whose held-out heads were measured 0.14 / 0.59 /
    0.99 cm at 0.35 / 0.5 / 0.65 Hz (nominal model: 5-25 cm; 0.63 / 0.62 / 0.52 cm at four steps
    per contact time constant, before 9822ff8).

    The compliant law is not chosen here, and its held-out error is not a claim: its fit stops
    where no step descends (``NO_DESCENT``) with joints 2-2.5 times the encoders' floor, and where
    that is moves with the runs' last bits (1.3 / 3.1 / 4.7 cm from three shapes, 0.8 / 3.1 /
    5.9 cm from the sharp ends alone; 0.6 / 2.1 / 4.0 cm from the sharp ends with the batch of
    before d8303bc, whose last bits differed by about 1e-13)."""
    choice, gaps = stiff_case
    assert choice.chosen == "soft_constraint", choice.to_json()
    heads = {law: [g["head_final_error_m"] for g in gaps[law]] for law in gaps}
    assert max(heads["soft_constraint"]) <= 0.05, heads
    assert max(heads["soft_constraint"]) < max(heads["compliant"]), heads


def test_on_mujocos_stiff_contact_the_compliant_law_finds_the_shapes_and_its_stiffness_bound(stiff_case):
    """What the compliant law can say of MuJoCo's stiff contact: the ends' shapes, the sliding
    friction, and that the ground is stiffer than the law's stiffest spring."""
    choice, _ = stiff_case
    fit = choice.fit_of("compliant").fit
    # measured: cone 0.93, rounding 0.037 of 0.045 m
    assert fit.params.friction_cone > 0.6 and fit.params.contact_rounding > 0.5 * design.MODULE_RADIUS_M
    # MuJoCo's sliding friction 0.24. The Coulomb level trades with the Stribeck terms, so its value
    # moves with the rounding of the runs: measured 0.226 and 0.246 on one machine, 0.175 on
    # another (AMD EPYC), whose 95 % interval 0.10-0.25 holds MuJoCo's value. Asserted: the
    # interval holds it and is no wider than +-0.1.
    mu_c = next(r for r in fit.report if r.name == "mu_c")
    assert mu_c.ci_low <= 0.24 <= mu_c.ci_high and mu_c.ci_high - mu_c.ci_low <= 0.2, mu_c
    # MuJoCo carries a sustained load almost rigidly: the ground stiffness ends on its bound, and says so
    assert "k1" in {r.name for r in fit.report if r.at_bound}


def test_on_mujocos_stiff_contact_the_soft_law_starts_on_a_stiff_ground_and_finds_it(stiff_case):
    """A fit of the soft law from MuJoCo's default 20 ms alone stops at 8-10 ms on this
    configuration (the cost along the time constant is rough on a stiff ground; on these runs
    10.2 ms, held-out joints 1.07-1.45 mrad, 2.4-3.3 times the encoders' floor). Every start on
    the stiffest ground screens lower on the first 1.5 s than every start on the soft one
    (measured 0.73-3.7 against 8.1-9.7); the lowest, capsule ends, is the one fitted on the whole
    runs, and ends near MuJoCo's values (measured: time constant 2.3 ms, damping 0.168, ``mu_c``
    0.2389, rounding 0.0450 m), with held-out joints at 0.51 / 0.55 / 0.56 mrad at 0.35 / 0.5 /
    0.65 Hz from these 3 s training runs (0.68 / 0.60 / 0.66 at four steps per time constant,
    before 9822ff8). Asserted: within issue 16's bar, 1.5x the encoders' floor (0.66 mrad), which
    four steps per time constant met only to its last digit and the soft ground's basin misses
    (2.4-3.3 times the floor)."""
    choice, gaps = stiff_case
    law = choice.fit_of("soft_constraint")
    stiffest = law.fit.params["contact_time_constant"].min          # the stiff start: MuJoCo's own lowest, 2 ms
    stiff = [s for s in law.starts if s.values["contact_time_constant"] == stiffest]
    soft = [s for s in law.starts if s.values["contact_time_constant"] != stiffest]
    assert max(s.screen_cost for s in stiff) < min(s.screen_cost for s in soft), law.starts
    assert [s.cost is not None for s in law.starts].count(True) == 1 and all(s.cost is None for s in soft)
    fitted = law.fit.params
    assert fitted.contact_time_constant <= 0.004, fitted          # MuJoCo's solref[0] 0.002 s
    assert abs(fitted.joint_damping - 0.16) <= 0.016 and abs(fitted.mu_c - 0.24) <= 0.024, fitted
    assert fitted.contact_rounding > 0.9 * design.MODULE_RADIUS_M  # MuJoCo's capsule ends
    joints = [g["joint_rmse_rad"]["mean"] for g in gaps["soft_constraint"]]
    assert max(joints) <= 1.5 * SENSOR_NOISE["joints"], joints
