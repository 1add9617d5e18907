"""The largest stable time steps of the semi-implicit step, checked before a run starts.

The step (:mod:`integrators.simulator`) evaluates every force at the start of the step. Linearised
about contact or about a servo's goal, each stiff force is a spring-damper ``m x'' = -k x - c x'``
(natural frequency ``w = sqrt(k / m)``, damping ratio ``z = c / (2 sqrt(k m))``), and the
semi-implicit Euler step ``v+ = v + h a(x, v)``, ``x+ = x + h v+`` of it is stable exactly when
(Jury's test on its 2x2 update matrix, trace ``2 - 2 z w h - w^2 h^2``, determinant ``1 - 2 z w h``)::

    h < 2 / (w (sqrt(1 + z^2) + z))

(for ``k = 0`` an explicit damper: ``h < 2 m / c``). The robot couples its springs, so the
bound on ``dt`` (:func:`step_limits`) is computed on the whole linearised robot ``D x'' = -K x -
C x'`` - the servo's spring ``P/128 * 4096/(2 pi) / 885 * V rKm / R`` [N m/rad] and the motor's
back-EMF and gearbox damping ``rKm^2 / R + b`` [N m s/rad] on every joint, the ground's ``k1``,
``k2`` on every contact's normal (all touching, the straight pose on flat ground), ``D`` the
joint-space inertia with the transmission inertia - as the largest ``h`` at which the step's
update matrix has no eigenvalue outside the unit circle (:func:`coupled_step_limit`). The
closed forms name which term binds: the ground on its stiffest normal mode (mass
``1 / lambda_max(J_n D^-1 J_n^T)`` [kg]) or the motor damping on the joints' stiffest mode
(inertia ``1 / lambda_max((D^-1)_aa)`` [kg m^2]). ``control_dt``, the period for which the
servo holds its PWM duty, is bounded by the servo's spring and damping on that joint mode
(conservative: the damping acts at the shorter ``dt``). The robot is not linear, so
:func:`check_steps` allows :data:`MARGIN` of these limits.

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
    """The linearised robot's largest stable steps [s] and, for each, what sets it (a phrase
    naming the force and where); ``allowed_*`` are the steps :func:`check_steps` accepts."""

    dt: float
    dt_reason: str
    control_dt: float
    control_dt_reason: str

    @property
    def allowed_dt(self) -> float:
        return MARGIN * self.dt

    @property
    def allowed_control_dt(self) -> float:
        return MARGIN * self.control_dt


def step_limits(model: RobotModel, params: ModelParameters, p_gain: int = 800,
                q: np.ndarray | None = None) -> StepLimits:
    """The largest stable ``dt`` and ``control_dt`` for ``model`` (armature included) and ``params``.

    ``dt``: the largest step at which the semi-implicit step of the linearised robot - the servo's
    spring (its loop running every step), the motor's back-EMF and gearbox damping, and the
    ground's normal spring-damper at every contact - has no growing mode (:func:`coupled_step_limit`).
    Its reason names the single term with the smallest limit of its own (the closed forms above).
    ``control_dt``: the position loop's spring and that damping on the joints' stiffest mode.
    ``q`` is the configuration of the linearisation (default: the straight pose, on the ground
    for a floating robot with contacts, where every contact touches).
    """
    if q is None:
        q = model.on_ground(model.configuration(), params.get("contact_rounding"))
    M = model.mass_matrix(q)
    D_inv = np.linalg.inv(M)
    K, C = np.zeros_like(M), np.zeros_like(M)
    terms = [(np.inf, "-")]
    control = (np.inf, "-")
    if len(model.features):
        Jn = model.contact_jacobian(q, params.get("contact_rounding"))[2::3]
        K += params.k1 * Jn.T @ Jn
        C += params.k2 * Jn.T @ Jn
        mass = _lightest_mode_mass(Jn @ D_inv @ Jn.T)
        terms.append((damped_spring_step_limit(params.k1, params.k2, mass),
                      f"the ground stiffness k1 = {params.k1:g} N/m and damping k2 = {params.k2:g} N s/m "
                      f"(lightest normal mode {mass:.3g} kg)"))
    n = model.n_joints
    if n:
        nb = model.n_base
        inertia = _lightest_mode_mass(D_inv[nb:, nb:])
        kp, kv = servo_stiffness_damping(params, p_gain)
        damping = kv + params.per_joint("joint_damping")[:n]
        K[nb:, nb:] += kp * np.eye(n)
        C[nb:, nb:] += np.diag(damping)
        where = f"on the {n} joints (lightest mode {inertia:.3g} kg m^2)"
        most = float(damping.max())  # the most damped joint binds: both limits fall with damping
        terms.append((damper_step_limit(most, inertia),
                      f"the motor's back-EMF and gearbox damping ({most:.3g} N m s/rad) {where}"))
        control = (damped_spring_step_limit(kp, most, inertia),
                   f"the servo's position loop (P gain {p_gain}: {kp:.3g} N m/rad) {where}")
    single, reason = min(terms, key=lambda x: x[0])
    dt = coupled_step_limit(M, K, C, upper=2.0 * single) if np.isfinite(single) else np.inf
    return StepLimits(dt, f"{reason}, coupled with the rest of the linearised robot", float(control[0]), control[1])


def coupled_step_limit(M: np.ndarray, K: np.ndarray, C: np.ndarray, upper: float = 1.0) -> float:
    """Largest step [s] (to 0.1 %) at which semi-implicit Euler on ``M x'' = -K x - C x'`` has no
    growing mode: the spectral radius of its update matrix
    ``[[I - h^2 M^-1 K, h (I - h M^-1 C)], [-h M^-1 K, I - h M^-1 C]]`` (on ``(x, v)``) is at most
    1 (the rigid modes' eigenvalue 1 stays). Bisection below ``upper`` [s]; ``upper`` itself
    when the step is stable there (the limit is then at least that)."""
    MK, MC, eye = np.linalg.solve(M, K), np.linalg.solve(M, C), np.eye(M.shape[0])

    def stable(h: float) -> bool:
        damp = eye - h * MC
        A = np.block([[eye - h * h * MK, h * damp], [-h * MK, damp]])
        return bool(np.max(np.abs(np.linalg.eigvals(A))) <= 1.0 + 1e-6)

    lo, hi = 0.0, upper
    if stable(hi):
        return float(hi)
    while hi - lo > 1e-3 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return float(lo)


def _lightest_mode_mass(inverse_mass: np.ndarray) -> float:
    """Mass [kg or kg m^2] of the stiffest mode when equal springs act on every coordinate of a
    block with inverse mass matrix ``inverse_mass``: ``1 / lambda_max``."""
    return float(1.0 / np.linalg.eigvalsh(0.5 * (inverse_mass + inverse_mass.T))[-1])


#: Fraction of the linearised limits that :func:`check_steps` allows. The robot is not linear:
#: a contact lets go instead of pulling (fewer contacts engaged, lighter modes) and the servo
#: holds its duty between ticks. Measured on COBRA (``tests/test_stability.py``): a 2 mm drop
#: onto the ground settles up to 0.85-0.9 of the limit (the softest, least damped ground:
#: k1 = 1e4 N/m, k2 = 1 N s/m) or 0.9-0.95 (stiffer or more damped), and joints at rest with the
#: lightest transmission settle up to 0.9 of the back-EMF limit and oscillate from 0.95.
MARGIN = 0.85


def check_steps(model: RobotModel, params: ModelParameters, dt: float, control_dt: float, p_gain: int = 800) -> None:
    """Raise :class:`InputError` if ``dt`` or ``control_dt`` [s] exceed :data:`MARGIN` times
    their linearised limits (:func:`step_limits`): the step would not settle.

    The message names the setting, the largest value allowed and what sets it.
    """
    lim = step_limits(model, params, p_gain)
    if dt > lim.allowed_dt:
        raise InputError(f"dt = {dt:g} s is unstable for {lim.dt_reason}: the largest stable dt is "
                         f"{lim.allowed_dt:.3g} s (use --dt {_round_down(lim.allowed_dt):g} or less)")
    if control_dt > lim.allowed_control_dt:
        raise InputError(f"control_dt = {control_dt:g} s is unstable for {lim.control_dt_reason}: the largest "
                         f"stable control_dt is {lim.allowed_control_dt:.3g} s "
                         f"(use --control-dt {_round_down(lim.allowed_control_dt):g} or less)")


def _round_down(x: float) -> float:
    """``x`` rounded down to two significant digits (a step a user can type)."""
    e = np.floor(np.log10(x)) - 1
    return float(np.floor(x / 10 ** e) * 10 ** e)
