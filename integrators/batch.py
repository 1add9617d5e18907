"""Batched rollouts: many environments stepped together (Pinocchio ``abaInParallel``).

Every environment shares the robot, its transmission inertia (``armature``) and link masses
(Pinocchio's ``ModelPool`` hands its models to threads, not to batch entries, so the inertia must
be common) and may differ in every other parameter (ground, damping, motor constant, effects) and in its
state and commands. The forces of all environments are one compiled call, the dynamics one
``abaInParallel`` call and the update one compiled call per step.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import pinocchio as pin

from cobra_model.errors import InputError
from cobra_model.model import RobotModel
from cobra_model.parameters import ModelParameters
from integrators import kernels as K
from integrators.simulator import SimSettings, SimState, Simulator


class BatchSimulator:
    """N simulators of one robot stepped in lock-step.

    Args:
        model: the robot.
        params: one parameter set per environment (same ``armature``).
        settings: numerical settings shared by all.
        threads: worker threads for ABA and the kernels.
    """

    def __init__(self, model: RobotModel, params: Sequence[ModelParameters], settings: SimSettings | None = None,
                 threads: int = 2):
        if not params:
            raise InputError("a batch needs at least one parameter set")
        arm = {(tuple(p.per_joint("armature")), p.get("link_mass_error", 0.0)) for p in params}
        if len(arm) != 1:
            raise InputError("all parameter sets of a batch must share 'armature' and 'link_mass_error' "
                             "(Pinocchio's ModelPool gives one model per thread); evaluate others in other batches")
        self.sims = [Simulator(model, p, settings) for p in params]
        first = self.sims[0]
        self.settings = first.settings
        self.model = first.model
        self.threads = threads
        self.pool = pin.ModelPool(self.model.pin_model, threads)
        self.act = np.ascontiguousarray(np.stack([s.act for s in self.sims]))
        self.ground = np.ascontiguousarray(np.stack([s.ground for s in self.sims]))
        self._first = first

    def rollout(self, states: Sequence[SimState], goals: np.ndarray, duration: float, *,
                record_every: int = 0, goal_index: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step every environment for ``duration`` [s] with servo goals per control tick.

        Args:
            states: N initial states (their servo loops tick at step 0).
            goals: (n_ticks, G, n_joints) [rad] goal sequences (the last tick is held); environment
                ``e`` follows sequence ``goal_index[e]`` (default: G = N, one sequence each).
            goal_index: (N,) int, which goal sequence each environment follows.
            duration: simulated time [s].
            record_every: record configurations and encoder readings every this many physics
                steps (0: record only the final state).

        Returns:
            (Q, V, Q_rec, M_rec): final (N, nq) configurations and (N, nv) velocities, and the
            recorded (n_rec, N, nq) configurations and (n_rec, N, n_joints) encoder readings
            [rad], the first record being the initial state.

        Raises:
            InputError: shape mismatch. RuntimeError: an environment diverged (names which).
        """
        n = len(self.sims)
        s, f = self.settings, self._first
        n_steps = int(round(duration / s.dt))
        gidx = np.arange(n, dtype=np.int64) if goal_index is None else np.asarray(goal_index, dtype=np.int64)
        if goals.ndim != 3 or goals.shape[2] != self.model.n_joints or gidx.shape != (n,) \
                or gidx.min() < 0 or gidx.max() >= goals.shape[1]:
            raise InputError(f"goals must be (n_ticks, G, {self.model.n_joints}) with a goal_index of {n} "
                             f"entries in 0..G-1; got goals {goals.shape}")
        Q = np.ascontiguousarray(np.stack([st.q for st in states]))
        V = np.ascontiguousarray(np.stack([st.v for st in states]))
        Qn, Vn = np.empty_like(Q), np.empty_like(V)
        TAU = np.zeros_like(V)
        A = np.empty((self.model.nv, n), order="F")
        integ = np.stack([st.integ for st in states])
        prev = np.stack([st.prev_err for st in states])
        duty = np.stack([st.duty for st in states])
        cur = np.zeros_like(duty)
        status = np.zeros(n, dtype=np.int64)
        X = np.empty((n, len(self.model.features), 3))
        F = np.empty_like(X)
        on = np.ones(self.model.n_joints, dtype=np.bool_)
        sub = s.substeps
        every = record_every if record_every > 0 else max(n_steps, 1)
        n_rec = n_steps // every + 1
        nj, nq = self.model.n_joints, self.model.nq
        Q_rec = np.empty((n_rec, n, nq))
        M_rec = np.empty((n_rec, n, nj))
        offset = self.act[:, :, K.A_ENC_OFFSET]
        for i in range(n_steps + 1):
            if i % every == 0:
                Q_rec[i // every] = Q
                M_rec[i // every] = Q[:, nq - nj:] + offset
            if i == n_steps:
                break
            g = goals[min(i // sub, len(goals) - 1)]
            K.batch_pre_step(i % sub == 0, Q, V, g, gidx, integ, prev, duty, on, self.act, f.scal, self.ground,
                          self.model.chain.floating, f._chain_i, f._chain_R, f._chain_f, f._feat_i, f._feat_f,
                          TAU, cur, X, F, status)
            pin.abaInParallel(self.threads, self.pool, Q.T, V.T, TAU.T, A)
            K.batch_post_step(Q, V, A.T, f.scal, self.model.chain.floating, Qn, Vn, status)
            if status.any():
                bad = np.flatnonzero(status)
                raise RuntimeError(f"environments {bad.tolist()} diverged at t = {i * s.dt:.4f} s (status "
                                   f"{status[bad].tolist()})")
            Q, Qn = Qn, Q
            V, Vn = Vn, V
        return Q, V, Q_rec, M_rec
