"""The paper's parameter-tuning problem as a vector of environments stepped in one batched evaluation.

:class:`sysid.identification.env.ParameterTuningEnv` is one environment: every step simulates
the training runs for one parameter vector. PPO learns from many steps, and one parameter
vector at a time leaves the batched simulator (:class:`integrators.batch.BatchSimulator`, both
cores on many environments at once) idle. :class:`BatchedTuningVecEnv` is a stable-baselines3
``VecEnv`` whose ``n_envs`` environments take their steps together: the ``n_envs`` parameter
vectors of one vectorised step are simulated in one call of
:meth:`sysid.identification.objective.Objective.terms`.
"""
from __future__ import annotations

import time
from typing import Any, Iterable, Sequence

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env import VecEnv

from cobra_model.errors import InputError
from sysid.identification.env import TermsObjective
from sysid.identification.lsq import feasible
from sysid.identification.objective import ObjectiveTerms

#: A proposal's reward is ``-ln(total / best total)`` with the ratio clipped to
#: [1 / WORST_RATIO, WORST_RATIO]; a proposal that is infeasible or makes a simulation diverge
#: gets the floor ``-ln(WORST_RATIO)``. The clip keeps one extreme proposal (a divergence, or a
#: total near zero) from dominating an update's normalised advantages.
WORST_RATIO = 10.0


class BatchedTuningVecEnv(VecEnv):
    """``n_envs`` one-step episodes of parameter tuning, simulated as one batch.

    ## Episode design

    Every episode starts from the best parameter vector found so far (its unit coordinates
    ``z`` in [0, 1]^d are the observation, the same for every environment) and lasts one step:
    the action ``a`` in [-1, 1]^d proposes ``z + a * radius`` (clipped to [0, 1]). The reward is
    ``-ln(total / total_best)``, the objective's external + internal error (paper Eqs. 7 and 8)
    relative to the best so far: positive for an improvement, 0 for none, and scale-free as the
    fit closes in (the totals fall by orders of magnitude over a fit). It lies within
    ``+-ln(WORST_RATIO)``; an infeasible (``mu_s < mu_c``) or diverging proposal gets the floor.
    So PPO's Gaussian policy is a search distribution around the best: its mean learns the
    direction of improvement and its standard deviations the step of each parameter.

    After every vectorised step the best proposal, if it beats the best so far, becomes the
    start of the next episodes. ``radius`` [unit coordinates] starts at ``max_step`` and halves
    whenever ``patience`` consecutive vectorised steps find no improvement (down to
    ``min_step``): near the minimum the cost valley is narrower than the policy's spread, whose
    standard deviation PPO only learns slowly (Adam steps and the clipped ratio bound its change
    per update), so without it most proposals overshoot. It is a trust region in the sense of
    Levenberg-Marquardt's, set by what the samples found, never by the objective's derivatives.

    ## Spaces

    Observation ``Box(0, 1, (d,), float32)``: the best unit coordinates. Action
    ``Box(-1, 1, (d,), float32)``: the proposal's change in units of ``radius``.

    ## Info

    Every step's info carries ``terminal_observation`` (each episode ends after one step) and
    ``episode`` (``r``: the reward, ``l``: 1, ``t``: seconds since construction), as
    stable-baselines3's ``Monitor`` would.

    Args:
        objective: the identification objective; its parameter set's current values are the
            first best and its free parameters are tuned.
        n_envs: environments (parameter vectors per batched evaluation).
        max_step: the first ``radius`` [unit coordinates].
        min_step: the smallest ``radius``.
        patience: vectorised steps without improvement before ``radius`` halves.

    Raises:
        InputError: for ``n_envs`` < 1, ``max_step`` outside (0, 1], ``min_step`` outside
            (0, ``max_step``], ``patience`` < 1, or initial parameters where the objective is
            not finite.
    """

    render_mode = None  # nothing to render

    def __init__(self, objective: TermsObjective, n_envs: int, *, max_step: float = 0.1,
                 min_step: float = 1e-4, patience: int = 2):
        if n_envs < 1:
            raise InputError(f"n_envs must be >= 1, got {n_envs}")
        if not 0.0 < max_step <= 1.0:
            raise InputError(f"max_step must be in (0, 1] (unit coordinates), got {max_step}")
        if not 0.0 < min_step <= max_step:
            raise InputError(f"min_step must be in (0, max_step = {max_step}], got {min_step}")
        if patience < 1:
            raise InputError(f"patience must be >= 1 vectorised step, got {patience}")
        self.objective = objective
        self.min_step = float(min_step)
        self.patience = int(patience)
        self.radius = float(max_step)
        z0 = objective.params.to_unit()
        d = z0.size
        super().__init__(n_envs, spaces.Box(0.0, 1.0, (d,), np.float32), spaces.Box(-1.0, 1.0, (d,), np.float32))
        self.evaluations = 0
        (terms,) = self._evaluate([z0])
        if terms is None:
            raise InputError("the objective is not finite at the initial parameters (invalid, diverging "
                             f"or NaN terms): {objective.params!r}")
        #: Terms at the initial parameters.
        self.reference_terms: ObjectiveTerms = terms
        self.best_z, self.best_terms = z0, terms
        self._stale = 0
        self._actions = np.zeros((n_envs, d))
        self._t0 = time.perf_counter()

    # -- evaluation ---------------------------------------------------------------------------
    def _evaluate(self, Z: Sequence[np.ndarray]) -> list[ObjectiveTerms | None]:
        """Terms of each row of unit coordinates ``Z`` in one batched evaluation (None for an
        infeasible row, a diverging simulation or a non-finite total; a diverging row does not
        stop the others: ``divergence="mask"``)."""
        params = self.objective.params
        ok = [feasible(params, z) for z in Z]
        rows = [params.from_unit(z).as_vector() for z, good in zip(Z, ok) if good]
        out: list[ObjectiveTerms | None] = [None] * len(Z)
        if not rows:
            return out
        self.evaluations += len(rows)
        it = iter(self.objective.terms(np.array(rows), divergence="mask"))
        for i, good in enumerate(ok):
            if good:
                t = next(it)
                out[i] = t if t is not None and np.isfinite(t.total) else None
        return out

    def _observations(self) -> np.ndarray:
        return np.repeat(self.best_z[None].astype(np.float32), self.num_envs, axis=0)

    # -- VecEnv API ---------------------------------------------------------------------------
    def reset(self) -> np.ndarray:
        """Every environment starts at the best parameters so far."""
        return self._observations()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.clip(np.asarray(actions, dtype=float), -1.0, 1.0)

    def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """Simulate the proposals together; reward, move the best, adapt the radius."""
        Z = np.clip(self.best_z[None] + self._actions * self.radius, 0.0, 1.0)
        terms = self._evaluate(list(Z))
        best_total = self.best_terms.total
        totals = np.array([t.total if t is not None else np.inf for t in terms])
        rewards = -np.log(np.clip(totals / best_total, 1.0 / WORST_RATIO, WORST_RATIO))
        k = int(np.argmin(totals))
        if totals[k] < best_total:
            self.best_z, self.best_terms, self._stale = Z[k].copy(), terms[k], 0
        else:
            self._stale += 1
            if self._stale >= self.patience:
                self.radius, self._stale = max(0.5 * self.radius, self.min_step), 0
        obs = self._observations()
        seconds = time.perf_counter() - self._t0
        infos = [{"terminal_observation": obs[i], "episode": {"r": float(rewards[i]), "l": 1, "t": seconds}}
                 for i in range(self.num_envs)]
        return obs, rewards.astype(np.float32), np.ones(self.num_envs, dtype=bool), infos

    def close(self) -> None:
        """Nothing to release: the environments live in this process."""

    def _indices(self, indices: None | int | Iterable[int]) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)

    def get_attr(self, attr_name: str, indices: None | int | Iterable[int] = None) -> list[Any]:
        """The attribute of this object (shared by every environment), once per index."""
        return [getattr(self, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: None | int | Iterable[int] = None) -> None:
        """Set the attribute of this object (shared by every environment)."""
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: None | int | Iterable[int] = None,
                   **method_kwargs) -> list[Any]:
        """Call the method of this object once, its result repeated per index."""
        result = getattr(self, method_name)(*method_args, **method_kwargs)
        return [result] * len(self._indices(indices))

    def env_is_wrapped(self, wrapper_class: type, indices: None | int | Iterable[int] = None) -> list[bool]:
        return [False] * len(self._indices(indices))
