"""COBRA's URDF in MuJoCo, for cross-checks and benchmarks only (never in the model path).

MuJoCo is an independent engine: the test suite compares Pinocchio's mass matrix and bias
forces with MuJoCo's on the same URDF, the speed benchmark runs the same gait in both, and the
discrepancy workflow is tested on runs MuJoCo generated (another contact model and integrator).

State conventions differ: MuJoCo's free joint has ``qpos = [p, quat w x y z]`` and
``qvel = [linear velocity in the world frame, angular velocity in the body frame]``;
Pinocchio's has ``q = [p, quat x y z w]`` and ``v = [linear, angular]`` both in the body frame.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cobra_model.design import SERVO_GEAR_RATIO
from cobra_model.parameters import WINDING_RESISTANCE_OHM, ModelParameters


def _mujoco():
    try:
        import mujoco
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("MuJoCo cross-checks need the 'mujoco' package: pip install 'cobra-sysid[test]'") from exc
    return mujoco


@dataclass(frozen=True)
class TwinOptions:
    """How the MuJoCo twin is built.

    Attributes:
        ground: add a ground plane with friction ``friction`` (sliding, torsional, rolling).
        actuators: add position servos on every joint (stiffness/damping of the nominal
            Dynamixel loop linearised: ``kp = P/128 * 4096/(2 pi) / 885 * V * rKm / R``).
        armature, damping, frictionloss: joint properties [kg m^2, N m s/rad, N m].
        forcerange: actuator torque limit [N m] (None: unlimited).
        timestep: [s]. condim: 3 (isotropic) or 4/6; friction anisotropy uses ``friction``.
    """

    ground: bool = True
    actuators: bool = True
    armature: float = 0.0
    damping: float = 0.0
    frictionloss: float = 0.0
    forcerange: float | None = None
    friction: tuple[float, float, float] = (0.3, 0.005, 0.0001)
    timestep: float = 1e-3


def servo_stiffness_damping(params: ModelParameters, p_gain: int = 800) -> tuple[float, float]:
    """Linearised nominal servo: position stiffness [N m/rad] and back-EMF damping [N m s/rad]."""
    rkm = SERVO_GEAR_RATIO * params.motor_km
    kp = p_gain / 128.0 * 4096.0 / (2 * np.pi) / 885.0 * 12.0 * rkm / WINDING_RESISTANCE_OHM
    kv = rkm * rkm / WINDING_RESISTANCE_OHM
    return kp, kv


def build(urdf: str | Path, options: TwinOptions = TwinOptions(), params: ModelParameters | None = None):
    """Compile the URDF into an ``mujoco.MjModel`` with a free joint at the root body."""
    mujoco = _mujoco()
    spec = mujoco.MjSpec.from_file(str(urdf))
    spec.option.timestep = options.timestep
    root = spec.worldbody.first_body()
    root.add_freejoint()
    for j in spec.joints:
        if j.type == mujoco.mjtJoint.mjJNT_HINGE:
            j.armature = options.armature
            j.damping = np.array([options.damping, 0.0, 0.0])  # MuJoCo 4: linear term first
            j.frictionloss = options.frictionloss
    for g in spec.geoms:
        g.friction = options.friction
    if options.ground:
        spec.worldbody.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1],
                                friction=options.friction)
    if options.actuators:
        kp, kv = servo_stiffness_damping(params or ModelParameters.nominal())
        for j in spec.joints:
            if j.type != mujoco.mjtJoint.mjJNT_HINGE:
                continue
            a = spec.add_actuator(name=f"servo_{j.name}", target=j.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            a.set_to_position(kp=kp, kv=kv)
            if options.forcerange is not None:
                a.forcelimited = True
                a.forcerange = [-options.forcerange, options.forcerange]
    return spec.compile()


def pin_to_mj(q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pinocchio (q, v) of a free-flyer model to MuJoCo (qpos, qvel)."""
    from cobra_model.kinematics import quat_xyzw_to_matrix

    qpos = np.concatenate([q[:3], [q[6], q[3], q[4], q[5]], q[7:]])
    R = quat_xyzw_to_matrix(q[3:7])
    qvel = np.concatenate([R @ v[:3], v[3:6], v[6:]])
    return qpos, qvel


def mj_to_pin(qpos: np.ndarray, qvel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """MuJoCo (qpos, qvel) of a free-joint model to Pinocchio (q, v)."""
    from cobra_model.kinematics import quat_xyzw_to_matrix

    q = np.concatenate([qpos[:3], [qpos[4], qpos[5], qpos[6], qpos[3]], qpos[7:]])
    R = quat_xyzw_to_matrix(q[3:7])
    v = np.concatenate([R.T @ qvel[:3], qvel[3:6], qvel[6:]])
    return q, v
