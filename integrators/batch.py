"""Batched rollouts: many environments stepped together (Pinocchio ``abaInParallel``).

Environments may differ in every parameter and in their state and commands. The update of all
environments from the last step and their forces for this one are one compiled call per step
(``kernels.batch_step``), the dynamics one Pinocchio call per model group. Parameters that change the
rigid-body model itself (the transmission inertia ``armature`` and ``link_mass_error``) split
the batch into model groups: Pinocchio's ``ModelPool`` hands one model to each thread, not to
each batch entry, so every group's dynamics is its own ``abaInParallel`` call on its own pool.
A least-squares Jacobian, whose ``armature`` column is such a group, thus steps in one loop
with the others instead of in a rollout of its own.
"""
from __future__ import annotations

from typing import Literal, Sequence, get_args

import numpy as np
import pinocchio as pin

from cobra_model.errors import InputError
from cobra_model.model import RobotModel
from cobra_model.parameters import ModelParameters
from integrators import kernels as K
from integrators.simulator import SimSettings, SimState, SimulationDiverged, Simulator, effect_value

#: What a batch does when an environment diverges (:meth:`BatchSimulator.rollout`).
Divergence = Literal["raise", "mask"]


def model_key(params: ModelParameters) -> tuple:
    """What of ``params`` is part of the Pinocchio model (environments with equal keys share one)."""
    return tuple(params.per_joint("armature")), effect_value(params, "link_mass_error")


class BatchSimulator:
    """N simulators of one robot stepped in lock-step.

    Args:
        model: the robot.
        params: one parameter set per environment.
        settings: numerical settings shared by all.
        threads: worker threads for ABA and the kernels.

    Internally the environments are stored grouped by :func:`model_key` (``_slots[k]`` is the
    environment in storage slot ``k``); inputs and outputs are in the order of ``params``.
    """

    def __init__(self, model: RobotModel, params: Sequence[ModelParameters], settings: SimSettings | None = None,
                 threads: int = 2):
        if not params:
            raise InputError("a batch needs at least one parameter set")
        if settings is not None and settings.scheme != "velocity":
            raise InputError(f"batched rollouts use the velocity-form step; scheme {settings.scheme!r} is for "
                             f"single rollouts (Simulator.rollout)")
        laws = sorted({p.contact_law for p in params})
        if len(laws) > 1:
            raise InputError(f"a batch steps one contact law; the parameter sets have {', '.join(laws)}")
        # environments given the same parameter set share its simulator (an objective passes one
        # parameter set per run); the batch reads their parameters, the states are its own
        made: dict[int, Simulator] = {}
        for p in params:
            if id(p) not in made:
                made[id(p)] = Simulator(model, p, settings)
        self.sims = [made[id(p)] for p in params]
        first = self.sims[0]
        self.settings = first.settings
        self.model = first.model
        self.threads = threads
        keys = [model_key(p) for p in params]
        rank = {k: i for i, k in enumerate(dict.fromkeys(keys))}
        self._slots = np.array(sorted(range(len(params)), key=lambda e: rank[keys[e]]), dtype=np.int64)
        bounds = np.flatnonzero(np.diff([rank[keys[e]] for e in self._slots])) + 1
        self._groups = [(int(a), int(b), pin.ModelPool(self.sims[self._slots[a]].model.pin_model, threads))
                        for a, b in zip(np.r_[0, bounds], np.r_[bounds, len(params)])]
        # the soft-constraint law needs each environment's inverse mass matrix (one Data per group)
        self._models = [(m, m.createData()) for m in (self.sims[self._slots[a]].model.pin_model for a, _, _ in self._groups)
                        ] if first.contact_law in K.SOFT_LAWS else []
        self.act = np.ascontiguousarray(np.stack([s.act for s in self.sims]))
        self.ground = np.ascontiguousarray(np.stack([s.ground for s in self.sims]))
        # each body's weight at the reference pose, which scales the soft laws' compliance
        self.body_weight = np.stack([s.model.reference_weights for s in self.sims]) if self._models else None
        self._first = first

    def rollout(self, states: Sequence[SimState], goals: np.ndarray, duration: float, *,
                record_every: int = 0, goal_index: np.ndarray | None = None, divergence: Divergence = "raise"
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step every environment for ``duration`` [s] with servo goals per control tick.

        Args:
            states: N initial states (their servo loops tick at step 0).
            goals: (n_ticks, G, n_joints) [rad] goal sequences (the last tick is held); environment
                ``e`` follows sequence ``goal_index[e]`` (default: G = N, one sequence each).
            goal_index: (N,) int, which goal sequence each environment follows.
            duration: simulated time [s].
            record_every: record configurations and encoder readings every this many physics
                steps (0: record only the final state).
            divergence: ``"raise"``: an environment that diverges stops the rollout;
                ``"mask"``: its records and final state are all NaN and the others go on
                unaffected (it restarts from its initial state so that the shared arrays stay
                finite; what it computes after that is discarded).

        Returns:
            (Q, V, Q_rec, M_rec, C_rec): final (N, nq) configurations and (N, nv) velocities, and
            the recorded (n_rec, N, nq) configurations, (n_rec, N, n_joints) encoder readings
            [rad] and (n_rec, N, n_joints) motor currents [A] (during the step before each record,
            zero at the initial state), the first record being the initial state.

        Raises:
            InputError: shape mismatch or an unknown ``divergence``. SimulationDiverged (a
            RuntimeError): an environment diverged and ``divergence`` is ``"raise"``; it names
            the environments, and for the first the time and the contact point or velocity
            coordinate that blew up.
        """
        if divergence not in get_args(Divergence):
            raise InputError(f"divergence must be one of {', '.join(map(repr, get_args(Divergence)))}, "
                             f"got {divergence!r}")
        n = len(self.sims)
        s, f = self.settings, self._first
        n_steps = int(round(duration / s.dt))
        gidx = np.arange(n, dtype=np.int64) if goal_index is None else np.asarray(goal_index, dtype=np.int64)
        if goals.ndim != 3 or goals.shape[2] != self.model.n_joints or gidx.shape != (n,) \
                or gidx.min() < 0 or gidx.max() >= goals.shape[1]:
            raise InputError(f"goals must be (n_ticks, G, {self.model.n_joints}) with a goal_index of {n} "
                             f"entries in 0..G-1; got goals {goals.shape}")
        if len(states) != n:
            raise InputError(f"rollout needs {n} initial states (one per environment), got {len(states)}")
        slots = self._slots
        back = np.argsort(slots)  # the storage slot of each environment
        states = [states[e] for e in slots]
        gidx = np.ascontiguousarray(gidx[slots])
        act, ground = np.ascontiguousarray(self.act[slots]), np.ascontiguousarray(self.ground[slots])
        Q = np.ascontiguousarray(np.stack([st.q for st in states]))
        V = np.ascontiguousarray(np.stack([st.v for st in states]))
        TAU = np.zeros_like(V)
        A = np.empty((self.model.nv, n), order="F")
        integ = np.stack([st.integ for st in states])
        prev = np.stack([st.prev_err for st in states])
        duty = np.stack([st.duty for st in states])
        dead = np.zeros(n, dtype=np.bool_)  # masked environments that diverged
        cur = np.zeros_like(duty)
        status = np.zeros(n, dtype=np.int64)
        X = np.empty((n, len(self.model.features), 3))
        F = np.empty_like(X)
        KR = np.empty((n, len(self.model.chain.parents), 3, 3))  # kernel workspace
        KV = np.empty((n, len(self.model.chain.parents), 6, 3))
        on = np.ones(self.model.n_joints, dtype=np.bool_)
        soft = self._first.contact_law in K.SOFT_LAWS
        if soft:
            nv = self.model.nv
            MINV = np.empty((n, nv, nv))
            NLE = np.empty((nv, n), order="F")
            ZERO = np.zeros((nv, n), order="F")
            WARM = np.zeros((n, len(self.model.features), 4))
            WEIGHT = np.ascontiguousarray(self.body_weight[slots])
        sub = s.substeps
        every = record_every if record_every > 0 else max(n_steps, 1)
        n_rec = n_steps // every + 1
        nj, nq = self.model.n_joints, self.model.nq
        Q_rec = np.empty((n_rec, n, nq))
        M_rec = np.empty((n_rec, n, nj))
        C_rec = np.empty((n_rec, n, nj))
        offset = act[:, :, K.A_ENC_OFFSET]
        aba_args = [(pool, Q[a:b].T, V[a:b].T, TAU[a:b].T, A[:, a:b]) for a, b, pool in self._groups]
        for i in range(n_steps + 1):
            if i % every == 0:
                C_rec[i // every] = cur  # the current of step i - 1, before step i's forces replace it
            g = goals[min(i // sub, len(goals) - 1)]
            last = i == n_steps
            # step i - 1's update in place, then step i's forces
            K.batch_step(i, last, i % sub == 0, Q, V, A.T, g, gidx, integ, prev, duty, on, act, f.scal, ground,
                         self.model.chain.floating, f._chain_i, f._chain_R, f._chain_f, f._feat_i, f._feat_f,
                         TAU, cur, X, F, KR, KV, status)
            if status.any():
                if divergence == "raise":
                    bad = np.flatnonzero(status[back])
                    k = back[bad[0]]
                    detail = self.sims[bad[0]].divergence_message(int(status[k]), i * s.dt, V[k], X[k])
                    raise SimulationDiverged(f"environments {bad.tolist()} of {n} diverged; environment {bad[0]}: "
                                             f"{detail}")
                for k in np.flatnonzero(status):
                    dead[k] = True  # restarted, its forces those of its last step: finite, discarded
                    st = states[k]
                    Q[k], V[k], integ[k], prev[k], duty[k] = st.q, st.v, st.integ, st.prev_err, st.duty
                    if soft:
                        WARM[k] = 0.0
            if i % every == 0:
                Q_rec[i // every] = Q
                M_rec[i // every] = Q[:, nq - nj:] + offset
            if last:
                break
            if soft:
                for (a, b, pool), (pm, data) in zip(self._groups, self._models):
                    pin.rneaInParallel(self.threads, pool, Q[a:b].T, V[a:b].T, ZERO[:, a:b], NLE[:, a:b])
                    for e in range(a, b):
                        MINV[e] = pin.computeMinverse(pm, data, Q[e])
                K.batch_soft_contact_acceleration(V, TAU, MINV, NLE.T, self.model.chain.floating, f._chain_i[:, 0],
                                                  f._chain_i[:, 2], f._feat_i[:, 0], X, KR, KV, ground,
                                                  K.SOFT_LAWS[self._first.contact_law], WEIGHT, WARM, A.T)
            else:
                for pool, q_t, v_t, tau_t, a_t in aba_args:
                    pin.abaInParallel(self.threads, pool, q_t, v_t, tau_t, a_t)
        Q[dead] = V[dead] = np.nan
        Q_rec[:, dead] = M_rec[:, dead] = C_rec[:, dead] = np.nan
        return Q[back], V[back], Q_rec[:, back], M_rec[:, back], C_rec[:, back]
