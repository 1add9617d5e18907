"""The identification objective shared by least squares and PPO (paper Eqs. 7 and 8).

For a parameter vector the objective simulates every training run from its own first pose with
its own commands, and compares with the measurement:

- **residuals** (least squares): the head's ground-plane position over time [m] divided by
  ``Weights.head_scale_m`` and every joint angle over time [rad] divided by
  ``Weights.joint_scale_rad``, sampled at ``Weights.sample_hz`` (motion-capture gaps are left
  out by zero residuals);
- **scalar** (PPO's negative reward): external = mean over runs of the final head-position
  error [m] (Eq. 7; plus ``mean_head`` x the mean error), internal = mean joint RMSE [rad] plus
  the squared CPG amplitude and phase errors of the joints (Eq. 8), each with a weight.

CPG terms are fitted at the commanded gait frequency (linear least squares on sin, cos and an
offset), so the frequency term of Eq. 8 is zero by construction: a servo-driven joint follows
its command's frequency; ``cobra compare`` reports the free-frequency fit.

Evaluation is batched: all (parameter vector, run) pairs step together in one
:class:`integrators.batch.BatchSimulator` (vectors that differ in the transmission inertia, a
link mass or the command delay included), and chunks of parameter vectors are spread over an
:class:`sysid.identification.executor.Executor`.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from cobra_model.errors import InputError
from cobra_model.model import DEFAULT_URDF, CobraModel
from cobra_model.parameters import ModelParameters
from cobra_model.resample import interpolate_rows
from cobra_model.run import Run
from cobra_model.servo import CURRENT_NOISE_A, PULSES_PER_REV
from integrators import kernels as K
from integrators.batch import BatchSimulator, Divergence, default_threads
from integrators.simulate import InitialPose, StartObservation, command_ticks
from integrators.simulator import SimSettings, SimState, contact_resolved, delay_commands, effect_value
from sysid.identification.executor import Executor, LocalExecutor


#: Each channel's measurement noise (RMS), below which :meth:`Objective.residual_weights` never
#: sets a scale: motion capture's position noise [m], the encoders' rounding (one count of
#: ``PULSES_PER_REV`` per turn, uniform: ``2 pi / 4096 / sqrt 12``) [rad], a Present Current
#: reading's noise [A].
SENSOR_NOISE = {"head": 0.5e-3, "joints": 2 * np.pi / PULSES_PER_REV / np.sqrt(12), "current": CURRENT_NOISE_A}


def runs_without_current(runs: Sequence[Run]) -> list[str]:
    """The names (file, else ``run i``) of the runs that logged no motor currents."""
    return [str(r.source or f"run {i}") for i, r in enumerate(runs) if r.current is None]


@dataclass(frozen=True)
class Weights:
    """Weights of the objective (documented defaults).

    Attributes:
        head_scale_m: head residual unit [m]: 1 cm of head error weighs as much as ...
        joint_scale_rad: ... 0.01 rad of joint error.
        sample_hz: residual sampling rate [Hz].
        final_head: weight of the final head error [1/m] (Eq. 7).
        mean_head: weight of the mean head error [1/m] (0: the paper's final-only reward).
        joint_rmse: weight of the mean joint RMSE [1/rad].
        cpg: weight of the mean squared CPG amplitude + phase error [1/rad^2] (Eq. 8).
        use_current: also fit the measured motor currents (``current_*`` columns, needed in
            every run), which pin the motor constant and the internal damping directly.
        current_scale_a: ... and (with ``use_current``) this much motor current [A]. The joint
            scale is 23 times the encoders' quantisation noise (0.44 mrad rms); the current scale
            is the same multiple of a Present Current reading's noise (about 20 mA), so that
            neither channel is weighted beyond what its noise allows (at 0.05 A the current's
            noise made the motor constant's interval twice as wide as without it).
    """

    head_scale_m: float = 0.01
    joint_scale_rad: float = 0.01
    sample_hz: float = 10.0
    final_head: float = 1.0
    mean_head: float = 0.0
    joint_rmse: float = 1.0
    cpg: float = 1.0
    use_current: bool = False
    current_scale_a: float = 0.45


@dataclass(frozen=True)
class RunTarget:
    """What one measured run contributes: its start, commands and measured samples."""

    name: str
    t0: float
    duration: float
    start: StartObservation
    pose: InitialPose        # with the encoders read as the joint angles (no encoder offset)
    ticks: np.ndarray        # (n_ticks, 11) commands at the control ticks from t0
    t_samples: np.ndarray    # (S,) sample times from t0 [s]
    head_xy: np.ndarray      # (S, 2) measured head, NaN in gaps
    q: np.ndarray            # (S, 11) measured joints [rad]
    freq_hz: float
    current: np.ndarray | None = None  # (S, 11) measured motor currents [A] (NaN where missing), if any

    @classmethod
    def of_run(cls, run: Run, settings: SimSettings, sample_hz: float, model: CobraModel) -> "RunTarget":
        t0, t1 = float(run.t[0]), float(run.t[-1])
        ticks = command_ticks(run, settings.control_dt)
        ts = np.minimum(np.arange(0.0, t1 - t0 + 1e-9, 1.0 / sample_hz), t1 - t0)
        head = interpolate_rows(t0 + ts, run.t, run.head_pos[:, :2], max_gap_samples=2)
        q = interpolate_rows(t0 + ts, run.t, run.q)
        freq = run.gait_frequency_hz
        start = StartObservation.of_run(run)
        current = None if run.current is None else interpolate_rows(t0 + ts, run.t, run.current, max_gap_samples=2)
        return cls(str(run.source or "run"), t0, t1 - t0, start, start.pose(model, start.q_reading), ticks, ts, head,
                   q, freq, current)

    def residual_size(self, weights: "Weights") -> int:
        """Length of this run's part of the residual vector (:func:`residual_vector`)."""
        S, n_j = len(self.t_samples), self.q.shape[1]
        return S * (2 + n_j + (n_j if weights.use_current else 0))


def cpg_fit(t: np.ndarray, y: np.ndarray, freq_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Amplitude [rad] and phase [rad] of ``y`` (S, J) ~ A sin(2 pi f t + phi) + c at known f."""
    w = 2 * np.pi * freq_hz * t
    basis = np.column_stack([np.sin(w), np.cos(w), np.ones_like(t)])
    coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
    return np.hypot(coef[0], coef[1]), np.arctan2(coef[1], coef[0])


@dataclass(frozen=True)
class Simulated:
    """Simulated samples of every run for one parameter vector."""

    head_xy: list[np.ndarray]   # per run (S, 2)
    q: list[np.ndarray]         # per run (S, 11)
    current: list[np.ndarray]   # per run (S, 11) motor currents [A]
    diverged: bool = False      # a run diverged (``divergence="mask"``): the samples are NaN


@dataclass(frozen=True)
class ObjectiveSpec:
    """Everything needed to evaluate the objective (picklable, for executors)."""

    targets: tuple[RunTarget, ...]
    params: ModelParameters
    weights: Weights
    settings: SimSettings
    urdf: Path | None  # None: the shipped COBRA, found where each process has it installed
    threads: int = 2


def shares_batch(a: ObjectiveSpec, b: ObjectiveSpec) -> bool:
    """Whether two objectives' evaluations can step in one batched rollout without changing
    either's results: the same robot file, physics and control steps, contact law, sample rate
    and threads. Their runs' lengths may differ: each environment runs for its own run's
    length and its samples read only its own records, which are those it would have alone."""
    return (a.urdf == b.urdf and a.settings == b.settings and a.threads == b.threads
            and a.params.contact_law == b.params.contact_law and a.weights.sample_hz == b.weights.sample_hz)


def simulate_batch(spec: ObjectiveSpec, X: np.ndarray, divergence: Divergence = "raise") -> list[Simulated]:
    """Simulate every run for each row of ``X`` (k, d) of free-parameter values (physical units).

    ``divergence``: ``"raise"`` (a RuntimeError when any simulation diverges) or ``"mask"``
    (a row whose simulation of any run diverged comes back ``diverged``, the others as they are;
    :meth:`integrators.batch.BatchSimulator.rollout`).
    """
    return simulate_together([(spec, X)], divergence)[0]


def recorded_span(duration: float, every: int, dt: float) -> float:
    """The shortest rollout [s] of whole record periods (``every`` steps of ``dt`` [s]) whose last
    record time, computed as :func:`simulate_together` computes its record times, is at or after
    ``duration`` [s]."""
    n = int(np.ceil(duration / (every * dt)))
    while n * every * dt < duration:
        n += 1
    return n * every * dt


def simulate_together(jobs: Sequence[tuple[ObjectiveSpec, np.ndarray]], divergence: Divergence = "raise"
                      ) -> list[list[Simulated]]:
    """:func:`simulate_batch` of several objectives' rows in one batched rollout (their specs
    must pair up under :func:`shares_batch`); per job, its rows' simulations. Each environment
    steps exactly as it would in a batch of its own.

    Raises:
        InputError: specs that cannot share a batch, or a row that is no valid parameter vector.
    """
    spec0 = jobs[0][0]
    if not all(shares_batch(spec0, spec) for spec, _ in jobs[1:]):
        raise InputError("simulate_together: these objectives cannot share a batch (robot, step, contact law, "
                         "sample rate, threads or run length differ)")
    model = CobraModel.load(spec0.urdf or DEFAULT_URDF)  # once per process and file (cached)
    settings = spec0.settings
    # per environment: its parameter set and run (a parameter set's environments are its runs)
    sets = [[spec.params.update_from_vector(x) for x in np.atleast_2d(X)] for spec, X in jobs]
    envs = [(p, tg) for (spec, _), ps in zip(jobs, sets) for p in ps for tg in spec.targets]
    targets = list({id(tg): tg for _, tg in envs}.values())
    index = {id(tg): r for r, tg in enumerate(targets)}
    n_ticks = max(len(tg.ticks) for tg in targets)
    every = max(1, int(round(1.0 / (spec0.weights.sample_hz * settings.dt))))
    # each environment for its own run's length rounded up to a whole record period, so that every
    # sample time lies inside its recorded span (a run's samples read only its records up to then)
    # and its final state is a record: a rollout of the same run and model kept from a longer
    # request answers it (integrators.rollout_memo)
    durations = [recorded_span(tg.duration, every, settings.dt) for _, tg in envs]
    # one goal sequence per (command delay, run) that an environment follows: environments share
    # a sequence, not a batch
    keys = [(effect_value(p, "actuator_delay"), index[id(tg)]) for p, tg in envs]
    sequences = {key: g for g, key in enumerate(dict.fromkeys(keys))}
    goals = np.empty((n_ticks, len(sequences), targets[0].ticks.shape[1]))
    for (delay, r), g in sequences.items():
        ticks = delay_commands(targets[r].ticks, delay, settings.control_dt)
        goals[:, g] = ticks[np.minimum(np.arange(n_ticks), len(targets[r].ticks) - 1)]
    goal_index = np.array([sequences[key] for key in keys])
    batch = BatchSimulator(model, [p for p, _ in envs], settings, threads=spec0.threads)
    # a run's rest state depends only on its encoder offsets and the ends' rounding: made once each
    rest: dict[tuple, SimState] = {}
    states = []
    for sim, (_, tg) in zip(batch.sims, envs):
        reading = sim.joints_reading(tg.start.q_reading)
        key = (index[id(tg)], reading.tobytes(), float(sim.ground[K.G_ROUND]))
        if key not in rest:
            pose = tg.start.pose(model, reading)
            rest[key] = sim.rest_state(pose.q_joints, head_xy=pose.head_xy, base_quat_wxyz=pose.head_quat_wxyz)
        states.append(rest[key])
    _, _, q_rec, m_rec, c_rec = batch.rollout(states, goals, durations, record_every=every, goal_index=goal_index,
                                              divergence=divergence)
    dead = np.isnan(q_rec[0]).any(axis=1)  # masked: the initial record of a diverged environment is NaN too
    t_rec = np.arange(q_rec.shape[0]) * every * settings.dt
    out, e = [], 0
    for (spec, _), ps in zip(jobs, sets):
        sims = []
        for _ in ps:
            heads, joints, currents = [], [], []
            for tg in spec.targets:
                heads.append(interpolate_rows(tg.t_samples, t_rec, q_rec[:, e, :2]))
                joints.append(interpolate_rows(tg.t_samples, t_rec, m_rec[:, e]))
                currents.append(interpolate_rows(tg.t_samples, t_rec, c_rec[:, e]))
                e += 1
            sims.append(Simulated(heads, joints, currents,
                                  diverged=bool(dead[e - len(spec.targets):e].any())))
        out.append(sims)
    return out


def residual_vector(spec: ObjectiveSpec, sim: Simulated) -> np.ndarray:
    """Stacked weighted residuals (head xy over time, joints over time, and with
    ``Weights.use_current`` the motor currents over time) of one parameter vector; missing
    measurements (motion-capture gaps, current samples) are zero residuals; a ``diverged``
    simulation's residuals are all NaN."""
    w = spec.weights
    if sim.diverged:
        return np.full(sum(tg.residual_size(w) for tg in spec.targets), np.nan)
    parts = []
    for tg, head, q, current in zip(spec.targets, sim.head_xy, sim.q, sim.current):
        dh = (head - tg.head_xy) / w.head_scale_m
        parts.append(np.where(np.isfinite(dh), dh, 0.0).ravel())
        parts.append(((q - tg.q) / w.joint_scale_rad).ravel())
        if w.use_current:
            dc = (current - tg.current) / w.current_scale_a
            parts.append(np.where(np.isfinite(dc), dc, 0.0).ravel())
    return np.concatenate(parts)


def residual_blocks(spec: ObjectiveSpec) -> list[np.ndarray]:
    """Where each run's samples sit in the residual vector of :func:`residual_vector`.

    Returns:
        per run, an ``(S, 13)`` integer array (``(S, 24)`` with ``Weights.use_current``): row
        ``t`` is sample time ``t_samples[t]``, columns are the channels head x, head y, joints
        1 to 11 (then the currents of joints 1 to 11); entries index the stacked residual
        vector (the time series of one channel is a column).
    """
    out = []
    k = 0
    for tg in spec.targets:
        S, n_j = len(tg.t_samples), tg.q.shape[1]
        head = k + 2 * np.arange(S)[:, None] + np.arange(2)[None, :]
        joints = k + 2 * S + n_j * np.arange(S)[:, None] + np.arange(n_j)[None, :]
        channels = [head, joints]
        if spec.weights.use_current:
            channels.append(joints + n_j * S)
        out.append(np.hstack(channels))
        k += tg.residual_size(spec.weights)
    return out


def current_rows(spec: ObjectiveSpec) -> np.ndarray:
    """``(m,)`` booleans: the residuals that are motor currents (none without ``use_current``)."""
    parts = []
    for tg in spec.targets:
        n = tg.residual_size(spec.weights)
        part = np.zeros(n, dtype=bool)
        if spec.weights.use_current:
            part[2 * len(tg.t_samples) + tg.q.size:] = True
        parts.append(part)
    return np.concatenate(parts)


def head_gaps(spec: ObjectiveSpec) -> np.ndarray:
    """``(m,)`` booleans: residuals that are motion-capture gaps (zeros, not measurements)."""
    parts = []
    for tg in spec.targets:
        parts.append(np.repeat(~np.isfinite(tg.head_xy).all(axis=1), 2))
        parts.append(np.zeros(tg.residual_size(spec.weights) - 2 * len(tg.t_samples), dtype=bool))
    return np.concatenate(parts)


def start_pose_sensitivity(spec: ObjectiveSpec, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How the residuals ``r`` of one parameter vector move with each run's start pose.

    Ground and friction laws do not depend on where the robot stands or which way it faces,
    so shifting a run's start by (dx, dy) [m] and turning it by dyaw [rad] about the head moves
    the simulated head path rigidly and leaves the joints alone: the derivative of the head
    residual is analytic, ``(1, 0)``, ``(0, 1)`` and ``(-(y - y0), x - x0)`` over the head scale,
    with no simulation.

    Returns:
        ``(m, 3 n_runs)`` derivatives of ``r`` with respect to every run's (dx, dy, dyaw), and
        the ``(3 n_runs,)`` standard uncertainties of those start-pose coordinates
        (:class:`integrators.simulate.InitialPose`).
    """
    scale = spec.weights.head_scale_m
    J = np.zeros((r.size, 3 * len(spec.targets)))
    std = np.zeros(3 * len(spec.targets))
    k = 0
    for i, tg in enumerate(spec.targets):
        S = len(tg.t_samples)
        seen = np.isfinite(tg.head_xy).all(axis=1)
        sim = np.where(seen[:, None], tg.head_xy + r[k:k + 2 * S].reshape(S, 2) * scale, 0.0)
        rel = sim - np.array(tg.pose.head_xy)
        rows = k + 2 * np.flatnonzero(seen)
        J[rows, 3 * i] = 1.0 / scale
        J[rows + 1, 3 * i + 1] = 1.0 / scale
        J[rows, 3 * i + 2] = -rel[seen, 1] / scale
        J[rows + 1, 3 * i + 2] = rel[seen, 0] / scale
        std[3 * i:3 * i + 3] = (tg.pose.xy_std_m, tg.pose.xy_std_m, tg.pose.yaw_std_rad)
        k += tg.residual_size(spec.weights)
    return J, std


#: The unweighted terms, in the order :meth:`ObjectiveTerms.observed` returns them.
OBSERVED_TERMS: tuple[str, ...] = ("head_final_m", "head_mean_m", "joint_rmse_rad", "cpg_sq")


@dataclass(frozen=True)
class ObjectiveTerms:
    """The paper's reward terms for one parameter vector, means over the runs (Eqs. 7 and 8).

    Attributes:
        head_final_m: final head position error [m]; head_mean_m: mean head position error [m].
        joint_rmse_rad: joint RMSE [rad]; cpg_sq: fitted CPG amplitude and phase error [rad^2].
        external, internal: the weighted head terms and the weighted joint terms;
        total: their sum, the scalar objective.
    """

    head_final_m: float
    head_mean_m: float
    joint_rmse_rad: float
    cpg_sq: float
    external: float
    internal: float
    total: float

    @classmethod
    def weighted(cls, head_final_m: float, head_mean_m: float, joint_rmse_rad: float, cpg_sq: float,
                 w: "Weights") -> "ObjectiveTerms":
        """The terms with their external, internal and total sums under the weights ``w``."""
        external = w.final_head * head_final_m + w.mean_head * head_mean_m
        internal = w.joint_rmse * joint_rmse_rad + w.cpg * cpg_sq
        return cls(head_final_m, head_mean_m, joint_rmse_rad, cpg_sq, external, internal, external + internal)

    def observed(self) -> np.ndarray:
        """The unweighted terms in the order of :data:`OBSERVED_TERMS` (what a PPO state may carry)."""
        return np.array([getattr(self, name) for name in OBSERVED_TERMS])

    def to_json(self) -> dict[str, float]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, data: Mapping[str, float]) -> "ObjectiveTerms":
        return cls(**{f.name: float(data[f.name]) for f in dataclasses.fields(cls)})


def scalar_terms(spec: ObjectiveSpec, sim: Simulated) -> ObjectiveTerms:
    """The paper's reward terms for one parameter vector (means over runs)."""
    finals, means, rmses, cpgs = [], [], [], []
    for tg, head, q in zip(spec.targets, sim.head_xy, sim.q):
        err = np.linalg.norm(head - tg.head_xy, axis=1)
        ok = np.flatnonzero(np.isfinite(err))
        finals.append(float(err[ok[-1]]) if ok.size else 0.0)
        means.append(float(np.mean(err[ok])) if ok.size else 0.0)
        rmses.append(float(np.sqrt(np.mean((q - tg.q) ** 2))))
        a_m, p_m = cpg_fit(tg.t_samples, tg.q, tg.freq_hz)
        a_s, p_s = cpg_fit(tg.t_samples, q, tg.freq_hz)
        dphi = np.angle(np.exp(1j * (p_s - p_m)))
        cpgs.append(float(np.mean((a_s - a_m) ** 2 + dphi ** 2)))
    return ObjectiveTerms.weighted(float(np.mean(finals)), float(np.mean(means)), float(np.mean(rmses)),
                                   float(np.mean(cpgs)), spec.weights)


def _evaluate_chunk(job: tuple[ObjectiveSpec, np.ndarray, bool, Divergence]
                    ) -> list[np.ndarray] | list[ObjectiveTerms | None]:
    spec, X, want_residuals, divergence = job
    sims = simulate_batch(spec, X, divergence)
    if want_residuals:
        return [residual_vector(spec, s) for s in sims]
    return [None if s.diverged else scalar_terms(spec, s) for s in sims]


@dataclass
class Objective:
    """The objective over a set of runs for the free parameters of ``params``.

    Args:
        runs: measured training runs.
        params: parameter set; its free parameters are the optimisation variables.
        weights: objective weights.
        settings: simulator settings (default: :class:`SimSettings`' with the step that resolves
            ``params``' soft contact, :func:`integrators.simulator.contact_resolved`, the step
            a :class:`~integrators.simulator.Simulator` of the same parameters takes: then
            ``auto_step`` is True and :meth:`with_params` follows the parameters' contact).
        executor: where parameter-vector chunks are evaluated (default: in-process).
        threads: threads of one batched evaluation (default: in-process
            :func:`integrators.batch.default_threads`, 2 unless ``$COBRA_THREADS`` says otherwise;
            1 per worker process). Use 1 when other processes share the cores (e.g. several fits
            run side by side): more threads than free cores only fight over them.
        model: the robot (default: ``urdf/cobra.urdf``); worker processes load the same file.
    """

    runs: Sequence[Run]
    params: ModelParameters
    weights: Weights = field(default_factory=Weights)
    settings: SimSettings | None = None
    executor: Executor = field(default_factory=lambda: LocalExecutor(1))
    threads: int | None = None
    model: CobraModel = field(default_factory=CobraModel.load)
    evaluations: int = 0

    def __post_init__(self) -> None:
        if not self.runs:
            raise InputError("the objective needs at least one run")
        if not self.params.free_names:
            raise InputError("every parameter is frozen: nothing to fit")
        if self.weights.use_current:
            missing = runs_without_current(self.runs)
            if missing:
                raise InputError(f"fitting the motor current needs current_1..current_11 columns in every run; "
                                 f"none in {', '.join(missing)}")
        if self.model.urdf_path is None:
            raise InputError("the objective's model must come from a URDF file (worker processes load it)")
        if self.threads is not None and self.threads < 1:
            raise InputError(f"an objective needs threads >= 1 (or None: the default), got {self.threads}")
        self.auto_step = self.settings is None
        if self.auto_step:
            self.settings = contact_resolved(SimSettings(), self.params)
        self.spec = ObjectiveSpec(tuple(RunTarget.of_run(r, self.settings, self.weights.sample_hz, self.model)
                                        for r in self.runs),
                                  self.params, self.weights, self.settings,
                                  None if self.model.urdf_path == DEFAULT_URDF.resolve() else self.model.urdf_path,
                                  threads=(self.threads if self.threads is not None
                                           else default_threads() if self.executor.workers == 1 else 1))

    @property
    def _given_settings(self) -> SimSettings | None:
        """The settings argument that rebuilds this objective's step rule (None: automatic)."""
        return None if self.auto_step else self.settings

    def with_params(self, params: ModelParameters) -> "Objective":
        """The same objective from ``params`` (its own evaluation count; an automatic step is
        ``params``' own)."""
        return Objective(self.runs, params, self.weights, self._given_settings, self.executor, self.threads,
                         self.model)

    def with_weights(self, weights: Weights) -> "Objective":
        """The same objective under ``weights`` (its own evaluation count)."""
        return Objective(self.runs, self.params, weights, self._given_settings, self.executor, self.threads,
                         self.model)

    def channel_residuals(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """The weighted residuals at ``x`` by channel: ``head`` (x and y of every run, the
        motion-capture gaps left out), ``joints`` and, with ``Weights.use_current``, ``current``."""
        return self.channels(self.residuals(np.atleast_2d(x))[0])

    def channels(self, r: np.ndarray) -> dict[str, np.ndarray]:
        """One residual vector ``r`` of this objective split by channel, as :meth:`channel_residuals`."""
        blocks = self.residual_blocks()
        head = np.concatenate([b[:, :2].ravel() for b in blocks])
        out = {"head": r[head[~self.head_gaps()[head]]],
               "joints": r[np.concatenate([b[:, 2:13].ravel() for b in blocks])]}
        if self.weights.use_current:
            out["current"] = r[np.concatenate([b[:, 13:].ravel() for b in blocks])]
        return out

    def residual_weights(self, x: np.ndarray) -> Weights:
        """The weights with each channel's scale set to its RMS residual at ``x`` [m, rad, A], but
        never below the channel's sensor noise (:data:`SENSOR_NOISE`): the second step of
        feasible weighted least squares (each channel's residuals then have unit variance). A
        channel without residuals keeps its scale.

        Why: the documented scales (1 cm of head error weighs as 0.01 rad of joint error) are each
        sensor's noise times about 20, the right ratio while the model's structure is right. Under a
        structural mismatch (another engine's ground, or a real one) the head path carries
        centimetres that no parameter explains while the servo-held joints stay within about a
        milliradian, so the fixed scales let the head's structural error pull the actuator and
        friction values to where they trade joint error for head path. Weighted by what the model
        leaves in each channel, the fit returns to the values both channels support.
        """
        w = self.weights
        scale = {"head": w.head_scale_m, "joints": w.joint_scale_rad, "current": w.current_scale_a}
        rms = {name: max(scale[name] * float(np.sqrt(np.mean(r ** 2))), SENSOR_NOISE[name])
               for name, r in self.channel_residuals(x).items() if r.size}
        return dataclasses.replace(w, head_scale_m=rms.get("head", w.head_scale_m),
                                   joint_scale_rad=rms.get("joints", w.joint_scale_rad),
                                   current_scale_a=rms.get("current", w.current_scale_a))

    def on_runs(self, runs: Sequence[Run]) -> "Objective":
        """The same objective over ``runs`` instead (its own evaluation count)."""
        return Objective(runs, self.params, self.weights, self._given_settings, self.executor, self.threads,
                         self.model)

    def truncated(self, seconds: float) -> "Objective":
        """The same objective over each run's first ``seconds`` [s] (its own evaluation count)."""
        return self.on_runs([r.slice_time(float(r.t[0]), float(r.t[0]) + seconds) for r in self.runs])

    @property
    def longest_run_s(self) -> float:
        """The longest run's span [s], first to last sample."""
        return max(tg.duration for tg in self.spec.targets)

    @property
    def names(self) -> tuple[str, ...]:
        return self.params.free_names

    def _map(self, X: np.ndarray, want_residuals: bool, divergence: Divergence = "raise") -> list:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        self.evaluations += len(X)
        chunks = np.array_split(np.arange(len(X)), min(len(X), self.executor.workers))
        results = self.executor.map(_evaluate_chunk, [(self.spec, X[c], want_residuals, divergence)
                                                      for c in chunks if len(c)])
        return [item for chunk in results for item in chunk]

    def residuals(self, X: np.ndarray, divergence: Divergence = "raise") -> np.ndarray:
        """(k, m) residual vectors for (k, d) free-parameter values in physical units.

        ``divergence``: ``"raise"`` (a RuntimeError when any row's simulation diverges) or
        ``"mask"`` (the rows whose simulation diverged are NaN, the others unaffected).
        """
        return np.array(self._map(X, True, divergence))

    def costs_by_run(self, r: np.ndarray) -> np.ndarray:
        """Sum of squares of each run's part of one residual vector ``r`` (in the order of ``runs``)."""
        sizes = [tg.residual_size(self.weights) for tg in self.spec.targets]
        return np.array([float(part @ part) for part in np.split(r, np.cumsum(sizes)[:-1])])

    def start_pose_sensitivity(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Derivatives of residuals ``r`` by every run's start pose, and its uncertainties
        (:func:`start_pose_sensitivity`)."""
        return start_pose_sensitivity(self.spec, r)

    def residual_blocks(self) -> list[np.ndarray]:
        """Per run, ``(S, 13)`` indices of its residuals by sample time and channel
        (:func:`residual_blocks`)."""
        return residual_blocks(self.spec)

    def current_rows(self) -> np.ndarray:
        """See :func:`current_rows`."""
        return current_rows(self.spec)

    def head_gaps(self) -> np.ndarray:
        """Residuals that are motion-capture gaps (:func:`head_gaps`)."""
        return head_gaps(self.spec)

    def terms(self, X: np.ndarray, divergence: Divergence = "raise") -> list[ObjectiveTerms | None]:
        """The paper's reward terms for each row of X (with ``divergence="mask"``, None for a
        row whose simulation diverged; see :meth:`residuals`)."""
        return self._map(X, False, divergence)

    def __call__(self, x: np.ndarray) -> float:
        """Scalar objective (external + internal) of one parameter vector."""
        return self.terms(np.atleast_2d(x))[0].total
