"""Identification by PPO (stable-baselines3) on :class:`sysid.identification.env.ParameterTuningEnv`.

The paper tunes the parameters with Proximal Policy Optimization: the state is the parameter
vector, an action modifies it and the reward is the negative identification objective. Here
``n_envs`` copies of the environment run in as many processes (``SubprocVecEnv``; in-process
``DummyVecEnv`` for one), each with its own in-process copy of the objective; the policy and
value networks are small MLPs and a rollout is short (``n_steps`` per environment), so several
policy updates fit in a budget of a few hundred objective evaluations.

PPO is used as the paper uses it, as a search: what is returned is the best parameter vector
any environment evaluated while training (the environments keep track of it; it is collected
after every rollout), not the policy's final suggestion. PPO gives no covariance, so the
report carries no confidence intervals.

Every evaluation runs on one thread (:func:`single_threaded`), and so does torch during the fit
(both restored afterwards): ``n_envs`` processes use ``n_envs`` cores.

Determinism: the same seed and ``n_envs`` give the same result when training stops on
``total_timesteps``. Torch's reductions do not depend on a thread count, the environments are
seeded ``seed, seed + 1, ...`` and a vectorised step waits for every environment, so process
scheduling changes nothing. A fit stopped by ``budget_seconds`` ends at a time-dependent step
and is not reproducible.
"""
from __future__ import annotations

import dataclasses
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import gymnasium as gym
import numba
import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters
from sysid.identification.env import ParameterTuningEnv
from sysid.identification.executor import LocalExecutor
from sysid.identification.lsq import FitResult, FitStatus, ParameterReport
from sysid.identification.objective import Objective, ObjectiveTerms

#: A unit coordinate closer than this to 0 or 1 counts as at a bound (as in :mod:`sysid.identification.lsq`).
AT_BOUND_UNIT = 1e-3


@dataclass(frozen=True)
class PPOSettings:
    """Environment and PPO settings of :func:`fit_ppo` (documented defaults).

    Each episode starts from the best parameters found so far (``start_from_best``) and lasts
    two steps, so that most evaluations are spent near the best parameters instead of wandering
    from the paper's fixed start; the policy starts narrow (``log_std_init`` -1) and observes the
    unit coordinates only. How each default was chosen, with the measurements, is in
    ``CHANGELOG.md`` ("PPO settings: how the defaults were chosen").

    Attributes:
        episode_length: environment steps (objective evaluations) per episode.
        max_step: largest change of a unit coordinate per step.
        start_jitter: half-width of the uniform start offset in unit coordinates.
        observe_terms: the observation carries the normalised objective terms besides ``z``.
        start_from_best: episodes start from the environment's best parameters so far.
        n_steps: steps per environment between policy updates (a multiple of
            ``episode_length`` keeps rollouts aligned with episodes).
        n_minibatches: minibatches per PPO epoch (the batch is ``n_steps * n_envs``).
        n_epochs: passes over a rollout per update.
        learning_rate: Adam step size.
        gamma: discount factor.
        gae_lambda: GAE parameter.
        clip_range: PPO's epsilon.
        log_std_init: initial log standard deviation of the Gaussian policy (in action units).
        hidden: hidden layer widths of the policy and of the value network.
    """

    episode_length: int = 2
    max_step: float = 0.1
    start_jitter: float = 0.0
    observe_terms: bool = False
    start_from_best: bool = True
    n_steps: int = 16
    n_minibatches: int = 2
    n_epochs: int = 10
    learning_rate: float = 1e-3
    gamma: float = 0.9
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    log_std_init: float = -1.0
    hidden: tuple[int, ...] = (32, 32)

    def env_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :class:`sysid.identification.env.ParameterTuningEnv`."""
        return {"episode_length": self.episode_length, "max_step": self.max_step,
                "start_jitter": self.start_jitter, "observe_terms": self.observe_terms,
                "start_from_best": self.start_from_best}


@dataclass(frozen=True)
class EnvFactory:
    """Builds one monitored environment; picklable, so ``SubprocVecEnv`` sends it to a worker.

    The calling thread's numba kernels are set to one thread (see :func:`single_threaded`).

    Attributes:
        objective: the objective (a :func:`single_threaded` copy; each worker unpickles its own).
        env_kwargs: keyword arguments of :class:`sysid.identification.env.ParameterTuningEnv`.
    """

    objective: Objective
    env_kwargs: dict[str, Any]

    def __call__(self) -> gym.Env:
        numba.set_num_threads(1)
        return Monitor(ParameterTuningEnv(self.objective, **self.env_kwargs))


def single_threaded(objective: Objective) -> Objective:
    """An in-process copy of ``objective`` whose batched simulation runs on one thread.

    The environments are the parallelism of :func:`fit_ppo`. Threads inside an evaluation
    (Pinocchio's ABA pool, which :class:`sysid.identification.objective.Objective` sizes to 2 for an in-process
    executor, and numba's ``prange`` kernels, sized by :func:`numba.set_num_threads`) meet at a
    barrier every physics step, so they stall whenever another process holds a core: measured
    with one core busy, a 0.5 s run took 0.12-0.35 s per evaluation with two threads and
    0.016 s with one (0.016 s either way on an idle machine).
    """
    return dataclasses.replace(objective, executor=LocalExecutor(1), threads=1, evaluations=0)


@dataclass(frozen=True)
class _Best:
    """The best parameter vector over all environments."""

    z: np.ndarray
    terms: ObjectiveTerms
    evaluations: int


class _TrainingMonitor(BaseCallback):
    """Collects episode returns and the environments' best, reports progress, enforces the budget."""

    def __init__(self, t_start: float, budget_seconds: float | None,
                 progress: Callable[[int, float, float], None] | None):
        super().__init__()
        self.t_start = t_start
        self.budget_seconds = budget_seconds
        self.progress = progress
        self.over_budget = False
        self.curve: list[tuple[int, float, float]] = []
        self.history: list[tuple[float, int, np.ndarray]] = []
        self.best: _Best | None = None
        self._returns: list[float] = []

    def collect_best(self) -> _Best:
        """Ask every environment for its best; keep the lowest total (first environment on ties)."""
        bests = self.training_env.env_method("best")
        z, terms, _ = min(bests, key=lambda b: b[1].total)
        self.best = _Best(z, terms, sum(b[2] for b in bests))
        return self.best

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            if "episode" in info:
                self._returns.append(float(info["episode"]["r"]))
        if self.budget_seconds is not None and time.perf_counter() - self.t_start > self.budget_seconds:
            self.over_budget = True
            return False
        return True

    def _on_rollout_end(self) -> None:
        self._add_point()

    def finish(self) -> _Best:
        """After training: the final best, and a last curve point if training stopped mid-rollout."""
        if self.best is not None and self.curve and self.curve[-1][0] == self.num_timesteps:
            return self.best
        return self._add_point()

    def _add_point(self) -> _Best:
        """Append (timesteps, mean return of the episodes ended since the last point or NaN if
        none ended, best total) to the curve and report it."""
        best = self.collect_best()
        mean_reward = float(np.mean(self._returns)) if self._returns else float("nan")
        self._returns = []
        self.curve.append((self.num_timesteps, mean_reward, best.terms.total))
        if not self.history or not np.array_equal(self.history[-1][2], best.z):
            self.history.append((time.perf_counter() - self.t_start, self.num_timesteps, best.z.copy()))
        if self.progress is not None:
            self.progress(self.num_timesteps, best.terms.total, mean_reward)
        return best


def fit_ppo(objective: Objective, *, budget_seconds: float | None = None, total_timesteps: int = 1024,
            seed: int = 0, n_envs: int = 2, progress: Callable[[int, float, float], None] | None = None,
            curve_png: str | Path | None = None, settings: PPOSettings = PPOSettings()) -> FitResult:
    """Tune the objective's free parameters with PPO from its parameter set's current values.

    Args:
        objective: the identification objective over the training runs.
        budget_seconds: stop after this wall time [s] (checked every environment step; the
            result then depends on timing).
        total_timesteps: environment steps (objective evaluations) over all environments.
        seed: seeds torch, numpy, the policy and environment ``i`` with ``seed + i``.
        n_envs: environments, each in its own process when more than one.
        progress: called after every rollout (and once more if training stops mid-rollout) with
            (timesteps, best total so far, mean return of the episodes that ended since the
            previous call, NaN if none did).
        curve_png: write the reward curve (:func:`plot_reward_curve`) to this PNG.
        settings: environment and PPO settings.

    Returns:
        FitResult with ``method="ppo"``: the best parameters evaluated, ``cost`` their total
        and ``initial_cost`` the initial one, status ``BUDGET`` or ``MAX_ITERATIONS``
        (timesteps exhausted), no iteration log, no singular values, a report without
        intervals, ``evaluations`` the objective evaluations of all environments (each
        evaluates the initial parameters once; invalid parameter vectors are not evaluated),
        ``seconds`` the wall time including process start-up, and in ``extra``: ``reward_curve``
        (list of (timesteps, mean episode reward, best total)), ``best_history`` (list of
        (seconds since the start, timesteps, best ModelParameters) each time the best changed,
        checked after every rollout), ``timesteps``, ``initial_terms``, ``best_terms``, ``n_envs``, ``seed``.

    With ``n_envs > 1`` the environments run in ``forkserver`` (or ``spawn``) processes, which
    import the calling script: a script calling this must guard its entry point with
    ``if __name__ == "__main__":``.

    Raises:
        InputError: for ``n_envs`` < 1, ``total_timesteps`` < 1 or ``settings.n_steps * n_envs``
            < 2 (PPO needs two samples per update).
    """
    if n_envs < 1:
        raise InputError(f"n_envs must be >= 1, got {n_envs}")
    if total_timesteps < 1:
        raise InputError(f"total_timesteps must be >= 1, got {total_timesteps}")
    batch = settings.n_steps * n_envs
    if batch < 2:
        raise InputError(f"n_steps * n_envs = {batch}: PPO needs at least 2 samples per update")
    t_start = time.perf_counter()
    factories = [EnvFactory(single_threaded(objective), settings.env_kwargs()) for _ in range(n_envs)]
    with _one_thread():
        vec_env: VecEnv = SubprocVecEnv(factories) if n_envs > 1 else DummyVecEnv(factories)
        try:
            model = PPO("MlpPolicy", vec_env, n_steps=settings.n_steps,
                        batch_size=max(1, batch // settings.n_minibatches), n_epochs=settings.n_epochs,
                        learning_rate=settings.learning_rate, gamma=settings.gamma,
                        gae_lambda=settings.gae_lambda, clip_range=settings.clip_range,
                        policy_kwargs={"net_arch": {"pi": list(settings.hidden), "vf": list(settings.hidden)},
                                       "log_std_init": settings.log_std_init},
                        seed=seed, device="cpu", verbose=0)
            monitor = _TrainingMonitor(t_start, budget_seconds, progress)
            model.learn(total_timesteps, callback=monitor)
            best = monitor.finish()
            initial_terms: ObjectiveTerms = vec_env.get_attr("reference_terms")[0]
            timesteps = model.num_timesteps
        finally:
            vec_env.close()
    fitted = objective.params.from_unit(best.z)
    if curve_png is not None:
        plot_reward_curve(monitor.curve, curve_png, initial_total=initial_terms.total)
    return FitResult(
        fitted, FitStatus.BUDGET if monitor.over_budget else FitStatus.MAX_ITERATIONS,
        best.terms.total, initial_terms.total, [], _report(objective.params, fitted, best.z),
        np.empty(0), best.evaluations, time.perf_counter() - t_start, method="ppo",
        extra={"reward_curve": monitor.curve, "timesteps": timesteps, "initial_terms": initial_terms,
               "best_history": [(sec, steps, objective.params.from_unit(z)) for sec, steps, z in monitor.history],
               "best_terms": best.terms, "n_envs": n_envs, "seed": seed},
    )


@contextmanager
def _one_thread() -> Iterator[None]:
    """Torch and this thread's numba kernels on one thread; the previous counts are restored."""
    torch_threads, numba_threads = torch.get_num_threads(), numba.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(torch_threads)
        numba.set_num_threads(numba_threads)


def _report(initial: ModelParameters, fitted: ModelParameters, z: np.ndarray) -> list[ParameterReport]:
    """Per-parameter report: the best value, no interval, identifiable unless at a bound."""
    nominal = ModelParameters.nominal()
    out = []
    for name, zi in zip(fitted.free_names, z):
        at_bound = bool(zi < AT_BOUND_UNIT or zi > 1.0 - AT_BOUND_UNIT)
        value = fitted.value(name)
        out.append(ParameterReport(name, fitted[name].unit, nominal.get(name, initial.value(name)),
                                   initial.value(name), value, float("nan"), float("nan"), at_bound,
                                   not at_bound, "at a bound; no interval (PPO)" if at_bound else "no interval (PPO)"))
    return out


def plot_reward_curve(curve: list[tuple[int, float, float]], out: str | Path, *,
                      initial_total: float | None = None) -> Path:
    """The paper's training-reward figure: mean episode reward and best total vs timesteps.

    Args:
        curve: (timesteps, mean episode reward, best total so far) per rollout, as in
            ``FitResult.extra["reward_curve"]``.
        out: PNG path (parent directories are created, an existing file is replaced).
        initial_total: drawn as a dashed reference on the best-total axis when given.

    Raises:
        InputError: for an empty curve.
    """
    if not curve:
        raise InputError("the reward curve is empty: training stopped before the first rollout ended")
    steps, reward, best = (np.array(c, dtype=float) for c in zip(*curve))
    fig = Figure(figsize=(6.4, 3.8), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    lines = ax.plot(steps, reward, marker=".", color="tab:blue", label="mean episode reward")
    ax.set_xlabel("timesteps (objective evaluations)")
    ax.set_ylabel("mean episode reward", color="tab:blue")
    right = ax.twinx()
    lines += right.plot(steps, best, color="tab:orange", drawstyle="steps-post", label="best total so far")
    if initial_total is not None:
        lines.append(right.axhline(initial_total, color="tab:orange", linestyle="--", label="initial total"))
    right.set_yscale("log")
    right.set_ylabel("best total (external + internal)", color="tab:orange")
    ax.legend(handles=lines, loc="center right", fontsize="small")
    ax.set_title("PPO training reward")
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, format="png", dpi=120)
    return path
