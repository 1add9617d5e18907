"""Batched rollouts: many environments, each through its whole rollout on a worker thread.

Environments may differ in every parameter and in their state and commands. They never
interact, so one compiled call (``kernels.batch_rollout_loop``) hands them to the threads, and
each runs the single rollout's compiled loop (``kernels.rollout_loop``, Pinocchio's dynamics
through ``integrators.native``) from its first step to its last: no parallel region and no trip
through the interpreter per physics step, which at a few environments cost more than the
physics. Every environment's arithmetic is a single rollout's (``tests/test_batch.py``).
Parameters that change the rigid-body model itself (the transmission inertia ``armature`` and
``link_mass_error``) give an environment its own model; each environment has its own Pinocchio
workspace.
"""
from __future__ import annotations

import os
from typing import Literal, Sequence, get_args

import numba
import numpy as np

from cobra_model.errors import InputError
from cobra_model.model import RobotModel
from cobra_model.parameters import ModelParameters
from integrators import kernels as K
from integrators import native
from integrators.rollout_memo import KeptRollout, active_memo
from integrators.simulator import SimSettings, SimState, SimulationDiverged, Simulator, contact_resolved, servo_memory

#: What a batch does when an environment diverges (:meth:`BatchSimulator.rollout`).
Divergence = Literal["raise", "mask"]
#: The environment variable that sets how many threads a batch runs on when not told
#: (:func:`default_threads`): 1 when other processes share the cores, e.g. fits side by side.
THREADS_ENV = "COBRA_THREADS"


def default_threads() -> int:
    """The threads a batch runs on when not told: ``$COBRA_THREADS``, else 2 (a 2-core machine's).

    Raises:
        InputError: the variable is set to anything but a whole number >= 1 (naming it).
    """
    raw = os.environ.get(THREADS_ENV, "").strip()
    if not raw:
        return 2
    if not raw.isdecimal() or int(raw) < 1:
        raise InputError(f"{THREADS_ENV}={raw!r}: expected a whole number of threads >= 1")
    return int(raw)


class BatchSimulator:
    """N simulators of one robot, rolled out together.

    Args:
        model: the robot.
        params: one parameter set per environment.
        settings: numerical settings shared by all; by default the finest step that any
            environment's soft contact needs (:func:`integrators.simulator.contact_resolved`;
            1 ms for the compliant ground), so that no environment steps coarser than it would
            alone.
        threads: worker threads (environments run at the same time; default
            :func:`default_threads`). The results do not depend on it: each environment runs its
            whole rollout on one thread.
    """

    def __init__(self, model: RobotModel, params: Sequence[ModelParameters], settings: SimSettings | None = None,
                 threads: int | None = None):
        if not params:
            raise InputError("a batch needs at least one parameter set")
        if threads is not None and threads < 1:
            raise InputError(f"a batch needs threads >= 1, got {threads}")
        if settings is not None and settings.scheme != "velocity":
            raise InputError(f"batched rollouts use the velocity-form step; scheme {settings.scheme!r} is for "
                             f"single rollouts (Simulator.rollout)")
        laws = sorted({p.contact_law for p in params})
        if len(laws) > 1:
            raise InputError(f"a batch steps one contact law; the parameter sets have {', '.join(laws)}")
        steps = sorted({p.friction_step for p in params})
        if len(steps) > 1:
            raise InputError(f"a batch steps one friction step; the parameter sets have {', '.join(steps)}")
        if settings is None:
            settings = min((contact_resolved(SimSettings(), p) for p in params), key=lambda s: s.dt)
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
        self.threads = default_threads() if threads is None else threads
        self.act = np.ascontiguousarray(np.stack([s.act for s in self.sims]))
        self.ground = np.ascontiguousarray(np.stack([s.ground for s in self.sims]))
        self._soft = first.contact_law in K.SOFT_LAWS
        self._minv = first.loop_law != K.LAW_COMPLIANT  # the loop takes D^-1 (soft laws, implicit friction)
        # each body's weight at the reference pose, which scales the soft laws' compliance
        self.body_weight = np.ascontiguousarray(np.stack([s.model.reference_weights for s in self.sims]) if self._soft
                                                else np.zeros((len(params), 0)))
        # one Pinocchio workspace per environment (environments run at the same time), of its own model
        self._native = [native.NativeData(native.native_model(s.model)) for s in self.sims]
        self._handles = (np.array([d.model.handle for d in self._native], dtype=np.intp),
                         np.array([d.handle for d in self._native], dtype=np.intp))
        self._first = first
        # what every rollout of this batch shares, as a memo's key (integrators.rollout_memo)
        self._const = (first.loop_law, first.scal.tobytes(), first._chain_i.tobytes(), first._chain_R.tobytes(),
                       first._chain_f.tobytes(), first._feat_i.tobytes(), first._feat_f.tobytes(),
                       self.settings.substeps, self.model.chain.floating)

    def _runs(self, Q: np.ndarray, V: np.ndarray, servo: np.ndarray, goals: np.ndarray, goal_index: np.ndarray,
              steps: np.ndarray, every: int) -> tuple[list[tuple], np.ndarray, np.ndarray]:
        """The rollouts that answer every environment: ``(keys, u, inverse)``, per rollout its
        key (everything that determines it but the goal sequence and the step count) and the
        environment whose goal sequence and step count it runs, and per environment the
        rollout that answers it. Two environments share a rollout when they share the rigid-body
        model (one object per value: ``RobotModel.with_armature`` and ``with_link_mass`` are
        memoised), the actuator and ground arrays, the initial configuration, velocity and servo
        state and the goal sequence (by its values: objectives built apart hold the same run's
        commands in sequences of their own); the longest of them runs, and a shorter one takes
        its records and, as its final state, the record at its own last step (so its step count
        must be a whole number of record periods; otherwise it runs on its own). The step, gains
        and contact law are the batch's."""
        sequence: dict[bytes, int] = {}
        same = {g: sequence.setdefault(goals[:, g].tobytes(), len(sequence)) for g in np.unique(goal_index)}
        keys = [(id(sim.model), self.act[e].tobytes(), self.ground[e].tobytes(), Q[e].tobytes(), V[e].tobytes(),
                 servo[e].tobytes(), every) for e, sim in enumerate(self.sims)]
        longest: dict[tuple, int] = {}
        for e, key in enumerate(keys):
            group = (key, same[goal_index[e]])
            if steps[e] > steps[longest.setdefault(group, e)]:
                longest[group] = e
        first: dict[tuple, int] = {}
        u, inverse = [], np.empty(len(self.sims), dtype=np.int64)
        for e, key in enumerate(keys):
            group = (key, same[goal_index[e]])
            runs_with = longest[group] if steps[e] % every == 0 else e
            run = (group, int(steps[runs_with]))
            if run not in first:
                first[run] = len(u)
                u.append(runs_with)
            inverse[e] = first[run]
        return [keys[e] for e in u], np.array(u, dtype=np.int64), inverse

    def rollout(self, states: Sequence[SimState], goals: np.ndarray, duration: float | Sequence[float], *,
                record_every: int = 0, goal_index: np.ndarray | None = None, divergence: Divergence = "raise"
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Step every environment for ``duration`` [s] with servo goals per control tick.

        Environments with the same rigid-body model, actuator and ground parameters, initial
        state and goal sequence are one rollout (:meth:`_runs`): the longest runs once and the
        others take its records up to their own last step (every environment's arithmetic is a
        single rollout's, so these are what each would have computed). Inside
        :func:`integrators.rollout_memo.memoised_rollouts`, a rollout that a request of the same
        scope ran already is taken from there. Rollouts run in turn on the threads, the longest
        first (chunks of one), so that rollouts of different lengths share the threads evenly.

        Args:
            states: N initial states (their servo loops tick at step 0).
            goals: (n_ticks, G, n_joints) [rad] goal sequences (the last tick is held); environment
                ``e`` follows sequence ``goal_index[e]`` (default: G = N, one sequence each).
            goal_index: (N,) int, which goal sequence each environment follows.
            duration: simulated time [s], one for all or (N,) one per environment; the records
                of an environment after its own duration are NaN.
            record_every: record configurations and encoder readings every this many physics
                steps (0: record only the final state).
            divergence: ``"raise"``: an environment that diverges makes the rollout raise;
                ``"mask"``: its records and final state are all NaN and the others are
                unaffected (every environment runs on its own).

        Returns:
            (Q, V, Q_rec, M_rec, C_rec): final (N, nq) configurations and (N, nv) velocities, and
            the recorded (n_rec, N, nq) configurations, (n_rec, N, n_joints) encoder readings
            [rad] and (n_rec, N, n_joints) motor currents [A] (during the step before each record,
            zero at the initial state), the first record being the initial state.

        Raises:
            InputError: shape mismatch or an unknown ``divergence``. SimulationDiverged (a
            RuntimeError): an environment diverged and ``divergence`` is ``"raise"``; it names
            the environments, and for the first to diverge the time and the contact point or
            velocity coordinate that blew up.
        """
        if divergence not in get_args(Divergence):
            raise InputError(f"divergence must be one of {', '.join(map(repr, get_args(Divergence)))}, "
                             f"got {divergence!r}")
        n = len(self.sims)
        s, f = self.settings, self._first
        durations = np.asarray(duration, dtype=float)
        if durations.shape not in ((), (n,)) or not np.all(durations >= 0):
            raise InputError(f"duration must be one value or one per environment ({n}), each >= 0 s; got {duration!r}")
        steps = np.rint(np.broadcast_to(durations, (n,)) / s.dt).astype(np.int64)
        n_steps = int(steps.max())
        gidx = np.arange(n, dtype=np.int64) if goal_index is None else np.asarray(goal_index, dtype=np.int64)
        if goals.ndim != 3 or goals.shape[2] != self.model.n_joints or gidx.shape != (n,) \
                or gidx.min() < 0 or gidx.max() >= goals.shape[1]:
            raise InputError(f"goals must be (n_ticks, G, {self.model.n_joints}) with a goal_index of {n} "
                             f"entries in 0..G-1; got goals {goals.shape}")
        if len(states) != n:
            raise InputError(f"rollout needs {n} initial states (one per environment), got {len(states)}")
        sub = s.substeps
        n_ticks = n_steps // sub + 1
        goals = np.asarray(goals, dtype=float)
        if len(goals) < n_ticks:  # the last tick held
            goals = np.concatenate([goals, np.repeat(goals[-1:], n_ticks - len(goals), axis=0)])
        goals = np.ascontiguousarray(goals[:n_ticks])
        every = record_every if record_every > 0 else max(n_steps, 1)
        n_rec = n_steps // every + 1
        nj, nq, nv = self.model.n_joints, self.model.nq, self.model.nv
        Q = np.ascontiguousarray(np.stack([st.q for st in states]), dtype=float)
        V = np.ascontiguousarray(np.stack([st.v for st in states]), dtype=float)
        A = np.zeros((n, nv))
        # the servo loops' integral, previous error, duty and motor current (zero before the first
        # step) and their gear plays, centred
        servo = np.ascontiguousarray(np.stack([servo_memory(st, self.model.n_base, with_current=False)
                                               for st in states]))
        plan = np.zeros((n, K.N_PLAN), dtype=np.int64)
        plan[:, [K.P_SUBSTEPS, K.P_RECORD_EVERY, K.P_INTEGRATE, K.P_FLOATING]] = (
            sub, every, 1, self.model.chain.floating)
        plan[:, K.P_STEPS] = steps
        nf, nb = len(self.model.features), len(self.model.chain.parents)
        # the rollouts that answer every environment (u: whose goals and step count each runs,
        # inverse: each environment's); inside a memoised scope, those run before are not run again
        keys, u, inverse = self._runs(Q, V, servo, goals, gidx, steps, every)
        memo = active_memo()
        runs: list[KeptRollout | None] = [None] * len(u)
        if memo is not None:
            for r, (key, e) in enumerate(zip(keys, u)):
                runs[r] = memo.find((self._const, key), goals[:, gidx[e]], int(steps[e]), every, sub)
        # the longest first, so that the threads run out of work together
        todo = sorted((r for r in range(len(u)) if runs[r] is None), key=lambda r: -steps[u[r]])
        if todo:
            t = u[todo]
            k = len(t)
            work = np.empty((k, K.workspace_size(nf, nb)))
            record = np.full((k, n_rec, nq + nv + nj), np.nan)
            minv = np.zeros((k, nv, nv) if self._minv else (k, 0, 0))
            warm = np.zeros((k, nf, 4) if self._soft else (k, 0, 4))
            status = np.zeros(k, dtype=np.int64)
            failed_at = np.zeros(k, dtype=np.int64)
            on = np.ones(nj, dtype=np.bool_)
            Qt, Vt = np.ascontiguousarray(Q[t]), np.ascontiguousarray(V[t])
            threads = numba.get_num_threads()
            numba.set_num_threads(min(self.threads, numba.config.NUMBA_NUM_THREADS))
            chunk = numba.set_parallel_chunksize(1)
            try:
                K.batch_rollout_loop(self._handles[0][t], self._handles[1][t], f.loop_law, plan[t], Qt,
                                     Vt, A[t], goals, gidx[t], servo[t], on, self.act[t], f.scal, self.ground[t],
                                     f._chain_i, f._chain_R, f._chain_f, f._feat_i, f._feat_f, np.empty((k, nv)), work,
                                     record, minv, self.body_weight[t], warm, status, failed_at)
            finally:
                numba.set_parallel_chunksize(chunk)
                numba.set_num_threads(threads)
            sequences: dict[int, np.ndarray] = {}  # one copy of each goal sequence, shared by its rollouts
            for j, (r, e) in enumerate(zip(todo, t)):
                sequence = sequences.setdefault(gidx[e], np.ascontiguousarray(goals[:, gidx[e]]))
                runs[r] = KeptRollout(int(steps[e]), sequence[:steps[e] // sub + 1],
                                      record[j, :steps[e] // every + 1].copy(), Qt[j], Vt[j], int(status[j]),
                                      int(failed_at[j]), work[j], self.sims[e].model)
                if memo is not None:
                    memo.keep((self._const, keys[r]), runs[r])
        # every environment from its rollout: the records up to its own last step, its final state
        # (the record there when the rollout ran longer) and whether it diverged by then
        record = np.full((n, n_rec, nq + nv + nj), np.nan)
        Q, V = np.empty((n, nq)), np.empty((n, nv))
        status = np.zeros(n, dtype=np.int64)
        failed_at = np.zeros(n, dtype=np.int64)
        work = np.empty((n, K.workspace_size(nf, nb)))
        for e in range(n):
            run, last = runs[inverse[e]], int(steps[e])
            record[e, :last // every + 1] = run.record[:last // every + 1]
            work[e] = run.work
            # a longer rollout stopped at step i: this one had run step i's integration (status
            # < 0) but not its forces (status > 0) when i is its own last step
            stopped = run.status != K.STATUS_OK and (run.failed_at < last or (run.failed_at == last and run.status < 0))
            if run.steps == last or stopped:
                Q[e], V[e], status[e], failed_at[e] = run.q, run.v, run.status, run.failed_at
            else:
                Q[e], V[e], failed_at[e] = run.record[last // every, :nq], run.record[last // every, nq:nq + nv], last
        dead = status != K.STATUS_OK
        if dead.any() and divergence == "raise":
            bad = np.flatnonzero(dead)
            k = bad[np.argmin(failed_at[bad])]  # the first to diverge (the lowest index of a tie)
            X = work[k, :3 * nf].reshape(nf, 3)
            detail = self.sims[k].divergence_message(int(abs(status[k])), failed_at[k] * s.dt, V[k], X)
            raise SimulationDiverged(f"environments {bad.tolist()} of {n} diverged; environment {k}: {detail}")
        Q_rec = record[:, :, :nq].transpose(1, 0, 2)  # environment e's rows after its own duration: NaN
        M_rec = Q_rec[:, :, nq - nj:] + self.act[None, :, :, K.A_ENC_OFFSET]
        C_rec = record[:, :, nq + nv:].transpose(1, 0, 2)
        Q[dead] = V[dead] = np.nan
        Q_rec[:, dead] = M_rec[:, dead] = C_rec[:, dead] = np.nan
        return Q, V, np.ascontiguousarray(Q_rec), np.ascontiguousarray(M_rec), np.ascontiguousarray(C_rec)
