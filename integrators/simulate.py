"""Simulated runs in the ``cobra-run/1`` shape: simulate a gait, or reproduce a recorded run.

A recorded run is reproduced from its first sample's pose (head position and orientation,
joint angles), at rest, and its ``q_ref`` columns alone (DATA_FORMAT.md). The commands are
put on the servo's control ticks as the run's sidecar says they were applied: interpolated
(Akima) between samples of a smooth command, or each goal held until the next sample when a
recorder streamed them (``q_ref_between_samples: "held"``); the simulated trajectory is sampled
back at the run's own times.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.interpolate import Akima1DInterpolator

from cobra_model.errors import InputError
from cobra_model.gait import SidewindingGait
from cobra_model.model import CobraModel
from cobra_model.parameters import ModelParameters
from cobra_model.run import Q_REF_BETWEEN_SAMPLES, Run
from integrators.simulator import SimSettings, SimState, Simulator, Trajectory, friction_eps

#: Bodies a simulated run reports besides the head (the paper tracked the head, link 6 and the tail).
TRACKED_BODIES: tuple[str, ...] = ("link_6", "tail")
DEFAULT_SAMPLE_RATE_HZ = 100.0


#: Span [s] at a run's start over which the initial pose is averaged (the robot barely moves in it).
START_WINDOW_S = 0.1


@dataclass(frozen=True)
class InitialPose:
    """Where a run starts: head (x, y) [m], head orientation (w, x, y, z), joint angles [rad],
    and the standard uncertainty of the measured planar pose: head position [m] (per axis) and
    heading [rad] (0 when it cannot be estimated)."""

    head_xy: tuple[float, float]
    head_quat_wxyz: np.ndarray
    q_joints: np.ndarray
    xy_std_m: float = 0.0
    yaw_std_rad: float = 0.0


@dataclass(frozen=True)
class StartObservation:
    """What a run measured at its start, from which its initial pose is estimated.

    The robot starts at rest lying on flat ground, so only its planar pose (x, y, yaw) is
    taken from the measurement; roll and pitch follow from the contact (see
    ``Simulator.rest_state``). The planar pose is a least-squares rigid fit of the model's
    tracked points (head origin and every ``body_*`` the run carries, placed by the start's
    joint angles) to their motion-capture positions averaged over the first
    :data:`START_WINDOW_S`. Bodies spread along the robot pin the heading far better than the
    head's own orientation: on the reference dataset the heading error drops from about
    0.4 deg to 0.05 deg. Without body tracks the yaw of the head's orientation is used.
    The joint angles are the first encoder readings less the encoder offset of the model that
    reproduces the run (:meth:`integrators.simulator.Simulator.joints_reading`), so they, and
    with them the fitted planar pose, depend on the model. A joint-only run (no head pose in
    any sample: recorded without motion capture) starts at the origin, heading along +x
    (``has_head_pose`` False); only its joints can then be compared.

    Attributes:
        q_reading: (11,) first encoder readings [rad].
        points_xy: (k, 2) window-averaged world (x, y) [m] of the head origin, then of ``bodies``.
        bodies: names of the tracked bodies in ``points_xy`` after the head.
        var_point: variance [m^2] of one averaged point per coordinate, from the samples' scatter.
        head_yaw: window-mean yaw of the head's orientation [rad].
        head_yaw_var: variance of that mean [rad^2].
        has_head_pose: False for a joint-only run (then the pose is the origin, exactly).
    """

    q_reading: np.ndarray
    points_xy: np.ndarray
    bodies: tuple[str, ...]
    var_point: float
    head_yaw: float
    head_yaw_var: float
    has_head_pose: bool = True

    @classmethod
    def of_run(cls, run: Run) -> "StartObservation":
        ok = np.all(np.isfinite(run.head_pos), axis=1) & np.all(np.isfinite(run.head_quat), axis=1)
        if not ok.any():
            return cls(run.q[0].copy(), np.zeros((1, 2)), (), 0.0, 0.0, 0.0, has_head_pose=False)
        first = int(np.flatnonzero(ok)[0])
        window = ok & (run.t <= run.t[first] + START_WINDOW_S)
        names = tuple(name for name, pos in run.bodies.items() if np.isfinite(pos[window, :2]).all(axis=1).any())
        tracks = [run.head_pos[window, :2]] + [run.bodies[name][window, :2] for name in names]
        n = np.array([np.isfinite(tr).all(axis=1).sum() for tr in tracks])
        scatter = [np.nanvar(tr, axis=0, ddof=1).mean() for tr, k in zip(tracks, n) if k > 1]
        w, x, y, z = run.head_quat[window].T
        yaw_k = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        yaw = float(np.arctan2(np.sin(yaw_k).mean(), np.cos(yaw_k).mean()))
        yaw_var = float(np.var(np.angle(np.exp(1j * (yaw_k - yaw))), ddof=1)) / len(yaw_k) if len(yaw_k) > 1 else 0.0
        return cls(run.q[0].copy(), np.array([np.nanmean(tr, axis=0) for tr in tracks]), names,
                   float(np.mean(scatter)) / float(n.mean()) if scatter else 0.0, yaw, yaw_var)

    def pose(self, model: CobraModel, q_joints: np.ndarray) -> InitialPose:
        """The initial pose with the robot's joints at ``q_joints`` [rad] (and its uncertainty)."""
        if self.bodies:
            centres = model.body_centres(model.configuration(q_joints, np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])))
            model_xy = np.array([np.zeros(2)] + [centres[name][:2] for name in self.bodies])
            xy, yaw, misfit = _planar_fit(model_xy, self.points_xy)
            var = max(self.var_point, misfit)
            var_yaw = var / float(((model_xy - model_xy.mean(axis=0)) ** 2).sum())
            lever = float(np.sum(model_xy.mean(axis=0) ** 2))     # head origin to the points' centroid
            var_xy = var / len(model_xy) + var_yaw * lever
        else:
            xy, yaw, var_xy, var_yaw = self.points_xy[0], self.head_yaw, self.var_point, self.head_yaw_var
        return InitialPose((float(xy[0]), float(xy[1])), np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]),
                           np.asarray(q_joints, dtype=float).copy(), float(np.sqrt(var_xy)), float(np.sqrt(var_yaw)))


def _planar_fit(model_xy: np.ndarray, world_xy: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Rigid planar transform taking ``model_xy`` (n, 2) onto ``world_xy``: translation [m], yaw
    [rad] and the misfit variance per coordinate [m^2] (0 for fewer than 3 points)."""
    pm, pw = model_xy.mean(axis=0), world_xy.mean(axis=0)
    H = (model_xy - pm).T @ (world_xy - pw)
    yaw = float(np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1]))
    R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    t = pw - R @ pm
    dof = 2 * len(model_xy) - 3
    misfit = float(np.sum((model_xy @ R.T + t - world_xy) ** 2)) / dof if dof > 0 else 0.0
    return t, yaw, misfit


def trajectory_to_run(model: CobraModel, traj: Trajectory, t_out: np.ndarray | None = None,
                      meta: dict | None = None) -> Run:
    """Convert a simulator trajectory to a run, optionally resampled at times ``t_out`` [s]."""
    q = traj.q
    heads = q[:, 0:3]
    quat = np.column_stack([q[:, 6], q[:, 3], q[:, 4], q[:, 5]])
    bodies = model.body_tracks(q, TRACKED_BODIES)
    t = traj.t
    cols = {"q_ref": traj.q_goal, "q": traj.q_meas, "dq": traj.v[:, model.n_base:], "current": traj.current,
            "head_pos": heads, "head_quat": quat}
    if t_out is not None:
        t_out = np.asarray(t_out, dtype=float)
        if t_out.size and (t_out[0] < t[0] - 1e-9 or t_out[-1] > t[-1] + 1e-9):
            raise ValueError(f"sample times {t_out[0]:.4f}..{t_out[-1]:.4f} s reach outside the simulated "
                             f"{t[0]:.4f}..{t[-1]:.4f} s (the nearest record would be held)")
        interp = lambda a: np.column_stack([np.interp(t_out, t, a[:, j]) for j in range(a.shape[1])])  # noqa: E731
        cols = {k: interp(a) for k, a in cols.items()}
        cols["head_quat"] /= np.linalg.norm(cols["head_quat"], axis=1, keepdims=True)
        bodies = {k: interp(a) for k, a in bodies.items()}
        t = t_out
    return Run(t=t, bodies=bodies, meta=dict(meta or {"format": "cobra-run/1"}), **cols)


def _meta(params: ModelParameters, settings: SimSettings, gait: dict | None, notes: str) -> dict:
    meta = {"format": "cobra-run/1", "source": "simulation", "params": params.to_json_dict(),
            "sim_settings": {"dt": settings.dt, "control_dt": settings.control_dt,
                             "sgn_eps": friction_eps(params, settings), "scheme": settings.scheme}, "notes": notes}
    if gait is not None:
        meta["gait"] = gait
    return meta


def record_period(sample_rate_hz: float, dt: float) -> int:
    """Physics steps of ``dt`` [s] per sample of a run sampled at ``sample_rate_hz`` [Hz]: the
    nearest whole number, at least one (a rate above the physics rate samples every step).

    Raises:
        InputError: a rate that is not a positive number of Hz.
    """
    if not (np.isfinite(sample_rate_hz) and sample_rate_hz > 0):
        raise InputError(f"sample rate must be a positive number of Hz, got {sample_rate_hz:g}")
    return max(1, int(round(1.0 / (sample_rate_hz * dt))))


def simulate_gait(gait: SidewindingGait, duration: float, *, params: ModelParameters | None = None,
                  settings: SimSettings | None = None, model: CobraModel | None = None,
                  simulator: Simulator | None = None, head_xy: tuple[float, float] = (0.0, 0.0), heading_rad: float = 0.0,
                  sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
                  progress: Callable[[float], None] | None = None) -> Run:
    """Simulate the gait from the straight pose at rest; the run is sampled at ``sample_rate_hz``.

    ``simulator`` (if given) replaces ``params``, ``settings`` and ``model``; the samples are
    every :func:`record_period` physics steps.

    Raises:
        InputError: a sample rate :func:`record_period` refuses.
    """
    sim = simulator or Simulator(model or CobraModel.load(), params or ModelParameters.nominal(), settings)
    every = record_period(sample_rate_hz, sim.settings.dt)
    state = sim.rest_state(gait.q_ref(0.0), head_xy=head_xy, heading_rad=heading_rad)
    traj = sim.rollout(state, gait.q_ref, duration, record_every=every, progress=progress)
    return trajectory_to_run(sim.model, traj, meta=_meta(sim.params, sim.settings, gait.to_json(),
                                                    f"simulated {duration} s of sidewinding at {gait.freq_hz} Hz"))


def simulate_like(run: Run, *, params: ModelParameters | None = None, settings: SimSettings | None = None,
                  model: CobraModel | None = None, simulator: Simulator | None = None,
                  progress: Callable[[float], None] | None = None) -> Run:
    """Reproduce ``run`` in simulation: same initial pose, same ``q_ref``, sampled at the run's times.

    A run of held goals (:attr:`~cobra_model.run.Run.q_ref_held`) gives a run of held goals: its
    ``q_ref`` rows are the run's own (the goal held at each sample time; sampling the simulated
    goal ticks linearly would blend two goals around each sample) and its sidecar says
    ``q_ref_between_samples: "held"``, so that the reproduction is reproduced alike."""
    sim = simulator or Simulator(model or CobraModel.load(), params or ModelParameters.nominal(), settings)
    traj = rollout_like(sim, run, progress=progress)
    gait = run.meta.get("gait") if isinstance(run.meta, dict) else None
    meta = _meta(sim.params, sim.settings, gait, f"reproduction of {run.source or 'a run'}")
    simulated = trajectory_to_run(sim.model, traj, t_out=run.t, meta=meta)
    if run.q_ref_held:
        simulated = dataclasses.replace(simulated, q_ref=run.q_ref, meta={**meta, Q_REF_BETWEEN_SAMPLES: "held"})
    return simulated


def start_state(sim: Simulator, run: Run) -> SimState:
    """The simulator state at rest in the run's first pose (time = the run's first time)."""
    start = StartObservation.of_run(run)
    pose = start.pose(sim.model, sim.joints_reading(start.q_reading))
    st = sim.rest_state(pose.q_joints, head_xy=pose.head_xy, base_quat_wxyz=pose.head_quat_wxyz)
    return SimState(float(run.t[0]), st.q, st.v, st.integ, st.prev_err, st.duty, st.current, 0)


def command_ticks(run: Run, control_dt: float) -> np.ndarray:
    """The run's ``q_ref`` (n_ticks, 11) [rad] on control ticks from its first time.

    A run whose goals were held by the servos (:attr:`~cobra_model.run.Run.q_ref_held`, what
    :mod:`hardware.recorder` writes) gets each row from its time until the next row's (a
    zero-order hold): at 50 Hz that is, on average, half a period (10 ms) behind a smooth
    command, 33 mrad at the yaw joints' peak speed; interpolating such goals instead made the
    rms gap between an emulated recording and its simulation six times larger (13 vs 2 mrad,
    ``tests/test_emulator_sim.py``).

    Otherwise the rows sample a smooth command, rebuilt by Akima's local cubic: a gait logged at
    50 Hz is rebuilt 20 times closer than by linear interpolation, which cuts a sinusoid's peaks
    by about (2 pi f dt)^2 / 8 of its amplitude and so biased the fitted transmission inertia by
    2.6 % in ``benchmarks/recovery.py``; unlike a global cubic spline it does not overshoot a step command
    (PCHIP, also step-safe, flattens every sampled extremum and is barely better than linear there).
    """
    t0, t1 = float(run.t[0]), float(run.t[-1])
    ticks = t0 + np.arange(int(np.floor((t1 - t0) / control_dt + 1e-9)) + 1) * control_dt
    if len(run.t) < 2:
        return np.repeat(run.q_ref[:1], len(ticks), axis=0)
    if run.q_ref_held:
        # a tick within 1 ns of a goal's time already sees that goal (times are float sums)
        return run.q_ref[np.searchsorted(run.t, ticks + 1e-9, side="right") - 1]
    return Akima1DInterpolator(run.t, run.q_ref, axis=0)(np.minimum(ticks, t1))


def rollout_like(sim: Simulator, run: Run, *, record_every: int | None = None,
                 progress: Callable[[float], None] | None = None) -> Trajectory:
    """Roll the simulator out over the run's span with its commands (interpolated onto the ticks).

    The rollout goes on to the first recorded sample at or after the run's last time (less than
    one record period more, the last command held), so that every sample time of the run lies
    inside the recorded span: a log's times jitter, and a last sample between two records would
    otherwise be read from the earlier one (20 ms old at 50 Hz: 60 mrad on a yaw joint at 0.5 Hz).
    """
    t0, t1 = float(run.t[0]), float(run.t[-1])
    table = command_ticks(run, sim.settings.control_dt)
    every = record_every or max(1, int(round(max(run.dt_median, sim.settings.dt) / sim.settings.dt)))
    period = every * sim.settings.dt
    duration = np.ceil((t1 - t0) / period - 1e-9) * period
    return sim.rollout(start_state(sim, run), table, duration, record_every=every, progress=progress)
