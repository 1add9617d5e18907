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

from cobra_model.servo import P_GAIN_DIVISOR, PULSES_PER_REV, PWM_FULL_SCALE
from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters
from integrators.stability import servo_stiffness_damping


def _mujoco():
    try:
        import mujoco
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("MuJoCo cross-checks need the 'mujoco' package: pip install 'cobra-sysid[test]'") from exc
    return mujoco


#: Ground-contact geometries of :class:`TwinOptions` (see its ``contact``).
CONTACT_MODES: tuple[str, ...] = ("cylinder", "capsule_pairs")
#: Servo models of :class:`TwinOptions` (see its ``servo``).
SERVO_MODES: tuple[str, ...] = ("saturating", "linear")
#: MuJoCo friction cones of :class:`TwinOptions` (see its ``cone``).
CONE_MODES: tuple[str, ...] = ("pyramidal", "elliptic")


@dataclass(frozen=True)
class TwinOptions:
    """How the MuJoCo twin is built.

    Attributes:
        ground: add a ground plane (the world's z = 0 plane, normal +z).
        actuators: add position servos on every joint (stiffness/damping of the nominal
            Dynamixel loop linearised: ``kp = P/128 * 4096/(2 pi) / 885 * V * rKm / R``,
            ``kv = rKm^2 / R``). The URDF's joint effort limit (the stall torque, 9.9 N m)
            bounds each joint's actuator torque in any case: MuJoCo imports it as the joint's
            ``actuatorfrcrange``.
        servo: ``"saturating"``: the loop's PWM duty saturates (see :func:`servo_error_limit`),
            so the drive torque is ``kp clip(e, +-e_max) - kv qdot`` -- the DC motor's
            torque-speed line: the joint cannot outrun its no-load speed ``V / rKm`` (4.1 rad/s
            for the XH540 at 12 V, below the 4.3 rad/s peak of the 60 deg yaw wave at 0.65 Hz).
            ``"linear"``: ``kp e - kv qdot`` with no duty limit (only the effort limit), a
            servo faster than the hardware.
        armature, damping, frictionloss: joint properties [kg m^2, N m s/rad, N m].
        forcerange: actuator torque limit [N m] (None: only the URDF's effort limit).
        friction: (sliding [1], torsional [m], rolling [m]) friction coefficients of every geom
            and of the ground; only sliding acts with MuJoCo's default contact dimension 3.
        contact: ``"cylinder"``: the URDF's collision cylinders collide with the ground and with
            each other through MuJoCo's dynamic contacts, whose tangent frame is derived from the
            contact normal alone (isotropic friction only). ``"capsule_pairs"``: each collision
            cylinder becomes a capsule of the same radius and segment (its two ground contacts
            when lying flat are the cylinder's two lowest rim points; tilted by ``a`` they move
            ``r sin a`` outwards and ``r (1 - cos a)`` down), self-collision is off (as in our
            simulator) and each capsule touches the ground through an explicit contact
            ``<pair>`` whose tangent frame is body-aligned: MuJoCo's plane-capsule collision
            sets the first tangent to the capsule axis, orthogonalised to the normal, i.e. the
            module's x axis projected on the ground, and the second to ``z x`` that -- the
            frame of ``integrators.kernels.ground_forces``.
        lateral_friction_ratio: sideways / along-body sliding friction [1]; the pair friction
            is ``(mu, ratio * mu)`` on those axes. Needs ``contact="capsule_pairs"`` unless 1.
        cone: MuJoCo's friction cone, ``"pyramidal"`` (its default: with body-aligned pairs a
            diamond-shaped limit in the ground plane) or ``"elliptic"`` (a circle).
        impratio: MuJoCo's frictional-to-normal constraint impedance ratio [1]; above 1 the
            friction is harder (less creep under a tangential load below the limit).
        solref: MuJoCo's contact reference ``(time constant [s], damping ratio [1])``.
        solimp: MuJoCo's contact impedance ``(d0, dwidth, width [m], midpoint, power)``.
        timestep: [s].
        command_delay: the servos receive each command this long after it was sent [s] (a
            buffer on the bus: :func:`sysid.generators.mujoco_recording.record_mujoco` delays the goals; the
            run logs them when sent).
        encoder_offset: every encoder reads the joint angle plus this [rad], and the servo loop
            holds its goal in readings (:func:`sysid.generators.mujoco_recording.record_mujoco`).
        backlash: half-width [rad] of the play in each servo's gear train (0: none). Each joint
            becomes two hinges on its axis: the motor side (the armature, damping and friction
            loss, driven by the actuator) and, in series, the output, free within
            ``+-backlash`` of the motor (gear teeth in contact: a joint limit as stiff as the
            time step resolves, time constant two steps, impedance 0.99), which carries the link
            and which the encoder reads; the
            servo loop acts on that reading (:func:`sysid.generators.mujoco_recording.rollout_with_torques`,
            addresses from :func:`joint_addresses`). While the play is crossed the motor turns
            with its own inertia only and the link is driven by nothing but its load: gear play
            as a Dynamixel has it, its encoder on the output shaft.
        payload: mass added to the head module [kg] (negative: removed), at the head's centre of
            mass with its rotational inertia scaled by the new mass over the URDF's, as our
            model's ``link_mass_error`` changes it (``cobra_model.model.RobotModel.with_link_mass``).
            The head's mass must stay positive (checked in :func:`build`, which knows it).
        self_collision: with ``contact="cylinder"``, whether the robot's cylinders also collide
            with each other (MuJoCo's default); False leaves ground contacts only, as in our
            simulator (for a like-for-like speed comparison).

    Raises:
        InputError: naming the option that is out of range or inconsistent.
    """

    ground: bool = True
    actuators: bool = True
    armature: float = 0.0
    damping: float = 0.0
    frictionloss: float = 0.0
    forcerange: float | None = None
    friction: tuple[float, float, float] = (0.3, 0.005, 0.0001)
    contact: str = "cylinder"
    servo: str = "saturating"
    lateral_friction_ratio: float = 1.0
    cone: str = "pyramidal"
    impratio: float = 1.0
    solref: tuple[float, float] = (0.02, 1.0)
    solimp: tuple[float, float, float, float, float] = (0.9, 0.95, 0.001, 0.5, 2.0)
    timestep: float = 1e-3
    command_delay: float = 0.0
    encoder_offset: float = 0.0
    backlash: float = 0.0
    payload: float = 0.0
    self_collision: bool = True

    def __post_init__(self) -> None:
        for name in ("armature", "damping", "frictionloss"):
            if not getattr(self, name) >= 0:
                raise InputError(f"TwinOptions.{name} must be >= 0, got {getattr(self, name)}")
        if self.forcerange is not None and not self.forcerange > 0:
            raise InputError(f"TwinOptions.forcerange must be > 0 N m or None, got {self.forcerange}")
        if len(self.friction) != 3 or not all(f >= 0 for f in self.friction):
            raise InputError(f"TwinOptions.friction must be 3 coefficients >= 0, got {self.friction}")
        if self.contact not in CONTACT_MODES:
            raise InputError(f"TwinOptions.contact must be one of {CONTACT_MODES}, got {self.contact!r}")
        if self.servo not in SERVO_MODES:
            raise InputError(f"TwinOptions.servo must be one of {SERVO_MODES}, got {self.servo!r}")
        if not self.lateral_friction_ratio > 0:
            raise InputError(f"TwinOptions.lateral_friction_ratio must be > 0, got {self.lateral_friction_ratio}")
        if self.lateral_friction_ratio != 1.0 and self.contact != "capsule_pairs":
            raise InputError("TwinOptions.lateral_friction_ratio != 1 needs contact='capsule_pairs' "
                             "(MuJoCo's dynamic contacts have no body-aligned tangent frame)")
        if self.cone not in CONE_MODES:
            raise InputError(f"TwinOptions.cone must be one of {CONE_MODES}, got {self.cone!r}")
        if not self.impratio > 0:
            raise InputError(f"TwinOptions.impratio must be > 0, got {self.impratio}")
        if len(self.solref) != 2 or not self.solref[0] > 0 or not self.solref[1] > 0:
            raise InputError(f"TwinOptions.solref must be (time constant > 0 s, damping ratio > 0), got {self.solref}")
        if len(self.solimp) != 5 or not 0 < self.solimp[0] <= self.solimp[1] < 1:
            raise InputError(f"TwinOptions.solimp must be (d0, dwidth, width, midpoint, power) with "
                             f"0 < d0 <= dwidth < 1, got {self.solimp}")
        if not self.timestep > 0:
            raise InputError(f"TwinOptions.timestep must be > 0 s, got {self.timestep}")
        if not 0 <= self.command_delay < 1.0:
            raise InputError(f"TwinOptions.command_delay must be in [0, 1) s, got {self.command_delay}")
        if not abs(self.encoder_offset) < 0.5:
            raise InputError(f"TwinOptions.encoder_offset must be within +-0.5 rad, got {self.encoder_offset}")
        if not 0 <= self.backlash < 0.2:
            raise InputError(f"TwinOptions.backlash must be a half-width in [0, 0.2) rad, got {self.backlash}")
        if not np.isfinite(self.payload):
            raise InputError(f"TwinOptions.payload must be a finite mass [kg], got {self.payload}")


def servo_error_limit(options: TwinOptions, p_gain: int = 800) -> float | None:
    """Position error [rad] at which the servo's PWM duty saturates (None for a linear servo).

    The Dynamixel loop sends ``P/128 * e`` [PWM units, e in encoder ticks] clipped at 885, so
    beyond ``885 * 128 / P`` ticks (0.217 rad at P = 800) a larger error drives no harder;
    the rollout clips the error it hands the linearised actuator to that.
    """
    if options.servo == "linear":
        return None
    return PWM_FULL_SCALE * P_GAIN_DIVISOR / p_gain * 2.0 * np.pi / PULSES_PER_REV


def build(urdf: str | Path, options: TwinOptions = TwinOptions(), params: ModelParameters | None = None):
    """Compile the URDF into an ``mujoco.MjModel`` with a free joint at the root body.

    ``params`` gives the servo gains (``motor_km``, see :func:`servo_stiffness_damping`;
    default nominal); every other physical property comes from the URDF and ``options``.

    Raises:
        InputError: naming ``TwinOptions.payload`` if it leaves the head no positive mass.
    """
    mujoco = _mujoco()
    spec = mujoco.MjSpec.from_file(str(urdf))
    spec.option.timestep = options.timestep
    spec.option.cone = getattr(mujoco.mjtCone, f"mjCONE_{options.cone.upper()}")
    spec.option.impratio = options.impratio
    root = spec.worldbody.first_body()
    root.add_freejoint()
    if options.payload:
        mass = root.mass + options.payload
        if not mass > 0:
            raise InputError(f"TwinOptions.payload {options.payload:g} kg leaves the head ({root.name!r}, "
                             f"{root.mass:g} kg in {urdf}) no positive mass")
        scale = mass / root.mass  # the URDF gives the inertia as fullinertia, MjSpec keeps both forms
        root.mass, root.fullinertia, root.inertia = mass, root.fullinertia * scale, root.inertia * scale
    servo_joints = [j for j in spec.joints if j.type == mujoco.mjtJoint.mjJNT_HINGE]
    for j in servo_joints:
        j.armature = options.armature
        j.damping = np.array([options.damping, 0.0, 0.0])  # MuJoCo 4: linear term first
        j.frictionloss = options.frictionloss
        if options.backlash:  # the output after the motor, in the same body: its angle adds to the motor's
            j.parent.add_joint(name=f"{j.name}{PLAY_SUFFIX}", type=mujoco.mjtJoint.mjJNT_HINGE, axis=j.axis,
                               pos=j.pos, limited=mujoco.mjtLimited.mjLIMITED_TRUE,
                               range=[-options.backlash, options.backlash],
                               solref_limit=[2 * options.timestep, 1.0], solimp_limit=[0.99, 0.99, 0.001, 0.5, 2.0])
    for g in spec.geoms:
        g.friction = options.friction
        g.solref, g.solimp = options.solref, options.solimp
        if not options.self_collision:
            g.conaffinity = 0  # a robot geom then meets only the ground (its conaffinity stays 1)
    if options.ground:
        spec.worldbody.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1],
                                friction=options.friction, solref=options.solref, solimp=options.solimp)
    if options.contact == "capsule_pairs":
        _capsule_ground_pairs(mujoco, spec, options)
    if options.actuators:
        kp, kv = servo_stiffness_damping(params or ModelParameters.nominal())
        for j in servo_joints:
            a = spec.add_actuator(name=f"servo_{j.name}", target=j.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
            a.set_to_position(kp=kp, kv=kv)
            if options.forcerange is not None:
                a.forcelimited = True
                a.forcerange = [-options.forcerange, options.forcerange]
    return spec.compile()


#: Name suffix of a joint's output hinge when the twin has backlash (``TwinOptions.backlash``).
PLAY_SUFFIX = "_play"


def joint_addresses(mj_model) -> tuple[np.ndarray, np.ndarray]:
    """``qpos`` addresses of the servos' joints (the motor side, in the URDF's order) and of their
    output hinges (``TwinOptions.backlash``; empty without backlash). A joint's angle, as the
    encoder reads it and as our model's joint has it, is the sum of the two."""
    mujoco = _mujoco()
    servo, play = [], []
    for k in range(mj_model.njnt):
        if mj_model.jnt_type[k] != mujoco.mjtJoint.mjJNT_HINGE:
            continue
        name = mujoco.mj_id2name(mj_model, mujoco.mjtObj.mjOBJ_JOINT, k)
        (play if name.endswith(PLAY_SUFFIX) else servo).append(mj_model.jnt_qposadr[k])
    return np.array(servo, dtype=int), np.array(play, dtype=int)


def _capsule_ground_pairs(mujoco, spec, options: TwinOptions) -> None:
    """Turn the collision cylinders into capsules touching the ground only through body-aligned pairs."""
    mu = options.friction[0]
    friction = [mu, options.lateral_friction_ratio * mu, options.friction[1], options.friction[2], options.friction[2]]
    for body in spec.bodies:
        for k, g in enumerate(body.geoms):
            if g.type != mujoco.mjtGeom.mjGEOM_CYLINDER:
                continue
            g.type = mujoco.mjtGeom.mjGEOM_CAPSULE  # same size semantics: radius, half-length
            g.contype, g.conaffinity = 0, 0
            if not g.name:
                g.name = f"{body.name}_collision_{k}"
            if options.ground:
                # geom1 = the plane: MuJoCo's plane-capsule collision then aligns the frame with the capsule
                spec.add_pair(geomname1="ground", geomname2=g.name, condim=3, friction=friction,
                              solref=options.solref, solimp=options.solimp)


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
