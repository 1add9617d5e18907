"""Simulated runs in the ``cobra-run/1`` shape: simulate a gait, or reproduce a recorded run.

A recorded run is reproduced from its first sample's pose (head position and orientation,
joint angles), at rest, and its ``q_ref`` columns alone (DATA_FORMAT.md). The commands are
linearly interpolated from the run's samples onto the servo's control ticks; the simulated
trajectory is sampled back at the run's own times.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from cobra_model.errors import InputError
from cobra_model.gait import SidewindingGait
from cobra_model.model import CobraModel
from cobra_model.parameters import ModelParameters
from cobra_model.runs import Run
from integrators.simulator import SimSettings, SimState, Simulator, Trajectory

#: Bodies a simulated run reports besides the head (the paper tracked the head, link 6 and the tail).
TRACKED_BODIES: tuple[str, ...] = ("link_6", "tail")
DEFAULT_SAMPLE_RATE_HZ = 100.0


@dataclass(frozen=True)
class InitialPose:
    """Where a run starts: head (x, y) [m], head orientation (w, x, y, z), joint angles [rad]."""

    head_xy: tuple[float, float]
    head_quat_wxyz: np.ndarray
    q_joints: np.ndarray

    @classmethod
    def of_run(cls, run: Run) -> "InitialPose":
        """The pose of a run's first sample with valid motion capture."""
        ok = np.flatnonzero(np.all(np.isfinite(run.head_pos), axis=1) & np.all(np.isfinite(run.head_quat), axis=1))
        if ok.size == 0:
            raise InputError(f"{run.source or 'run'}: no sample has a head pose (head_* all empty)")
        i = int(ok[0])
        return cls((float(run.head_pos[i, 0]), float(run.head_pos[i, 1])), run.head_quat[i].copy(), run.q[0].copy())


def trajectory_to_run(model: CobraModel, traj: Trajectory, t_out: np.ndarray | None = None,
                      meta: dict | None = None) -> Run:
    """Convert a simulator trajectory to a run, optionally resampled at times ``t_out`` [s]."""
    q = traj.q
    heads = q[:, 0:3]
    quat = np.column_stack([q[:, 6], q[:, 3], q[:, 4], q[:, 5]])
    bodies = {name: np.array([model.body_centres(qi)[name] for qi in q]) for name in TRACKED_BODIES}
    t = traj.t
    cols = {"q_ref": traj.q_goal, "q": traj.q_meas, "dq": traj.v[:, model.n_base:], "current": traj.current,
            "head_pos": heads, "head_quat": quat}
    if t_out is not None:
        t_out = np.asarray(t_out, dtype=float)
        interp = lambda a: np.column_stack([np.interp(t_out, t, a[:, j]) for j in range(a.shape[1])])  # noqa: E731
        cols = {k: interp(a) for k, a in cols.items()}
        cols["head_quat"] /= np.linalg.norm(cols["head_quat"], axis=1, keepdims=True)
        bodies = {k: interp(a) for k, a in bodies.items()}
        t = t_out
    return Run(t=t, bodies=bodies, meta=dict(meta or {"format": "cobra-run/1"}), **cols)


def _meta(params: ModelParameters, settings: SimSettings, gait: dict | None, notes: str) -> dict:
    meta = {"format": "cobra-run/1", "source": "simulation", "params": params.to_json_dict(),
            "sim_settings": {"dt": settings.dt, "control_dt": settings.control_dt,
                             "sgn_eps": settings.sgn_eps}, "notes": notes}
    if gait is not None:
        meta["gait"] = gait
    return meta


def simulate_gait(gait: SidewindingGait, duration: float, *, params: ModelParameters | None = None,
                  settings: SimSettings | None = None, model: CobraModel | None = None,
                  head_xy: tuple[float, float] = (0.0, 0.0), heading_rad: float = 0.0,
                  sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
                  progress: Callable[[float], None] | None = None) -> Run:
    """Simulate the gait from the straight pose at rest; the run is sampled at ``sample_rate_hz``."""
    model = model or CobraModel.load()
    params = params or ModelParameters.nominal()
    sim = Simulator(model, params, settings)
    every = max(1, int(round(1.0 / (sample_rate_hz * sim.settings.dt))))
    state = sim.rest_state(gait.q_ref(0.0), head_xy=head_xy, heading_rad=heading_rad)
    traj = sim.rollout(state, gait.q_ref, duration, record_every=every, progress=progress)
    return trajectory_to_run(model, traj, meta=_meta(params, sim.settings, gait.to_json(),
                                                    f"simulated {duration} s of sidewinding at {gait.freq_hz} Hz"))


def simulate_like(run: Run, *, params: ModelParameters | None = None, settings: SimSettings | None = None,
                  model: CobraModel | None = None, simulator: Simulator | None = None,
                  progress: Callable[[float], None] | None = None) -> Run:
    """Reproduce ``run`` in simulation: same initial pose, same ``q_ref``, sampled at the run's times."""
    sim = simulator or Simulator(model or CobraModel.load(), params or ModelParameters.nominal(), settings)
    traj = rollout_like(sim, run, progress=progress)
    gait = run.meta.get("gait") if isinstance(run.meta, dict) else None
    return trajectory_to_run(sim.model, traj, t_out=run.t,
                             meta=_meta(sim.params, sim.settings, gait, f"reproduction of {run.source or 'a run'}"))


def start_state(sim: Simulator, run: Run) -> SimState:
    """The simulator state at rest in the run's first pose (time = the run's first time)."""
    pose = InitialPose.of_run(run)
    st = sim.rest_state(pose.q_joints, head_xy=pose.head_xy, base_quat_wxyz=pose.head_quat_wxyz)
    return SimState(float(run.t[0]), st.q, st.v, st.integ, st.prev_err, st.duty, st.current, 0)


def command_ticks(run: Run, control_dt: float) -> np.ndarray:
    """The run's ``q_ref`` (n_ticks, 11) [rad] linearly interpolated onto control ticks from its first time."""
    t0, t1 = float(run.t[0]), float(run.t[-1])
    ticks = t0 + np.arange(int(np.floor((t1 - t0) / control_dt + 1e-9)) + 1) * control_dt
    return np.column_stack([np.interp(ticks, run.t, run.q_ref[:, j]) for j in range(run.q_ref.shape[1])])


def rollout_like(sim: Simulator, run: Run, *, record_every: int | None = None,
                 progress: Callable[[float], None] | None = None) -> Trajectory:
    """Roll the simulator out over the run's span with its commands (interpolated onto the ticks)."""
    t0, t1 = float(run.t[0]), float(run.t[-1])
    table = command_ticks(run, sim.settings.control_dt)
    every = record_every or max(1, int(round(max(run.dt_median, sim.settings.dt) / sim.settings.dt)))
    return sim.rollout(start_state(sim, run), table, t1 - t0, record_every=every, progress=progress)
