"""The base fit on runs MuJoCo made (no effect added): what it recovers of another engine's contact.

MuJoCo's twin (sysid.generators.mujoco_recording) touches the ground through body-aligned capsule pairs with a
pyramidal friction cone: a diamond-shaped friction limit in the ground plane and hemispherical
module ends. Our paper's law is a box limit on sharp cylinder rims; with the limit's shape
(``friction_cone``) and the ends' rounding (``contact_rounding``) free, the fit must find
MuJoCo's shapes from the motion alone, and its joints must then follow MuJoCo's far better.
"""
from __future__ import annotations

import numpy as np
import pytest

from cobra_model import design
from cobra_model.parameters import ModelParameters
from integrators.simulate import simulate_like
from sysid.generators.dataset import RunPlan
from sysid.identification.lsq import fit_lsq
from sysid.gap.metrics import compare_runs
from sysid.generators.mujoco_recording import record_mujoco, stiff_contact, twin_options
from sysid.identification.objective import Objective, Weights

pytestmark = pytest.mark.slow
mujoco = pytest.importorskip("mujoco")

TRUTH = {"mu_c": 0.24, "joint_damping": 0.16, "motor_km": 0.0098}
FREE = ["joint_damping", "motor_km", "k1", "k2", "mu_c", "mu_s", "mu_v", "v_s", "friction_cone", "contact_rounding"]
GAITS = (0.35, 0.5, 0.65)


def fit_case(cobra, options_of):
    """Three 3 s training runs and three 6 s held-out runs at another heading (seed 5, the
    development seed of benchmarks/mujoco_fit.py), the LM fit and the held-out comparisons."""
    truth = ModelParameters.nominal().with_values(**TRUTH)
    rng = np.random.default_rng(5)
    options = options_of(twin_options(truth))
    train = [record_mujoco(RunPlan(f"t{f}", f, 3.0, (0.0, 0.0), 0.3, "train"), options, rng, cobra, truth)
             for f in GAITS]
    hold = [record_mujoco(RunPlan(f"h{f}", f, 6.0, (0.5, -0.5), 1.3, "holdout"), options, rng, cobra, truth)
            for f in GAITS]
    start = ModelParameters.nominal().with_frozen(free=FREE)
    fit = fit_lsq(Objective(train, start, Weights()), horizons_s=(1.5,), max_iterations=8)
    gaps = {name: [compare_runs(run, simulate_like(run, params=p)).to_json_dict() for run in hold]
            for name, p in (("nominal", start), ("fitted", fit.params))}
    return fit, gaps


@pytest.fixture(scope="module")
def case(cobra):
    return fit_case(cobra, lambda twin: twin)


@pytest.fixture(scope="module")
def stiff_case(cobra):
    return fit_case(cobra, stiff_contact)


def test_the_fit_finds_mujocos_contact_shapes(case):
    fit, _ = case
    # pyramid with body-aligned edges -> a diamond, cone -> 1 (0 = box, 0.5 = circle); measured 0.87
    assert fit.params.friction_cone > 0.6
    # capsule ends: rounding = the module radius (0 = sharp rim); measured 0.042 of 0.045 m
    assert 0.5 * design.MODULE_RADIUS_M < fit.params.contact_rounding <= design.MODULE_RADIUS_M


def test_the_fitted_joints_follow_mujocos(case):
    _, gaps = case
    before = np.array([g["joint_rmse_rad"]["mean"] for g in gaps["nominal"]])
    after = np.array([g["joint_rmse_rad"]["mean"] for g in gaps["fitted"]])
    # held-out runs at another heading; measured 5.9-16 -> 1.4-2.5 mrad on the development seed
    assert np.all(after < 0.5 * before), (before, after)


@pytest.mark.xfail(strict=True, reason="issue 16: MuJoCo's default soft contact (solref 20 ms) moves the path in a "
                                       "way no parameter of our ground follows (6-21 cm held-out, "
                                       "benchmarks/results/mujoco_fit.md, contact_time_constant.md)")
def test_held_out_head_error_within_5_cm_on_every_gait(case):
    _, gaps = case
    assert max(g["head_final_error_m"] for g in gaps["fitted"]) <= 0.05


def test_on_mujocos_stiff_contact_the_held_out_head_error_is_within_5_cm(stiff_case):
    """Issue 16's bound where our ground can express MuJoCo's contact (2 ms time constant).

    Measured 0.6 / 2.1 / 4.0 cm at 0.35 / 0.5 / 0.65 Hz (nominal model: 5-25 cm); over 36 cases
    of benchmarks/mujoco_fit.py (other seeds, both headings, two cones) 34 within 5 cm, worst 5.2 cm.
    """
    fit, gaps = stiff_case
    heads = [g["head_final_error_m"] for g in gaps["fitted"]]
    assert max(heads) <= 0.05, heads
    assert fit.params.friction_cone > 0.6 and fit.params.contact_rounding > 0.5 * design.MODULE_RADIUS_M
    assert abs(fit.params.mu_c - 0.24) <= 0.03          # MuJoCo's sliding friction (measured 0.226)
    # MuJoCo carries a sustained load almost rigidly: the ground stiffness ends on its bound, and says so
    assert "k1" in {r.name for r in fit.report if r.at_bound}
