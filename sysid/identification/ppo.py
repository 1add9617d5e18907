"""Identification by PPO (stable-baselines3) on :class:`sysid.identification.vec_env.BatchedTuningVecEnv`.

The paper tunes the parameters with Proximal Policy Optimization: the state is the parameter
vector, an action modifies it and the reward is the negative identification objective. Here
``n_envs`` environments take their steps together, so that one vectorised step is one batched
simulation of ``n_envs`` parameter vectors (:class:`integrators.batch.BatchSimulator`, both
cores); each episode is one modification of the best parameters so far, rewarded by how much
it lowers the objective (the episode design is the vector environment's docstring's). The
policy and value networks are small MLPs and a rollout is short (``n_steps`` per
environment), so that the policy is updated after every few batches.

Each evaluation simulates ``episode_runs`` of the training runs, spread over the gait
frequencies (:func:`sysid.identification.splits.spread_over_gaits`): a batch of proposals
costs what one evaluation on every run would, and the search needs many. The best parameters
are evaluated on every training run at the end, for the result's cost.

PPO is used as the paper uses it, as a search: what is returned is the best parameter vector
evaluated while training, not the policy's final suggestion. PPO gives no covariance, so the
report carries no confidence intervals.

Determinism: the same seed, ``n_envs`` and settings give the same result when training stops on
``total_timesteps`` (the batched simulation is deterministic and torch runs on one thread
during the fit). A fit stopped by ``budget_seconds`` ends at a time-dependent step and is not
reproducible.
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger

from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters
from sysid.identification.lsq import FitResult, FitStatus, ParameterReport
from sysid.identification.objective import Objective, ObjectiveTerms
from sysid.identification.splits import spread_over_gaits
from sysid.identification.vec_env import BatchedTuningVecEnv

#: A unit coordinate closer than this to 0 or 1 counts as at a bound (as in :mod:`sysid.identification.lsq`).
AT_BOUND_UNIT = 1e-3


@dataclass(frozen=True)
class PPOSettings:
    """Environment and PPO settings of :func:`fit_ppo` (documented defaults).

    How the defaults were chosen, with the measurements, is in ``CHANGELOG.md`` ("PPO on the
    batched simulator").

    Attributes:
        episode_runs: training runs each evaluation simulates, spread over the gaits (0: all).
        max_step: the proposals' first radius [unit coordinates] (:class:`BatchedTuningVecEnv`).
        min_step: their smallest radius.
        patience: vectorised steps without improvement before the radius halves.
        n_steps: vectorised steps between policy updates (the batch is ``n_steps * n_envs``).
        n_minibatches: minibatches per PPO epoch.
        n_epochs: passes over a rollout per update.
        learning_rate: Adam step size.
        clip_range: PPO's epsilon.
        log_std_init: initial log standard deviation of the Gaussian policy (in action units).
        hidden: hidden layer widths of the policy and of the value network.
    """

    episode_runs: int = 6
    max_step: float = 0.1
    min_step: float = 1e-4
    patience: int = 2
    n_steps: int = 2
    n_minibatches: int = 2
    n_epochs: int = 10
    learning_rate: float = 3e-3
    clip_range: float = 0.2
    log_std_init: float = -1.0
    hidden: tuple[int, ...] = (32, 32)


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
        """The vector environment's best so far."""
        env = self.training_env
        z, terms, evaluations = (env.get_attr(name)[0] for name in ("best_z", "best_terms", "evaluations"))
        self.best = _Best(z.copy(), terms, evaluations)
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


def fit_ppo(objective: Objective, *, budget_seconds: float | None = None, total_timesteps: int = 2048,
            seed: int = 0, n_envs: int = 32, progress: Callable[[int, float, float], None] | None = None,
            curve_png: str | Path | None = None, settings: PPOSettings = PPOSettings()) -> FitResult:
    """Tune the objective's free parameters with PPO from its parameter set's current values.

    Args:
        objective: the identification objective over the training runs.
        budget_seconds: stop after this wall time [s] (checked every vectorised step; the
            result then depends on timing).
        total_timesteps: environment steps (proposals, each one parameter vector simulated on
            ``settings.episode_runs`` runs) over all environments.
        seed: seeds torch, numpy and the policy.
        n_envs: environments stepped together (parameter vectors per batched simulation).
        progress: called after every rollout (and once more if training stops mid-rollout) with
            (timesteps, best total so far, mean return of the episodes that ended since the
            previous call, NaN if none did).
        curve_png: write the reward curve (:func:`plot_reward_curve`) to this PNG.
        settings: environment and PPO settings.

    Returns:
        FitResult with ``method="ppo"``: the best parameters evaluated, ``cost`` their total
        and ``initial_cost`` the initial one (both on every run of ``objective``), status
        ``BUDGET`` or ``MAX_ITERATIONS`` (timesteps exhausted), no iteration log, no singular
        values, a report without intervals, ``evaluations`` the parameter vectors simulated
        (invalid ones are not), ``seconds`` the wall time, and in ``extra``: ``reward_curve``
        (list of (timesteps, mean episode reward, best total on the episodes' runs)),
        ``best_history`` (list of (seconds since the start, timesteps, best ModelParameters)
        each time the best changed, checked after every rollout), ``timesteps``,
        ``initial_terms``, ``best_terms`` (on every run), ``n_envs``, ``seed``, ``episode_runs``.

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
    runs = spread_over_gaits(objective.runs, settings.episode_runs)
    episodes = objective if len(runs) == len(objective.runs) else objective.on_runs(runs)
    vec_env = BatchedTuningVecEnv(episodes, n_envs, max_step=settings.max_step, min_step=settings.min_step,
                                  patience=settings.patience)
    with _one_thread():
        model = PPO("MlpPolicy", vec_env, n_steps=settings.n_steps,
                    batch_size=max(2, batch // settings.n_minibatches), n_epochs=settings.n_epochs,
                    learning_rate=settings.learning_rate, clip_range=settings.clip_range,
                    policy_kwargs={"net_arch": {"pi": list(settings.hidden), "vf": list(settings.hidden)},
                                   "log_std_init": settings.log_std_init},
                    seed=seed, device="cpu", verbose=0)
        # a logger with no outputs: SB3's default at verbose 0 still makes an empty SB3-<date>
        # folder in the temporary directory on every fit
        model.set_logger(Logger(folder=None, output_formats=[]))
        monitor = _TrainingMonitor(t_start, budget_seconds, progress)
        model.learn(total_timesteps, callback=monitor)
    best = monitor.finish()
    fitted = objective.params.from_unit(best.z)
    evaluations = best.evaluations
    if episodes is objective:
        initial_terms, best_terms = vec_env.reference_terms, best.terms
    else:  # the result's cost is on every training run
        initial_terms, best_terms = objective.terms(np.array([objective.params.as_vector(), fitted.as_vector()]))
        evaluations += 2
    if curve_png is not None:
        plot_reward_curve(monitor.curve, curve_png, initial_total=vec_env.reference_terms.total)
    return FitResult(
        fitted, FitStatus.BUDGET if monitor.over_budget else FitStatus.MAX_ITERATIONS,
        best_terms.total, initial_terms.total, [], _report(objective.params, fitted, best.z),
        np.empty(0), evaluations, time.perf_counter() - t_start, method="ppo",
        extra={"reward_curve": monitor.curve, "timesteps": model.num_timesteps, "initial_terms": initial_terms,
               "best_history": [(sec, steps, objective.params.from_unit(z)) for sec, steps, z in monitor.history],
               "best_terms": best_terms, "n_envs": n_envs, "seed": seed, "episode_runs": len(runs)},
    )


@contextmanager
def _one_thread() -> Iterator[None]:
    """Torch on one thread (its networks are tiny; the cores are the batched simulation's); the
    previous count is restored."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


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
