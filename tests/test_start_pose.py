"""What a recorded run is reproduced from: its start pose (and its uncertainty) and its commands."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobra_model import CobraModel, ModelParameters
from cobra_model.run import Run
from integrators.simulate import InitialPose, StartObservation, command_ticks
from integrators.simulator import Simulator
from sysid.generators.dataset import RunPlan, record
from sysid.identification.objective import Objective


@pytest.fixture(scope="module")
def recorded() -> tuple[list[Run], list[RunPlan]]:
    """Short runs measured like the reference dataset (mocap noise 0.5 mm, 0.2 deg)."""
    model = CobraModel.load()
    sim = Simulator(model, ModelParameters.nominal())
    rng = np.random.default_rng(21)
    plans = [RunPlan(f"p{i}", 0.5, 2.0, (rng.uniform(-1, 1), rng.uniform(-1, 1)), rng.uniform(0, 2 * np.pi), "train")
             for i in range(4)]
    return [record(sim, p, rng, model) for p in plans], plans


def _pose(run: Run, model: CobraModel | None = None) -> InitialPose:
    """The run's start pose with the encoders read as the joint angles."""
    start = StartObservation.of_run(run)
    return start.pose(model or CobraModel.load(), start.q_reading)


def _yaw(quat_wxyz: np.ndarray) -> float:
    w, x, y, z = quat_wxyz
    return float(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def _wrap(angle: float) -> float:
    return float(np.angle(np.exp(1j * angle)))


def test_start_pose_from_tracked_bodies_is_accurate_and_its_uncertainty_honest(recorded):
    """Head, link_6 and tail spread along the body pin the heading to a few hundredths of a
    degree; the reported uncertainties cover the actual errors (4 sigma)."""
    runs, plans = recorded
    model = CobraModel.load()
    for run, plan in zip(runs, plans):
        pose = _pose(run, model)
        yaw_err = _wrap(_yaw(pose.head_quat_wxyz) - plan.heading_rad)
        xy_err = np.array(pose.head_xy) - np.array(plan.head_xy)
        assert 0 < pose.yaw_std_rad < np.deg2rad(0.05)
        assert abs(yaw_err) < 4 * pose.yaw_std_rad
        assert np.all(np.abs(xy_err) < 4 * pose.xy_std_m)
        assert abs(pose.head_quat_wxyz[1]) == abs(pose.head_quat_wxyz[2]) == 0.0   # at rest: yaw only


def test_start_pose_without_bodies_uses_the_head_orientation(recorded):
    """Without body tracks the heading comes from the head's own (noisier) orientation, and
    its uncertainty says so."""
    runs, plans = recorded
    with_bodies = [_pose(r).yaw_std_rad for r in runs]
    head_only = [_pose(dataclasses.replace(r, bodies={})) for r in runs]
    assert np.mean([p.yaw_std_rad for p in head_only]) > 2 * np.mean(with_bodies)
    for pose, plan in zip(head_only, plans):
        assert abs(_wrap(_yaw(pose.head_quat_wxyz) - plan.heading_rad)) < 4 * pose.yaw_std_rad + 1e-3


def _command_run(t: np.ndarray, q_ref: np.ndarray) -> Run:
    n = len(t)
    quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return Run(t=t, q_ref=q_ref, q=q_ref, head_pos=np.zeros((n, 3)), head_quat=quat)


def test_commands_logged_at_50_hz_are_rebuilt_to_third_order():
    """A 0.65 Hz, 60 deg sinusoid logged at 50 Hz: linear interpolation cuts the peaks by about
    (2 pi f dt)^2 / 8 * A = 0.7 mrad; Akima's cubic is more than 10x closer."""
    t = np.arange(0.0, 4.0, 0.02)
    w = 2 * np.pi * 0.65
    q_ref = np.tile(np.deg2rad(60) * np.sin(w * t)[:, None], (1, 11))
    ticks = command_ticks(_command_run(t, q_ref), 1e-3)
    tt = np.arange(len(ticks)) * 1e-3
    exact = np.deg2rad(60) * np.sin(w * tt)
    linear = np.abs(np.interp(tt, t, q_ref[:, 0]) - exact).max()
    assert linear > 5e-4
    assert np.abs(ticks[:, 0] - exact).max() < linear / 10


def test_held_goals_stay_until_the_next_sample():
    """A recorder's goals (sidecar ``q_ref_between_samples: "held"``) are what the servos hold
    between writes: each tick carries the latest goal sent at or before it, never a blend, and
    a sample's own tick already has its goal (times jitter, as a host's clock does)."""
    rng = np.random.default_rng(3)
    t = 0.05 + np.cumsum(rng.uniform(0.018, 0.022, 100))
    q_ref = np.tile(rng.normal(size=(100, 1)), (1, 11))
    run = _command_run(t, q_ref).with_meta(q_ref_between_samples="held")
    ticks = command_ticks(run, 1e-3)
    tick_t = t[0] + np.arange(len(ticks)) * 1e-3
    latest = np.array([np.flatnonzero(t <= tt + 1e-9)[-1] for tt in tick_t])
    np.testing.assert_array_equal(ticks[:, 0], q_ref[latest, 0])
    # every goal is held for a while (the last one from its time on, past the last tick maybe)
    assert set(q_ref[:-1, 0]) <= set(ticks[:, 0])
    smooth = command_ticks(_command_run(t, q_ref), 1e-3)
    assert np.abs(smooth[:, 0] - ticks[:, 0]).max() > 0.1  # the default blends the same rows


def test_a_reproduction_of_held_goals_is_a_run_of_held_goals(recorded):
    """``simulate_like`` of a recording keeps its goals and says they were held: its ``q_ref`` rows
    are the recording's (not blends of two goals around each sample), so reproducing the
    reproduction drives the servos exactly as the first did."""
    from integrators.simulate import simulate_like

    measured = recorded[0][0].slice_time(0.0, 0.6).with_meta(q_ref_between_samples="held")
    held = simulate_like(measured)
    assert held.q_ref_held and np.array_equal(held.q_ref, measured.q_ref)
    np.testing.assert_array_equal(command_ticks(held, 1e-3), command_ticks(measured, 1e-3))
    smooth = simulate_like(recorded[0][0].slice_time(0.0, 0.6))
    assert not smooth.q_ref_held
    # the joints followed other commands: held goals lag the interpolated ones by half a period
    assert np.abs(held.q - smooth.q).max() > 1e-3


def test_step_commands_are_not_overshot():
    t = np.arange(0.0, 1.0, 0.02)
    q_ref = np.tile(np.where(t < 0.5, 0.0, 1.0)[:, None], (1, 11))
    ticks = command_ticks(_command_run(t, q_ref), 1e-3)
    assert ticks.min() == 0.0 and ticks.max() == 1.0


def test_start_pose_sensitivity_matches_resimulation(recorded):
    """The analytic derivative of the head residual by a run's start pose (rigid motion of the
    simulated path) agrees with simulating from a moved and turned start: the ground law does
    not depend on where the robot stands or which way it faces."""
    runs, _ = recorded
    obj = Objective(runs[:1], ModelParameters.nominal())
    x = obj.params.as_vector()[None]
    r0 = obj.residuals(x)[0]
    J, std = obj.start_pose_sensitivity(r0)
    assert J.shape == (r0.size, 3) and np.all(std > 0)
    tg = obj.spec.targets[0]
    start = tg.start
    for column, (dx, dy, dyaw, step) in enumerate([(1e-3, 0.0, 0.0, 1e-3), (0.0, 1e-3, 0.0, 1e-3),
                                                   (0.0, 0.0, 2e-3, 2e-3)]):
        # the measured start moved by (dx, dy) and turned by dyaw about the head
        c, s_ = np.cos(dyaw), np.sin(dyaw)
        rel = start.points_xy - start.points_xy[0]
        points = start.points_xy[0] + rel @ np.array([[c, s_], [-s_, c]]) + np.array([dx, dy])
        moved_start = dataclasses.replace(start, points_xy=points, head_yaw=start.head_yaw + dyaw)
        moved = dataclasses.replace(obj, runs=obj.runs)
        moved.spec = dataclasses.replace(obj.spec, targets=(dataclasses.replace(tg, start=moved_start),))
        numeric = (moved.residuals(x)[0] - r0) / step
        assert np.linalg.norm(numeric - J[:, column]) < 0.02 * np.linalg.norm(J[:, column]), column


def test_a_run_is_reproduced_from_where_its_joints_really_were():
    """With an encoder offset the first reading is not the first joint angle: a run simulated
    with the offset is reproduced (same parameters) from reading - offset, its planar pose
    fitted with the joints there, so the reproduction follows it; from the raw readings every
    joint would start 0.05 rad off and the fitted heading 7 deg off."""
    from cobra_model import SidewindingGait
    from integrators.simulate import simulate_gait, simulate_like
    from sysid.discrepancy.effects import EffectLibrary
    from sysid.gap.metrics import compare_runs

    params = EffectLibrary().transform(ModelParameters.nominal(), {"encoder_offset": 0.05}, frozen=True)
    run = simulate_gait(SidewindingGait(0.5), 3.0, params=params, heading_rad=0.4)
    again = simulate_like(run, params=params)
    assert compare_runs(run, again).to_json_dict()["head_final_error_m"] < 2e-3
    assert np.abs(again.q - run.q).max() < 5e-3


def test_a_jittered_log_is_reproduced_up_to_its_last_sample():
    """A log's times jitter, so a run's span is rarely a whole number of record periods. Logged
    at 50 Hz from a 1 kHz simulation with each time up to 1 ms early (the last 2 ms early),
    the run is reproduced (same parameters) at every sample, its last included: before, the last
    sample was read from the record 20 ms before it (61 mrad off on yaw joint 2 at 0.5 Hz, which
    alone raised that joint's RMSE over 3 s by 8 mrad)."""
    from cobra_model import SidewindingGait
    from integrators.simulate import simulate_gait, simulate_like

    fine = simulate_gait(SidewindingGait(0.5), 3.0, heading_rad=0.4, sample_rate_hz=1000)
    rng = np.random.default_rng(3)
    index = np.arange(0, len(fine.t), 20) + rng.integers(-1, 1, size=len(fine.t[::20]))
    index[0], index[-1] = 0, len(fine.t) - 3   # 2.998 s: 2 ms short of the 3 s record
    logged = fine.select(np.clip(index, 0, len(fine.t) - 1))
    again = simulate_like(logged)
    assert logged.t[-1] == pytest.approx(2.998)
    # the same simulation: equal within the encoders' rounding (one count 1.5 mrad) and the
    # commands' rebuilding from a 50 Hz log
    assert np.abs(again.q - logged.q).max() < 5e-3
    assert np.abs(again.q[-1] - logged.q[-1]).max() < 5e-3
