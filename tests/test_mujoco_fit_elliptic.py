"""The base fit on MuJoCo's elliptic friction cone with a softer (40 ms) contact, no effect added: the
elliptic soft-constraint law is chosen over the pyramid's on validation runs."""
from __future__ import annotations

import dataclasses

import pytest

from cobra_model import design
from cobra_model.parameters import ModelParameters
from sysid.identification.contact_choice import choose_contact_law
from mujoco_fit_cases import fit, gaps_of, runs_of, validation_runs

pytestmark = pytest.mark.slow
mujoco = pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def elliptic_case(cobra):
    """On MuJoCo's elliptic friction cone with a softer (40 ms) contact, ``benchmarks/mujoco_fit.py``'s
    ``elliptic_soft`` configuration: the two soft-constraint laws fitted, one chosen on three
    validation runs. Each law's fit starts from capsule ends only (MuJoCo's; the search over the
    ends' shape is the default case's) and goes on to the whole runs from the better of its soft
    and stiff ground's screens, which keeps this test to two whole-run fits."""
    train, hold, options = runs_of(cobra, lambda twin: dataclasses.replace(twin, cone="elliptic", solref=(0.04, 1.0)))
    valid = validation_runs(cobra, options)
    choice = choose_contact_law(train, valid, ModelParameters.nominal(), laws=("soft_constraint", "soft_elliptic"),
                                rounding_starts=(design.MODULE_RADIUS_M,), fit=fit, whole_run_fits=1)
    return choice, gaps_of(hold, {f.law: f.fit.params for f in choice.fits})


def test_on_mujocos_elliptic_cone_the_elliptic_law_is_chosen_and_within_5_cm(elliptic_case):
    """The pyramid's diamond-shaped friction limit cannot bend to MuJoCo's round one (issue 16's
    elliptic_soft configuration missed the 5 cm bound on 10 of 18 held-out runs with it); the
    elliptic law is chosen on validation runs and brings every held-out final head error under
    the bound, with joints that follow MuJoCo's at least twice as closely as the pyramid's."""
    choice, gaps = elliptic_case
    assert choice.chosen == "soft_elliptic", choice.to_json()
    heads = {law: [g["head_final_error_m"] for g in gaps[law]] for law in gaps}
    joints = {law: [g["joint_rmse_rad"]["mean"] for g in gaps[law]] for law in gaps}
    assert max(heads["soft_elliptic"]) <= 0.05, heads
    assert max(joints["soft_elliptic"]) < 0.5 * max(joints["soft_constraint"]), joints
