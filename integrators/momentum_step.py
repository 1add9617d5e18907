"""The momentum-form (symplectic Euler) step: energy error bounded instead of drifting.

The velocity-form step of :mod:`integrators.simulator` (``v+ = v + dt a(q, v)``) is symplectic
only for constant inertia; on a chain whose inertia depends on its configuration its energy
drifts at first order (0.29 % per second for COBRA in free flight at dt = 1 ms). This step
advances the generalized momentum ``p = D(q) v`` instead, as symplectic Euler does for the
non-separable Hamiltonian ``H(q, p) = p^T D(q)^-1 p / 2 + V(q)`` (Hairer, Lubich & Wanner,
*Geometric Numerical Integration*, VI.3):

    pi   = p_n + dt * (dL/dq(q_n, v*) + tau_n),     v* = D(q_n)^-1 pi    (implicit in v*)
    q+   = q_n (+) dt v*
    p+   = J(dt v*)^-T pi,                          v+ = D(q+)^-1 p+

``dL/dq`` is taken in the chart ``q = q_n (+) delta`` around the current configuration, so that
the floating root (a Lie group, velocities in its own frame) is treated like the joints:
``dL/d delta = C(q, v)^T v - g(q)``, less ``ad_v^T p / 2`` on the root's six coordinates
(Pinocchio's Coriolis matrix ``C``, with ``dD/dt = C + C^T``; the root's term is the chart's
own, from the right Jacobian of the exponential ``J(delta) ~ I - ad_delta / 2``; checked against
finite differences of the chart's Lagrangian to 1e-8), and the momentum found in
the old chart is carried to the new one by ``J^-T``. ``tau_n`` (motors, joint friction, ground
contact: ``integrators.kernels.pre_step``) is evaluated at ``(q_n, v_n)``, as in the velocity
form, so the two steps differ only in how the rigid body's own dynamics is advanced.

The implicit equation in ``v*`` is solved by fixed-point iteration to :data:`TOLERANCE`
(contraction ``~ dt |dC^T v/dv| / |D|``, about 0.15 on COBRA at dt = 1 ms). It starts from the
velocity form's ``v + dt a`` (Pinocchio's ABA) plus, when the step continues from the last
one's result, the last step's difference between the two, which changes little from one step
to the next (8 iterations instead of 12); a step from any other state starts without it, so a
rollout does not depend on what the stepper did before. The step is
first order in the trajectory, like the velocity form; what it adds is a bounded energy error
in free flight (``tests/test_momentum_step.py``: no growth over 60 s). It costs about 20 times
the velocity form's compiled loop (``benchmarks/results/sim_speed.md``) and is offered for
single rollouts (``SimSettings(scheme="momentum")``), not for the batched fits.

Joints other than revolute or prismatic (spherical, planar) below the root would need their own
chart term and are refused.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from cobra_model.errors import InputError
from cobra_model.model import RobotModel

#: Fixed-point tolerance on ``v*`` [m/s or rad/s], relative to ``1 + |v*|``: an error this
#: size changes the energy by about as much per step, 1e-7 of it per second at dt = 1 ms.
TOLERANCE = 1e-10
#: Fixed-point iterations after which the step is declared not converged.
MAX_ITERATIONS = 30


class MomentumStep:
    """Momentum-form steps of one robot model (holds the inertia of the last configuration).

    Args:
        model: the robot, armature included (its ``pin_model``).
        dt: physics step [s].
    """

    def __init__(self, model: RobotModel, dt: float):
        pm = model.pin_model
        kinds = {pm.joints[i].shortname() for i in range(1 + (model.n_base > 0), pm.njoints)}
        if not kinds <= {"JointModelRX", "JointModelRY", "JointModelRZ", "JointModelRevoluteUnaligned",
                         "JointModelPX", "JointModelPY", "JointModelPZ", "JointModelPrismaticUnaligned",
                         "JointModelRUBX", "JointModelRUBY", "JointModelRUBZ", "JointModelRevoluteUnboundedUnaligned"}:
            raise InputError(f"the momentum-form step handles revolute and prismatic joints below an optional "
                             f"free-flying root; {model.pin_model.name} has {sorted(kinds)}")
        self._pin = pm
        self._data = pm.createData()
        self._floating = model.n_base == 6
        self.dt = dt
        self._q_cached: np.ndarray | None = None
        self._D = self._D_inv = np.empty((pm.nv, pm.nv))
        self._correction = np.zeros(pm.nv)  # the last step's v* - (v + dt a) [m/s or rad/s]

    def _inertia(self, q: np.ndarray) -> None:
        """``D(q)`` (armature included) and its inverse, kept until ``q`` changes."""
        if self._q_cached is None or not np.array_equal(q, self._q_cached):
            D = pin.crba(self._pin, self._data, q)
            self._D = np.triu(D) + np.triu(D, 1).T
            self._D_inv = np.linalg.inv(self._D)
            self._q_cached = q.copy()

    def step(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, q_out: np.ndarray, v_out: np.ndarray) -> int:
        """One step from ``(q, v)`` under generalized force ``tau`` (nv,) into ``q_out``, ``v_out``.

        Returns the fixed-point iterations used; raises :class:`FloatingPointError` if the
        iteration did not converge in :data:`MAX_ITERATIONS` (the step is far too long).
        """
        pm, data, dt = self._pin, self._data, self.dt
        continuing = self._q_cached is not None and np.array_equal(q, self._q_cached)
        self._inertia(q)
        p = self._D @ v
        gravity = pin.computeGeneralizedGravity(pm, data, q)
        v_explicit = v + dt * pin.aba(pm, data, q, v, tau)
        v_star = v_explicit + self._correction if continuing else v_explicit
        for iteration in range(1, MAX_ITERATIONS + 1):
            pi = p + dt * (tau + self._velocity_gradient(q, v_star) - gravity)
            v_new = self._D_inv @ pi
            done = np.max(np.abs(v_new - v_star)) <= TOLERANCE * (1.0 + np.max(np.abs(v_new)))
            v_star = v_new
            if done or not np.all(np.isfinite(v_star)):
                break
        else:
            raise FloatingPointError(f"momentum step: v* did not converge in {MAX_ITERATIONS} iterations")
        self._correction = v_star - v_explicit
        delta = dt * v_star
        q_out[:] = pin.integrate(pm, q, delta)
        p_new = pi.copy()
        if self._floating:
            p_new[:6] = np.linalg.solve(pin.Jexp6(pin.Motion(delta[:6])).T, pi[:6])
        self._inertia(q_out)
        v_out[:] = self._D_inv @ p_new
        return iteration

    def lagrangian_gradient(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """``dL/d delta`` (nv,) [N or N m] at ``delta = 0`` of the chart ``q (+) delta``, the
        chart velocity held at ``v``: what drives the momentum besides the applied forces."""
        self._inertia(q)
        return self._velocity_gradient(q, v) - pin.computeGeneralizedGravity(self._pin, self._data, q)

    def _velocity_gradient(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The kinetic part of :meth:`lagrangian_gradient` (``D(q)`` cached): ``C(q, v)^T v``,
        less ``ad_v^T p / 2`` on the root."""
        C = pin.computeCoriolisMatrix(self._pin, self._data, q, v)
        out = C.T @ v
        if self._floating:
            p_root = (self._D @ v)[:6]
            out[:6] -= 0.5 * pin.Motion(v[:6]).action.T @ p_root
        return out
