"""The largest stable time steps of the semi-implicit step, checked before a run starts.

The step (:mod:`integrators.simulator`) evaluates every force at the start of the step. Linearised
about contact or about a servo's goal, each stiff force is a spring-damper ``m x'' = -k x - c x'``
(natural frequency ``w = sqrt(k / m)``, damping ratio ``z = c / (2 sqrt(k m))``), and the
semi-implicit Euler step ``v+ = v + h a(x, v)``, ``x+ = x + h v+`` of it is stable exactly when
(Jury's test on its 2x2 update matrix, trace ``2 - 2 z w h - w^2 h^2``, determinant ``1 - 2 z w h``)::

    h < 2 / (w (sqrt(1 + z^2) + z))

(for ``k = 0`` an explicit damper: ``h < 2 m / c``). They bound the steps of
:class:`integrators.simulator.SimSettings`:

- ``dt``: the ground's normal spring-damper (``k1``, ``k2``, the same at every contact) with
  every contact touching, as in the robot's straight pose on flat ground: its stiffest mode has
  the mass ``1 / lambda_max(J_n D^-1 J_n^T)`` [kg] (``J_n`` the contact points' normal
  Jacobian rows, ``D`` the joint-space inertia with the transmission inertia); and the motor's
  back-EMF and gearbox damping ``rKm^2 / R + b`` [N m s/rad] on every joint, re-evaluated every
  physics step, whose stiffest mode has the inertia ``1 / lambda_max((D^-1)_aa)`` [kg m^2];
- ``control_dt``: the servo's position loop, which holds its PWM duty for a tick: its
  linearised stiffness ``P/128 * 4096/(2 pi) / 885 * V rKm / R`` [N m/rad] with that damping,
  on the same joint mode (conservative: the damping acts at the shorter ``dt``).

The friction's regularised sign is not a limit of this kind: its slope ``s F_z / eps`` can exceed
``2 m / h``, but the ``tanh`` caps the force at ``s F_z``, so an overshoot stays a bounded chatter
of about ``eps h``-sized slips instead of growing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cobra_model import servo
from cobra_model.errors import InputError
from cobra_model.model import RobotModel
from cobra_model.parameters import WINDING_RESISTANCE_OHM, ModelParameters


def damped_spring_step_limit(stiffness: float, damping: float, mass: float) -> float:
    """Largest stable semi-implicit Euler step [s] of ``mass x'' = -stiffness x - damping x'``.

    Args: stiffness [N/m or N m/rad] > 0, damping [N s/m or N m s/rad] >= 0, mass [kg or kg m^2] > 0.
    """
    w = np.sqrt(stiffness / mass)
    z = damping / (2.0 * np.sqrt(stiffness * mass))
    return float(2.0 / (w * (np.sqrt(1.0 + z * z) + z)))


def servo_stiffness_damping(params: ModelParameters, p_gain: int = 800) -> tuple[float, float]:
    """Linearised nominal servo: position stiffness [N m/rad] and back-EMF damping [N m s/rad].

    The Dynamixel loop sends ``P/128 * e`` PWM units for an error of ``e`` encoder pulses; a duty
    ``u / 885`` drives the current ``(u V / 885 - rKm qdot) / R`` through the motor, whose torque
    at the joint is ``rKm`` times it.
    """
    rkm = servo.SERVO_GEAR_RATIO * params.motor_km
    kp = (p_gain / servo.P_GAIN_DIVISOR * servo.PULSES_PER_REV / (2 * np.pi) / servo.PWM_FULL_SCALE
          * servo.SUPPLY_VOLTAGE_V * rkm / WINDING_RESISTANCE_OHM)
    kv = rkm * rkm / WINDING_RESISTANCE_OHM
    return kp, kv


def damper_step_limit(damping: float, mass: float) -> float:
    """Largest stable explicit step [s] of ``mass x'' = -damping x'``: ``2 mass / damping``."""
    return float(2.0 * mass / damping) if damping > 0 else np.inf


@dataclass(frozen=True)
class StepLimits:
    """The largest stable steps [s] and, for each, what sets it (a phrase naming the force and where)."""

    dt: float
    dt_reason: str
    control_dt: float
    control_dt_reason: str


def step_limits(model: RobotModel, params: ModelParameters, p_gain: int = 800,
                q: np.ndarray | None = None) -> StepLimits:
    """The largest stable ``dt`` and ``control_dt`` for ``model`` (armature included) and ``params``.

    ``dt`` is bounded by the ground's normal spring-damper at the lightest contact and by the
    motor's back-EMF and gearbox damping (evaluated every physics step) at the lightest joint;
    ``control_dt`` by the position loop's spring and that damping at the lightest joint.
    ``q`` is the configuration at which the effective masses are taken (default: the straight
    pose, on the ground for a floating robot with contacts).
    """
    if q is None:
        q = model.configuration()
        if model.chain.floating and len(model.features):
            q[2] -= model.contact_points(q, params.get("contact_rounding", 0.0))[:, 2].min()
    D_inv = np.linalg.inv(model.mass_matrix(q))
    limits = [(np.inf, "-")]
    control = (np.inf, "-")
    if len(model.features):
        Jn = model.contact_jacobian(q, params.get("contact_rounding", 0.0))[2::3]
        mass = _lightest_mode_mass(Jn @ D_inv @ Jn.T)
        limits.append((damped_spring_step_limit(params.k1, params.k2, mass),
                       f"the ground stiffness k1 = {params.k1:g} N/m and damping k2 = {params.k2:g} N s/m with all "
                       f"{len(model.features)} contacts touching (lightest normal mode {mass:.3g} kg)"))
    n = model.n_joints
    if n:
        inertia = _lightest_mode_mass(D_inv[model.n_base:, model.n_base:])
        kp, kv = servo_stiffness_damping(params, p_gain)
        damping = kv + float(np.min(params.per_joint("joint_damping", None)[:n]))
        where = f"on the {n} joints (lightest mode {inertia:.3g} kg m^2)"
        limits.append((damper_step_limit(damping, inertia),
                       f"the motor's back-EMF and gearbox damping ({damping:.3g} N m s/rad) {where}"))
        control = (damped_spring_step_limit(kp, damping, inertia),
                   f"the servo's position loop (P gain {p_gain}: {kp:.3g} N m/rad) {where}")
    dt, reason = min(limits, key=lambda x: x[0])
    return StepLimits(float(dt), reason, float(control[0]), control[1])


def _lightest_mode_mass(inverse_mass: np.ndarray) -> float:
    """Mass [kg or kg m^2] of the stiffest mode when equal springs act on every coordinate of a
    block with inverse mass matrix ``inverse_mass``: ``1 / lambda_max``."""
    return float(1.0 / np.linalg.eigvalsh(0.5 * (inverse_mass + inverse_mass.T))[-1])


def check_steps(model: RobotModel, params: ModelParameters, dt: float, control_dt: float, p_gain: int = 800) -> None:
    """Raise :class:`InputError` if ``dt`` or ``control_dt`` [s] would make the step unstable.

    The message names the setting, the largest stable value and what sets it.
    """
    lim = step_limits(model, params, p_gain)
    if dt >= lim.dt:
        raise InputError(f"dt = {dt:g} s is unstable for {lim.dt_reason}: the largest stable dt is {lim.dt:.3g} s "
                         f"(use --dt {_round_down(lim.dt):g} or less)")
    if control_dt >= lim.control_dt:
        raise InputError(f"control_dt = {control_dt:g} s is unstable for {lim.control_dt_reason}: the largest stable "
                         f"control_dt is {lim.control_dt:.3g} s (use --control-dt {_round_down(lim.control_dt):g} or less)")


def _round_down(x: float) -> float:
    """``x`` rounded down to two significant digits (a step a user can type)."""
    e = np.floor(np.log10(x)) - 1
    return float(np.floor(x / 10 ** e) * 10 ** e)
