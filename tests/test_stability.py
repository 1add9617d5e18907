"""The largest stable steps (integrators.stability) against what the step really does.

The limits are exact for the linearised robot. The real contact is one-sided (it lets go instead
of pulling) and the servo holds its duty between ticks, which moved the threshold by up to 15 %
below the limit in the measurements below (``integrators.stability.MARGIN``); the tests check
20 % either side of each limit: below it the motion settles, above it the step feeds energy in.
"""
from __future__ import annotations

import numpy as np
import pytest

from cobra_cli.main import main as cobra_main
from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters
from integrators.simulator import SimSettings, SimulationDiverged, Simulator
from integrators.stability import check_steps, damped_spring_step_limit, step_limits


def test_the_closed_form_limit_matches_the_step_on_one_spring_damper():
    """Semi-implicit Euler on m x'' = -k x - c x': bounded just below the limit, growing just above."""
    k, c, m = 5e4, 30.0, 0.2
    h_max = damped_spring_step_limit(k, c, m)

    def peak(h: float) -> float:
        x, v = 1.0, 0.0
        for _ in range(2000):
            v += h * (-k * x - c * v) / m
            x += h * v
        return abs(x)

    assert peak(0.99 * h_max) < 1.0
    assert peak(1.01 * h_max) > 1e3


@pytest.mark.parametrize("k1, k2", [(5e4, 1.0), (5e4, 10.0), (1e4, 1.0)])
def test_a_drop_on_the_ground_settles_below_the_contact_limit_and_bounces_above(cobra, k1, k2):
    params = ModelParameters.nominal().with_values(k1=k1, k2=k2)
    limit = step_limits(Simulator(cobra, params).model, params)
    assert "ground stiffness" in limit.dt_reason

    def second_half_top(factor: float) -> float:
        dt = factor * limit.dt
        sim = Simulator(cobra, params, SimSettings(dt=dt, control_dt=dt))
        rest = sim.rest_state()
        start = sim.state(rest.q + np.r_[0.0, 0.0, 0.002, np.zeros(cobra.nq - 3)])  # 2 mm above rest
        try:
            tr = sim.rollout(start, np.zeros((1, cobra.n_joints)), 2.0)
        except SimulationDiverged:
            return np.inf
        return float(tr.q[len(tr.t) // 2:, 2].max() - rest.q[2])

    # measured: in the second second the head stays at rest (within 0.2 mm) at 0.8 x the limit for
    # all three grounds; at 1.2 x it diverged for (5e4, 1) and (1e4, 1) and rose 20 mm for (5e4, 10)
    assert second_half_top(0.8) < 0.5e-3
    assert second_half_top(1.2) > 2e-3   # higher than it was dropped from: the step feeds energy in


def test_the_motor_damping_limit_holds_on_a_light_transmission(cobra):
    """With the lightest transmission inertia the back-EMF damping bounds dt, below 1 ms: joints
    at rest stay at rest below the limit and oscillate above it (the motor's torque clip at the
    stall torque keeps the oscillation bounded)."""
    params = ModelParameters.nominal().with_values(armature=1e-4)
    limit = step_limits(Simulator(cobra, params).model, params)
    assert "back-EMF" in limit.dt_reason and limit.dt < 1e-3     # measured 0.84 ms

    def late_joint_speed(factor: float) -> float:
        dt = factor * limit.dt
        sim = Simulator(cobra, params, SimSettings(dt=dt, control_dt=dt))
        tr = sim.rollout(sim.rest_state(), np.zeros((1, cobra.n_joints)), 2.0)
        return float(np.abs(tr.v[3 * len(tr.t) // 4:, cobra.n_base:]).max())

    # measured: 1e-14 rad/s at 0.8 and 0.9 x the limit; 0.7 rad/s at 0.95 x, 5.4 rad/s at 1.2 x
    assert late_joint_speed(0.8) < 1e-6
    assert late_joint_speed(1.2) > 1.0


def test_a_divergence_names_the_coordinate_and_the_stable_steps(cobra):
    sim = Simulator(cobra, ModelParameters.nominal(), SimSettings(dt=0.05, control_dt=0.05))
    with pytest.raises(SimulationDiverged, match=r"largest stable dt is .* s \(set by .*\) and control_dt"):
        sim.rollout(sim.rest_state(), np.zeros((1, cobra.n_joints)), 5.0)


def test_check_steps_names_the_setting_and_the_largest_stable_value(cobra):
    params = ModelParameters.nominal().with_values(k1=5e4, k2=200.0)
    model = Simulator(cobra, params).model
    limit = step_limits(model, params)
    check_steps(model, params, 1e-3, 1e-3)
    with pytest.raises(InputError, match=r"dt = 0.01 s is unstable .* largest stable dt is"):
        check_steps(model, params, 0.01, 0.01)
    with pytest.raises(InputError, match=r"control_dt = 0.05 s is unstable for the servo's position loop"):
        check_steps(model, params, 1e-3, 0.05)
    assert limit.dt < 0.01 and limit.control_dt < 0.05
    with pytest.raises(InputError, match="largest stable dt"):       # the margin is enforced
        check_steps(model, params, 0.9 * limit.dt, 0.9 * limit.dt)


def test_cobra_simulate_refuses_an_unstable_dt_before_running(tmp_path, capsys):
    out = tmp_path / "run.csv"
    code = cobra_main(["simulate", "--out", str(out), "--dt", "0.02", "--duration", "1"])
    err = capsys.readouterr().err
    assert code != 0 and "largest stable dt" in err and "--dt" in err
    assert not out.exists()


@pytest.mark.parametrize("option, message", [
    (["--rate", "0"], "--rate: sample rate must be a positive number of Hz, got 0"),
    (["--rate", "-5"], "--rate: sample rate must be a positive number of Hz, got -5"),
    (["--rate", "nan"], "--rate: sample rate must be a positive number of Hz, got nan"),
    (["--duration", "nan"], "--duration must be > 0 s, got nan"),
    (["--heading", "nan"], "--heading must be a finite angle [deg], got nan"),
])
def test_cobra_simulate_refuses_a_rate_duration_or_heading_out_of_range(tmp_path, capsys, option, message):
    """Before these checks a rate of 0 and a NaN duration ended in a traceback, a negative rate
    wrote 1 kHz samples, and a NaN heading was reported as a divergence."""
    out = tmp_path / "run.csv"
    assert cobra_main(["simulate", "--out", str(out), "--duration", "0.1", *option]) == 2
    assert message in capsys.readouterr().err and not out.exists()


def test_cobra_simulate_says_when_the_rate_is_rounded_to_whole_steps(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert cobra_main(["simulate", "--out", str(out), "--duration", "0.3", "--rate", "300"]) == 0
    printed = capsys.readouterr().out
    assert "note: sampled at 333.3 Hz, one sample every 3 physics steps of 0.001 s (the nearest to --rate 300 Hz)" \
        in printed
    assert cobra_main(["simulate", "--out", str(tmp_path / "every.csv"), "--duration", "0.3", "--rate", "5000"]) == 0
    assert "note: sampled at 1000 Hz, one sample every physics step of 0.001 s" in capsys.readouterr().out
    assert cobra_main(["simulate", "--out", str(tmp_path / "exact.csv"), "--duration", "0.3", "--rate", "250"]) == 0
    assert "note: sampled at" not in capsys.readouterr().out


def test_a_rollout_refuses_a_duration_or_a_start_that_is_not_finite(cobra):
    sim = Simulator(cobra, ModelParameters.nominal())
    with pytest.raises(InputError, match="rollout duration must be a number of seconds >= 0, got nan"):
        sim.rollout(sim.rest_state(), np.zeros((1, 11)), float("nan"))
    with pytest.raises(InputError, match="rollout duration must be a number of seconds >= 0, got -1"):
        sim.rollout(sim.rest_state(), np.zeros((1, 11)), -1.0)
    with pytest.raises(InputError, match=r"rest_state: head_xy \[m\] and heading_rad must be finite"):
        sim.rest_state(heading_rad=float("nan"))
