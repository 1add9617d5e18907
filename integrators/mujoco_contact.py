"""MuJoCo's contact (condim 3, pyramidal cone) as a soft constraint inside our step: a diagnosis.

MuJoCo's contact is a *soft constraint on the pyramid's edges*, normal and friction together.
Each edge row ``J_k = J_n +- mu J_t`` (``t1`` the module's axis on the ground, ``t2 = z x t1``:
the body-aligned capsule pairs of ``sysid.generators.mujoco_recording.twin_options``) carries a
force ``f_k >= 0`` that solves

    (A + R) f = a_ref - a0,   A = J_k D^-1 J_k^T,   R = (1 - d) / d diag(A),
    a_ref = -b J_k v - k d(r) r,   b = 2 / (d_max tc),   k = 1 / (d_max^2 tc^2 zeta^2),

with ``a0`` the edges' acceleration without contact forces, ``r`` the penetration [m] and ``d(r)``
MuJoCo's default impedance (:data:`SOLIMP`); solved here by projected Gauss-Seidel. Friction is
then a spring-damper in acceleration units with the contact's time constant ``tc``: a sliding
contact is not held at ``mu f_n`` at once but relaxes toward it over ``tc``, and the force
depends on the robot's inertia at the contact, not only on the contact's own state.

:func:`pyramid_rollout` puts these rows into our step (same servos, motors, joints, geometry
and explicit 1 ms step; the kernels give the motor and joint torques with the ground switched
off). It exists to test what in MuJoCo's contact our ground lacks
(``benchmarks/contact_law.py``), not to simulate: Python around Pinocchio, about 2 ms per step.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from cobra_model.gait import SidewindingGait
from cobra_model.model import RobotModel
from cobra_model.parameters import ModelParameters
from integrators import kernels as K
from integrators.simulator import Simulator

#: MuJoCo's default ``solimp`` (d0, d_width, width [m], midpoint, power) and ``solref`` damping ratio.
SOLIMP = (0.9, 0.95, 0.001, 0.5, 2.0)
DAMPRATIO = 1.0
#: Projected Gauss-Seidel sweeps per step.
PGS_SWEEPS = 80


def impedance(r: np.ndarray) -> np.ndarray:
    """MuJoCo's constraint impedance d(r) for penetration ``r`` [m] (:data:`SOLIMP`)."""
    d0, dw, width, mid, power = SOLIMP
    x = np.clip(np.abs(r) / width, 0.0, 1.0)
    y = np.where(x <= mid, x**power / mid ** (power - 1), 1 - (1 - x) ** power / (1 - mid) ** (power - 1))
    return d0 + y * (dw - d0)


def pyramid_rows(sim: Simulator, data: pin.Data, q: np.ndarray, J: np.ndarray, touching: np.ndarray,
                 mu: float) -> np.ndarray:
    """(4 n, nv) Jacobians of the pyramid's edges ``n +- mu t1``, ``n +- mu t2`` of the touching contacts."""
    pin.forwardKinematics(sim.model.pin_model, data, q)
    z = np.array([0.0, 0.0, 1.0])
    rows = []
    for c in touching:
        R = data.oMi[int(sim.model.features.body[c]) + 1].rotation
        t1 = R[:, 0] - R[2, 0] * z
        t1 /= np.linalg.norm(t1)
        Jp = J[3 * c:3 * c + 3]
        Jn = z @ Jp
        for t in (t1, np.cross(z, t1)):
            rows += [Jn + mu * (t @ Jp), Jn - mu * (t @ Jp)]
    return np.array(rows)


def edge_forces(rows: np.ndarray, r: np.ndarray, v: np.ndarray, a0: np.ndarray, D_inv: np.ndarray,
                tc: float) -> np.ndarray:
    """Forces (>= 0) of the edge rows of MuJoCo's soft constraint (module docstring)."""
    d_max = SOLIMP[1]
    A = rows @ D_inv @ rows.T
    d = impedance(r)
    a_ref = -2.0 / (d_max * tc) * (rows @ v) - d / (d_max**2 * tc**2 * DAMPRATIO**2) * r
    M = A + np.diag((1 - d) / d * np.diag(A))
    rhs = a_ref - rows @ a0
    f = np.zeros(len(rows))
    for _ in range(PGS_SWEEPS):
        for j in range(len(rows)):
            f[j] = max(0.0, f[j] + (rhs[j] - M[j] @ f) / M[j, j])
    return f


def pyramid_rollout(model: RobotModel, params: ModelParameters, gait: SidewindingGait, duration_s: float,
                    q0: np.ndarray, tc: float, dt: float = 1e-3) -> np.ndarray:
    """Final head (x, y) [m] of our step with the pyramid's edge rows, MuJoCo's soft constraint
    of time constant ``tc`` [s], as the ground."""
    sim = Simulator(model, params)
    pm = sim.model.pin_model
    data = pm.createData()
    rounding, mu = params.get("contact_rounding"), params.mu_c
    no_ground = sim.ground.copy()
    no_ground[[K.G_K1, K.G_K2, K.G_MU_V]] = 0.0  # the kernels then give motor and joint torques only
    q, v = q0.copy(), np.zeros(pm.nv)
    n = sim.model.n_joints
    integ, prev, duty, current = np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n)
    on = np.ones(n, dtype=np.bool_)
    tau = np.empty(pm.nv)
    X, F = np.empty_like(sim._X), np.empty_like(sim._F)
    kin_R, kin_v = np.empty_like(sim._kin_R), np.empty_like(sim._kin_v)
    steps = int(round(duration_s / dt))
    goals = gait.q_ref(np.arange(steps + 1) * dt)
    for i in range(steps):
        K.pre_step(True, q, v, goals[i], integ, prev, duty, on, sim.act, sim.scal, no_ground, sim.model.chain.floating,
                   sim._chain_i, sim._chain_R, sim._chain_f, sim._feat_i, sim._feat_f, tau, current, X, F, kin_R, kin_v)
        depth = sim.model.contact_points(q, rounding)[:, 2]
        touching = np.flatnonzero(depth < 0)
        total = tau.copy()
        if len(touching):
            J = sim.model.contact_jacobian(q, rounding)
            rows = pyramid_rows(sim, data, q, J, touching, mu)
            D_inv = pin.computeMinverse(pm, data, q)
            D_inv = np.triu(D_inv) + np.triu(D_inv, 1).T
            f = edge_forces(rows, np.repeat(depth[touching], 4), v, pin.aba(pm, data, q, v, tau), D_inv, tc)
            total += rows.T @ f
        v = v + dt * pin.aba(pm, data, q, v, total)
        q = pin.integrate(pm, q, dt * v)
    return q[:2].copy()
