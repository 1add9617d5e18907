"""Helpers shared by the step's invariant tests (``test_integrator``, ``test_momentum_step``,
``test_kernels``): the robots of example-robot-data, an undamped parameter set, the mechanical
energy and a free flight from a random state."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from cobra_model.model import RobotModel
from cobra_model.parameters import ModelParameters
from integrators.simulator import SimSettings, Simulator, Trajectory

#: Solo's feet as contact spheres (frame, radius [m]).
SOLO_FEET = tuple((f"{leg}_FOOT", 0.0175) for leg in ("FL", "FR", "HL", "HR"))


def solo(erd_dir: Path, feet: bool = True) -> RobotModel:
    """example-robot-data's Solo on a free-flying root, its feet touching the ground if ``feet``."""
    return RobotModel.from_urdf(erd_dir / "solo_description" / "robots" / "solo.urdf", floating=True,
                                contact_frames=SOLO_FEET if feet else (), package_dirs=[str(erd_dir.parent.parent)])


def double_pendulum(erd_dir: Path, contact_frames: tuple[tuple[str, float], ...] = ()) -> RobotModel:
    """example-robot-data's double pendulum on a fixed base at the origin."""
    return RobotModel.from_urdf(erd_dir / "double_pendulum_description" / "urdf" / "double_pendulum.urdf",
                                floating=False, contact_frames=contact_frames)


def undamped_params() -> ModelParameters:
    """The nominal parameters without joint damping."""
    p = ModelParameters.nominal()
    return p.with_parameters([replace(p["joint_damping"], value=0.0, min=0.0, log_scale=False)])


def energy(model: RobotModel, q: np.ndarray, v: np.ndarray) -> float:
    """Kinetic (transmission inertia included) plus gravitational energy [J]."""
    return model.kinetic_energy(q, v) + model.potential_energy(q)


def free_flight(model: RobotModel, gravity: np.ndarray, seconds: float = 10.0, *, seed: int = 0, dt: float = 1e-3,
                scheme: str = "velocity", record_s: float = 0.01) -> tuple[Simulator, Trajectory, np.ndarray]:
    """Unpowered, undamped, contact-free flight from a random pose and speed (1 rad/s rms), 1 m
    up: the simulator, the trajectory (a sample every ``record_s``) and the energy of each sample."""
    model = model.without_contacts().with_gravity(gravity)
    sim = Simulator(model, undamped_params(), SimSettings(dt=dt, control_dt=dt, scheme=scheme))
    rng = np.random.default_rng(seed)
    st = sim.state(model.configuration(rng.uniform(-0.8, 0.8, model.n_joints), np.array([0, 0, 1.0])),
                   rng.normal(0, 1.0, model.nv))
    off = np.zeros(model.n_joints, dtype=bool)
    tr = sim.rollout(st, np.zeros((1, model.n_joints)), seconds, record_every=int(round(record_s / dt)), torque_on=off)
    return sim, tr, np.array([energy(sim.model, q, v) for q, v in zip(tr.q, tr.v)])
