"""The effect library and the residual localisation on analytic cases."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobra_model import ModelParameters, SidewindingGait
from cobra_model.errors import InputError
from integrators.simulate import simulate_gait
from sysid.discrepancy.effects import EFFECTS, EffectLibrary, parse_effects
from sysid.discrepancy.signature import localise

ISSUE_NAMES = ("joint_coulomb_friction", "backlash", "actuator_delay", "torque_saturation",
               "anisotropic_ground_friction", "encoder_offset", "link_mass_error")


def test_library_has_the_issue_names_and_composes():
    lib = EffectLibrary()
    assert lib.names == ISSUE_NAMES
    assert len(lib.get_feature_names()) == 7 and "joint_coulomb_friction(joint_coulomb [N m])" in lib.get_feature_names()
    a, b = EffectLibrary(EFFECTS[:2]), EffectLibrary(EFFECTS[1:4])
    assert (a + b).names == ISSUE_NAMES[:4]
    p = lib.transform(ModelParameters.nominal(), {"backlash": 0.01, "actuator_delay": None})
    assert p.backlash == 0.01 and p.actuator_delay == lib["actuator_delay"].start


def test_parse_effects_errors_name_the_problem():
    assert parse_effects(["joint_coulomb_friction=0.2,actuator_delay=0.02"]) == {
        "joint_coulomb_friction": 0.2, "actuator_delay": 0.02}
    with pytest.raises(InputError, match="unknown effect 'friction'"):
        parse_effects(["friction=0.2"])
    with pytest.raises(InputError, match="NAME=VALUE"):
        parse_effects(["backlash"])
    with pytest.raises(InputError, match="must be a number"):
        parse_effects(["backlash=wide"])
    with pytest.raises(InputError, match="outside its bounds"):
        EffectLibrary().transform(ModelParameters.nominal(), {"backlash": 1.0})


@pytest.fixture(scope="module")
def nominal_gait_run():
    """3 s of the 0.5 Hz gait from rest with the nominal model, sampled at 50 Hz."""
    return simulate_gait(SidewindingGait(0.5), 3.0, sample_rate_hz=50)


def _effect_signature(nominal_gait_run, name: str, value: float):
    """The residual signature of the gait run with one effect added, against the nominal run."""
    params = EffectLibrary().transform(ModelParameters.nominal(), {name: value})
    changed = simulate_gait(SidewindingGait(0.5), 3.0, params=params, sample_rate_hz=50)
    return changed, localise([(changed, nominal_gait_run)])


def test_friction_makes_the_joints_lag_against_their_motion_and_a_gear_play_does_not(nominal_gait_run):
    """Joint friction resists the motion: the reading falls behind the command, so the residual
    has the opposite sign of the commanded velocity (r_sign_signed < 0) and the amplitude falls
    short. A 0.03 rad gear play moves the readings too (mrad), but the loop acts on the output's
    reading and takes the play up: the amplitude is kept and the residual hardly follows the
    motion's sign."""
    _, sig = _effect_signature(nominal_gait_run, "joint_coulomb_friction", 0.5)
    assert sig.r_sign_signed < -0.4                             # -0.64 when written
    assert sig.amplitude_ratio < 0.995                          # 0.992
    _, sig = _effect_signature(nominal_gait_run, "backlash", 0.03)
    assert sig.joint_rmse_rad > 0.003                           # 0.009
    assert abs(sig.amplitude_ratio - 1.0) < 0.005               # 1.002
    assert abs(sig.r_sign) < 0.3                                # 0.17


def test_a_command_delay_shifts_the_joints_in_time(nominal_gait_run):
    """Commands late by 50 ms: the joints follow the same path 50 ms later, a residual
    proportional to -qdot, and the cross-correlation's best lag within one 20 ms sample."""
    _, sig = _effect_signature(nominal_gait_run, "actuator_delay", 0.05)
    assert abs(sig.lag_s - 0.05) <= 0.02 + 1e-9
    assert sig.r_vel_signed < -0.9


def test_a_torque_limit_cuts_the_amplitude_of_the_loaded_joints(nominal_gait_run):
    """At 1 N m (a quarter of the gait's demand) the joints cannot follow the command's swings:
    their amplitude falls short by several percent and the tracking error is a large part of
    a 60 degree yaw swing."""
    _, sig = _effect_signature(nominal_gait_run, "torque_saturation", 1.0)
    assert sig.amplitude_ratio < 0.95                          # 0.90 when written
    assert sig.joint_rmse_rad > 0.05                           # 0.15 rad when written


def test_ground_effects_move_the_head_more_than_the_joints(nominal_gait_run):
    """Sideways friction 2.5 times the along-body one, or 1 kg on the head: the joints still
    follow their servos, the body slides or drags differently, so the head path carries most of
    the disagreement (head_share > 1/2) and the head ends centimetres away."""
    for name, value in (("anisotropic_ground_friction", 2.5), ("link_mass_error", 1.0)):
        _, sig = _effect_signature(nominal_gait_run, name, value)
        assert sig.head_share > 0.5, (name, sig.head_share)    # 0.63 and 0.82 when written
        assert sig.head_final_m > 0.05, (name, sig.head_final_m)
        assert abs(sig.r_sign) < 0.3, (name, sig.r_sign)       # no lag against the motion


def test_an_encoder_offset_is_a_constant_reading_error(nominal_gait_run):
    """The encoders read q + 0.05 rad: at rest before the gait every reading is off by exactly
    the offset, and afterwards the residual keeps a mean larger than its spread that does not
    depend on the commanded velocity."""
    changed, sig = _effect_signature(nominal_gait_run, "encoder_offset", 0.05)
    np.testing.assert_allclose(changed.q[0] - nominal_gait_run.q[0], 0.05, atol=1e-12)
    assert sig.offset_score > 1.0                              # 1.46 when written
    assert abs(sig.r_vel) < 0.2 and abs(sig.r_sign) < 0.2


def test_localisation_on_analytic_residuals():
    run = simulate_gait(SidewindingGait(0.5), 6.0, sample_rate_hz=50)
    same = localise([(run, run)])
    assert same.joint_rmse_rad == 0 and same.head_final_m == 0
    # a constant encoder-like offset: the offset score is large, velocity correlations are not
    offset = dataclasses.replace(run, q=run.q + 0.02)
    sig = localise([(offset, run)])
    assert sig.offset_score > 5 and abs(sig.offset_rad - 0.02) < 1e-9 and sig.r_vel < 0.1
    # a Coulomb-like lag: residual = -c sign(qdot_ref)
    qd = np.gradient(run.q_ref, run.t, axis=0)
    lagged = dataclasses.replace(run, q=run.q - 0.01 * np.sign(qd))
    sig = localise([(lagged, run)])
    assert sig.r_sign > 0.95 and sig.r_sign_signed < 0
    # a time shift: the measurement lags by 0.1 s
    shift = 5
    delayed = dataclasses.replace(run, q=np.vstack([np.repeat(run.q[:1], shift, 0), run.q[:-shift]]))
    sig = localise([(delayed, run)])
    assert sig.lag_s == pytest.approx(0.1, abs=0.021) and sig.r_vel > 0.8
    # a head-path offset sideways: head channel
    moved = dataclasses.replace(run, head_pos=run.head_pos + np.array([0.0, 0.05, 0.0]))
    assert localise([(moved, run)]).head_share > 0.99


@pytest.mark.parametrize("effect", EFFECTS, ids=lambda e: e.name)
def test_screening_starts_lie_between_inactive_and_the_bounds(effect):
    """Every effect is tried from values where it acts, on each side it can act, within its
    bounds; a torque limit is tried at fractions of the torque the model demands, finest just
    below it, where a limit starts to act."""
    from sysid.discrepancy.diagnose import start_grid

    p = effect.parameter
    demand = 4.0 if effect.acts_below_demand else None
    for coarse in (False, True):
        grid = np.array(start_grid(effect, demand_nm=demand, coarse=coarse))
        assert np.all((grid >= p.min) & (grid <= p.max)) and np.all(grid != p.value)
        sides = {np.sign(v - p.value) for v in grid}
        assert sides == {s for s, bound in ((-1.0, p.min), (1.0, p.max)) if bound != p.value}
    if effect.acts_below_demand:
        grid = np.array(start_grid(effect, demand_nm=demand))
        assert grid.max() < demand and grid.max() >= 0.9 * demand and grid.min() < 2.0
        # the unbent model's profile looks wherever a start would: a fit that bent the motor to
        # mimic a limit hides it wherever the limit lies
        profile = np.array(start_grid(effect, demand_nm=demand, coarse=True))
        assert profile.min() == pytest.approx(grid.min()) and profile.max() <= grid.max()
        with pytest.raises(InputError, match=effect.name):
            start_grid(effect)
