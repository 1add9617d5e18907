"""Compiled (numba) kernels of the simulator's hot path: contact-point kinematics, the Stribeck
ground model and the Dynamixel/DC-motor actuator.

Pinocchio does the rigid-body algorithms (ABA, CRBA, RNEA, energies); these kernels do only
what is this project's own: locating the ground-contact points on the collision geometry,
evaluating the compliant ground and the actuator, and mapping the contact forces to generalized
forces ``J^T F``. To do so in one compiled call per step they walk the kinematic tree with the
joint placements and axes read from the Pinocchio model; ``tests/test_kernels.py`` checks
positions, velocities and ``J^T F`` against Pinocchio's own frame Jacobians to 1e-12. A single
rollout's loop (:func:`rollout_loop`) calls ABA (COBRA's generated from Pinocchio's; for the
soft-constraint laws Pinocchio's, with the inverse mass matrix from the same pass) through
:mod:`integrators.native`, so that the whole loop is compiled; a batch
(:func:`batch_rollout_loop`) runs that loop for each of its environments on the worker threads. Each contact law has a loop and a batch of its own
(:data:`LAW_LOOPS`, :data:`LAW_BATCHES`), so that numba compiles, on first use, only the laws
a user runs: one loop with every law's solver took 70 s to compile on a 2-core Xeon, the
compliant ground's takes 17 s and its batch 15 s more (``benchmarks/results/first_run.md``).

The helpers of one physics step are inlined into one compiled step (``inline="always"``,
numba's IR inlining; :func:`_step`, which every contact law's loop calls), and they index the
packed arrays (``chain_i[i, 0]``) rather than slice them: a call from one compiled function to
another hands over each array, and a slice makes a view, each
with an atomic reference-count increment and decrement (numba's ``NRT_incref``/``NRT_decref``).
Those were about 10 % of a single rollout's step (perf) and more of a batch's, whose threads
counted on the same read-only arrays (a cache line both cores then wrote at every step; each
thread now reads copies of its own, :func:`_batch_rollout_loop`). Inlined, numba's
reference-count pruning removes most of the rest. The arithmetic is the same, bit for bit. The
soft-constraint laws' solvers stay out of line: inlined into the loop, the pyramid's made both
laws slower. Within the elliptic cone's, the small helpers that its Newton iterations call
several times a step (the Cholesky factor and solve, the cone's projection and the primal
cost) are inlined: each call counted a reference on every array it
took (25.3 -> 24.2 us per elliptic step; the pyramid's unchanged). The pyramid's working
arrays, and the elliptic cone's, are views of scratch arrays that a rollout's loop makes once
(:func:`soft_scratch`, :func:`elliptic_scratch`), so that a step allocates none; each law has a
solver of its own (:func:`soft_contact_acceleration`, :func:`soft_elliptic_acceleration`), so
that the pyramid's call does not hand over the cone's arrays.

Conventions (Pinocchio's): a floating root has ``q = [p (3), quat x y z w (4), joints]`` and
``v = [v_lin (3), omega (3), joint rates]`` with both root velocities expressed in the root's
local frame; the root's generalized force is (force, torque about its origin) in that frame.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from cobra_model.parameters import Parameter
from cobra_model.servo import PULSES_PER_REV, PWM_FULL_SCALE, SERVO_STALL_TORQUE_NM
from integrators.native import ABA, ABA_MINVERSE

# Indices into the ground parameter array ``ground``.
G_K1, G_K2, G_MU_C, G_MU_S, G_MU_V, G_V_S, G_EPS, G_LATERAL, G_CONE, G_ROUND, G_TC = range(11)
N_GROUND = 11

# Indices into the per-joint actuator array ``act`` (shape (n_joints, N_ACT)).
A_DAMPING, A_RKM, A_COULOMB, A_TAU_MAX, A_COULOMB_EPS, A_ENC_OFFSET, A_BACKLASH, A_ARMATURE = range(8)
N_ACT = 8

#: Rows of a rollout's servo memory ``servo`` (N_SERVO, n_joints): the position loop's integral
#: and previous error [pulses], the held duty, the motor current [A], then the gear play's state
#: (:func:`gear_step`; rows ``SV_GEAR:``, indexed by ``GEAR_*``).
SV_INTEG, SV_PREV_ERR, SV_DUTY, SV_CURRENT, SV_GEAR = range(5)
#: The gear play's rows: the motor's angle less the output's [rad] (within +-backlash), the
#: motor's rate [rad/s], which tooth flank is in contact (+1, -1; 0 while the play is open), the
#: motor's net torque in the last step [N m], the momentum of an impact in the last step [N m s]
#: (the motor's relative to the output's, which :func:`gear_impacts` hands to the joined bodies)
#: and the part of that step after the teeth met (in [0, 1]).
GEAR_GAP, GEAR_RATE, GEAR_ENGAGED, GEAR_TORQUE, GEAR_IMPULSE, GEAR_LATE = range(6)
N_GEAR = 6
N_SERVO = SV_GEAR + N_GEAR

#: The parameters of the effects these kernels model beyond the nominal table
#: (``sysid.discrepancy.effects`` names them): unit, bounds and the value at which the kernel's
#: term vanishes, the one place each lives. A parameter set without one simulates it at that value.
EFFECT_PARAMETERS: tuple[Parameter, ...] = (
    Parameter("joint_coulomb", "N m", 0.0, 0.0, 3.0, group="joint_coulomb_friction",
              doc="Coulomb friction torque of the gearbox"),
    Parameter("backlash", "rad", 0.0, 0.0, 0.2, group="backlash", doc="half-width of the gear train's play"),
    # inactive at the stall torque: the motor cannot exceed it at the nominal constant, and the
    # URDF's effort limit (which MuJoCo enforces) is the same 9.9 N m
    Parameter("torque_limit", "N m", SERVO_STALL_TORQUE_NM, 0.5, SERVO_STALL_TORQUE_NM,
              group="torque_saturation", doc="motor torque limit (voltage/current)"),
    Parameter("lateral_friction_ratio", "1", 1.0, 0.2, 5.0, log_scale=True, group="anisotropic_ground_friction",
              doc="sideways / along-body friction ratio"),
    Parameter("encoder_offset", "rad", 0.0, -0.2, 0.2, group="encoder_offset", doc="encoder zero offset (all joints)"),
)

#: Where a parameter of a parameter set lands in ``ground`` (by name: the simulator packs every
#: name listed here, an effect parameter the set lacks at its value in :data:`EFFECT_PARAMETERS`).
#: A new effect that acts in these kernels adds its parameter there, its slot here and its
#: physics in the kernel that reads the slot.
GROUND_PARAMETERS: dict[str, int] = {
    "k1": G_K1, "k2": G_K2, "mu_c": G_MU_C, "mu_s": G_MU_S, "mu_v": G_MU_V, "v_s": G_V_S,
    "lateral_friction_ratio": G_LATERAL, "friction_cone": G_CONE, "contact_rounding": G_ROUND,
    "contact_time_constant": G_TC,
}
#: The ground parameters each contact law reads (``cobra_model.parameters.CONTACT_LAWS``); the
#: others do not enter its forces. The soft-constraint laws' normal stiffness and damping are
#: their time constant (``soft_contact_acceleration``); they have no Stribeck or viscous term and
#: their friction limit is the pyramid or the elliptic cone, not ``friction_cone``.
CONTACT_LAW_PARAMETERS: dict[str, tuple[str, ...]] = {
    "compliant": ("k1", "k2", "mu_c", "mu_s", "mu_v", "v_s", "lateral_friction_ratio", "friction_cone",
                  "contact_rounding"),
    "soft_constraint": ("mu_c", "lateral_friction_ratio", "contact_time_constant", "contact_rounding"),
    "soft_elliptic": ("mu_c", "lateral_friction_ratio", "contact_time_constant", "contact_rounding"),
}
#: The contact laws that are MuJoCo's soft constraint (:func:`soft_contact_acceleration`), each
#: with whether its friction cone is elliptic (else the pyramid).
SOFT_LAWS: dict[str, bool] = {"soft_constraint": False, "soft_elliptic": True}
#: Where a per-joint parameter lands in ``act`` (packed with :meth:`ModelParameters.per_joint`).
#: ``A_RKM`` (the motor constant times the gear ratio) and the settings' ``A_COULOMB_EPS`` are
#: packed by the simulator itself.
ACTUATOR_PARAMETERS: dict[str, int] = {
    "joint_damping": A_DAMPING, "joint_coulomb": A_COULOMB, "torque_limit": A_TAU_MAX,
    "encoder_offset": A_ENC_OFFSET, "backlash": A_BACKLASH,
}

# Indices into the scalar settings array ``scal``.
S_DT, S_VOLTAGE, S_RESISTANCE, S_MAX_DEPTH, S_MAX_SPEED, S_KP, S_KI, S_KD, S_PWM_LIMIT = range(9)
N_SCAL = 9

# Contact feature kinds.
FEATURE_POINT = 0       # sphere or point: lowest point = centre - radius * z
FEATURE_CIRCLE = 1      # end circle of a cylinder: lowest point of the circle

# Status codes returned by the kernels (0 = fine).
STATUS_OK = 0
STATUS_NONFINITE = 1
STATUS_PENETRATION = 2
STATUS_VELOCITY = 3


@njit(cache=True, inline="always", fastmath=False)
def _quat_xyzw_to_rot_into(R, b: int, qx: float, qy: float, qz: float, qw: float) -> None:
    """The rotation matrix of the quaternion ``(x, y, z, w)`` (normalised first) into ``R[b]`` (3, 3)."""
    n = np.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    x, y, z, w = qx / n, qy / n, qz / n, qw / n
    R[b, 0, 0] = 1 - 2 * (y * y + z * z)
    R[b, 0, 1] = 2 * (x * y - z * w)
    R[b, 0, 2] = 2 * (x * z + y * w)
    R[b, 1, 0] = 2 * (x * y + z * w)
    R[b, 1, 1] = 1 - 2 * (x * x + z * z)
    R[b, 1, 2] = 2 * (y * z - x * w)
    R[b, 2, 0] = 2 * (x * z - y * w)
    R[b, 2, 1] = 2 * (y * z + x * w)
    R[b, 2, 2] = 1 - 2 * (x * x + y * y)


@njit(cache=True, inline="always")
def chain_kinematics(q, v, floating, chain_i, chain_R, chain_f, kin_R, kin_v):
    """World pose and velocity of every body of the tree (allocation-free).

    Args:
        q, v: configuration (nq,) and velocity (nv,) in Pinocchio's convention.
        floating: True when body 0 is a free-flyer root.
        chain_i: (nb, 3) per body its parent (-1 for the universe) and the index of its
            revolute joint's coordinate in q and in v.
        chain_R, chain_f: (nb, 3, 3) and (nb, 6): the joint placement in the parent body frame
            (rotation; translation in ``chain_f[:, :3]``) and the revolute axis in the joint
            frame (``chain_f[:, 3:]``, unused for a floating root).
        kin_R: output (nb, 3, 3), the bodies' world rotations.
        kin_v: output (nb, 6, 3); rows 0-3 of each body: world origin [m], angular velocity
            [rad/s], origin velocity [m/s] and the joint axis in the world frame.

    The packed arrays are indexed, not sliced: a slice is a view, which costs an atomic
    reference count in numba (see the module's docstring).
    """
    R = kin_R
    nb = chain_i.shape[0]
    for i in range(nb):
        if floating and i == 0:
            _quat_xyzw_to_rot_into(R, 0, q[3], q[4], q[5], q[6])
            for r in range(3):
                kin_v[0, 0, r] = q[r]
                kin_v[0, 1, r] = R[0, r, 0] * v[3] + R[0, r, 1] * v[4] + R[0, r, 2] * v[5]
                kin_v[0, 2, r] = R[0, r, 0] * v[0] + R[0, r, 1] * v[1] + R[0, r, 2] * v[2]
                kin_v[0, 3, r] = 0.0
            continue
        par = chain_i[i, 0]
        if par < 0:
            for r in range(3):
                kin_v[i, 0, r] = chain_f[i, r]
                kin_v[i, 1, r] = 0.0
                kin_v[i, 2, r] = 0.0
        else:
            for r in range(3):
                acc = kin_v[par, 0, r]
                for c in range(3):
                    acc += R[par, r, c] * chain_f[i, c]
                kin_v[i, 0, r] = acc
            dx = kin_v[i, 0, 0] - kin_v[par, 0, 0]
            dy = kin_v[i, 0, 1] - kin_v[par, 0, 1]
            dz = kin_v[i, 0, 2] - kin_v[par, 0, 2]
            wx, wy, wz = kin_v[par, 1, 0], kin_v[par, 1, 1], kin_v[par, 1, 2]
            kin_v[i, 2, 0] = kin_v[par, 2, 0] + wy * dz - wz * dy
            kin_v[i, 2, 1] = kin_v[par, 2, 1] + wz * dx - wx * dz
            kin_v[i, 2, 2] = kin_v[par, 2, 2] + wx * dy - wy * dx
            kin_v[i, 1, 0], kin_v[i, 1, 1], kin_v[i, 1, 2] = wx, wy, wz
        # the joint's rotation about its axis (Rodrigues), as scalars
        a0, a1, a2 = chain_f[i, 3], chain_f[i, 4], chain_f[i, 5]
        cth, sth = np.cos(q[chain_i[i, 1]]), np.sin(q[chain_i[i, 1]])
        C = 1.0 - cth
        ra00, ra01, ra02 = cth + a0 * a0 * C, a0 * a1 * C - a2 * sth, a0 * a2 * C + a1 * sth
        ra10, ra11, ra12 = a1 * a0 * C + a2 * sth, cth + a1 * a1 * C, a1 * a2 * C - a0 * sth
        ra20, ra21, ra22 = a2 * a0 * C - a1 * sth, a2 * a1 * C + a0 * sth, cth + a2 * a2 * C
        qd = v[chain_i[i, 2]]
        jR = chain_R
        for r in range(3):
            # row r of the joint frame's world rotation R_parent jR (jR alone under the universe)
            if par < 0:
                j0, j1, j2 = jR[i, r, 0], jR[i, r, 1], jR[i, r, 2]
            else:
                j0 = R[par, r, 0] * jR[i, 0, 0] + R[par, r, 1] * jR[i, 1, 0] + R[par, r, 2] * jR[i, 2, 0]
                j1 = R[par, r, 0] * jR[i, 0, 1] + R[par, r, 1] * jR[i, 1, 1] + R[par, r, 2] * jR[i, 2, 1]
                j2 = R[par, r, 0] * jR[i, 0, 2] + R[par, r, 1] * jR[i, 1, 2] + R[par, r, 2] * jR[i, 2, 2]
            R[i, r, 0] = j0 * ra00 + j1 * ra10 + j2 * ra20
            R[i, r, 1] = j0 * ra01 + j1 * ra11 + j2 * ra21
            R[i, r, 2] = j0 * ra02 + j1 * ra12 + j2 * ra22
            kin_v[i, 3, r] = j0 * a0 + j1 * a1 + j2 * a2
            kin_v[i, 1, r] += kin_v[i, 3, r] * qd


@njit(cache=True, inline="always")
def add_body_wrenches(tau, floating, chain_i, kin_R, kin_v):
    """Accumulate ``J^T`` of every body's world wrench into ``tau`` in one sweep from the leaves.

    ``kin_v[i, 4]`` [N] and ``kin_v[i, 5]`` [N m] (moment about the world origin) hold the
    wrench applied to body ``i`` and are overwritten by its subtree's; ``kin_R`` and rows 0 and
    3 of ``kin_v`` are :func:`chain_kinematics`' rotations, origins and world joint axes. A
    revolute joint takes the subtree's moment about its origin along its world axis; a floating
    root takes the force and the moment about its origin in its own frame (Pinocchio's
    convention). Bodies are in Pinocchio's order (a parent before its children).
    """
    R = kin_R
    for i in range(chain_i.shape[0] - 1, -1, -1):
        f0, f1, f2 = kin_v[i, 4, 0], kin_v[i, 4, 1], kin_v[i, 4, 2]
        mx = kin_v[i, 5, 0] - (kin_v[i, 0, 1] * f2 - kin_v[i, 0, 2] * f1)
        my = kin_v[i, 5, 1] - (kin_v[i, 0, 2] * f0 - kin_v[i, 0, 0] * f2)
        mz = kin_v[i, 5, 2] - (kin_v[i, 0, 0] * f1 - kin_v[i, 0, 1] * f0)
        if floating and i == 0:
            for c in range(3):
                tau[c] += R[0, 0, c] * f0 + R[0, 1, c] * f1 + R[0, 2, c] * f2
                tau[3 + c] += R[0, 0, c] * mx + R[0, 1, c] * my + R[0, 2, c] * mz
        else:
            tau[chain_i[i, 2]] += kin_v[i, 3, 0] * mx + kin_v[i, 3, 1] * my + kin_v[i, 3, 2] * mz
        par = chain_i[i, 0]
        if par >= 0:
            for c in range(3):
                kin_v[par, 4, c] += kin_v[i, 4, c]
                kin_v[par, 5, c] += kin_v[i, 5, c]


@njit(cache=True, inline="always")
def cone_weights(v1: float, v2: float, eps: float, cone: float):
    """Weights on the two per-component Coulomb terms that shape the friction limit surface.

    With ``q = 1 / cone`` the full-slip friction force lies on the unit ``q``-norm ball
    (scaled per axis by ``s_i F_z``) and points against the slip, the maximum-dissipation
    direction for that ball: ``cone = 0`` is the box of the paper's per-component law
    (weights exactly 1), ``cone = 0.5`` the isotropic circle, ``cone -> 1`` the diamond of a
    pyramidal cone with edges along the body axes (MuJoCo's default ``cone="pyramidal"``).
    Args: contact-velocity components ``v1, v2`` [m/s], the creep speed ``eps`` [m/s] below
    which slip counts as zero, and ``cone`` in ``[0, 1)``.
    """
    if cone <= 0.0:
        return 1.0, 1.0
    a1, a2 = abs(v1), abs(v2)
    top = max(a1, a2)
    if top <= 1e-9 * eps:
        return 1.0, 1.0
    p = 1.0 / (1.0 - cone)
    r1, r2 = a1 / top, a2 / top
    norm = (r1 ** p + r2 ** p) ** (1.0 / p)
    return (r1 / norm) ** (p - 1.0), (r2 / norm) ** (p - 1.0)


@njit(cache=True, inline="always")
def ground_tangent(R, b):
    """The contact frame's first axis ``t1`` (x, y) on the ground: body ``b``'s x axis projected
    on the ground and normalised (world x for a body standing upright); ``t2 = z x t1``."""
    bx0, bx1 = R[b, 0, 0], R[b, 1, 0]
    n = np.sqrt(bx0 * bx0 + bx1 * bx1)
    if n > 1e-6:
        return bx0 / n, bx1 / n
    return 1.0, 0.0


@njit(cache=True, inline="always")
def contact_friction(v1, v2, fz, mu_c, mu_s, mu_v, v_s, eps, lateral, cone):
    """The Stribeck friction law of :func:`ground_forces` at one contact: the forces ``f1, f2``
    [N] along its tangents ``t1, t2`` at the slip ``v1, v2`` [m/s] under the normal force ``fz``
    [N], and their dissipative slopes ``c1, c2`` [N s/m],
    ``c_i = s_i F_z w_i (1 - tanh^2(v_i / eps)) / eps + mu_v`` (the Stribeck shape's and the
    cone weights' derivatives left out: :func:`implicit_friction_acceleration`'s Newton steps).

    Returns:
        ``(f1, c1, f2, c2)``.
    """
    s1 = mu_c - (mu_c - mu_s) * np.exp(-(v1 / v_s) ** 2)
    s2 = lateral * (mu_c - (mu_c - mu_s) * np.exp(-(v2 / v_s) ** 2))
    w1, w2 = cone_weights(v1, v2, eps, cone)
    t1, t2 = np.tanh(v1 / eps), np.tanh(v2 / eps)
    return (-s1 * fz * w1 * t1 - mu_v * v1, s1 * fz * w1 * (1.0 - t1 * t1) / eps + mu_v,
            -s2 * fz * w2 * t2 - mu_v * v2, s2 * fz * w2 * (1.0 - t2 * t2) / eps + mu_v)


@njit(cache=True, inline="always")
def ground_forces(q, v, floating, chain_i, chain_R, chain_f, feat_i, feat_f, ground, tau, X, F, max_depth, kin_R,
                  kin_v):
    """Stribeck ground (paper Eqs. 3-6) on every contact feature, accumulated as ``J^T F``.

    Contact points: a point feature touches at ``centre - radius z``; a circle feature (a
    cylinder's end) at the lowest point of its edge, rounded with radius
    ``rho = min(ground[G_ROUND], radius)``: the edge is the tube of radius ``rho`` around the
    circle of radius ``radius - rho`` in the end plane, so the point is
    ``centre + (radius - rho) d - rho z`` (``d`` the in-plane direction of steepest descent):
    ``rho = 0`` is the sharp rim of a cylinder, ``rho = radius`` the hemisphere of a capsule.
    Normal: ``F_z = max(0, -k1 p_z - k2 pdot_z)`` below ground, 0 above (no adhesion).
    Tangential, per component ``i`` of the contact velocity in the contact's ground frame
    (``t1`` = the body's x axis projected on the ground, ``t2 = z x t1``):
    ``F_i = -s_i F_z sgn_eps(pdot_i) - mu_v pdot_i`` (:func:`contact_friction`) with
    ``s_i = mu_c - (mu_c - mu_s) exp(-pdot_i^2 / v_s^2)``, the lateral (``t2``) component's
    ``s`` multiplied by ``ground[G_LATERAL]`` (1 = isotropic, the paper's model), and each
    Coulomb/Stribeck term weighted by :func:`cone_weights` with the friction-cone shape
    ``ground[G_CONE]`` (0 = the paper's per-component law).
    ``sgn_eps(x) = tanh(x / eps)``: below ``eps`` [m/s] friction acts as a viscous damper of
    slope ``s F_z / eps``, so a contact loaded tangentially below its friction limit creeps at
    about ``eps F_t / (s F_z)``; eps bounds the stiffness the explicit step must resolve.
    The frame is the body's so that the law does not depend on the robot's world heading.

    Returns:
        status: STATUS_OK, or STATUS_PENETRATION if a point is deeper than ``max_depth`` [m].
    Outputs ``X`` (nf, 3) contact points [m] and ``F`` (nf, 3) world forces [N]; ``kin_R``
    (nb, 3, 3) and ``kin_v`` (nb, 6, 3) are the workspace: the bodies' rotations and their
    origins, angular and origin velocities and joint axes (:func:`chain_kinematics`), then the
    wrenches of :func:`add_body_wrenches`. The chain's arrays are :func:`chain_kinematics`';
    ``feat_i`` (nf, 2) = body, kind; ``feat_f`` (nf, 7) = centre (3), axis (3), radius, in the
    body's frame.
    """
    R = kin_R
    for i in range(kin_v.shape[0]):
        for c in range(3):
            kin_v[i, 4, c] = 0.0
            kin_v[i, 5, c] = 0.0
    chain_kinematics(q, v, floating, chain_i, chain_R, chain_f, kin_R, kin_v)
    k1, k2 = ground[G_K1], ground[G_K2]
    mu_c, mu_s, mu_v, v_s = ground[G_MU_C], ground[G_MU_S], ground[G_MU_V], ground[G_V_S]
    eps, lateral, cone, rounding = ground[G_EPS], ground[G_LATERAL], ground[G_CONE], ground[G_ROUND]
    status = STATUS_OK
    for k in range(feat_i.shape[0]):
        b = feat_i[k, 0]
        c0 = kin_v[b, 0, 0] + R[b, 0, 0] * feat_f[k, 0] + R[b, 0, 1] * feat_f[k, 1] + R[b, 0, 2] * feat_f[k, 2]
        c1 = kin_v[b, 0, 1] + R[b, 1, 0] * feat_f[k, 0] + R[b, 1, 1] * feat_f[k, 1] + R[b, 1, 2] * feat_f[k, 2]
        c2 = kin_v[b, 0, 2] + R[b, 2, 0] * feat_f[k, 0] + R[b, 2, 1] * feat_f[k, 1] + R[b, 2, 2] * feat_f[k, 2]
        rad = feat_f[k, 6]
        if feat_i[k, 1] == FEATURE_POINT:
            x0, x1, x2 = c0, c1, c2 - rad
        else:
            a0 = R[b, 0, 0] * feat_f[k, 3] + R[b, 0, 1] * feat_f[k, 4] + R[b, 0, 2] * feat_f[k, 5]
            a1 = R[b, 1, 0] * feat_f[k, 3] + R[b, 1, 1] * feat_f[k, 4] + R[b, 1, 2] * feat_f[k, 5]
            a2 = R[b, 2, 0] * feat_f[k, 3] + R[b, 2, 1] * feat_f[k, 4] + R[b, 2, 2] * feat_f[k, 5]
            # -(z - (z.a) a): the in-plane direction of steepest descent
            d0, d1, d2 = a0 * a2, a1 * a2, a2 * a2 - 1.0
            n = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            rho = min(rounding, rad)
            if n > 1e-9:
                ring = (rad - rho) / n
                x0, x1, x2 = c0 + ring * d0, c1 + ring * d1, c2 + ring * d2 - rho
            else:
                x0, x1, x2 = c0, c1, c2 - rho
        X[k, 0], X[k, 1], X[k, 2] = x0, x1, x2
        F[k, 0] = 0.0
        F[k, 1] = 0.0
        F[k, 2] = 0.0
        if x2 >= 0.0:
            continue
        if -x2 > max_depth:
            status = STATUS_PENETRATION
        rx, ry, rz = x0 - kin_v[b, 0, 0], x1 - kin_v[b, 0, 1], x2 - kin_v[b, 0, 2]
        xv0 = kin_v[b, 2, 0] + kin_v[b, 1, 1] * rz - kin_v[b, 1, 2] * ry
        xv1 = kin_v[b, 2, 1] + kin_v[b, 1, 2] * rx - kin_v[b, 1, 0] * rz
        xv2 = kin_v[b, 2, 2] + kin_v[b, 1, 0] * ry - kin_v[b, 1, 1] * rx
        fz = -k1 * x2 - k2 * xv2
        if fz <= 0.0:
            continue
        t1x, t1y = ground_tangent(R, b)
        v1 = xv0 * t1x + xv1 * t1y
        v2 = -xv0 * t1y + xv1 * t1x
        f1, _, f2, _ = contact_friction(v1, v2, fz, mu_c, mu_s, mu_v, v_s, eps, lateral, cone)
        fx = f1 * t1x - f2 * t1y
        fy = f1 * t1y + f2 * t1x
        F[k, 0], F[k, 1], F[k, 2] = fx, fy, fz
        kin_v[b, 4, 0] += fx
        kin_v[b, 4, 1] += fy
        kin_v[b, 4, 2] += fz
        kin_v[b, 5, 0] += x1 * fz - x2 * fy
        kin_v[b, 5, 1] += x2 * fx - x0 * fz
        kin_v[b, 5, 2] += x0 * fy - x1 * fx
    add_body_wrenches(tau, floating, chain_i, kin_R, kin_v)
    return status


@njit(cache=True, inline="always")
def servo_duty(j, err_rad, integ, prev_err, kp, ki, kd, pwm_limit, duty_out):
    """Dynamixel X position loop of joint ``j``: PWM duty in [-1, 1] from its position error
    ``err_rad`` (goal - measured) [rad].

    Errors are in encoder pulses (``PULSES_PER_REV`` per turn); ``kp = P/128``, ``ki = I/65536``,
    ``kd = D/16`` (e-manual gain conversions, :mod:`cobra_model.servo`); the output in PWM units
    is clipped at ``pwm_limit`` and scaled by ``PWM_FULL_SCALE`` (= 100 % duty). ``integ`` and
    ``prev_err`` (pulses) are updated in place once per control tick.
    """
    e = err_rad * (PULSES_PER_REV / (2.0 * np.pi))
    integ[j] += e
    u = kp * e + ki * integ[j] + kd * (e - prev_err[j])
    prev_err[j] = e
    if u > pwm_limit:
        u = pwm_limit
    elif u < -pwm_limit:
        u = -pwm_limit
    duty_out[j] = u / PWM_FULL_SCALE


@njit(cache=True, inline="always")
def actuator_torques(duty, v, torque_on, act, voltage, resistance, tau, current_out, gear):
    """Spong's DC motor behind the gearbox, at the joint.

    ``i = (duty V - r Km w) / R`` [A], ``tau = r Km i - b w - tau_c tanh(w / eps_c)`` at the
    motor's rate ``w`` (the joint's, but for a gear play that is open) with the motor torque
    ``r Km i`` clipped at ``tau_max`` [N m] as a current limit clips it: the current too, at
    ``tau_max / (r Km)`` (``act`` columns: damping b, r*Km, Coulomb tau_c, tau_max, eps_c). With
    torque off the motor circuit is open: no motor torque, no current.
    ``v`` (nv,) and ``tau`` (nv,): the joints' rates and torques are their last ``nj`` entries
    (``duty`` (nj,)), read and written in place (a slice would be a view, see the module's docstring).

    A joint with a gear play (``act[:, A_BACKLASH] > 0``; ``gear``: the rows of
    :func:`gear_step`) passes that torque to its output only while a tooth flank is in contact;
    while the play is open the output gets none and the torque turns the motor alone
    (``gear[GEAR_TORQUE]``, which :func:`gear_step` integrates).
    """
    nbase = v.shape[0] - duty.shape[0]
    for j in range(duty.shape[0]):
        play = act[j, A_BACKLASH] > 0.0
        w = gear[GEAR_RATE, j] if play and gear[GEAR_ENGAGED, j] == 0.0 else v[nbase + j]
        rkm = act[j, A_RKM]
        if torque_on[j]:
            i = (duty[j] * voltage - rkm * w) / resistance
        else:
            i = 0.0
        t = rkm * i
        tmax = act[j, A_TAU_MAX]
        if t > tmax:
            t = tmax
            i = tmax / rkm
        elif t < -tmax:
            t = -tmax
            i = -tmax / rkm
        t -= act[j, A_DAMPING] * w
        if act[j, A_COULOMB] > 0.0:
            t -= act[j, A_COULOMB] * np.tanh(w / act[j, A_COULOMB_EPS])
        if play:
            gear[GEAR_TORQUE, j] = t
            if gear[GEAR_ENGAGED, j] == 0.0:
                t = 0.0
        tau[nbase + j] = t
        current_out[j] = i


@njit(cache=True, inline="always")
def gear_step(v, a, act, dt, gear, armature):
    """The gear play of every joint with one (``act[:, A_BACKLASH]`` = its half-width b > 0 [rad])
    after a step that produced the acceleration ``a`` (nv,) and the new velocity ``v`` (nv,).

    The motor (its reflected inertia ``act[:, A_ARMATURE]`` = I [kg m^2]) and the joint's output
    are two bodies on one axis, a play of +-b between the teeth; the encoder reads the output (a
    Dynamixel's sits on its output shaft), so the position loop acts on the output's angle.

    - Flank in contact (``gear[GEAR_ENGAGED]`` = s = +-1): motor and output move as one, the
      motor's inertia on the joint's diagonal (``armature``, what the next ABA takes) and its
      torque ``T`` on the joint (:func:`actuator_torques`); the motor's rate is the joint's, so
      ``gear[GEAR_RATE]`` is read only while the play is open. The teeth pass ``f = T - I a_j``;
      when it would pull (``s f < 0``) the play opens: the motor keeps the joint's rate.
    - Play open: the output carries no motor inertia and no torque; the motor turns alone,
      ``I dw/dt = T`` (semi-implicit Euler), and the gap ``motor - output`` moves by
      ``dt (w - v_j)``. When it reaches +-b the teeth meet in a plastic impact, at the part
      ``alpha`` of the step where the gap crossed the flank (linear in the step): the motor's
      momentum relative to the output, ``P = I (w - v_j)``, goes into ``gear[GEAR_IMPULSE]``
      and ``1 - alpha`` into ``gear[GEAR_LATE]``, for :func:`gear_impacts` to hand to the joined
      bodies before the next step, with the inertia back on the joint's diagonal.

    ``gear`` (N_GEAR, nj) and ``armature`` (nv,) are updated in place; a joint without play is
    left alone (its armature stays on the diagonal).
    """
    nj = act.shape[0]
    nbase = v.shape[0] - nj
    for j in range(nj):
        b = act[j, A_BACKLASH]
        if b <= 0.0:
            continue
        inertia = act[j, A_ARMATURE]
        vj = v[nbase + j]
        s = gear[GEAR_ENGAGED, j]
        if s != 0.0:
            if s * (gear[GEAR_TORQUE, j] - inertia * a[nbase + j]) < 0.0:
                gear[GEAR_ENGAGED, j] = 0.0
                gear[GEAR_RATE, j] = vj
                armature[nbase + j] = 0.0
            continue
        w = gear[GEAR_RATE, j] + dt * gear[GEAR_TORQUE, j] / inertia
        gap0 = gear[GEAR_GAP, j]
        gap = gap0 + dt * (w - vj)
        if gap >= b or gap <= -b:
            s = 1.0 if gap > 0.0 else -1.0
            gear[GEAR_ENGAGED, j] = s
            gear[GEAR_IMPULSE, j] = inertia * (w - vj)
            gear[GEAR_LATE, j] = 1.0 - min(max((s * b - gap0) / (gap - gap0), 0.0), 1.0)
            armature[nbase + j] = inertia
            gap = s * b
            w = vj
        gear[GEAR_GAP, j] = gap
        gear[GEAR_RATE, j] = w


#: Rows of :func:`gear_impacts`' scratch (``N_IMPACT_ROWS * nv``): zeros, the impacts' momenta as
#: generalized forces, the same times their late parts, and the three accelerations ABA gives.
N_IMPACT_ROWS = 6


@njit(cache=True, inline="always")
def gear_impacts(q, v, gear, armature, dt, floating, aba_model, aba_data, scratch):
    """The plastic impacts of the gear plays that closed in the last step (:func:`gear_step`:
    momentum ``P_j = gear[GEAR_IMPULSE, j]`` [N m s], late part ``l_j = gear[GEAR_LATE, j]``),
    handed to the joined bodies at once, in place on ``q`` (nq,) and ``v`` (nv,); returns whether
    there was one. No-op (and no ABA call) without an impact.

    Momentum conservation for the joined bodies: ``D v+ = D v + sum_j P_j e_j`` with ``D`` the
    inertia with every joined motor on its joint's diagonal (``armature`` after
    :func:`gear_step`), so ``v+ = v + D^-1 P``; ``D^-1 x`` is ABA's acceleration at zero velocity
    under the force ``x`` less its acceleration under none (ABA is linear in the force; gravity
    cancels). The step moved the positions with the rate before the impact all along; the teeth
    met ``l_j`` of a step before its end, so the positions move on by ``dt D^-1 (l P)`` as well
    (on the free-flyer's manifold: :func:`integrate` at the rate ``D^-1 (l P)``).

    Why not a torque ``P / dt`` over the next step (what this kernel replaced): that puts the
    impact a step late, after the servo and the ground have acted on the rates before it. On
    ``benchmarks/gear_play_step.py``'s runs with the realistic 0.02 rad play at 1 ms it left the
    final head up to 33 mm from the same run at 0.125 ms, and a 0.5 % change of the play moved it
    by up to 24 mm: which step an impact fell in decided the head's path.

    ``aba_model``, ``aba_data``: the native handles (:data:`integrators.native.ABA`);
    ``scratch`` (:data:`N_IMPACT_ROWS` * nv,).
    """
    nj = gear.shape[1]
    hit = False
    for j in range(nj):  # every step of every rollout passes here: no impact costs this scan alone
        if gear[GEAR_IMPULSE, j] != 0.0:
            hit = True
    if not hit:
        return False
    nv = v.shape[0]
    nbase = nv - nj
    zero, force, late = scratch[:nv], scratch[nv:2 * nv], scratch[2 * nv:3 * nv]
    a0, a_force, a_late = scratch[3 * nv:4 * nv], scratch[4 * nv:5 * nv], scratch[5 * nv:]
    for i in range(nv):
        zero[i] = 0.0
        force[i] = 0.0
        late[i] = 0.0
    for j in range(nj):
        p = gear[GEAR_IMPULSE, j]
        force[nbase + j] = p
        late[nbase + j] = gear[GEAR_LATE, j] * p
        gear[GEAR_IMPULSE, j] = 0.0
    qp, zp, armp = q.ctypes, zero.ctypes, armature.ctypes
    ABA(aba_model, aba_data, qp, zp, zp, armp, a0.ctypes)
    ABA(aba_model, aba_data, qp, zp, force.ctypes, armp, a_force.ctypes)
    ABA(aba_model, aba_data, qp, zp, late.ctypes, armp, a_late.ctypes)
    for i in range(nv):
        v[i] += a_force[i] - a0[i]
        late[i] = a_late[i] - a0[i]
    integrate(q, late, zero, dt, floating, q, late)
    return True


@njit(cache=True, inline="always")
def gear_armature(act, gear, nv, armature):
    """The armature (nv,) [kg m^2] the ABA takes in the gear state ``gear``: each joint's motor
    inertia ``act[:, A_ARMATURE]``, but none where the joint's gear play is open; zero on the
    root's coordinates."""
    nj = act.shape[0]
    for i in range(nv - nj):
        armature[i] = 0.0
    for j in range(nj):
        open_play = act[j, A_BACKLASH] > 0.0 and gear[GEAR_ENGAGED, j] == 0.0
        armature[nv - nj + j] = 0.0 if open_play else act[j, A_ARMATURE]


@njit(cache=True, inline="always")
def check_state(v, max_speed):
    """STATUS_NONFINITE if any entry of v is not finite, STATUS_VELOCITY if any |v_i| > max_speed."""
    for i in range(v.shape[0]):
        if not np.isfinite(v[i]):
            return STATUS_NONFINITE
    for i in range(v.shape[0]):
        if abs(v[i]) > max_speed:
            return STATUS_VELOCITY
    return STATUS_OK


@njit(cache=True, inline="always")
def control_tick(q, goal, act, scal, integ, prev_err, duty):
    """One tick of every servo's position loop on its encoder's reading of the joint's output."""
    nj = act.shape[0]
    nq = q.shape[0]
    for j in range(nj):
        err = goal[j] - (q[nq - nj + j] + act[j, A_ENC_OFFSET])  # the encoder's reading
        servo_duty(j, err, integ, prev_err, scal[S_KP], scal[S_KI], scal[S_KD], scal[S_PWM_LIMIT], duty)


@njit(cache=True, inline="always")
def generalized_forces(q, v, duty, torque_on, act, scal, ground, floating, chain_i, chain_R, chain_f,
                       feat_i, feat_f, tau, current, X, F, kin_R, kin_v, gear):
    """Actuator torques and ground forces as one generalized force ``tau`` (nv,); returns a status.

    ``chain_i`` (nb, 3) = parent, q index, v index; ``chain_R`` (nb, 3, 3) = placement rotation;
    ``chain_f`` (nb, 6) = placement translation (3), axis (3); ``feat_i`` (nf, 2) = body, kind;
    ``feat_f`` (nf, 7) = centre (3), axis (3), radius; ``kin_R``, ``kin_v``: the workspace of
    :func:`ground_forces`.
    """
    nbase = v.shape[0] - act.shape[0]
    for i in range(nbase):
        tau[i] = 0.0
    actuator_torques(duty, v, torque_on, act, scal[S_VOLTAGE], scal[S_RESISTANCE], tau, current, gear)
    return ground_forces(q, v, floating, chain_i, chain_R, chain_f, feat_i, feat_f, ground, tau, X, F,
                         scal[S_MAX_DEPTH], kin_R, kin_v)


@njit(cache=True, inline="always")
def integrate(q, v, a, dt, floating, q_out, v_out):
    """Semi-implicit Euler: ``v+ = v + dt a``, ``q+ = pin.integrate(q, dt v+)``.

    The free-flyer part is Pinocchio's ``integrate`` for its joint: ``M+ = M exp6(dt v+)``
    with the SE(3) exponential in the root frame (``tests/test_kernels.py`` checks equality
    with ``pin.integrate``); revolute coordinates add ``dt qdot+``. ``q_out``, ``v_out`` may be
    ``q``, ``v`` (every entry is read before it is written).
    """
    nv = v.shape[0]
    for i in range(nv):
        v_out[i] = v[i] + dt * a[i]
    start_q, start_v = 0, 0
    if floating:
        vx, vy, vz = v_out[0] * dt, v_out[1] * dt, v_out[2] * dt
        wx, wy, wz = v_out[3] * dt, v_out[4] * dt, v_out[5] * dt
        th2 = wx * wx + wy * wy + wz * wz
        th = np.sqrt(th2)
        if th < 1e-6:
            B = 0.5 - th2 / 24.0
            C = 1.0 / 6.0 - th2 / 120.0
        else:
            B = (1.0 - np.cos(th)) / th2
            C = (th - np.sin(th)) / (th2 * th)
        # translation: V (dt v_lin) with V = I + B w^ + C w^2 (w^2 = w w^T - th2 I), in the root
        # frame, then rotated into the world by the root's rotation
        wv = wx * vx + wy * vy + wz * vz
        cx, cy, cz = wy * vz - wz * vy, wz * vx - wx * vz, wx * vy - wy * vx
        dp0 = vx + B * cx + C * (wx * wv - th2 * vx)
        dp1 = vy + B * cy + C * (wy * wv - th2 * vy)
        dp2 = vz + B * cz + C * (wz * wv - th2 * vz)
        x, y, z, w = q[3], q[4], q[5], q[6]
        n = np.sqrt(x * x + y * y + z * z + w * w)
        x, y, z, w = x / n, y / n, z / n, w / n
        q_out[0] = q[0] + (1 - 2 * (y * y + z * z)) * dp0 + 2 * (x * y - z * w) * dp1 + 2 * (x * z + y * w) * dp2
        q_out[1] = q[1] + 2 * (x * y + z * w) * dp0 + (1 - 2 * (x * x + z * z)) * dp1 + 2 * (y * z - x * w) * dp2
        q_out[2] = q[2] + 2 * (x * z - y * w) * dp0 + 2 * (y * z + x * w) * dp1 + (1 - 2 * (x * x + y * y)) * dp2
        # quaternion product q * dq (x, y, z, w), dq from the rotation vector
        h = 0.5 * th
        sh = np.sin(h) / th if th > 1e-12 else 0.5 - th2 / 48.0
        dx, dy, dz, dw = wx * sh, wy * sh, wz * sh, np.cos(h)
        x, y, z, w = q[3], q[4], q[5], q[6]
        nx = w * dx + x * dw + y * dz - z * dy
        ny = w * dy - x * dz + y * dw + z * dx
        nz = w * dz + x * dy - y * dx + z * dw
        nw = w * dw - x * dx - y * dy - z * dz
        n = np.sqrt(nx * nx + ny * ny + nz * nz + nw * nw)
        q_out[3], q_out[4], q_out[5], q_out[6] = nx / n, ny / n, nz / n, nw / n
        start_q, start_v = 7, 6
    for i in range(nv - start_v):
        q_out[start_q + i] = q[start_q + i] + dt * v_out[start_v + i]


@njit(cache=True, inline="always")
def pre_step(control, q, v, goal, integ, prev_err, duty, torque_on, act, scal, ground, floating,
             chain_i, chain_R, chain_f, feat_i, feat_f, tau, current, X, F, kin_R, kin_v, gear):
    """A servo tick (when ``control``) then :func:`generalized_forces`; returns the status."""
    if control:
        control_tick(q, goal, act, scal, integ, prev_err, duty)
    return generalized_forces(q, v, duty, torque_on, act, scal, ground, floating, chain_i, chain_R,
                              chain_f, feat_i, feat_f, tau, current, X, F, kin_R, kin_v, gear)


@njit(cache=True)
def post_step(q, v, a, scal, floating, q_out, v_out):
    """:func:`integrate` then :func:`check_state` on the new velocity; returns the status."""
    integrate(q, v, a, scal[S_DT], floating, q_out, v_out)
    return check_state(v_out, scal[S_MAX_SPEED])


#: Slots of a rollout's ``plan`` (int64 array) for :func:`rollout_step`: physics steps, steps per
#: servo tick, steps per recorded sample, whether the kernel integrates (not the momentum
#: scheme), whether the root floats.
P_STEPS, P_SUBSTEPS, P_RECORD_EVERY, P_INTEGRATE, P_FLOATING = 0, 1, 2, 3, 4
N_PLAN = 5

#: The contact laws' codes in :func:`rollout_loop` (the soft laws' from :data:`SOFT_LAWS`' cone;
#: the compliant ground with its friction taken implicitly, :func:`implicit_friction_acceleration`,
#: is a code of its own, not a law of :data:`LOOP_LAWS`: a parameter set's ``friction_step`` chooses it).
LAW_COMPLIANT, LAW_SOFT_PYRAMID, LAW_SOFT_ELLIPTIC, LAW_COMPLIANT_IMPLICIT = 0, 1, 2, 3
LOOP_LAWS: dict[str, int] = {"compliant": LAW_COMPLIANT,
                             **{law: LAW_SOFT_ELLIPTIC if elliptic else LAW_SOFT_PYRAMID
                                for law, elliptic in SOFT_LAWS.items()}}


def workspace_size(n_features: int, n_bodies: int) -> int:
    """Length of the flat workspace :func:`rollout_step` takes: contact points ``X`` and forces
    ``F`` (n_features, 3) each, body rotations (n_bodies, 3, 3) and velocities (n_bodies, 6, 3)."""
    return 6 * n_features + 27 * n_bodies


@njit(cache=True, inline="always")
def workspace_views(work, n_features, n_bodies):
    """``X``, ``F``, ``kin_R``, ``kin_v`` as views of the flat ``work`` (:func:`workspace_size`)."""
    nf, nb = n_features, n_bodies
    return (work[:3 * nf].reshape((nf, 3)), work[3 * nf:6 * nf].reshape((nf, 3)),
            work[6 * nf:6 * nf + 9 * nb].reshape((nb, 3, 3)), work[6 * nf + 9 * nb:6 * nf + 27 * nb].reshape((nb, 6, 3)))


@njit(cache=True, inline="always")
def rollout_step(i, plan, q, v, a, goals, servo, torque_on, act, scal, ground, chain_i, chain_R, chain_f,
                 feat_i, feat_f, tau, work, record):
    """Step ``i`` of a rollout in one compiled call (one call per physics step, not three).

    1. when ``i > 0`` and ``plan[P_INTEGRATE]``: finish step ``i - 1`` with the acceleration ``a``
       (nv,) it produced: :func:`integrate` in place on ``q``, ``v``, then :func:`check_state`;
    2. when ``i`` is a multiple of ``plan[P_RECORD_EVERY]``: write ``q``, ``v`` and the motor
       current ``servo[3]`` of step ``i - 1`` into row ``i // plan[P_RECORD_EVERY]`` of ``record``
       (N, nq + nv + nj);
    3. when ``i < plan[P_STEPS]``: :func:`pre_step` with the servo goals ``goals[i //
       plan[P_SUBSTEPS]]`` (the loop ticks on multiples of ``plan[P_SUBSTEPS]``) into ``tau``.

    ``servo`` (N_SERVO, nj) holds the position loops' integral, previous error, duty and the
    motor current [A], then the gear play's state (rows ``SV_GEAR:``, :func:`gear_step`);
    ``work`` is the flat workspace (:func:`workspace_views`). The arguments are packed this way
    because each one costs a call from Python about 0.05 us. Returns 0, the status of step 3, or
    minus the status of step 1. Used by the momentum-form step, which models no gear play
    (``armature`` here is only the argument :func:`_step` takes; the simulator refuses the pair).
    """
    X, F, kin_R, kin_v = workspace_views(work, feat_i.shape[0], chain_i.shape[0])
    armature = np.empty(v.shape[0])
    gear_armature(act, servo[SV_GEAR:], v.shape[0], armature)
    return _step(i, plan, q, v, a, goals, servo[SV_INTEG], servo[SV_PREV_ERR], servo[SV_DUTY], servo[SV_CURRENT],
                 servo[SV_GEAR:], armature, torque_on, act, scal, ground, chain_i, chain_R, chain_f, feat_i, feat_f,
                 tau, X, F, kin_R, kin_v, record, 0, 0, np.empty(0))


@njit(cache=True)
def _step(i, plan, q, v, a, goals, integ, prev_err, duty, current, gear, armature, torque_on, act, scal, ground,
          chain_i, chain_R, chain_f, feat_i, feat_f, tau, X, F, kin_R, kin_v, record, aba_model, aba_data, impact):
    """:func:`rollout_step` on the views of the workspace and of ``servo``'s rows (a loop makes
    them once, not at every step: each view costs an atomic reference count), with the gear
    plays' impacts after the integration (:func:`gear_impacts`: ``aba_model``, ``aba_data``, its
    scratch ``impact``; it calls ABA only when an impact is owed, which takes a play, so the
    momentum-form step, which models none, passes no handles).

    Compiled once and called by every contact law's loop (:data:`LAW_LOOPS`), not inlined into
    each: the step's inlined helpers are most of a loop's compile time (about 13 s on a 2-core
    Xeon, ``docs/benchmarks.md``), and the call costs no measurable time per step (its arrays
    are views the loop made once)."""
    floating = plan[P_FLOATING] != 0
    if i > 0 and plan[P_INTEGRATE]:
        integrate(q, v, a, scal[S_DT], floating, q, v)
        gear_step(v, a, act, scal[S_DT], gear, armature)
        gear_impacts(q, v, gear, armature, scal[S_DT], floating, aba_model, aba_data, impact)
        status = check_state(v, scal[S_MAX_SPEED])
        if status:
            return -status
    if i % plan[P_RECORD_EVERY] == 0:
        row = record[i // plan[P_RECORD_EVERY]]
        nq, nv = q.shape[0], v.shape[0]
        row[:nq] = q
        row[nq:nq + nv] = v
        row[nq + nv:] = current
    if i == plan[P_STEPS]:
        return STATUS_OK
    return pre_step(i % plan[P_SUBSTEPS] == 0, q, v, goals[i // plan[P_SUBSTEPS]], integ, prev_err, duty,
                    torque_on, act, scal, ground, floating, chain_i, chain_R, chain_f, feat_i, feat_f, tau,
                    current, X, F, kin_R, kin_v, gear)


@njit(cache=True, inline="always")
def _rollout_loop(law, args):
    """Steps ``start`` to ``stop - 1`` of a rollout in one compiled loop: :func:`rollout_step`,
    then the acceleration ``a`` (nv,) that the next step integrates, by the contact law ``law``
    (:data:`LOOP_LAWS`): ABA (:data:`integrators.native.ABA`, generated from Pinocchio's on
    COBRA's structure) for the compliant ground; for a soft-constraint law the same pass's acceleration without contact and ``D^-1``
    into ``minv`` (nv, nv) (:data:`integrators.native.ABA_MINVERSE`), then
    :func:`soft_contact_acceleration` with the bodies' weights ``body_weight`` and the
    solver's warm start ``warm``; for ``LAW_COMPLIANT_IMPLICIT`` that pass under the compliant
    ground's forces, then :func:`implicit_friction_acceleration`. ``aba_model``, ``aba_data``:
    the native model and workspace handles. The other arguments are :func:`rollout_step`'s.

    Returns ``(status, i)``: 0 and the last step done, or :func:`rollout_step`'s non-zero status
    at step ``i``. The loop ends after step ``plan[P_STEPS]`` (which only integrates and
    records). A caller runs the rollout in chunks to report progress between them.

    ``law`` is a constant of each law's own loop (:data:`LAW_LOOPS`), which inlines this body:
    numba prunes the branches of the other laws before it types them, so that a loop compiles
    only its own law's solver (the soft laws' solvers are most of the compile time). The
    pruning needs ``law`` to be a constant of the loop: a law read at run time compiles every
    solver into it again (``tests/test_wheel.py`` checks). ``args`` is the tuple of the other
    arguments (numba inlines no call with ``*args``).
    """
    (start, stop, aba_model, aba_data, plan, q, v, a, goals, servo, torque_on, act, scal, ground,
     chain_i, chain_R, chain_f, feat_i, feat_f, tau, work, record, minv, body_weight, warm) = args
    X, F, kin_R, kin_v = workspace_views(work, feat_i.shape[0], chain_i.shape[0])
    integ, prev_err, duty, current, gear = (servo[SV_INTEG], servo[SV_PREV_ERR], servo[SV_DUTY], servo[SV_CURRENT],
                                            servo[SV_GEAR:])
    # the armature the ABA takes: the motors' inertia, none on a joint whose gear play is open
    armature = np.empty(v.shape[0])
    gear_armature(act, gear, v.shape[0], armature)
    parents, vidx, f_body = chain_i[:, 0], chain_i[:, 2], feat_i[:, 0]  # the soft laws' columns
    # the arrays' addresses for Pinocchio, taken once (the loop updates the arrays in place)
    qp, vp, taup, ap, minvp, armp = q.ctypes, v.ctypes, tau.ctypes, a.ctypes, minv.ctypes, armature.ctypes
    floating = plan[P_FLOATING] != 0
    soft = law == LAW_SOFT_PYRAMID or law == LAW_SOFT_ELLIPTIC
    scratch = soft_scratch(feat_i.shape[0] if soft else 0, v.shape[0])
    friction = friction_scratch(feat_i.shape[0] if law == LAW_COMPLIANT_IMPLICIT else 0, v.shape[0])
    elliptic = law == LAW_SOFT_ELLIPTIC
    cone_scratch = elliptic_scratch(feat_i.shape[0] if elliptic else 0, v.shape[0] if elliptic else 0)
    impact = np.empty(N_IMPACT_ROWS * v.shape[0])
    for i in range(start, stop):
        status = _step(i, plan, q, v, a, goals, integ, prev_err, duty, current, gear, armature, torque_on, act, scal,
                       ground, chain_i, chain_R, chain_f, feat_i, feat_f, tau, X, F, kin_R, kin_v, record,
                       aba_model, aba_data, impact)
        if status != STATUS_OK or i == plan[P_STEPS]:
            return status, i
        if law == LAW_COMPLIANT:
            ABA(aba_model, aba_data, qp, vp, taup, armp, ap)
        else:
            ABA_MINVERSE(aba_model, aba_data, qp, vp, taup, armp, ap, minvp)
            if law == LAW_COMPLIANT_IMPLICIT:
                implicit_friction_acceleration(v, minv, floating, parents, vidx, f_body, X, F, kin_R, kin_v, ground,
                                               scal[S_DT], a, friction)
            elif law == LAW_SOFT_ELLIPTIC:
                soft_elliptic_acceleration(v, minv, floating, parents, vidx, f_body, X, kin_R, kin_v, ground,
                                           body_weight, warm, a, scratch, cone_scratch)
            else:
                soft_contact_acceleration(v, minv, floating, parents, vidx, f_body, X, kin_R, kin_v, ground,
                                          body_weight, warm, a, scratch)
    return STATUS_OK, stop - 1


# One compiled loop per contact law (numba compiles a function on its first call, each with its
# own on-disk cache): a user of one law compiles that law's solver alone. Each takes its
# arguments as one tuple, from Python and from a batch alike: a ``*args`` signature is typed
# ``StarArgTuple`` from Python and ``Tuple`` from compiled code, two copies of the loop to compile.
@njit(cache=True)
def compliant_loop(args):
    """:func:`_rollout_loop` under the compliant ground (``LAW_COMPLIANT``)."""
    return _rollout_loop(LAW_COMPLIANT, args)


@njit(cache=True)
def soft_pyramid_loop(args):
    """:func:`_rollout_loop` under the soft-constraint law's pyramid (``LAW_SOFT_PYRAMID``)."""
    return _rollout_loop(LAW_SOFT_PYRAMID, args)


@njit(cache=True)
def soft_elliptic_loop(args):
    """:func:`_rollout_loop` under the soft-constraint law's elliptic cone (``LAW_SOFT_ELLIPTIC``)."""
    return _rollout_loop(LAW_SOFT_ELLIPTIC, args)


@njit(cache=True)
def compliant_implicit_loop(args):
    """:func:`_rollout_loop` under the compliant ground, its friction implicit
    (``LAW_COMPLIANT_IMPLICIT``)."""
    return _rollout_loop(LAW_COMPLIANT_IMPLICIT, args)


def rollout_loop(start: int, stop: int, aba_model: int, aba_data: int, law: int, *args) -> tuple[int, int]:
    """:func:`_rollout_loop` for the law code ``law``, by that law's compiled loop
    (:data:`LAW_LOOPS`); the arguments are :func:`_rollout_loop`'s."""
    return LAW_LOOPS[law]((start, stop, aba_model, aba_data, *args))


@njit(cache=True, inline="always")
def _batch_rollout_loop(law, aba_models, aba_data, PLAN, Q, V, A, goals, goal_index, SERVO, torque_on, act, scal,
                        ground, chain_i, chain_R, chain_f, feat_i, feat_f, TAU, WORK, RECORD, MINV, WEIGHT, WARM,
                        status, failed_at):
    """Every environment ``e`` of a batch (rows of the arrays) through a whole rollout, one
    environment per thread at a time: the law's loop (:data:`LAW_LOOPS`) on ``Q[e]``, ``V[e]``,
    ... with the goal sequence ``goals[:, goal_index[e]]`` (n_ticks, G, nj), its own plan
    ``PLAN[e]`` (environments may run for different numbers of steps) and the native
    handles ``aba_models[e]``, ``aba_data[e]`` (one workspace per environment), recording into
    ``RECORD[e]`` (n_rec, nq + nv + nj; an environment with fewer steps leaves the rows after its
    last record as they were). The environments are independent, so each runs its
    whole rollout without meeting the others at every step (no parallel region per step, no
    trip through the interpreter per step); each one's arithmetic is :func:`_rollout_loop`'s.
    The threads take the environments in any order (the batch hands them out one at a time).

    ``status[e]``, ``failed_at[e]``: :func:`_rollout_loop`'s status and the step it stopped at
    (0 and the last step when it finished); an environment that fails stops there, its state
    and workspace left as they were at the failure.

    Each law's batch (:data:`LAW_BATCHES`) inlines this body with ``law`` a constant, so that it
    calls that law's compiled loop alone. Its arrays are parameters of their own, not a tuple's
    items as the loops take them: numba 0.68's parallel loop drops the writes to an array it took
    from a tuple (``tests/test_batch.py`` caught it: the final states stayed the initial ones).
    The loop's first step is ``np.int64(0)``, not ``0``: numba types a literal argument as
    ``Literal[int](0)`` and compiles a copy of the loop for it (most of a batch's compile time
    before).

    It lives in this file because numba's on-disk cache of a function is invalidated only by
    changes to the file that defines it: a batch kernel in another module kept running an old,
    inlined copy of these kernels after they were edited.
    """
    for e in prange(Q.shape[0]):
        # the state and workspaces a step writes, in arrays of this thread's own: rows of the
        # batch's arrays are a few cache lines, and neighbouring rows stepped on two threads at
        # once would share one, written at every step (false sharing)
        q, v, a, servo, tau = Q[e].copy(), V[e].copy(), A[e].copy(), SERVO[e].copy(), TAU[e].copy()
        work, minv, warm = WORK[e].copy(), MINV[e].copy(), WARM[e].copy()
        # and the arrays a step reads, too: every view a step takes of an array counts a reference
        # on it (atomically), and two threads counting on one shared array write one cache line
        args = (np.int64(0), PLAN[e, P_STEPS] + 1, aba_models[e], aba_data[e], PLAN[e].copy(), q, v, a,
                goals[:, goal_index[e]].copy(), servo, torque_on.copy(), act[e].copy(), scal.copy(),
                ground[e].copy(), chain_i.copy(), chain_R.copy(), chain_f.copy(), feat_i.copy(),
                feat_f.copy(), tau, work, RECORD[e], minv, WEIGHT[e].copy(), warm)
        if law == LAW_COMPLIANT:
            s, i = compliant_loop(args)
        elif law == LAW_SOFT_PYRAMID:
            s, i = soft_pyramid_loop(args)
        elif law == LAW_SOFT_ELLIPTIC:
            s, i = soft_elliptic_loop(args)
        else:
            s, i = compliant_implicit_loop(args)
        Q[e], V[e], A[e], SERVO[e], TAU[e], WORK[e], MINV[e], WARM[e] = q, v, a, servo, tau, work, minv, warm
        status[e] = s
        failed_at[e] = i


@njit(cache=True, parallel=True)
def compliant_batch(aba_models, aba_data, PLAN, Q, V, A, goals, goal_index, SERVO, torque_on, act, scal,
    ground, chain_i, chain_R, chain_f, feat_i, feat_f, TAU, WORK, RECORD, MINV, WEIGHT, WARM, status, failed_at):
    """:func:`_batch_rollout_loop` under the compliant ground (``LAW_COMPLIANT``)."""
    _batch_rollout_loop(LAW_COMPLIANT, aba_models, aba_data, PLAN, Q, V, A, goals, goal_index, SERVO,
                        torque_on, act, scal, ground, chain_i, chain_R, chain_f, feat_i, feat_f, TAU, WORK,
                        RECORD, MINV, WEIGHT, WARM, status, failed_at)


@njit(cache=True, parallel=True)
def soft_pyramid_batch(aba_models, aba_data, PLAN, Q, V, A, goals, goal_index, SERVO, torque_on, act, scal,
    ground, chain_i, chain_R, chain_f, feat_i, feat_f, TAU, WORK, RECORD, MINV, WEIGHT, WARM, status, failed_at):
    """:func:`_batch_rollout_loop` under the soft-constraint law's pyramid (``LAW_SOFT_PYRAMID``)."""
    _batch_rollout_loop(LAW_SOFT_PYRAMID, aba_models, aba_data, PLAN, Q, V, A, goals, goal_index, SERVO,
                        torque_on, act, scal, ground, chain_i, chain_R, chain_f, feat_i, feat_f, TAU, WORK,
                        RECORD, MINV, WEIGHT, WARM, status, failed_at)


@njit(cache=True, parallel=True)
def soft_elliptic_batch(aba_models, aba_data, PLAN, Q, V, A, goals, goal_index, SERVO, torque_on, act, scal,
    ground, chain_i, chain_R, chain_f, feat_i, feat_f, TAU, WORK, RECORD, MINV, WEIGHT, WARM, status, failed_at):
    """:func:`_batch_rollout_loop` under the soft-constraint law's elliptic cone (``LAW_SOFT_ELLIPTIC``)."""
    _batch_rollout_loop(LAW_SOFT_ELLIPTIC, aba_models, aba_data, PLAN, Q, V, A, goals, goal_index, SERVO,
                        torque_on, act, scal, ground, chain_i, chain_R, chain_f, feat_i, feat_f, TAU, WORK,
                        RECORD, MINV, WEIGHT, WARM, status, failed_at)


@njit(cache=True, parallel=True)
def compliant_implicit_batch(aba_models, aba_data, PLAN, Q, V, A, goals, goal_index, SERVO, torque_on, act, scal,
    ground, chain_i, chain_R, chain_f, feat_i, feat_f, TAU, WORK, RECORD, MINV, WEIGHT, WARM, status, failed_at):
    """:func:`_batch_rollout_loop` under the compliant ground, its friction implicit
    (``LAW_COMPLIANT_IMPLICIT``)."""
    _batch_rollout_loop(LAW_COMPLIANT_IMPLICIT, aba_models, aba_data, PLAN, Q, V, A, goals, goal_index, SERVO,
                        torque_on, act, scal, ground, chain_i, chain_R, chain_f, feat_i, feat_f, TAU, WORK,
                        RECORD, MINV, WEIGHT, WARM, status, failed_at)


def batch_rollout_loop(aba_models: np.ndarray, aba_data: np.ndarray, law: int, *args) -> None:
    """:func:`_batch_rollout_loop` for the law code ``law``, by that law's compiled batch
    (:data:`LAW_BATCHES`); the arguments are :func:`_batch_rollout_loop`'s."""
    LAW_BATCHES[law](aba_models, aba_data, *args)


#: Each law code's compiled loop and batch (the codes index these tuples).
LAW_LOOPS = (compliant_loop, soft_pyramid_loop, soft_elliptic_loop, compliant_implicit_loop)
LAW_BATCHES = (compliant_batch, soft_pyramid_batch, soft_elliptic_batch, compliant_implicit_batch)


#: MuJoCo's default constraint impedance ``solimp`` (d0, d_width, width [m], midpoint, power) and
#: ``solref`` damping ratio: the soft-constraint contact law's fixed shape (:func:`soft_contact_acceleration`).
SOFT_SOLIMP = (0.9, 0.95, 0.001, 0.5, 2.0)
SOFT_DAMPRATIO = 1.0


@njit(cache=True)
def soft_impedance(depth: float) -> float:
    """MuJoCo's constraint impedance ``d(r)`` in (0, 1) at penetration ``|depth|`` [m] (:data:`SOFT_SOLIMP`)."""
    d0, dw, width, mid, power = SOFT_SOLIMP
    x = min(abs(depth) / width, 1.0)
    if x <= mid:
        y = x ** power / mid ** (power - 1.0)
    else:
        y = 1.0 - (1.0 - x) ** power / (1.0 - mid) ** (power - 1.0)
    return d0 + y * (dw - d0)


@njit(cache=True, inline="always")
def spd_factor(A, k, L):
    """Cholesky factor ``A[:k, :k] = L L^T`` into the lower triangle of ``L[:k, :k]``, reading
    only ``A``'s lower triangle. ``A`` must be symmetric positive definite; a matrix that is not
    gives a NaN pivot, which the rollout's divergence check reports.

    Written here rather than called from LAPACK: the contact solvers factor matrices of 4-50
    rows every physics step, where numba's ``np.linalg.solve`` costs 0.8-6 us per call in copies
    and checks around about a tenth of that in arithmetic."""
    for j in range(k):
        d = A[j, j]
        for c in range(j):
            d -= L[j, c] * L[j, c]
        d = np.sqrt(d) if d > 0.0 else np.nan
        L[j, j] = d
        for i in range(j + 1, k):
            s = A[i, j]
            for c in range(j):
                s -= L[i, c] * L[j, c]
            L[i, j] = s / d


@njit(cache=True, inline="always")
def spd_substitute(L, b, k, x):
    """``x[:k] = (L L^T)^-1 b[:k]`` for the factor :func:`spd_factor` left in ``L``."""
    for i in range(k):
        s = b[i]
        for c in range(i):
            s -= L[i, c] * x[c]
        x[i] = s / L[i, i]
    for i in range(k - 1, -1, -1):
        s = x[i]
        for c in range(i + 1, k):
            s -= L[c, i] * x[c]
        x[i] = s / L[i, i]


@njit(cache=True, inline="always")
def spd_inverse_into(A, L, X, out):
    """``out = A^-1`` (n, n), both triangles, for a symmetric positive definite ``A`` (reading
    its lower triangle): its factor ``A = L L^T`` (:func:`spd_factor`, into ``L``), ``X =
    L^-1`` row by row (each row a sum of the rows above it: loops along a row, which the
    compiler vectorises) and ``out = X^T X`` (BLAS). A column-by-column substitution is a chain
    of dependent steps instead: 17 columns of 17 took 5 us, this about 1."""
    n = A.shape[0]
    spd_factor(A, n, L)
    for i in range(n):
        for c in range(n):
            X[i, c] = 0.0
        X[i, i] = 1.0
        for j in range(i):
            lij = L[i, j]
            for c in range(j + 1):        # row j of L^-1 is zero right of j
                X[i, c] -= lij * X[j, c]
        inv = 1.0 / L[i, i]
        for c in range(i + 1):
            X[i, c] *= inv
    np.dot(X.T, X, out)


@njit(cache=True, inline="always")
def max_abs_into(largest: float, x: float) -> float:
    """``max(largest, |x|)``, NaN once either is (as ``np.max`` propagates it)."""
    y = abs(x)
    return y if y > largest or y != y else largest


@njit(cache=True, inline="always")
def max_abs(x) -> float:
    """``np.max(np.abs(x))`` of a non-empty vector without the temporary array: the solvers take
    it at every iteration, where each temporary is an allocation."""
    largest = 0.0
    for i in range(x.shape[0]):
        largest = max_abs_into(largest, x[i])
    return largest


@njit(cache=True, inline="always")
def _move_towards(f, z, free) -> bool:
    """The active-set method's step (:func:`nonnegative_qp`): ``f`` moved towards ``z`` (the best
    point with the bound rows at zero) as far as ``f`` stays >= 0; True when it reached ``z``,
    else the free rows it brought to zero are bound."""
    alpha = 1.0
    for j in range(f.shape[0]):
        if free[j] and z[j] < 0.0:
            alpha = min(alpha, f[j] / (f[j] - z[j]))
    for j in range(f.shape[0]):
        f[j] += alpha * (z[j] - f[j])
    if alpha >= 1.0:
        return True
    for j in range(f.shape[0]):
        if free[j] and f[j] <= 1e-15:
            f[j] = 0.0
            free[j] = False
    return False


@njit(cache=True, inline="always")
def _joining_row(P, x, r, free, m, scale, w) -> int:
    """The active-set method's next free row (:func:`nonnegative_qp`): of the first ``m`` rows,
    the bound one whose ``w_j = P_j . x - r_j``, ``(M f - r)_j`` (into ``w``), is the most
    negative, below ``-scale``; -1 when none is (the solution). ``P_j . x`` is ``M_j . f`` on
    the formed system, ``J_j . D^-1 J^T f`` through the velocities."""
    w_min, j_min = -scale, -1
    for j in range(m):
        if not free[j]:
            wj = -r[j]
            for c in range(x.shape[0]):
                wj += P[j, c] * x[c]
            w[j] = wj
            if wj < w_min:
                w_min, j_min = wj, j
    return j_min


@njit(cache=True)
def nonnegative_qp(M, r, f):
    """The LCP ``f >= 0, w = M f - r >= 0, f . w = 0`` for a positive definite ``M`` (m, m): the
    minimum of ``f M f / 2 - r f`` over ``f >= 0``, by Lawson and Hanson's active-set method.

    ``f`` (m,) holds a start (>= 0: the last step's forces) and receives the solution. Each
    iteration solves the system of the rows carrying a force (by Cholesky: that block of a
    positive definite ``M`` is positive definite); from a start near the solution a few do.
    Returns the number of iterations.
    """
    m = r.shape[0]
    return nonnegative_qp_into(M, r, f, np.empty(m, dtype=np.bool_), np.empty(m, dtype=np.int64), np.empty((m, m)),
                               np.empty((m, m)), np.empty(m), np.empty(m), np.empty(m))


@njit(cache=True)
def nonnegative_qp_into(M, r, f, free, idx, sub, L, rs, zs, z):
    """:func:`nonnegative_qp` on scratch arrays of at least ``m = len(r)`` rows: ``free`` (bool),
    ``idx`` (int64), ``sub`` and ``L`` (m, m) or larger, ``rs``, ``zs``, ``z``; the same
    arithmetic, bit for bit."""
    m = r.shape[0]
    for j in range(m):
        free[j] = f[j] > 0.0
    scale = 1e-12 * (max_abs(r) + 1e-300)
    for it in range(1, 3 * m + 10):
        # the best point with the bound rows at zero, approached as far as f stays >= 0
        while True:
            k = 0
            for j in range(m):
                if free[j]:
                    idx[k] = j
                    k += 1
            for j in range(m):
                z[j] = 0.0
            if k > 0:
                for a in range(k):
                    rs[a] = r[idx[a]]
                    for b in range(a + 1):
                        sub[a, b] = M[idx[a], idx[b]]
                spd_factor(sub, k, L)
                spd_substitute(L, rs, k, zs)
                for a in range(k):
                    z[idx[a]] = zs[a]
            if _move_towards(f, z, free):
                break
        # the bound row that most wants a force joins
        j_min = _joining_row(M, f[:m], r, free, m, scale, z)
        if j_min < 0:
            return it
        free[j_min] = True
    return 3 * m + 10


#: A soft contact solve with more rows than this many per velocity solves through the velocities
#: (:func:`nonnegative_qp_through_velocities_into`): its free sets' systems then cost about
#: ``nv^3 / 6`` each against ``k^3 / 6`` for the ``k`` rows' own, and ``A`` (``m^2 nv``) is not
#: formed. On COBRA's gait states of 35-68 rows both cost the same (8 us); below, the rows'
#: system is cheaper (3.2 against 5.3 us at 18-34 rows); with all 24 ends down (96 rows), the
#: velocities' (``docs/benchmarks.md``, "Simulation speed").
THROUGH_VELOCITIES_ROWS_PER_VELOCITY = 4


@njit(cache=True, inline="always")
def _add_row_to_system(rows, j, weight, r_j, S, b):
    """``S += weight J_j^T J_j`` (its lower triangle) and ``b += weight r_j J_j^T``: row ``j``
    of ``rows`` joining (``weight > 0``) or leaving (``< 0``) the velocities' system."""
    nv = rows.shape[1]
    for i in range(nv):
        wi = weight * rows[j, i]
        b[i] += wi * r_j
        if wi != 0.0:
            for c in range(i + 1):
                S[i, c] += wi * rows[j, c]


@njit(cache=True)
def nonnegative_qp_through_velocities_into(rows, reg, Minv, r, f, free, z, scratch):
    """:func:`nonnegative_qp` for ``M = rows D^-1 rows^T + diag(reg)`` without forming ``M``:
    the same active-set method, each free set ``F``'s system solved through the velocities by
    Woodbury's identity, as MuJoCo's primal solvers work,

        z_F = (r_F - J_F y) / reg_F,   (D + J_F^T diag(1 / reg_F) J_F) y = J_F^T (r_F / reg_F),

    (``J = rows``, ``D = Minv^-1`` the mass matrix), and a bound row's ``(M f - r)_j`` as
    ``J_j . D^-1 (J^T f) - r_j``. The velocities' system is formed once for the start's free
    set and then updated by each row that joins or leaves it (:func:`_add_row_to_system`, ``nv^2``
    each). The forces are the row system's to roundoff; a solve costs ``O(nv^3)`` whatever the
    number of free rows, against ``O(k^3)``: cheaper when the rows outnumber the velocities.

    Args:
        rows: ``J`` (m, nv); ``reg``: (m,) the rows' regulariser ``R`` (> 0); ``Minv``: ``D^-1``
            (nv, nv), both triangles filled.
        r, f: as :func:`nonnegative_qp` (``f`` the start on entry, the solution on return).
        free: (at least m,) bool; ``z``: (at least m,); ``scratch``: :func:`soft_scratch`'s
            last entry (``D``, the system and its factor (nv, nv), an (m nv) buffer, three
            (nv,) vectors and an (m,) bool), every entry written before it is read.

    Returns:
        the number of iterations; ``scratch``'s ``y`` holds ``D^-1 J^T f`` of the solution (what
        the forces add to the acceleration).
    """
    m, nv = rows.shape
    D, S, LS, H_buf, b, y, u, was = scratch
    spd_inverse_into(Minv, LS, S, D)  # D = (D^-1)^-1; S is formed below
    k = 0
    for j in range(m):
        free[j] = f[j] > 0.0
        k += free[j]
    H = H_buf[:k * nv].reshape((k, nv))       # diag(reg_F^(-1/2)) J_F, the start's free set
    for i in range(nv):
        b[i] = 0.0
    a = 0
    for j in range(m):
        if free[j]:
            s = 1.0 / np.sqrt(reg[j])
            rs = r[j] * s * s
            for i in range(nv):
                H[a, i] = rows[j, i] * s
                b[i] += rows[j, i] * rs
            a += 1
    np.dot(H.T, H, S)
    for i in range(nv):
        for c in range(i + 1):
            S[i, c] += D[i, c]
    scale = 1e-12 * (max_abs(r) + 1e-300)
    for it in range(1, 3 * m + 10):
        # the best point with the bound rows at zero, approached as far as f stays >= 0
        while True:
            spd_factor(S, nv, LS)
            spd_substitute(LS, b, nv, y)
            for j in range(m):
                z[j] = 0.0
                if free[j]:
                    jy = 0.0
                    for i in range(nv):
                        jy += rows[j, i] * y[i]
                    z[j] = (r[j] - jy) / reg[j]
            for j in range(m):
                was[j] = free[j]
            if _move_towards(f, z, free):
                break
            for j in range(m):
                if was[j] and not free[j]:
                    _add_row_to_system(rows, j, -1.0 / reg[j], r[j], S, b)
        # the bound row that most wants a force joins: (M f - r)_j = J_j . D^-1 J^T f - r_j (f_j = 0)
        for i in range(nv):
            u[i] = 0.0
        for j in range(m):
            if f[j] != 0.0:
                for i in range(nv):
                    u[i] += rows[j, i] * f[j]
        for i in range(nv):
            acc = 0.0
            for c in range(nv):
                acc += Minv[i, c] * u[c]
            y[i] = acc
        j_min = _joining_row(rows, y, r, free, m, scale, z)
        if j_min < 0:
            return it
        free[j_min] = True
        _add_row_to_system(rows, j_min, 1.0 / reg[j_min], r[j_min], S, b)
    return 3 * m + 10


@njit(cache=True)
def soft_contact_rows(nv, floating, parents, vidx, f_body, X, kin_R, kin_v, v, mu1, mu2, elliptic=False):
    """The constraint rows of every touching point (``X[k, 2] < 0``), in feature order.

    Returns ``rows``, ``depth`` and ``drift``. On the friction pyramid (``elliptic`` False)
    ``rows`` is (4 n, nv): ``J_n + mu1 J_t1``, ``J_n - mu1 J_t1``, ``J_n + mu2 J_t2``,
    ``J_n - mu2 J_t2`` for each of the n touching points; on the elliptic cone (3 n, nv):
    ``J_n``, ``J_t1``, ``J_t2``. ``J_*`` is the point's world Jacobian along the ground normal
    ``z``, the body's x axis on the ground ``t1`` and ``t2 = z x t1`` (Pinocchio's velocity
    convention: a floating root's columns act in its own frame); ``depth`` (one per row) the
    points' heights [m] (< 0).

    ``drift`` (one per row) [m/s^2] is ``J_root,lin (omega x v_lin)``, with ``v_lin`` and
    ``omega`` the floating root's linear and angular velocity in its own frame (``v[:3]``,
    ``v[3:6]``; zero for a fixed root). The soft constraint takes a point's acceleration as
    ``J a`` and drops ``Jdot v``, as MuJoCo does. In the root's rotating frame
    ``dv_lin/dt`` lacks the frame's turning, ``omega x v_lin``, so what is dropped would
    depend on how fast the root translates while it turns: a robot sliding and turning would
    be pushed differently from one turning in place, which no physical contact does. With
    ``J a + drift`` the acceleration is that of the root's world-frame velocity (MuJoCo's free
    joint), and what is dropped no longer depends on the root's speed. Without it our forces
    differed from MuJoCo's at the same state by up to 8 N of 20 (the contact's share of the
    joint accelerations by up to 5 %).
    """
    most = 4 * X.shape[0]             # rows if every point touched
    return soft_contact_rows_into(nv, floating, parents, vidx, f_body, X, kin_R, kin_v, v, mu1, mu2, elliptic,
                                  np.empty(most * nv), np.empty(most), np.empty(most), np.empty((3, nv)))


@njit(cache=True, inline="always")
def soft_contact_rows_into(nv, floating, parents, vidx, f_body, X, kin_R, kin_v, v, mu1, mu2, elliptic, rows_buf,
                           depth_buf, drift_buf, Jp):
    """:func:`soft_contact_rows` into scratch arrays: ``rows_buf`` (at least ``m nv``, ``m``
    the rows), ``depth_buf``, ``drift_buf`` (at least ``m``) and ``Jp`` (3, nv); returns the
    views ``rows`` (m, nv), ``depth`` and ``drift`` (m,) of them. The same arithmetic, bit for bit."""
    per = 3 if elliptic else 4
    touching = 0
    for k in range(X.shape[0]):
        if X[k, 2] < 0.0:
            touching += 1
    m = per * touching
    rows = rows_buf[:m * nv].reshape((m, nv))   # every entry is written below
    depth = depth_buf[:m]
    drift = drift_buf[:m]
    t0, t1, t2 = 0.0, 0.0, 0.0
    if floating:                      # omega x v_lin, the root's own frame
        t0 = v[4] * v[2] - v[5] * v[1]
        t1 = v[5] * v[0] - v[3] * v[2]
        t2 = v[3] * v[1] - v[4] * v[0]
    R, p, aw = kin_R, kin_v[:, 0], kin_v[:, 3]
    row = 0
    for k in range(X.shape[0]):
        if X[k, 2] >= 0.0:
            continue
        b = f_body[k]
        x0, x1, x2 = X[k, 0], X[k, 1], X[k, 2]
        Jp[:, :] = 0.0
        i = b
        while i >= 0:
            if floating and i == 0:
                rx, ry, rz = x0 - p[0, 0], x1 - p[0, 1], x2 - p[0, 2]
                for c in range(3):
                    e0, e1, e2 = R[0, 0, c], R[0, 1, c], R[0, 2, c]
                    Jp[0, c], Jp[1, c], Jp[2, c] = e0, e1, e2
                    Jp[0, 3 + c] = e1 * rz - e2 * ry
                    Jp[1, 3 + c] = e2 * rx - e0 * rz
                    Jp[2, 3 + c] = e0 * ry - e1 * rx
            else:
                rx, ry, rz = x0 - p[i, 0], x1 - p[i, 1], x2 - p[i, 2]
                e0, e1, e2 = aw[i, 0], aw[i, 1], aw[i, 2]
                col = vidx[i]
                Jp[0, col] = e1 * rz - e2 * ry
                Jp[1, col] = e2 * rx - e0 * rz
                Jp[2, col] = e0 * ry - e1 * rx
            i = parents[i]
        t1x, t1y = ground_tangent(R, b)
        for col in range(nv):
            jn = Jp[2, col]
            j1 = Jp[0, col] * t1x + Jp[1, col] * t1y
            j2 = -Jp[0, col] * t1y + Jp[1, col] * t1x
            if elliptic:
                rows[row, col], rows[row + 1, col], rows[row + 2, col] = jn, j1, j2
            else:
                rows[row, col] = jn + mu1 * j1
                rows[row + 1, col] = jn - mu1 * j1
                rows[row + 2, col] = jn + mu2 * j2
                rows[row + 3, col] = jn - mu2 * j2
        for e in range(per):
            depth[row + e] = x2
            drift[row + e] = rows[row + e, 0] * t0 + rows[row + e, 1] * t1 + rows[row + e, 2] * t2
        row += per
    return rows, depth, drift


@njit(cache=True, inline="always")
def cone_projection(p0, p1, p2, slope, G):
    """Euclidean projection ``g`` of ``p`` onto the circular cone ``|(g1, g2)| <= slope g0``, and
    its Jacobian ``dg/dp = G^T G`` as its factor ``G`` (3, 3): ``p`` itself and the identity
    inside the cone, 0 inside its polar cone, else the nearest point of the cone's surface, where
    the Jacobian ``k u u^T + s w w^T`` (``k = 1 / (1 + slope^2)``, ``u = (1, slope e1, slope e2)``,
    ``w = (0, -e2, e1)``, ``e`` the direction of ``(p1, p2)``, ``s = slope g0 / |(p1, p2)|``) has
    rank 2: ``G``'s rows are ``sqrt(k) u``, ``sqrt(s) w`` and zeros."""
    t = np.sqrt(p1 * p1 + p2 * p2)
    if t <= slope * p0:
        for i in range(3):
            for j in range(3):
                G[i, j] = 1.0 if i == j else 0.0
        return p0, p1, p2
    if slope * t <= -p0:
        G[:, :] = 0.0
        return 0.0, 0.0, 0.0
    k = 1.0 / (1.0 + slope * slope)
    g0 = (p0 + slope * t) * k
    e1, e2 = p1 / t, p2 / t
    sk, ss = np.sqrt(k), np.sqrt(slope * g0 / t)
    G[0, 0], G[0, 1], G[0, 2] = sk, sk * slope * e1, sk * slope * e2
    G[1, 0], G[1, 1], G[1, 2] = 0.0, -ss * e2, ss * e1
    G[2, 0], G[2, 1], G[2, 2] = 0.0, 0.0, 0.0
    return g0, slope * g0 * e1, slope * g0 * e2


@njit(cache=True, inline="always")
def _elliptic_row_cost(lam, y, y0, aref, sR, slope, f, G):
    """The primal cost of :func:`elliptic_contact_acceleration` at ``a = a0 + D^-1 J^T lam``,
    given ``y = J a`` and ``y0 = J a0``: ``lam (y - y0) / 2`` (which is ``(a - a0) M (a - a0) / 2``)
    plus the contacts' terms; the contact forces there in ``f`` and each contact's projection
    factor (:func:`cone_projection`) in ``G``."""
    m = y.shape[0]
    cost = 0.0
    for j in range(m):
        cost += 0.5 * lam[j] * (y[j] - y0[j])
    for c in range(m // 3):
        r = 3 * c
        g0, g1, g2 = cone_projection(-(y[r] - aref[r]) / sR[r], -(y[r + 1] - aref[r + 1]) / sR[r + 1],
                                     -(y[r + 2] - aref[r + 2]) / sR[r + 2], slope, G[c])
        f[r], f[r + 1], f[r + 2] = g0 / sR[r], g1 / sR[r + 1], g2 / sR[r + 2]
        cost += 0.5 * (g0 * g0 + g1 * g1 + g2 * g2)
    return cost


@njit(cache=True, inline="always")
def _elliptic_cost(rows, aref, sR, slope, a, a0, M, f, Gc):
    """The primal cost of :func:`elliptic_contact_acceleration` at acceleration ``a``; the
    contact forces there in ``f`` and each contact's projection factor (:func:`cone_projection`)
    in ``Gc``."""
    m, nv = rows.shape
    cost = 0.0
    for i in range(nv):
        di = a[i] - a0[i]
        acc = 0.0
        for j in range(nv):
            acc += M[i, j] * (a[j] - a0[j])
        cost += 0.5 * di * acc
    for c in range(m // 3):
        p0, p1, p2 = 0.0, 0.0, 0.0
        for e in range(3):
            r = 3 * c + e
            w = -aref[r]
            for col in range(nv):
                w += rows[r, col] * a[col]
            if e == 0:
                p0 = -w / sR[r]
            elif e == 1:
                p1 = -w / sR[r]
            else:
                p2 = -w / sR[r]
        g0, g1, g2 = cone_projection(p0, p1, p2, slope, Gc[c])
        f[3 * c], f[3 * c + 1], f[3 * c + 2] = g0 / sR[3 * c], g1 / sR[3 * c + 1], g2 / sR[3 * c + 2]
        cost += 0.5 * (g0 * g0 + g1 * g1 + g2 * g2)
    return cost


@njit(cache=True)
def elliptic_contact_acceleration(D, a0, v, rows, depth, drift, weight, mu1, mu2, tc, f, a_out):
    """Accelerations (nv,) under MuJoCo's soft constraint on the elliptic friction cone
    (condim 3, ``cone="elliptic"``, ``impratio`` 1), by Newton's method on its primal problem.

    Each touching point carries a force ``f = (f_n, f_1, f_2)`` on its rows ``J_n, J_t1, J_t2``
    (:func:`soft_contact_rows` with ``elliptic``) inside the cone ``|(f_1 / mu1, f_2 / mu2)| <= f_n``;
    together they minimise ``f (A + R) f / 2 - f (a_ref - J a0)``, ``A = J D^-1 J^T``, with

        R_n = R_1 = (1 - d) / d w,  R_2 = R_1 mu1^2 / mu2^2,
        a_ref,n = -b J_n v - k d r - c_n,   a_ref,t = -b J_t v - c_t,   b = 2 / (d_max tc),  k = 1 / (d_max^2 tc^2 zeta^2),

    MuJoCo's regulariser and reference acceleration on this cone (the friction rows carry no
    position term; their ``R`` makes the cone circular in the coordinates ``R^(1/2) f``), ``w``
    the contact's body's weight at the reference pose (MuJoCo's ``diagApprox``; see
    :func:`soft_contact_acceleration`) and ``c`` the rows' ``drift`` (the root frame's turning,
    :func:`soft_contact_rows`). The same problem in
    accelerations ``a`` (MuJoCo's primal form): minimise
    ``(a - a0) M (a - a0) / 2 + sum |P(-R^(-1/2) (J a - a_ref))|^2 / 2`` over the contacts, ``P``
    the projection onto that circular cone (:func:`cone_projection`); its gradient is
    ``M (a - a0) - J^T f``. Newton steps with an Armijo line search on this convex,
    piecewise-smooth cost, from ``a0 + D^-1 J^T f`` of the last step's forces, converge in a few
    iterations (MuJoCo's default solver is also Newton's method on this cost).

    Args:
        D: ``M^-1`` (nv, nv), symmetric.
        a0: acceleration without contact (nv,).
        v: velocity (nv,).
        rows, depth, drift: :func:`soft_contact_rows` (elliptic).
        weight: (n,) each touching point's body weight ``w`` [1/kg].
        mu1, mu2: friction along the body and sideways [1]; tc: time constant [s].
        f: (3 n,) the last step's forces [N] on entry (the start), this step's on return.
        a_out: output (nv,).

    Returns:
        the Newton iterations.
    """
    m, nv = rows.shape
    return elliptic_contact_acceleration_into(D, a0, v, rows, depth, drift, weight, mu1, mu2, tc, f, a_out,
                                              np.empty(m * nv), elliptic_scratch(m // 3, nv))


@njit(cache=True)
def elliptic_scratch(n_contacts: int, nv: int):
    """Scratch arrays of :func:`elliptic_contact_acceleration_into` for up to ``n_contacts``
    touching points and ``nv`` velocities: a rollout's loop makes them once, so that its steps
    allocate none of them (each step allocated 16).

    Returns the tuple ``(mats, vecs, per_row, cones, row_mats, row_vecs)``:
    ``mats`` (3, nv, nv) the Cholesky factor, the mass matrix and the Newton matrix; ``vecs``
    (4, nv) the acceleration, the gradient, the Newton step and the line search's trial
    acceleration; ``per_row`` (3, 3 n) the rows' ``sqrt(R)``, reference accelerations and
    trial forces; ``cones`` (2, n, 3, 3) each contact's projection factor (:func:`cone_projection`)
    at the current and the trial acceleration; ``row_mats`` (4, max(9 n^2, 3 n nv)) and
    ``row_vecs`` (10, 3 n) the Newton solve in the rows (:func:`_elliptic_newton_in_rows`):
    ``A``, ``A B^T``, the Newton system and its factor, and its vectors (the solve in the
    velocities keeps its scaled rows in the second matrix)."""
    m = 3 * n_contacts
    return (np.empty((3, nv, nv)), np.empty((4, nv)), np.empty((3, m)),
            np.empty((2, n_contacts, 3, 3)), np.empty((4, max(m * m, m * nv))), np.empty((10, m)))


#: An elliptic-cone solve with at most this many rows per velocity takes its Newton steps in the
#: contact rows (:func:`_elliptic_newton_in_rows`, ``O(m^3)`` a step for ``m`` rows), with more
#: in the velocities (:func:`_elliptic_newton_in_velocities`, ``O(nv^3)``, and ``D``'s inverse
#: once). Both take the same steps. Measured on COBRA's states (``docs/benchmarks.md``,
#: "Simulation speed").
ELLIPTIC_ROWS_PER_VELOCITY = 2


@njit(cache=True)
def elliptic_contact_acceleration_into(D, a0, v, rows, depth, drift, weight, mu1, mu2, tc, f, a_out, W_buf,
                                       scratch):
    """:func:`elliptic_contact_acceleration` on scratch arrays: ``W_buf`` (at least ``m nv``,
    ``m`` the rows) for ``rows D^-1`` and ``scratch`` from :func:`elliptic_scratch` for at least
    ``m / 3`` contacts and exactly ``nv`` velocities. ``a_out`` may be ``a0`` itself (it is
    written last). The same arithmetic, bit for bit; every scratch entry is written before it
    is read. With at most :data:`ELLIPTIC_ROWS_PER_VELOCITY` rows per velocity the Newton steps
    are taken in the rows (:func:`_elliptic_newton_in_rows`), else in the velocities
    (:func:`_elliptic_newton_in_velocities`): the same steps, to roundoff."""
    m, nv = rows.shape
    per_row = scratch[2]
    sR, aref = per_row[0, :m], per_row[1, :m]
    W = W_buf[:m * nv].reshape((m, nv))
    np.dot(rows, D, W)
    d_max = SOFT_SOLIMP[1]
    bcoef = 2.0 / (d_max * tc)
    kcoef = 1.0 / (d_max * d_max * tc * tc * SOFT_DAMPRATIO * SOFT_DAMPRATIO)
    for r0 in range(0, m, 3):
        d = soft_impedance(depth[r0])
        s_n = np.sqrt((1.0 - d) / d * weight[r0 // 3])
        sR[r0], sR[r0 + 1], sR[r0 + 2] = s_n, s_n, s_n * mu1 / mu2
        for e in range(3):
            jv = 0.0
            for col in range(nv):
                jv += rows[r0 + e, col] * v[col]
            aref[r0 + e] = -bcoef * jv - drift[r0 + e]
        aref[r0] -= kcoef * d * depth[r0]
    if m <= ELLIPTIC_ROWS_PER_VELOCITY * nv:
        return _elliptic_newton_in_rows(W, rows, a0, aref, sR, mu1, f, a_out, scratch)
    return _elliptic_newton_in_velocities(D, W, rows, a0, aref, sR, mu1, f, a_out, scratch)


@njit(cache=True)
def _elliptic_newton_in_rows(W, rows, a0, aref, sR, mu1, f, a_out, scratch):
    """The Newton iteration of :func:`elliptic_contact_acceleration` in the contact rows: ``a =
    a0 + D^-1 J^T lam`` (``W = J D^-1``), so that the cost is
    ``lam A lam / 2 + sum |P(-R^(-1/2) (y - a_ref))|^2 / 2`` with ``y = J a0 + A lam``,
    ``A = J D^-1 J^T``. The velocities' Newton step ``-(M + J^T S J)^-1 J^T (lam - f)``, ``S``
    the contacts' curvature ``B^T B`` (``B`` each contact's :func:`cone_projection` factor
    over ``R^(1/2)``), is ``D^-1 J^T dlam`` with

        dlam = (I + S A)^-1 r = r - B^T (I + B A B^T)^-1 B A r,   r = f - lam,

    (the push-through identity): a symmetric positive definite system of the rows' size, so a
    step costs ``O(m^3)`` for ``m`` rows and neither ``M`` nor the velocities' system is formed.
    The line search, the tests and the start are :func:`_elliptic_newton_in_velocities`'; the
    steps are the same to roundoff. ``scratch``: :func:`elliptic_scratch`'s; returns the Newton
    iterations."""
    m, nv = rows.shape
    nc = m // 3
    vecs, per_row, cones, row_mats, row_vecs = scratch[1], scratch[2], scratch[3], scratch[4], scratch[5]
    ft = per_row[2, :m]
    a, grad, da = vecs[0], vecs[1], vecs[2]
    G, Gt = cones[0, :nc], cones[1, :nc]
    A = row_mats[0, :m * m].reshape((m, m))
    C = row_mats[1, :m * m].reshape((m, m))       # A B^T
    K = row_mats[2, :m * m].reshape((m, m))       # I + B A B^T (lower triangle)
    LK = row_mats[3, :m * m].reshape((m, m))
    lam, y0, y, yt, dy, dlam, r, t, bt, x = (row_vecs[0, :m], row_vecs[1, :m], row_vecs[2, :m], row_vecs[3, :m],
                                             row_vecs[4, :m], row_vecs[5, :m], row_vecs[6, :m], row_vecs[7, :m],
                                             row_vecs[8, :m], row_vecs[9, :m])
    np.dot(W, rows.T, A)
    for j in range(m):
        acc = 0.0
        for col in range(nv):
            acc += rows[j, col] * a0[col]
        y0[j] = acc
        lam[j] = f[j]                             # the last step's forces
    for j in range(m):
        acc = y0[j]
        for k in range(m):
            acc += A[j, k] * lam[k]
        y[j] = acc
    cost = _elliptic_row_cost(lam, y, y0, aref, sR, mu1, f, G)
    for col in range(nv):
        acc = a0[col]
        for j in range(m):
            acc += W[j, col] * lam[j]
        a[col] = acc
    iterations = 0
    for it in range(1, 51):
        size = 1e-300                             # the velocities' gradient J^T (lam - f) and its scale
        for i in range(nv):
            acc_m, acc_f = 0.0, 0.0
            for j in range(m):
                acc_m += rows[j, i] * lam[j]
                acc_f += rows[j, i] * f[j]
            grad[i] = acc_m - acc_f
            size = max(size, abs(acc_m), abs(acc_f))
        if max_abs(grad) <= 1e-10 * size:
            break
        iterations = it
        for j in range(m):
            r[j] = f[j] - lam[j]
        for j in range(m):
            acc = 0.0
            for k in range(m):
                acc += A[j, k] * r[k]
            t[j] = acc
        for c in range(nc):                       # C = A B^T, B t
            o = 3 * c
            for e in range(3):
                g0, g1, g2 = G[c, e, 0] / sR[o], G[c, e, 1] / sR[o + 1], G[c, e, 2] / sR[o + 2]
                for i in range(m):
                    C[i, o + e] = A[i, o] * g0 + A[i, o + 1] * g1 + A[i, o + 2] * g2
                bt[o + e] = t[o] * g0 + t[o + 1] * g1 + t[o + 2] * g2
        for c in range(nc):                       # K = I + B C, its lower triangle
            o = 3 * c
            for e in range(3):
                g0, g1, g2 = G[c, e, 0] / sR[o], G[c, e, 1] / sR[o + 1], G[c, e, 2] / sR[o + 2]
                for j in range(o + e + 1):
                    K[o + e, j] = g0 * C[o, j] + g1 * C[o + 1, j] + g2 * C[o + 2, j]
                K[o + e, o + e] += 1.0
        spd_factor(K, m, LK)
        spd_substitute(LK, bt, m, x)
        for c in range(nc):                       # dlam = r - B^T x
            o = 3 * c
            for k in range(3):
                dlam[o + k] = r[o + k] - (G[c, 0, k] * x[o] + G[c, 1, k] * x[o + 1] + G[c, 2, k] * x[o + 2]) / sR[o + k]
        descent = 0.0                             # the velocities' gradient . step = -(r . A dlam)
        for j in range(m):
            acc = 0.0
            for k in range(m):
                acc += A[j, k] * dlam[k]
            dy[j] = acc
            descent -= r[j] * acc
        for col in range(nv):
            acc = 0.0
            for j in range(m):
                acc += W[j, col] * dlam[j]
            da[col] = acc
        alpha = 1.0
        while True:
            for j in range(m):
                t[j] = lam[j] + alpha * dlam[j]
                yt[j] = y[j] + alpha * dy[j]
            ct = _elliptic_row_cost(t, yt, y0, aref, sR, mu1, ft, Gt)
            if ct <= cost + 1e-4 * alpha * descent or alpha < 1e-10:
                break
            alpha *= 0.5
        moved = 0.0
        for i in range(nv):
            moved = max_abs_into(moved, alpha * da[i])
            a[i] += alpha * da[i]
        lam[:] = t
        y[:] = yt
        f[:m] = ft
        G[:, :, :] = Gt
        cost = ct
        if moved <= 1e-14 * (1.0 + max_abs(a)):
            break
    for col in range(nv):                         # a_out may be a0: written last
        acc = a0[col]
        for j in range(m):
            acc += W[j, col] * lam[j]
        a[col] = acc
    a_out[:] = a
    return iterations


@njit(cache=True)
def _elliptic_newton_in_velocities(D, W, rows, a0, aref, sR, mu1, f, a_out, scratch):
    """The Newton iteration of :func:`elliptic_contact_acceleration` in the velocities: ``D``
    inverted once into the mass matrix ``M``, each step's system ``M + V^T V`` (nv, nv) with
    ``V`` the rows scaled by ``R^(-1/2)`` and turned by each contact's projection factor
    (:func:`cone_projection`; one BLAS product). ``W = J D^-1``; ``scratch``:
    :func:`elliptic_scratch`'s (``V`` in the rows' solve's second matrix, unused here); returns
    the Newton iterations."""
    m, nv = rows.shape
    mats, vecs, per_row, cones, row_mats = scratch[0], scratch[1], scratch[2], scratch[3], scratch[4]
    L, M, H = mats[0], mats[1], mats[2]
    a, grad, step, at = vecs[0], vecs[1], vecs[2], vecs[3]
    ft = per_row[2, :m]
    nc = m // 3
    Gc, Gt = cones[0, :nc], cones[1, :nc]
    V = row_mats[1, :m * nv].reshape((m, nv))
    spd_inverse_into(D, L, H, M)      # H is the Newton matrix below
    a[:] = a0
    for col in range(nv):
        for j in range(m):
            a[col] += W[j, col] * f[j]
    cost = _elliptic_cost(rows, aref, sR, mu1, a, a0, M, f, Gc)
    iterations = 0
    for it in range(1, 51):
        size = 1e-300
        for i in range(nv):
            acc_m = 0.0
            for j in range(nv):
                acc_m += M[i, j] * (a[j] - a0[j])
            acc_f = 0.0
            for j in range(m):
                acc_f += rows[j, i] * f[j]
            grad[i] = acc_m - acc_f
            size = max(size, abs(acc_m), abs(acc_f))
        if max_abs(grad) <= 1e-10 * size:
            break
        iterations = it
        for c in range(nc):                   # V = G R^(-1/2) J, contact by contact
            o = 3 * c
            for e in range(3):
                g0, g1, g2 = Gc[c, e, 0] / sR[o], Gc[c, e, 1] / sR[o + 1], Gc[c, e, 2] / sR[o + 2]
                for col in range(nv):
                    V[o + e, col] = g0 * rows[o, col] + g1 * rows[o + 1, col] + g2 * rows[o + 2, col]
        np.dot(V.T, V, H)
        for i in range(nv):
            for j in range(i + 1):
                H[i, j] += M[i, j]
        spd_factor(H, nv, L)          # H = M + J^T P' J, positive definite
        spd_substitute(L, grad, nv, step)
        for i in range(nv):
            step[i] = -step[i]
        slope = 0.0
        for i in range(nv):
            slope += grad[i] * step[i]
        alpha = 1.0
        while True:
            for i in range(nv):
                at[i] = a[i] + alpha * step[i]
            ct = _elliptic_cost(rows, aref, sR, mu1, at, a0, M, ft, Gt)
            if ct <= cost + 1e-4 * alpha * slope or alpha < 1e-10:
                break
            alpha *= 0.5
        moved = 0.0
        for i in range(nv):
            moved = max_abs_into(moved, at[i] - a[i])
        a[:] = at
        f[:] = ft
        Gc[:, :, :] = Gt
        cost = ct
        if moved <= 1e-14 * (1.0 + max_abs(a)):
            break
    a_out[:] = a
    return iterations


@njit(cache=True)
def _store_warm(X, f, per, warm):
    """Each feature's forces (``per`` per touching point, in feature order) into ``warm`` (nf, 4),
    zeros for the features not touching (``X[k, 2] >= 0``)."""
    row = 0
    for k in range(X.shape[0]):
        warm[k, :] = 0.0
        if X[k, 2] < 0.0:
            for e in range(per):
                warm[k, e] = f[row + e]
            row += per


@njit(cache=True)
def soft_scratch(n_features: int, nv: int):
    """Scratch arrays of :func:`soft_contact_acceleration` for up to ``n_features`` touching
    points (four rows each): a rollout's loop makes them once, so that its steps allocate none
    (each step allocated 17 arrays: 8.9 -> 8.5 us per step on the pyramid, the same arithmetic).

    Returns the tuple ``(rows, depth, drift, Jp, f, weight, W, A, rhs, free, idx, sub, L, rs, zs,
    z, reg, through)`` that :func:`soft_contact_acceleration` unpacks (``through``: the arrays of
    :func:`nonnegative_qp_through_velocities_into`); :func:`soft_elliptic_acceleration` uses its
    first seven (the elliptic cone's three rows a point fit in the pyramid's four)."""
    m = 4 * n_features
    return (np.empty(m * nv), np.empty(m), np.empty(m), np.empty((3, nv)), np.empty(m), np.empty(n_features),
            np.empty(m * nv), np.empty(m * m), np.empty(m), np.empty(m, dtype=np.bool_), np.empty(m, dtype=np.int64),
            np.empty((m, m)), np.empty((m, m)), np.empty(m), np.empty(m), np.empty(m), np.empty(m),
            (np.empty((nv, nv)), np.empty((nv, nv)), np.empty((nv, nv)), np.empty(m * nv), np.empty(nv),
             np.empty(nv), np.empty(nv), np.empty(m, dtype=np.bool_)))


@njit(cache=True, inline="always")
def _touching_contacts(v, Minv, floating, parents, vidx, f_body, X, kin_R, kin_v, ground, elliptic, body_weight,
                       warm, scratch):
    """What both soft-constraint solvers start from: ``Minv`` made whole (Pinocchio fills its
    upper triangle), the touching points' rows, depths and drifts (:func:`soft_contact_rows`,
    ``elliptic`` choosing the cone's rows), their last forces from ``warm`` and their bodies'
    weights, as views of :func:`soft_scratch`'s arrays. With no point touching, ``rows`` has no
    row and ``warm`` is zeroed."""
    nv = v.shape[0]
    for i in range(nv):
        for j in range(i):
            Minv[i, j] = Minv[j, i]
    mu1 = ground[G_MU_C]
    rows_buf, depth_buf, drift_buf, Jp, f_buf, weight_buf = scratch[:6]
    rows, depth, drift = soft_contact_rows_into(nv, floating, parents, vidx, f_body, X, kin_R, kin_v, v, mu1,
                                                mu1 * ground[G_LATERAL], elliptic, rows_buf, depth_buf, drift_buf, Jp)
    m = rows.shape[0]
    per = 3 if elliptic else 4
    f = f_buf[:m]
    weight = weight_buf[:m // per]
    if m == 0:
        warm[:, :] = 0.0
        return rows, depth, drift, f, weight
    row = 0
    for k in range(X.shape[0]):       # the last step's forces of the points touching now
        if X[k, 2] < 0.0:
            for e in range(per):
                f[row + e] = warm[k, e]
            weight[row // per] = body_weight[f_body[k]]
            row += per
    return rows, depth, drift, f, weight


@njit(cache=True)
def soft_contact_acceleration(v, Minv, floating, parents, vidx, f_body, X, kin_R, kin_v, ground, body_weight,
                              warm, a, scratch):
    """Accelerations (nv,) under the soft-constraint contact law, MuJoCo's (condim 3), on the
    friction pyramid (on the elliptic cone: :func:`soft_elliptic_acceleration`).

    Every touching point (``X[k, 2] < 0``, from the last :func:`generalized_forces` on this
    state with the compliant ground switched off) gets the four edge rows
    ``J_n +- mu1 J_t1``, ``J_n +- mu2 J_t2`` of the friction pyramid (``t1`` the body's x axis on
    the ground, ``t2 = z x t1``, as in :func:`ground_forces`), each carrying a force ``f >= 0``
    that solves, for all rows together,

        (A + R) f = a_ref - J a0,  A = J D^-1 J^T,  R = 2 mu1^2 (1 - d) / d (1 + mu1^2) w  (each edge of a contact),
        a_ref = -b J v - k d r - c,    b = 2 / (d_max tc),  k = 1 / (d_max^2 tc^2 zeta^2),

    with ``a0`` the acceleration without contact, ``r`` the depth [m],
    ``c`` the rows' ``drift`` (the floating root frame's turning, :func:`soft_contact_rows`),
    ``d(r)`` :func:`soft_impedance` and ``w`` the weight of the contact's body, its mean
    translational inverse inertia at the reference pose
    (:attr:`cobra_model.model.RobotModel.reference_weights`): a contact is a constraint whose
    violation (approach speed, penetration, and slip along the pyramid's edges) relaxes with the
    time constant ``tc`` [s]. ``R`` is MuJoCo's pyramidal regulariser (``mj_makeImpedance``): one
    value for all four edges, ``2 mu^2`` times the first edge's ``(1 - d) / d diagApprox``, with
    ``diagApprox = (1 + mu^2) w`` from the body's weight at the reference pose, as MuJoCo's
    ``body_invweight0``. So ``R``, the contact's compliance in force units, is a property of the
    contact and its body, not of the robot's pose: taken from the current pose
    (``J D^-1 J^T``, this law's earlier form) it changed as the chain bent, and MuJoCo's runs
    were followed less closely (joint RMSE over 6 s at MuJoCo's values: 0.30 -> 0.20
    mrad at 0.35 Hz, 0.43 -> 0.39 mrad at 0.65 Hz; elliptic cone 0.44 -> 0.23 and
    0.69 -> 0.61 mrad). Per-edge ``(1 - d) / d diag(A)``, the form before that, made the pyramid
    ``1 / (2 mu^2)`` (9 at ``mu = 0.24``) times softer than MuJoCo's: fitted to MuJoCo's runs it
    left a residual that a lateral/along friction ratio of 0.87 mimicked, named on every
    MuJoCo-made null.
    Solved exactly by an active-set
    method (:func:`nonnegative_qp`) from the last step's forces; the solution is unique
    (``A + R`` is positive definite). (Gauss-Seidel sweeps, MuJoCo's PGS, stall here: a
    contact's four edges are nearly parallel and so are the two contacts of one module.)
    With more than :data:`THROUGH_VELOCITIES_ROWS_PER_VELOCITY` rows per velocity (a robot at
    rest on all its ends: COBRA's 24 ends give 96 rows for 17 velocities) the same method
    solves each free set through the velocities' system instead
    (:func:`nonnegative_qp_through_velocities_into`) and neither ``A`` nor ``J D^-1`` is formed.

    Args:
        v: velocity (nv,).
        Minv: ``D^-1`` (nv, nv) with its upper triangle filled (as ``pin.computeMinverse``
            leaves it); its lower triangle is filled here.
        f_body, X, kin_R, kin_v: the features' bodies and the points, rotations and body
            velocities :func:`ground_forces` left.
        ground: the ground parameters: ``mu1 = G_MU_C`` along the body, ``mu2 = mu1 G_LATERAL``
            sideways [1], the time constant ``tc = G_TC`` [s] (the others are unused).
        body_weight: (n_bodies,) each body's weight ``w`` at the reference pose [1/kg].
        warm: (nf, 4) each feature's edge forces [N] of the last step, the solver's start;
            overwritten with this step's (zero where not touching).
        a: (nv,) the acceleration without contact ``a0`` on entry (Pinocchio's ABA under the
            generalized force without contact), the acceleration with the contact forces on
            return.
        scratch: :func:`soft_scratch` for at least ``X``'s features: the step's working arrays,
            every entry written before it is read (nothing carries over from the last step).

    Returns:
        the solver's iterations (0 without contact).
    """
    rows, depth, drift, f, weight = _touching_contacts(v, Minv, floating, parents, vidx, f_body, X, kin_R, kin_v,
                                                       ground, False, body_weight, warm, scratch)
    m, nv = rows.shape
    if m == 0:
        return 0
    mu1, tc = ground[G_MU_C], ground[G_TC]
    W_buf, A_buf, rhs_buf, free, idx, sub, L, rs, zs, z, reg_buf, through = scratch[6:]
    d_max = SOFT_SOLIMP[1]
    bcoef = 2.0 / (d_max * tc)
    kcoef = 1.0 / (d_max * d_max * tc * tc * SOFT_DAMPRATIO * SOFT_DAMPRATIO)
    rhs, reg = rhs_buf[:m], reg_buf[:m]
    for r0 in range(0, m, 4):         # one contact: its four edges share the depth and impedance
        d = soft_impedance(depth[r0])
        edge_reg = 2.0 * mu1 * mu1 * (1.0 - d) / d * (1.0 + mu1 * mu1) * weight[r0 // 4]
        for j in range(r0, r0 + 4):
            reg[j] = edge_reg
            jv = 0.0
            ja = 0.0
            for col in range(nv):
                jv += rows[j, col] * v[col]
                ja += rows[j, col] * a[col]
            rhs[j] = -bcoef * jv - kcoef * d * depth[j] - drift[j] - ja
    if m > THROUGH_VELOCITIES_ROWS_PER_VELOCITY * nv:
        iterations = nonnegative_qp_through_velocities_into(rows, reg, Minv, rhs, f, free, z, through)
        y = through[5]                # D^-1 J^T f, left by the solve
        for col in range(nv):
            a[col] += y[col]
    else:
        W = W_buf[:m * nv].reshape((m, nv))
        np.dot(rows, Minv, W)         # rows D^-1, D^-1 symmetric
        A = A_buf[:m * m].reshape((m, m))
        np.dot(W, rows.T, A)
        for j in range(m):
            A[j, j] += reg[j]
        iterations = nonnegative_qp_into(A, rhs, f, free, idx, sub, L, rs, zs, z)
        for col in range(nv):
            acc = 0.0
            for j in range(m):
                acc += W[j, col] * f[j]
            a[col] += acc
    _store_warm(X, f, 4, warm)
    return iterations


@njit(cache=True)
def soft_elliptic_acceleration(v, Minv, floating, parents, vidx, f_body, X, kin_R, kin_v, ground, body_weight,
                               warm, a, scratch, cone_scratch):
    """Accelerations (nv,) under the soft-constraint contact law on MuJoCo's elliptic friction
    cone (:func:`elliptic_contact_acceleration`); the arguments are
    :func:`soft_contact_acceleration`'s, with ``warm``'s first three columns each feature's
    normal and two friction forces [N] and ``cone_scratch`` :func:`elliptic_scratch` for at
    least ``X``'s features (the solver's working arrays; ``scratch`` holds the rows).

    Returns:
        the Newton iterations (0 without contact).
    """
    rows, depth, drift, f, weight = _touching_contacts(v, Minv, floating, parents, vidx, f_body, X, kin_R, kin_v,
                                                       ground, True, body_weight, warm, scratch)
    if rows.shape[0] == 0:
        return 0
    mu1 = ground[G_MU_C]
    iterations = elliptic_contact_acceleration_into(Minv, a, v, rows, depth, drift, weight, mu1,
                                                    mu1 * ground[G_LATERAL], ground[G_TC], f, a, scratch[6],
                                                    cone_scratch)
    _store_warm(X, f, 3, warm)
    return iterations


#: Newton iterations of :func:`implicit_friction_acceleration` at most, and its tolerance on the
#: slip's update as a fraction of the sign's regularisation velocity ``eps``.
FRICTION_NEWTON_ITERATIONS = 20
FRICTION_NEWTON_TOLERANCE = 1e-2


@njit(cache=True)
def friction_scratch(n_features: int, nv: int):
    """Scratch arrays of :func:`implicit_friction_acceleration` for up to ``n_features``
    touching points: their three contact rows each and what :func:`soft_contact_rows_into`
    writes, the loaded points' tangent rows ``J`` and ``J D^-1`` (two each), ``W``, the Newton
    matrix and its factor, and nine vectors (a rollout's loop makes them once)."""
    m = 2 * n_features
    return (np.empty(3 * n_features * nv), np.empty(3 * n_features), np.empty(3 * n_features), np.empty((3, nv)),
            np.empty(m * nv), np.empty(m * nv), np.empty((m, m)), np.empty((m, m)), np.empty((m, m)),
            np.empty((9, m)))


@njit(cache=True)
def implicit_friction_acceleration(v, Minv, floating, parents, vidx, f_body, X, F, kin_R, kin_v, ground, dt, a,
                                   scratch):
    """The compliant ground's friction taken implicitly: accelerations (nv,) under the friction
    forces at the step's end slip, ``v+ = v + dt a``.

    :func:`ground_forces` evaluates the friction ``f(u0)`` at the slip ``u0 = J v`` of each
    touching point along its contact frame's tangents (``J``: the loaded points' tangent rows,
    ``t1``, ``t2`` of :func:`ground_forces`), with the normal force kept at ``v``. The end slip
    ``u = J v+`` solves

        u = u* + dt W f(u),    u* = u0 + dt J a0 - dt W f(u0),    W = J D^-1 J^T,

    (``a0``: the explicit acceleration, ``u*`` the slip without friction), by Newton's method on
    the slope of the law's dissipative part ``C = diag(c_i)``,
    ``c_i = s_i F_z w_i (1 - tanh^2(u_i / eps)) / eps + mu_v`` (the Stribeck shape's and the
    cone weights' derivatives left out), each update solved in the symmetric form
    ``(I + S W S) S d = -S R`` with ``S = (dt C)^1/2``. An update that would carry a slip faster
    than ``eps`` through zero is shortened to leave it at ``eps / 2`` on its side (the
    transition-aware step of Castro et al.'s TAMSI, ICRA 2020; without it Newton's method cycles
    across the ``tanh``). Then ``a = a0 + D^-1 J^T (f(u) - f(u0))``.

    Why: the law's slope reaches ``s F_z / eps`` at rest, a stiffness the explicit step
    resolves only when ``dt c_i`` is small next to the contact's effective mass; taken
    implicitly it is stable at any ``eps``, so the sign can be regularised below the Stribeck
    velocity's lower bound (``ModelParameters.friction_step``). One linearised step (no Newton
    iteration) is stable too, but it holds a contact that breaks away to a slip of about
    ``eps`` more per step: at 1 ms steps and ``eps`` = 1 mm/s a yaw joint lagged the
    converged step by up to 30 mrad.

    Args:
        v: velocity (nv,).
        Minv: ``D^-1`` (nv, nv) with its upper triangle filled; its lower triangle is filled here.
        f_body, X, F, kin_R, kin_v: the features' bodies, the points [m], their world forces [N],
            rotations and body velocities :func:`ground_forces` left on this state.
        ground: the ground parameters (``G_MU_C``, ``G_MU_S``, ``G_MU_V``, ``G_V_S``, ``G_EPS``,
            ``G_LATERAL``, ``G_CONE``).
        dt: the physics step [s].
        a: (nv,) ``a0`` on entry, the acceleration on return.
        scratch: :func:`friction_scratch` for at least ``X``'s features.

    Returns:
        Newton's iterations (0 without a loaded contact).
    """
    nv = v.shape[0]
    for i in range(nv):
        for j in range(i):
            Minv[i, j] = Minv[j, i]
    rows_buf, depth_buf, drift_buf, Jp, J_buf, B_buf, W_all, A, L, vec = scratch
    rows, _, _ = soft_contact_rows_into(nv, floating, parents, vidx, f_body, X, kin_R, kin_v, v, 0.0, 0.0, True,
                                        rows_buf, depth_buf, drift_buf, Jp)
    mu_c, mu_s, mu_v, v_s = ground[G_MU_C], ground[G_MU_S], ground[G_MU_V], ground[G_V_S]
    eps, lateral, cone = ground[G_EPS], ground[G_LATERAL], ground[G_CONE]
    fz, u, ustar, f0, f, c, res, p, d = vec[0], vec[1], vec[2], vec[3], vec[4], vec[5], vec[6], vec[7], vec[8]
    n = 0                              # tangent rows of the loaded points
    touching = 0
    for k in range(X.shape[0]):
        if X[k, 2] >= 0.0:
            continue
        r = 3 * touching
        touching += 1
        if F[k, 2] <= 0.0:
            continue
        for e in range(2):
            fz[n + e] = F[k, 2]
            acc = 0.0
            for col in range(nv):
                J_buf[(n + e) * nv + col] = rows[r + 1 + e, col]
                acc += rows[r + 1 + e, col] * v[col]
            u[n + e] = acc
        n += 2
    if n == 0:
        return 0
    J = J_buf[:n * nv].reshape((n, nv))
    B = B_buf[:n * nv].reshape((n, nv))
    np.dot(J, Minv, B)                 # J D^-1, D^-1 symmetric
    W = W_all[:n, :n]
    for i in range(n):
        for j in range(i + 1):
            acc = 0.0
            for col in range(nv):
                acc += B[i, col] * J[j, col]
            W[i, j] = acc
            W[j, i] = acc
    for i in range(0, n, 2):
        f0[i], c[i], f0[i + 1], c[i + 1] = contact_friction(u[i], u[i + 1], fz[i], mu_c, mu_s, mu_v,
                                                            v_s, eps, lateral, cone)
    for i in range(n):
        acc = 0.0
        for col in range(nv):
            acc += J[i, col] * a[col]
        for j in range(n):
            acc -= W[i, j] * f0[j]
        ustar[i] = u[i] + dt * acc
        f[i] = f0[i]
    iterations = 0
    while iterations < FRICTION_NEWTON_ITERATIONS:
        iterations += 1
        for i in range(n):             # R = u - u* - dt W f(u), then S R with S = (dt c)^1/2
            acc = 0.0
            for j in range(n):
                acc += W[i, j] * f[j]
            res[i] = u[i] - ustar[i] - dt * acc
            c[i] = np.sqrt(dt * c[i])
            p[i] = -c[i] * res[i]
        for i in range(n):             # I + S W S, lower triangle
            for j in range(i + 1):
                A[i, j] = c[i] * W[i, j] * c[j]
            A[i, i] += 1.0
        spd_factor(A, n, L)
        spd_substitute(L, p, n, d)     # d = S (update)
        step = 0.0
        alpha = 1.0
        for i in range(n):             # update = -R - W S (S update)
            acc = -res[i]
            for j in range(n):
                acc -= W[i, j] * c[j] * d[j]
            p[i] = acc
            step = max_abs_into(step, acc)
            end = u[i] + acc
            if abs(u[i]) > eps and end * u[i] < 0.0:
                alpha = min(alpha, (abs(u[i]) - 0.5 * eps) / abs(acc))
        for i in range(n):
            u[i] += alpha * p[i]
        for i in range(0, n, 2):
            f[i], c[i], f[i + 1], c[i + 1] = contact_friction(u[i], u[i + 1], fz[i], mu_c, mu_s, mu_v,
                                                              v_s, eps, lateral, cone)
        if alpha >= 1.0 and step <= FRICTION_NEWTON_TOLERANCE * eps:
            break
    for col in range(nv):
        acc = 0.0
        for i in range(n):
            acc += B[i, col] * (f[i] - f0[i])
        a[col] += acc
    return iterations
