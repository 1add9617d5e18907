"""Shared by the identification benchmarks: held-out measures and PPO's progress line."""
from __future__ import annotations

import sys
from typing import Callable, Sequence

import numpy as np

from cobra_model import ModelParameters
from cobra_model.run import Run
from integrators.simulate import simulate_like
from sysid.gap.metrics import compare_runs


def final_head_errors(runs: Sequence[Run], params: ModelParameters) -> np.ndarray:
    """Final head-position error [m] of each run simulated with ``params``."""
    return np.array([compare_runs(r, simulate_like(r, params=params)).head.final for r in runs])


def time_to_reach(runs: Sequence[Run], history: Sequence[tuple[float, int, ModelParameters]],
                  target_m: float) -> tuple[float, int] | None:
    """(seconds, timesteps) at which a PPO best-so-far first had a summed held-out final head
    error at or below ``target_m`` [m]; None if it never did (``history``: the
    ``best_history`` of :func:`sysid.identification.ppo.fit_ppo`)."""
    for seconds, steps, params in history:
        if final_head_errors(runs, params).sum() <= target_m:
            return seconds, steps
    return None


def ppo_progress(label: str, total: int) -> Callable[[int, float, float], None]:
    """A ``fit_ppo`` progress callback: timesteps, best objective and mean episode reward, to stderr."""
    return lambda steps, best, reward: print(f"{label}: {steps}/{total} timesteps, best objective {best:.4g}, "
                                             f"mean episode reward {reward:.4g}", file=sys.stderr, flush=True)
