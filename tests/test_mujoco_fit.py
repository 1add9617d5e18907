"""The base fit on runs MuJoCo made (no effect added): what it recovers of another engine's contact.

MuJoCo's twin (sysid.generators.mujoco_recording) touches the ground through body-aligned capsule pairs with a
pyramidal friction cone: a diamond-shaped friction limit in the ground plane and hemispherical
module ends, all a soft constraint with a 20 ms time constant. Our paper's law is a box limit on
sharp cylinder rims; with the limit's shape (``friction_cone``) and the ends' rounding
(``contact_rounding``) free, the compliant ground's fit must find MuJoCo's shapes from the motion
alone. Its path still drifts from MuJoCo's; the soft-constraint law, fitted beside it and chosen
on validation runs (``sysid.identification.contact_choice``), follows it. MuJoCo's stiff contact
and its elliptic cone have files of their own (``test_mujoco_fit_stiff.py``,
``test_mujoco_fit_elliptic.py``), so that pytest-xdist runs the three configurations' fits side by
side; their runs come from ``mujoco_fit_cases.py``.
"""
from __future__ import annotations

import numpy as np
import pytest

from cobra_model import design
from cobra_model.parameters import ModelParameters
from sysid.identification.contact_choice import choose_contact_law
from mujoco_fit_cases import fit, gaps_of, runs_of, validation_runs

pytestmark = pytest.mark.slow
mujoco = pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def case(cobra):
    """On MuJoCo's default contact: the compliant and the soft-constraint (pyramid) laws fitted, one
    chosen on three validation runs (3 s, heading 0.8 rad, their own noise). The elliptic law is
    left to ``test_mujoco_fit_elliptic.py``, to ``benchmarks/mujoco_fit.py``, which fits all three (two keep this
    test short), and to ``tests/test_soft_contact.py`` (the law against MuJoCo's elliptic cone)."""
    train, hold, options = runs_of(cobra, lambda twin: twin)
    valid = validation_runs(cobra, options)
    start = ModelParameters.nominal()
    choice = choose_contact_law(train, valid, start, laws=("compliant", "soft_constraint"), fit=fit)
    fits = {f.law: f.fit for f in choice.fits}
    gaps = gaps_of(hold, {"nominal": start, **{law: r.params for law, r in fits.items()}})
    return choice, fits, gaps


def test_the_compliant_fit_finds_mujocos_contact_shapes(case):
    _, fits, _ = case
    fit = fits["compliant"]
    # pyramid with body-aligned edges -> a diamond, cone -> 1 (0 = box, 0.5 = circle); measured 0.93
    assert fit.params.friction_cone > 0.6
    # capsule ends: rounding = the module radius (0 = sharp rim); measured 0.045 of 0.045 m (the bound)
    assert 0.5 * design.MODULE_RADIUS_M < fit.params.contact_rounding <= design.MODULE_RADIUS_M


def test_the_fitted_joints_follow_mujocos(case):
    choice, _, gaps = case
    before = np.array([g["joint_rmse_rad"]["mean"] for g in gaps["nominal"]])
    after = np.array([g["joint_rmse_rad"]["mean"] for g in gaps[choice.chosen]])
    # held-out runs at another heading; measured 8.5-22 -> 0.55-0.63 mrad on the development seed
    assert np.all(after < 0.5 * before), (before, after)


def test_on_mujocos_soft_contact_the_soft_constraint_law_is_chosen(case):
    """Chosen on validation runs, with MuJoCo's time constant and sliding friction found."""
    choice, fits, gaps = case
    assert choice.chosen == "soft_constraint", choice.to_json()
    soft = fits["soft_constraint"].params
    assert 0.01 <= soft.contact_time_constant <= 0.04        # MuJoCo's solref[0] 0.02 s
    assert abs(soft.mu_c - 0.24) <= 0.04
    assert soft.contact_rounding > 0.5 * design.MODULE_RADIUS_M  # MuJoCo's capsule ends: the module radius
    worse = [max(g["head_final_error_m"] for g in gaps[law]) for law in ("compliant", "soft_constraint")]
    assert worse[1] < worse[0]                               # and it predicts the held-out runs better


def test_held_out_head_error_within_5_cm_on_every_gait(case):
    """Issue 16's bound on MuJoCo's default contact, with the law chosen on validation runs.

    Measured 0.38 / 1.36 / 1.18 cm at 0.35 / 0.5 / 0.65 Hz (held-out joints 0.55-0.63 mrad; the
    nominal model 5-13 cm, the compliant law's fit 3.8-9.6 cm; 0.22 / 0.51 / 0.89 cm before the
    soft solver's Cholesky and the rule of eight steps per contact time constant, 9822ff8). With the soft law's per-edge
    regulariser of before (``integrators.kernels.soft_contact_acceleration``) it was 1.0 / 3.1 /
    7.8 cm and this test an expected failure."""
    choice, _, gaps = case
    assert max(g["head_final_error_m"] for g in gaps[choice.chosen]) <= 0.05
