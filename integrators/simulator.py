"""Semi-implicit (symplectic) Euler simulation of COBRA with a compliant Stribeck ground and
Dynamixel servos driving DC motors.

One physics step of length ``dt``::

    a  = ABA(q, v, tau_motor(u, qdot) + J^T F_ground(q, v))      # Pinocchio, armature included
    v+ = v + dt * a
    q+ = pin.integrate(q, dt * v+)                                # on the configuration manifold

All forces are evaluated explicitly at (q, v) by default; the step is the symplectic Euler of
the issue. A parameter set's ``friction_step="implicit"`` takes the ground's friction at the step's
end slip instead (:func:`integrators.kernels.implicit_friction_acceleration`), so that its sign
can be regularised at 1 mm/s rather than 1 cm/s. In the explicit step what bounds the stable
step would be the stiffest dissipative term, the regularised Coulomb friction ``s F_z / eps``
(see ``integrators.kernels.ground_forces``), were ``eps`` not large enough to cap it (at 1 cm/s
it is; at 1 mm/s the 1 ms step chatters); the springs and dampers that do bound it are the ground's normal
contact, the motor's back-EMF damping (every step) and the servo loop (every tick):
:mod:`integrators.stability` gives the largest stable ``dt`` and ``control_dt`` for a model
and parameter set. At ``dt = 1 ms`` the step is stable over the ground parameters' bounds, but
not for the lightest transmission inertias: below about 3.5e-4 kg m^2 (at the nominal motor
constant) the back-EMF damping needs a shorter step. ``cobra simulate`` checks its steps
before the run; a divergence names the limits.

The servo's position loop runs at ``control_dt`` (an integer multiple of ``dt``, checked): its
PWM duty is held between ticks while the motor torque, which depends on the joint speed through
the back-EMF, is re-evaluated every physics step.

Model effects beyond the nominal parameter table enter through parameters of the same set:
``joint_coulomb`` [N m], ``torque_limit`` [N m], ``lateral_friction_ratio``, ``backlash`` [rad]
(play between each motor and its joint's output, the encoder on the output:
:func:`integrators.kernels.gear_step`; stepped by :meth:`Simulator.rollout`, :meth:`Simulator.step`
(its state in :attr:`SimState.gear`) and the batch, in the velocity scheme),
``encoder_offset`` [rad] (the encoder reads ``q + offset``), ``actuator_delay`` [s] (commands
reach the servo late) and ``link_mass_error`` [kg] (added to the root module). A set without
one of them simulates it at its inactive value. Each parameter (unit, bounds, inactive value)
is defined beside the physics that reads it: in the kernels' :data:`integrators.kernels.EFFECT_PARAMETERS`
with its slot in ``GROUND_PARAMETERS`` or ``ACTUATOR_PARAMETERS`` (the simulator packs by
those tables, so an effect that acts in the kernels is added there and nowhere in this module),
or in :data:`STEP_EFFECT_PARAMETERS` here for the two that act on the commands and on the
rigid-body model; :func:`effect_parameter` looks up either. ``sysid.discrepancy.effects`` names them.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
import pinocchio as pin

from cobra_model import servo
from cobra_model.servo import SERVO_GEAR_RATIO
from cobra_model.model import RobotModel
from cobra_model.errors import InputError
from cobra_model.parameters import WINDING_RESISTANCE_OHM, ModelParameters, Parameter
from integrators import kernels as K
from integrators import native, stability
from integrators.momentum_step import MomentumStep


#: The effects that act in this module rather than in the kernels, by the stage they enter at
#: (:class:`Entry`): the servo goals (``"commands"``) and the rigid-body model (``"model"``).
STEP_EFFECT_PARAMETERS: dict[str, Parameter] = {
    "commands": Parameter("actuator_delay", "s", 0.0, 0.0, 0.2, group="actuator_delay", doc="command / bus latency"),
    "model": Parameter("link_mass_error", "kg", 0.0, -0.5, 2.0, group="link_mass_error",
                       doc="mass added to the head module (payload)"),
}
_EFFECT_PARAMETERS: dict[str, Parameter] = {p.name: p for p in (*K.EFFECT_PARAMETERS, *STEP_EFFECT_PARAMETERS.values())}


def effect_parameter(name: str) -> Parameter:
    """The parameter of a modelled effect (the kernels' or this module's), at its inactive value.

    Raises:
        InputError: for a name that is no effect parameter, listing the known ones.
    """
    if name not in _EFFECT_PARAMETERS:
        raise InputError(f"unknown effect parameter {name!r}; known: {', '.join(_EFFECT_PARAMETERS)}")
    return _EFFECT_PARAMETERS[name]


@dataclass(frozen=True)
class Entry:
    """Where a parameter enters the simulation: the array a kernel reads, or the step stage.

    Attributes:
        parameter: the parameter's name.
        stage: ``"ground"`` (``Simulator.ground[slot]``, read by the contact kernels for every
            contact), ``"actuator"`` (``Simulator.act[:, slot]``, one value per joint, read by
            the servo and motor kernel), ``"commands"`` (the servo goals are delayed,
            :func:`delay_commands`) or ``"model"`` (the rigid-body model's head module gains the
            mass, ``RobotModel.with_link_mass``).
        slot: the index into ``ground`` or ``act`` (None for the other stages).
    """

    parameter: str
    stage: str
    slot: int | None = None

    def read(self, sim: "Simulator") -> np.ndarray:
        """The value(s) ``sim`` holds at this entry: (1,) for a shared value, (n_joints,) per joint;
        for ``"model"`` the mass [kg] the simulated model has beyond the one it was given."""
        if self.stage == "ground":
            return sim.ground[[self.slot]]
        if self.stage == "actuator":
            return sim.act[:, self.slot]
        if self.stage == "commands":
            return np.array([sim.delay_s])
        return np.array([sim.model.total_mass - sim.given_model.total_mass])

    def __str__(self) -> str:
        where = {"ground": f"ground[{self.slot}] of the contact kernels",
                 "actuator": f"act[:, {self.slot}] of the actuator kernel (per joint)",
                 "commands": "the servo goals (delay_commands)", "model": "the rigid-body model (with_link_mass)"}
        return f"{self.parameter} -> {where[self.stage]}"


def entry_of(name: str) -> Entry:
    """Where parameter ``name`` (an effect's or a nominal one the kernels read) enters the simulation.

    Raises:
        InputError: for a name that enters nowhere this module knows (listing the known ones).
    """
    if name in K.GROUND_PARAMETERS:
        return Entry(name, "ground", K.GROUND_PARAMETERS[name])
    if name in K.ACTUATOR_PARAMETERS:
        return Entry(name, "actuator", K.ACTUATOR_PARAMETERS[name])
    for stage, p in STEP_EFFECT_PARAMETERS.items():
        if p.name == name:
            return Entry(name, stage)
    known = [*K.GROUND_PARAMETERS, *K.ACTUATOR_PARAMETERS, *(p.name for p in STEP_EFFECT_PARAMETERS.values())]
    raise InputError(f"parameter {name!r} enters no kernel array or step stage; known: {', '.join(known)}")


def _inactive_value(name: str) -> float | None:
    """The inactive value of effect parameter ``name``; None for any other parameter."""
    inactive = _EFFECT_PARAMETERS.get(name)
    return None if inactive is None else inactive.value


def effect_value(params: ModelParameters, name: str) -> float:
    """The value of parameter ``name`` in ``params``: an effect's parameter the set lacks at its
    inactive value (:func:`effect_parameter`), any other the set's or nominal value."""
    return params.get(name, _inactive_value(name))


class SimulationDiverged(RuntimeError):
    """The simulation produced NaN, an exploding velocity or a deep penetration."""


@dataclass(frozen=True)
class ServoGains:
    """Dynamixel X position-loop registers (raw register values) and PWM limit
    (``servo.PWM_FULL_SCALE`` = 100 %)."""

    p: int = 800
    i: int = 0
    d: int = 0
    pwm_limit: int = servo.PWM_FULL_SCALE

    def __post_init__(self) -> None:
        for name in ("p", "i", "d"):
            if not 0 <= getattr(self, name) <= servo.GAIN_REGISTER_MAX:
                raise ValueError(f"servo gain {name} = {getattr(self, name)} outside 0..{servo.GAIN_REGISTER_MAX}")
        if not 0 <= self.pwm_limit <= servo.PWM_FULL_SCALE:
            raise ValueError(f"PWM limit {self.pwm_limit} outside 0..{servo.PWM_FULL_SCALE}")


#: The physics steps :class:`SimSettings` offers.
SCHEMES = ("velocity", "momentum")
#: The friction sign's regularisation velocity [m/s] of each friction step
#: (:data:`cobra_model.parameters.FRICTION_STEPS`), unless ``SimSettings.sgn_eps`` sets another.
FRICTION_EPS: dict[str, float] = {"explicit": 0.01, "implicit": 0.001}
#: How close [fraction] the regularised sign ``tanh(u / eps)`` comes to ``sign(u)`` above
#: :attr:`Simulator.faithful_slip`.
SIGN_TOLERANCE = 0.01


@dataclass(frozen=True)
class SimSettings:
    """Numerical settings (not identified).

    Attributes:
        dt: physics step [s].
        control_dt: servo position-loop period [s], an integer multiple of ``dt``.
        gains: servo position-loop gains.
        voltage: motor supply voltage [V].
        sgn_eps: friction sign regularisation velocity [m/s] (see ``ground_forces``); None:
            the parameter set's friction step's (:data:`FRICTION_EPS`).
        joint_coulomb_eps: joint Coulomb friction regularisation [rad/s].
        max_depth: penetration [m] beyond which the run is declared diverged.
        max_speed: generalized speed [m/s or rad/s] beyond which the run is declared diverged.
        scheme: ``"velocity"`` (the step above; batched fits use it) or ``"momentum"``
            (:mod:`integrators.momentum_step`: symplectic Euler on the momentum, bounded energy
            error, about 20 times the cost; single rollouts only).

    How the compliant ground's friction is stepped is the parameter set's
    (:attr:`cobra_model.parameters.ModelParameters.friction_step`): it is part of the model.
    """

    dt: float = 1e-3
    control_dt: float = 1e-3
    gains: ServoGains = field(default_factory=ServoGains)
    voltage: float = servo.SUPPLY_VOLTAGE_V
    sgn_eps: float | None = None
    joint_coulomb_eps: float = 0.05
    max_depth: float = 0.03
    max_speed: float = 100.0
    scheme: str = "velocity"

    def __post_init__(self) -> None:
        if not self.dt > 0:
            raise ValueError(f"dt must be > 0 s, got {self.dt}")
        if self.scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {', '.join(SCHEMES)}, got {self.scheme!r}")
        if self.sgn_eps is not None and not self.sgn_eps > 0:
            raise ValueError(f"sgn_eps must be > 0 m/s, got {self.sgn_eps}")
        ratio = self.control_dt / self.dt
        if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6:
            raise ValueError(
                f"control_dt = {self.control_dt} s must be an integer multiple of dt = {self.dt} s"
            )

    @property
    def substeps(self) -> int:
        """Physics steps per control tick."""
        return int(round(self.control_dt / self.dt))


def friction_eps(params: ModelParameters, settings: SimSettings) -> float:
    """The friction sign's regularisation velocity [m/s]: ``settings.sgn_eps``, or that of
    ``params``' friction step (:data:`FRICTION_EPS`)."""
    return FRICTION_EPS[params.friction_step] if settings.sgn_eps is None else settings.sgn_eps


def faithful_slip(eps: float) -> float:
    """The slip speed [m/s] below which the sign regularised at ``eps`` [m/s], ``tanh(u / eps)``,
    falls more than :data:`SIGN_TOLERANCE` short of ``sign(u)``: a model is faithful to a
    Stribeck curve (``v_s``) only above it (``eps atanh(0.99)`` = 2.65 ``eps``)."""
    return float(eps * np.arctanh(1.0 - SIGN_TOLERANCE))


#: Physics steps per soft-contact time constant at the least (:func:`contact_resolved`).
STEPS_PER_CONTACT_TIME_CONSTANT = 8


def contact_resolved(settings: SimSettings, params: ModelParameters) -> SimSettings:
    """``settings`` with a physics step short enough for ``params``' soft contact: at least
    :data:`STEPS_PER_CONTACT_TIME_CONSTANT` steps per ``contact_time_constant`` ``tc``, ``dt`` an
    integer fraction of ``control_dt`` (the servo loop keeps its period). Unchanged for the
    compliant ground, or where ``dt`` already resolves ``tc``; never coarser than ``settings``.

    Why: a soft-constraint contact relaxes its approach velocity and penetration at the rate
    ``b = 2 / (d tc)`` (``d`` ~ 0.95 the impedance). The semi-implicit step takes that decay as
    ``1 - b dt`` per step instead of ``exp(-b dt)``, an error of about ``1 / N`` of each
    transient with ``N = tc / dt`` steps per time constant. At ``tc = 2 dt`` (MuJoCo's own
    lowest, its stability limit) the contact is removed in about one step: at MuJoCo's values
    against MuJoCo's 2 ms contact (its 0.25 ms steps), our joints are 0.57-1.60 mrad off with
    1 ms steps, 0.28-0.54 mrad with 0.5 ms (N = 4) and 0.27-0.40 mrad with 0.25 ms (N = 8; the
    encoders' rounding floor is 0.44 mrad). On the held-out runs of
    ``benchmarks/mujoco_fit.py`` at MuJoCo's values (``benchmarks/contact_step.py``) four steps
    leave the 0.65 Hz gaits' joints up to 1.84 times the floor from MuJoCo's, eight 1.34 times
    and sixteen 1.29 times: eight is where halving the step stops paying (what is left is the
    two engines' other differences), at four times the 1 ms step's cost for a 2 ms contact.
    MuJoCo's default 20 ms contact needs no change at 1 ms.
    """
    if params.contact_law not in K.SOFT_LAWS:
        return settings
    shortest = params.value("contact_time_constant") / STEPS_PER_CONTACT_TIME_CONSTANT
    if settings.dt <= shortest * (1 + 1e-9):
        return settings
    per_tick = int(np.ceil(settings.control_dt / shortest - 1e-9))
    return replace(settings, dt=settings.control_dt / per_tick)


@dataclass(frozen=True)
class SimState:
    """Everything that evolves: time [s], q (nq,), v (nv,), the servo loop's memory (pulses),
    the held PWM duty and the last motor current [A]; ``step`` counts physics steps. ``gear``
    (:data:`integrators.kernels.N_GEAR`, n_joints): the gear play's state
    (:func:`integrators.kernels.gear_step`), which :meth:`Simulator.step` carries for parameters
    with a play; None: every play open and centred, its motor turning at its joint's rate."""

    t: float
    q: np.ndarray
    v: np.ndarray
    integ: np.ndarray
    prev_err: np.ndarray
    duty: np.ndarray
    current: np.ndarray
    step: int = 0
    gear: np.ndarray | None = None


def servo_memory(state: SimState, n_base: int, with_current: bool = True) -> np.ndarray:
    """A rollout's servo memory (:data:`integrators.kernels.N_SERVO`, n_joints) from ``state``:
    its loops' integral, previous error and duty, its motor current (zero unless
    ``with_current``), then the gear play's state: ``state.gear``, or, when the state carries
    none, each play open and centred with the motor turning at its joint's rate
    (``state.v[n_base:]``), as a servo at rest between its flanks is."""
    memory = np.zeros((K.N_SERVO, len(state.integ)))
    memory[K.SV_INTEG], memory[K.SV_PREV_ERR], memory[K.SV_DUTY] = state.integ, state.prev_err, state.duty
    if with_current:
        memory[K.SV_CURRENT] = state.current
    if state.gear is None:
        memory[K.SV_GEAR + K.GEAR_RATE] = state.v[n_base:]
    else:
        memory[K.SV_GEAR:] = state.gear
    return memory


@dataclass(frozen=True)
class Trajectory:
    """A recorded rollout: samples every ``record_every`` physics steps.

    Attributes:
        t: (N,) s. q: (N, nq). v: (N, nv). q_goal: (N, n_joints) command the servos received
        (rad). q_meas: (N, n_joints) encoder reading (rad). current: (N, n_joints) A.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    q_goal: np.ndarray
    q_meas: np.ndarray
    current: np.ndarray


def delay_commands(table: np.ndarray, delay_s: float, control_dt: float) -> np.ndarray:
    """Commands (n_ticks, n_joints) as the servos receive them ``delay_s`` [s] late.

    Fractional ticks are linearly interpolated so that the delay is a smooth parameter; before
    the first command arrives the servos hold the first one.
    """
    if delay_s <= 0:
        return np.ascontiguousarray(table)
    k = np.arange(len(table)) - delay_s / control_dt
    idx = np.arange(len(table))
    return np.ascontiguousarray(np.column_stack([np.interp(k, idx, table[:, j]) for j in range(table.shape[1])]))


class Simulator:
    """Immutable simulator of one robot model with one parameter set.

    The ground-contact law is the parameter set's (``params.contact_law``, one of
    :data:`cobra_model.parameters.CONTACT_LAWS`): ``"compliant"``, the spring-damper ground with
    the Stribeck friction law (:func:`integrators.kernels.ground_forces`), ``"soft_constraint"``,
    MuJoCo's contact law: a soft constraint on the friction pyramid's edges, solved for all
    contacts together (:func:`integrators.kernels.soft_contact_acceleration`), or
    ``"soft_elliptic"``, the same constraint on MuJoCo's elliptic friction cone
    (:func:`integrators.kernels.soft_elliptic_acceleration`); both with sliding friction
    ``mu_c`` along the body and ``lateral_friction_ratio`` x ``mu_c`` sideways, no Stribeck or
    viscous term, ``k1``/``k2`` unused, their time constant the parameter ``contact_time_constant``;
    velocity-form steps only, about twice the cost. The compliant ground's friction is stepped
    as the parameter set says (``params.friction_step``): at the step's start velocity with its
    sign regularised at 1 cm/s (``"explicit"``), or at the step's end slip with the sign at
    1 mm/s (``"implicit"``, :func:`integrators.kernels.implicit_friction_acceleration`: stable at
    any ``eps``; velocity-form steps only, a few times the cost), so that the model is faithful to
    the Stribeck curve above :attr:`faithful_slip`, 2.65 cm/s or 2.65 mm/s (``v_s``'s lower
    bound is 5 mm/s).

    Args:
        model: the robot (COBRA or any URDF loaded by :class:`RobotModel`).
        params: physical parameters (actuator, ground, optional effects), the contact law and
            the friction step.
        settings: numerical settings (default: :class:`SimSettings`' with a step that resolves a
            soft contact's time constant, :func:`contact_resolved`; given settings are kept).

    Raises:
        InputError: the soft-constraint law, the implicit friction step or a gear play
            (``backlash`` > 0) with the momentum scheme, a gear play without the motors'
            inertia, or a contact time constant shorter than two steps.
    """

    def __init__(self, model: RobotModel, params: ModelParameters | None = None,
                 settings: SimSettings | None = None):
        self.params = params if params is not None else ModelParameters.nominal()
        self.settings = settings if settings is not None else contact_resolved(SimSettings(), self.params)
        p, s = self.params, self.settings
        n = model.n_joints
        def per_joint(name: str) -> np.ndarray:
            return p.per_joint(name, _inactive_value(name))[:n]

        self.given_model = model
        if effect_value(p, "link_mass_error"):
            model = model.with_link_mass(model.body_names[0], p.value("link_mass_error"))
        self.model = model.with_armature(per_joint("armature"))
        self._pin = self.model.pin_model
        self._data = self._pin.createData()
        self._pin_play: tuple[pin.Model, pin.Data] | None = None  # _pin_with_armature's
        ground = np.zeros(K.N_GROUND)
        for name, slot in K.GROUND_PARAMETERS.items():
            ground[slot] = effect_value(p, name)
        #: the friction sign's regularisation velocity [m/s] and the slip above which the model is
        #: faithful to its Stribeck curve
        self.friction_eps = friction_eps(p, s)
        self.faithful_slip = faithful_slip(self.friction_eps)
        ground[K.G_EPS] = self.friction_eps
        self.contact_law = p.contact_law
        if self.contact_law in K.SOFT_LAWS:
            if s.scheme != "velocity":
                raise InputError(f"the {self.contact_law} contact law runs with the velocity scheme, got {s.scheme!r}")
            # the compliant ground off (no normal force, hence no friction in the force kernels):
            # the contact forces come from the constraint (soft_contact_acceleration)
            ground[[K.G_K1, K.G_K2, K.G_MU_V]] = 0.0
            if not ground[K.G_TC] >= 2 * s.dt - 1e-12:
                raise InputError(f"contact_time_constant = {ground[K.G_TC]:g} s: the soft-constraint contact needs "
                                 f"at least two steps (2 dt = {2 * s.dt:g} s)")
        self.ground = ground
        #: the compiled loop's law code (:data:`integrators.kernels.LOOP_LAWS`, or the compliant
        #: ground with its friction taken implicitly)
        self.loop_law = (K.LAW_COMPLIANT_IMPLICIT if self.contact_law == "compliant" and p.friction_step == "implicit"
                         else K.LOOP_LAWS[self.contact_law])
        if self.loop_law == K.LAW_COMPLIANT_IMPLICIT and s.scheme != "velocity":
            raise InputError(f"the implicit friction step is a velocity-scheme step, got scheme {s.scheme!r}")
        act = np.zeros((n, K.N_ACT))
        for name, slot in K.ACTUATOR_PARAMETERS.items():
            act[:, slot] = per_joint(name)
        act[:, K.A_RKM] = SERVO_GEAR_RATIO * per_joint("motor_km")
        act[:, K.A_ARMATURE] = per_joint("armature")
        act[:, K.A_COULOMB_EPS] = s.joint_coulomb_eps
        self.act = act
        self.delay_s = effect_value(p, "actuator_delay")
        g = s.gains
        scal = np.zeros(K.N_SCAL)
        scal[K.S_DT], scal[K.S_VOLTAGE], scal[K.S_RESISTANCE] = s.dt, s.voltage, WINDING_RESISTANCE_OHM
        scal[K.S_MAX_DEPTH], scal[K.S_MAX_SPEED] = s.max_depth, s.max_speed
        scal[K.S_KP], scal[K.S_KI], scal[K.S_KD], scal[K.S_PWM_LIMIT] = (
            g.p / servo.P_GAIN_DIVISOR, g.i / servo.I_GAIN_DIVISOR, g.d / servo.D_GAIN_DIVISOR, g.pwm_limit)
        self.scal = scal
        ch, f = self.model.chain, self.model.features
        self._chain_i = np.ascontiguousarray(np.column_stack([ch.parents, ch.qidx, ch.vidx]), dtype=np.int64)
        self._chain_R = np.ascontiguousarray(ch.jR)
        self._chain_f = np.ascontiguousarray(np.column_stack([ch.jp, ch.axes]))
        self._feat_i = np.ascontiguousarray(np.column_stack([f.body, f.kind]), dtype=np.int64).reshape(-1, 2)
        self._feat_f = np.ascontiguousarray(np.column_stack([f.centre, f.axis, f.radius])).reshape(-1, 7)
        # the kernels' workspace: contact points and forces, body poses and velocities (views of one array)
        self._work = np.empty(K.workspace_size(len(f), len(ch.parents)))
        self._X, self._F, self._kin_R, self._kin_v = K.workspace_views(self._work, len(f), len(ch.parents))
        #: whether a joint has a gear play (``backlash`` > 0): stepped by :meth:`rollout` alone
        self.gear_play = bool(np.any(act[:, K.A_BACKLASH] > 0))
        if self.gear_play and s.scheme != "velocity":
            raise InputError(f"backlash = {p.value('backlash'):g} rad: the gear play is stepped by the velocity "
                             f"scheme, got scheme {s.scheme!r}")
        if self.gear_play and not np.all(act[:, K.A_ARMATURE] > 0):
            raise InputError(f"backlash = {p.value('backlash'):g} rad needs the motors' inertia (armature > 0 "
                             f"kg m^2) to cross the play, got {act[:, K.A_ARMATURE].min():g}")
        self._momentum = MomentumStep(self.model, s.dt) if s.scheme == "momentum" else None
        self._soft_warm = np.zeros((len(f), 4))  # the soft-constraint solver's last edge forces [N]
        self._no_gear = np.zeros((K.N_GEAR, self.model.n_joints))  # step's gear rows without a play (not read)
        self._impact = np.empty(K.N_IMPACT_ROWS * self.model.nv)  # step's scratch for K.gear_impacts
        self._native: native.NativeData | None = None  # the compiled loop's ABA workspace, made at its first use

    def __getstate__(self) -> dict:
        """Pickled without the compiled loop's workspace, which points into this process's memory
        (the next rollout makes a new one), and without the gear play's Pinocchio copy (a cache
        :meth:`_pin_with_armature` makes again)."""
        return {**self.__dict__, "_native": None, "_pin_play": None}

    def with_gains(self, gains: ServoGains) -> "Simulator":
        """A simulator identical but for the servo gains."""
        return Simulator(self.model, self.params, replace(self.settings, gains=gains))

    # -- states -----------------------------------------------------------------------------
    def state(self, q: np.ndarray, v: np.ndarray | None = None, t: float = 0.0) -> SimState:
        """A state at configuration q (nq,), velocity v (default zero) and time t [s]."""
        n = self.model.n_joints
        v = np.zeros(self.model.nv) if v is None else np.asarray(v, dtype=float).copy()
        return SimState(t, np.asarray(q, dtype=float).copy(), v, np.zeros(n), np.zeros(n),
                        np.zeros(n), np.zeros(n))

    def joints_reading(self, reading: np.ndarray) -> np.ndarray:
        """The joint angles [rad] whose encoders read ``reading`` [rad] (``reading - encoder_offset``):
        where a measured run really started."""
        return np.asarray(reading, dtype=float) - self.act[:, K.A_ENC_OFFSET]

    def rest_state(self, q_joints: np.ndarray | None = None, head_xy: tuple[float, float] = (0.0, 0.0),
                   heading_rad: float = 0.0, base_quat_wxyz: np.ndarray | None = None) -> SimState:
        """At rest in joint pose ``q_joints`` with the lowest contact point touching the ground.

        The root is placed at ``head_xy`` with yaw ``heading_rad`` (or orientation
        ``base_quat_wxyz``), then lifted or lowered so that the lowest contact point is at z = 0.

        Raises:
            InputError: a position or heading that is not finite.
        """
        if not np.all(np.isfinite([head_xy[0], head_xy[1], heading_rad])):
            raise InputError(f"rest_state: head_xy [m] and heading_rad must be finite, got {tuple(head_xy)} and "
                             f"{heading_rad}")
        model = self.model
        if base_quat_wxyz is None:
            half = 0.5 * heading_rad
            base_quat_wxyz = np.array([np.cos(half), 0.0, 0.0, np.sin(half)])
        q = model.configuration(q_joints, np.array([head_xy[0], head_xy[1], 0.0]), base_quat_wxyz)
        return self.state(model.on_ground(q, self.ground[K.G_ROUND]))

    # -- stepping ---------------------------------------------------------------------------
    def _raise(self, status: int, t: float, q: np.ndarray, v: np.ndarray) -> None:
        raise SimulationDiverged(self.divergence_message(status, t, v, self._X))

    def _raise_step(self, status: int, i: int, t0: float, q: np.ndarray, v: np.ndarray) -> None:
        """Raise for :func:`integrators.kernels.rollout_step`'s ``status`` at step ``i`` of a rollout
        from ``t0`` [s]: minus, step ``i - 1``'s integration failed; plus, step ``i``'s forces."""
        self._raise(abs(status), t0 + (i - (status < 0)) * self.settings.dt, q, v)

    def divergence_message(self, status: int, t: float, v: np.ndarray, X: np.ndarray) -> str:
        """What blew up, where and when: the deepest contact point of ``X`` (n_features, 3)
        [m] for a penetration, else the velocity coordinates of ``v`` (nv,) that are not finite
        or the fastest, with the largest stable steps; ``t`` [s] is the time of the state."""
        if status == K.STATUS_PENETRATION:
            k = int(np.argmin(X[:, 2]))
            return (f"at t = {t:.4f} s contact point {self.model.features.names[k]} penetrated "
                    f"{-X[k, 2] * 100:.2f} cm into the ground (limit {self.settings.max_depth * 100:.1f} cm): "
                    f"ground too soft or the step diverged")
        if status == K.STATUS_NONFINITE:
            bad = np.flatnonzero(~np.isfinite(v))
            return (f"at t = {t:.4f} s velocity became NaN/inf at coordinates {bad.tolist()} "
                    f"({self._coordinate_names(bad)}); {self._stable_steps()}")
        i = int(np.argmax(np.abs(v)))
        return (f"at t = {t:.4f} s velocity coordinate {i} ({self._coordinate_names([i])}) reached {v[i]:.3g} "
                f"(limit {self.settings.max_speed}): the step is unstable; {self._stable_steps()}")

    def _coordinate_names(self, indices) -> str:
        """Names of velocity coordinates: the root's linear/angular components or the joint names."""
        nb = self.model.n_base
        root = ("root vx", "root vy", "root vz", "root wx", "root wy", "root wz")
        return ", ".join(root[i] if i < nb else self.model.joint_names[i - nb] for i in indices)

    def check_steps(self) -> None:
        """Raise :class:`InputError` before a run if ``dt`` or ``control_dt`` would not settle for
        this model and these parameters (:func:`integrators.stability.check_steps`)."""
        stability.check_steps(self.model, self.params, self.settings.dt, self.settings.control_dt,
                              self.settings.gains.p)

    def _stable_steps(self) -> str:
        """The largest stable steps for this model and parameters (:mod:`integrators.stability`)."""
        lim = stability.step_limits(self.model, self.params, self.settings.gains.p)
        return (f"with these parameters the largest stable dt is {lim.allowed_dt:.3g} s (set by {lim.dt_reason}) "
                f"and control_dt {lim.allowed_control_dt:.3g} s; this run used {self.settings.dt:g} s and "
                f"{self.settings.control_dt:g} s")

    def step(self, state: SimState, q_goal: np.ndarray, torque_on: np.ndarray | None = None) -> SimState:
        """Advance one physics step with servo goal angles ``q_goal`` (n_joints,) [rad].

        The position loop runs when ``state.step`` is a multiple of ``settings.substeps``.
        ``torque_on`` (n_joints,) bool, default all on. With a gear play the step carries its
        state in :attr:`SimState.gear` (from an open, centred play when the state has none) and
        takes the motors' inertia off the joints whose play is open, as :meth:`rollout` does:
        the same states step for step.
        """
        integ, prev_err, duty, current = (state.integ.copy(), state.prev_err.copy(),
                                          state.duty.copy(), state.current.copy())
        on = np.ones(self.model.n_joints, dtype=np.bool_) if torque_on is None else np.asarray(torque_on, dtype=np.bool_)
        q, v, tau = np.empty(self.model.nq), np.empty(self.model.nv), np.empty(self.model.nv)
        gear, armature = self._no_gear, None
        if self.gear_play:
            gear = servo_memory(state, self.model.n_base)[K.SV_GEAR:]
            armature = np.empty(self.model.nv)
            K.gear_armature(self.act, gear, self.model.nv, armature)
        status = K.pre_step(state.step % self.settings.substeps == 0, state.q, state.v,
                            np.asarray(q_goal, dtype=float), integ, prev_err, duty, on, self.act, self.scal,
                            self.ground, self.model.chain.floating, self._chain_i, self._chain_R, self._chain_f,
                            self._feat_i, self._feat_f, tau, current, self._X, self._F, self._kin_R,
                            self._kin_v, gear)
        if status:
            self._raise(status, state.t, state.q, state.v)
        if self._momentum is None:
            a = self._acceleration(self._pin, self._data, state.q, state.v, tau, armature)
            status = K.post_step(state.q, state.v, a, self.scal, self.model.chain.floating, q, v)
        else:
            status = self._momentum_step(state.q, state.v, tau, q, v)
        if status:
            self._raise(status, state.t, state.q, v)
        if self.gear_play:
            K.gear_step(v, a, self.act, self.settings.dt, gear, armature)
            nd = self._native_data()
            K.gear_impacts(q, v, gear, armature, self.settings.dt, self.model.chain.floating, nd.model.handle,
                           nd.handle, self._impact)
        return SimState(state.t + self.settings.dt, q, v, integ, prev_err, duty, current, state.step + 1,
                        gear if self.gear_play else None)

    def _native_data(self) -> native.NativeData:
        """The compiled loop's ABA workspace (:mod:`integrators.native`), made at its first use."""
        if self._native is None:
            self._native = native.NativeData(native.native_model(self.model))
        return self._native

    def _acceleration(self, model: pin.Model, data: pin.Data, q: np.ndarray, v: np.ndarray,
                      tau: np.ndarray, armature: np.ndarray | None = None) -> np.ndarray:
        """The acceleration (nv,) under generalized force ``tau`` by the contact law, as the
        compiled loops compute it: for the compliant ground the native ABA
        (:func:`integrators.native.aba`: the generated one on COBRA's structure), for the other
        laws Pinocchio's ABA with the contact forces (``model``, ``data``: this simulator's
        Pinocchio model and data, as :func:`pin.aba` takes them). ABA runs in the WORLD
        convention. ``armature`` (nv,) [kg m^2]: the transmission inertia in this step (a gear
        play's, :func:`integrators.kernels.gear_armature`); None: the model's."""
        if self.loop_law == K.LAW_COMPLIANT:
            return native.aba(self._native_data(), q, v, tau, armature)
        if armature is not None:
            model, data = self._pin_with_armature(armature)
        a = pin.aba(model, data, q, v, tau, pin.Convention.WORLD).copy()  # the contact laws below add to it
        if self.loop_law == K.LAW_COMPLIANT_IMPLICIT:
            K.implicit_friction_acceleration(v, pin.computeMinverse(model, data).copy(), self.model.chain.floating,
                                             self._chain_i[:, 0], self._chain_i[:, 2], self._feat_i[:, 0], self._X,
                                             self._F, self._kin_R, self._kin_v, self.ground, self.settings.dt, a,
                                             K.friction_scratch(len(self._feat_i), self.model.nv))
            return a
        args = (v, pin.computeMinverse(model, data).copy(), self.model.chain.floating, self._chain_i[:, 0],
                self._chain_i[:, 2], self._feat_i[:, 0], self._X, self._kin_R, self._kin_v, self.ground,
                self.model.reference_weights, self._soft_warm, a, K.soft_scratch(len(self._feat_i), self.model.nv))
        if K.SOFT_LAWS[self.contact_law]:
            K.soft_elliptic_acceleration(*args, K.elliptic_scratch(len(self._feat_i), self.model.nv))
        else:
            K.soft_contact_acceleration(*args)
        return a

    def _pin_with_armature(self, armature: np.ndarray) -> tuple[pin.Model, pin.Data]:
        """A copy of this simulator's Pinocchio model (made at the first call, then reused) with
        the transmission inertia ``armature`` (nv,) [kg m^2] set, and its data (a gear play's
        step, whose open plays carry no motor)."""
        if self._pin_play is None:
            model = self._pin.copy()
            self._pin_play = (model, model.createData())
        self._pin_play[0].armature = armature
        return self._pin_play

    def _momentum_step(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, q_out: np.ndarray,
                       v_out: np.ndarray) -> int:
        """The momentum-form step under ``tau`` into ``q_out``, ``v_out``; a kernel status."""
        try:
            self._momentum.step(q, v, tau, q_out, v_out)
        except FloatingPointError:
            v_out[:] = np.nan
        return K.check_state(v_out, self.scal[K.S_MAX_SPEED])

    def motor_current(self, state: SimState) -> np.ndarray:
        """Motor current [A] (n_joints,) during the last step."""
        return state.current.copy()

    def commands(self, q_ref: Callable[[np.ndarray], np.ndarray] | np.ndarray, t0: float,
                 n_ticks: int) -> np.ndarray:
        """Servo goals (n_ticks, n_joints) [rad] at the control ticks from ``t0``, delay applied.

        ``q_ref`` is an array of commands per tick or a function of a time array [s] returning
        (len(t), n_joints) (e.g. ``SidewindingGait.q_ref``).
        """
        if callable(q_ref):
            table = np.asarray(q_ref(t0 + np.arange(n_ticks) * self.settings.control_dt), dtype=float)
        else:
            table = np.asarray(q_ref, dtype=float)
            if table.ndim != 2 or table.shape[1] != self.model.n_joints or len(table) == 0:
                raise ValueError(f"command table must be (n_ticks, {self.model.n_joints}), got {table.shape}")
            if len(table) < n_ticks:
                table = np.vstack([table, np.repeat(table[-1:], n_ticks - len(table), axis=0)])
            table = table[:n_ticks]
        return delay_commands(table, self.delay_s, self.settings.control_dt)

    def rollout(self, state: SimState, q_ref: Callable[[np.ndarray], np.ndarray] | np.ndarray,
                duration: float, *, record_every: int = 1, torque_on: np.ndarray | None = None,
                progress: Callable[[float], None] | None = None) -> Trajectory:
        """Simulate ``duration`` [s] from ``state`` with commands ``q_ref``.

        Args:
            state: initial state (its servo loop is assumed to tick at ``state.step == 0``).
            q_ref: commands at each control tick from ``state.t``: an array (n_ticks, n_joints)
                [rad] (the last row is held if short) or a function of a time array (see
                :meth:`commands`).
            duration: simulated time [s].
            record_every: record one sample per this many physics steps (the first sample is
                the initial state).
            torque_on: (n_joints,) bool, motors powered (default all); an unpowered motor is an
                open circuit (no torque, no back-EMF braking), its gearbox damping remains.
            progress: called with the fraction done (0..1) about 100 times.

        Raises:
            InputError: a duration that is not a number of seconds >= 0.
            SimulationDiverged: naming the time and the offending contact point or coordinate.
        """
        if not (np.isfinite(duration) and duration >= 0):
            raise InputError(f"rollout duration must be a number of seconds >= 0, got {duration}")
        s = self.settings
        sub = s.substeps
        n_steps = int(round(duration / s.dt))
        n_ticks = n_steps // sub + 1
        goals = self.commands(q_ref, state.t, n_ticks)
        n_rec = n_steps // record_every + 1
        nj, nq, nv = self.model.n_joints, self.model.nq, self.model.nv
        T = state.t + np.arange(n_rec) * record_every * s.dt
        record = np.empty((n_rec, nq + nv + nj))
        servo = servo_memory(state, self.model.n_base)
        q, v = state.q.copy(), state.v.copy()
        q_next, v_next, tau, a = np.empty(nq), np.empty(nv), np.empty(nv), np.zeros(nv)
        on = np.ones(nj, dtype=np.bool_) if torque_on is None else np.asarray(torque_on, dtype=np.bool_)
        momentum = self._momentum
        plan = np.zeros(K.N_PLAN, dtype=np.int64)
        plan[[K.P_STEPS, K.P_SUBSTEPS, K.P_RECORD_EVERY, K.P_INTEGRATE, K.P_FLOATING]] = (
            n_steps, sub, record_every, momentum is None, self.model.chain.floating)
        act, scal, ground, work = self.act, self.scal, self.ground, self._work
        ci, cR, cf, fi, ff = self._chain_i, self._chain_R, self._chain_f, self._feat_i, self._feat_f
        report_every = max(1, n_steps // 100)
        if momentum is None:
            # the whole loop compiled, Pinocchio's dynamics included (integrators.native); chunks
            # only to report progress
            nd = self._native_data()
            handles = nd.model.handle, nd.handle, self.loop_law
            # the soft-constraint laws' workspace: D^-1, the bodies' weights, warm start
            weights = self.model.reference_weights if self.contact_law in K.SOFT_LAWS else np.zeros(0)
            soft = (np.zeros((nv, nv)), weights, self._soft_warm)
            chunk = report_every if progress is not None else n_steps + 1
            for start in range(0, n_steps + 1, chunk):
                status, i = K.rollout_loop(start, min(start + chunk, n_steps + 1), *handles, plan, q, v, a, goals,
                                           servo, on, act, scal, ground, ci, cR, cf, fi, ff, tau, work, record, *soft)
                if status:
                    self._raise_step(status, i, state.t, q, v)
                if progress is not None:
                    progress(min(start + chunk, n_steps) / max(n_steps, 1))
        else:  # the momentum-form step: its fixed-point iteration calls Pinocchio from Python
            kernel = K.rollout_step
            for i in range(n_steps + 1):
                status = kernel(i, plan, q, v, a, goals, servo, on, act, scal, ground, ci, cR, cf, fi, ff, tau, work,
                                record)
                if status:
                    self._raise_step(status, i, state.t, q, v)
                if i == n_steps:
                    break
                status = self._momentum_step(q, v, tau, q_next, v_next)
                if status:
                    self._raise(status, state.t + i * s.dt, q, v_next)
                q, q_next = q_next, q
                v, v_next = v_next, v
                if progress is not None and i % report_every == 0:
                    progress(i / n_steps)
        if progress is not None:
            progress(1.0)
        Q = np.ascontiguousarray(record[:, :nq])
        V = np.ascontiguousarray(record[:, nq:nq + nv])
        C = np.ascontiguousarray(record[:, nq + nv:])
        # the goals and encoder readings of the recorded samples, taken after the loop (one array
        # operation each instead of one call per sample; the same values)
        G = goals[(np.arange(n_rec) * record_every) // sub]
        M = Q[:, nq - nj:] + act[:, K.A_ENC_OFFSET]
        return Trajectory(T, Q, V, G, M, C)
