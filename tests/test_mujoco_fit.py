"""The base fit on runs MuJoCo made (no effect added): what it recovers of another engine's contact.

MuJoCo's twin (sysid.generators.mujoco_recording) touches the ground through body-aligned capsule pairs with a
pyramidal friction cone: a diamond-shaped friction limit in the ground plane and hemispherical
module ends, all a soft constraint with a 20 ms time constant. Our paper's law is a box limit on
sharp cylinder rims; with the limit's shape (``friction_cone``) and the ends' rounding
(``contact_rounding``) free, the compliant ground's fit must find MuJoCo's shapes from the motion
alone. Its path still drifts from MuJoCo's; the soft-constraint law, fitted beside it and chosen
on validation runs (``sysid.identification.contact_choice``), follows it. On MuJoCo's elliptic
friction cone the soft-constraint law on the elliptic cone is chosen over the pyramid's.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobra_model import design
from cobra_model.parameters import ModelParameters
from integrators.simulate import simulate_like
from sysid.generators.dataset import RunPlan
from sysid.identification.contact_choice import choose_contact_law
from sysid.identification.lsq import fit_lsq
from sysid.gap.metrics import compare_runs
from sysid.generators.mujoco_recording import record_mujoco, stiff_contact, twin_options
from sysid.identification.objective import SENSOR_NOISE

pytestmark = pytest.mark.slow
mujoco = pytest.importorskip("mujoco")

TRUTH = {"mu_c": 0.24, "joint_damping": 0.16, "motor_km": 0.0098}
FREE = ["joint_damping", "motor_km", "k1", "k2", "mu_c", "mu_s", "mu_v", "v_s", "friction_cone", "contact_rounding"]
GAITS = (0.35, 0.5, 0.65)


def record(cobra, options, rng, name, duration, xy, heading):
    truth = ModelParameters.nominal().with_values(**TRUTH)
    return [record_mujoco(RunPlan(f"{name}{f}", f, duration, xy, heading, name), options, rng, cobra, truth)
            for f in GAITS]


def runs_of(cobra, options_of):
    """Three 3 s training runs and three 6 s held-out runs at another heading (seed 5, the
    development seed of benchmarks/mujoco_fit.py)."""
    truth = ModelParameters.nominal().with_values(**TRUTH)
    options = options_of(twin_options(truth))
    rng = np.random.default_rng(5)
    return (record(cobra, options, rng, "t", 3.0, (0.0, 0.0), 0.3), record(cobra, options, rng, "h", 6.0, (0.5, -0.5), 1.3),
            options)


def validation_runs(cobra, options):
    """Three 3 s validation runs at heading 0.8 rad with their own noise: what chooses the law."""
    return record(cobra, options, np.random.default_rng(5 + 10_000), "v", 3.0, (-0.5, 0.5), 0.8)


def fit(objective):
    return fit_lsq(objective, horizons_s=(1.5,), max_iterations=8)


def gaps_of(runs, named_params):
    return {name: [compare_runs(run, simulate_like(run, params=p)).to_json_dict() for run in runs]
            for name, p in named_params.items()}


@pytest.fixture(scope="module")
def case(cobra):
    """On MuJoCo's default contact: the compliant and the soft-constraint (pyramid) laws fitted, one
    chosen on three validation runs (3 s, heading 0.8 rad, their own noise). The elliptic law is
    left to ``elliptic_case``, to ``benchmarks/mujoco_fit.py``, which fits all three (two keep this
    test short), and to ``tests/test_soft_contact.py`` (the law against MuJoCo's elliptic cone)."""
    train, hold, options = runs_of(cobra, lambda twin: twin)
    valid = validation_runs(cobra, options)
    start = ModelParameters.nominal()
    choice = choose_contact_law(train, valid, start, laws=("compliant", "soft_constraint"), fit=fit)
    fits = {f.law: f.fit for f in choice.fits}
    gaps = gaps_of(hold, {"nominal": start, **{law: r.params for law, r in fits.items()}})
    return choice, fits, gaps


@pytest.fixture(scope="module")
def stiff_case(cobra):
    """On MuJoCo's stiff contact (2 ms): the compliant and the soft-constraint (pyramid) laws fitted
    from every shape of the ends (and, for the soft law, a soft and the stiffest ground), each
    start screened on the first 1.5 s and only the lowest fitted on the whole runs; one law chosen
    on three validation runs, as in ``case``."""
    train, hold, options = runs_of(cobra, stiff_contact)
    valid = validation_runs(cobra, options)
    choice = choose_contact_law(train, valid, ModelParameters.nominal(), laws=("compliant", "soft_constraint"),
                                fit=fit, whole_run_fits=1)
    return choice, gaps_of(hold, {f.law: f.fit.params for f in choice.fits})


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
