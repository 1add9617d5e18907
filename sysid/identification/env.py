"""The paper's reinforcement-learning framework as a Gymnasium environment.

The state is the parameter vector being tuned, the action a bounded modification of it and the
reward the negative identification objective (external + internal errors, paper Eqs. 7 and 8)
of :class:`sysid.identification.objective.Objective`: one environment, one parameter vector
simulated per step, for any Gymnasium learner. :func:`sysid.identification.ppo.fit_ppo` trains
PPO on its batched form, :class:`sysid.identification.vec_env.BatchedTuningVecEnv`, whose
environments take their steps as one batched simulation.
"""
from __future__ import annotations

from typing import Any, Protocol

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters
from integrators.batch import Divergence
from sysid.identification.objective import OBSERVED_TERMS, ObjectiveTerms

#: Observed terms are ``log10(term / reference term)`` clipped to +-this many decades, then
#: divided by it (so each lies in [-1, 1]).
TERM_DECADES = 3.0
#: Added to terms and reference terms before the ratio, so a zero term stays finite [term units].
TERM_FLOOR = 1e-9


class TermsObjective(Protocol):
    """What the environment needs of an objective (:class:`sysid.identification.objective.Objective` has it)."""

    params: ModelParameters

    def terms(self, X: np.ndarray, divergence: Divergence = "raise") -> list[ObjectiveTerms | None]:
        """Objective terms per row of X; a row whose simulation diverges raises a RuntimeError,
        or with ``divergence="mask"`` is None."""
        ...


class ParameterTuningEnv(gym.Env[np.ndarray, np.ndarray]):
    """Tune the free model parameters by small modifications; reward = -(external + internal error).

    ## Description

    The paper's PPO framework (Section "Reinforcement Learning Framework"): the state
    encapsulates the model parameters, the actions are modifications applied to them and the
    reward penalises the deviation of the simulated runs from the measured ones. Every step
    simulates all training runs of the objective with the modified parameters, so one step is
    one objective evaluation.

    Parameters are handled in their unit coordinates ``z`` in [0, 1]^d
    (:meth:`cobra_model.parameters.ModelParameters.to_unit`: linear across the bounds, or
    logarithmic for log-scaled parameters such as ``joint_damping``), ``d`` the number of free
    parameters of ``objective.params``.

    The environment remembers the best (lowest total) parameter vector it has evaluated:
    :attr:`best_z`, :attr:`best_params`, :attr:`best_terms`.

    ## Action Space

    ``Box(-1, 1, (d,), float32)``; action ``a`` moves the parameters by ``dz = a * max_step``
    in unit coordinates, and ``z + dz`` is clipped to [0, 1]:

    | Num   | Action                                    | Min  | Max |
    |-------|-------------------------------------------|------|-----|
    | i     | change of free parameter i / ``max_step`` | -1.0 | 1.0 |

    ## Observation Space

    ``Box(lo, hi, (d,) or (d + 4,), float32)``:

    | Num       | Observation                                               | Min  | Max | Unit |
    |-----------|-----------------------------------------------------------|------|-----|------|
    | 0..d-1    | unit coordinate z_i of free parameter i                   | 0.0  | 1.0 | 1    |
    | d         | head_final_m of the current parameters (see below)        | -1.0 | 1.0 | 1    |
    | d+1       | head_mean_m                                               | -1.0 | 1.0 | 1    |
    | d+2       | joint_rmse_rad                                            | -1.0 | 1.0 | 1    |
    | d+3       | cpg_sq                                                    | -1.0 | 1.0 | 1    |

    The last four are present when ``observe_terms`` is true: the objective terms of the current
    parameters as ``log10(term / reference)`` clipped to +-3 decades and divided by 3, the
    reference being the terms at the initial parameters (so 0 at the start, -1 for a 1000-fold
    improvement).

    ## Rewards

    ``-terms.total`` of the parameters after the step: the objective's weighted external
    (final head position error [m]) plus internal (joint RMSE [rad] and squared CPG errors
    [rad^2]) errors, so 0 is a perfect match. A modification that gives invalid parameters
    (``mu_s < mu_c``), makes a simulation diverge or gives a non-finite total is not applied:
    the parameters stay and the reward is ``-failure_factor`` times the total at the initial
    parameters.

    ## Starting State

    The initial parameters of ``objective.params`` (or, with ``start_from_best``, the best
    parameters this environment has evaluated so far), each unit coordinate jittered by a
    uniform offset in [-start_jitter, start_jitter] (drawn from ``self.np_random``) and clipped
    to [0, 1]. The initial parameters are evaluated once, at construction; a jittered start costs
    one evaluation per reset (and falls back to the initial parameters if it fails).

    ## Episode End

    The episode is truncated after ``episode_length`` steps; it never terminates (there is no
    absorbing state: the objective's minimum is unknown).

    ## Info

    ``reset`` and ``step`` return ``{"z": current unit coordinates, "terms": their objective
    terms, "failed": whether the step's modification was rejected, "best_total": the lowest
    total so far}``.

    ## Arguments

    - ``objective``: an :class:`sysid.identification.objective.Objective` (or anything with ``params`` and
      ``terms``); its free parameters are tuned.
    - ``episode_length``: steps per episode (default 8).
    - ``max_step``: largest change of a unit coordinate per step (default 0.1).
    - ``start_jitter``: half-width of the uniform start offset in unit coordinates (default 0).
    - ``observe_terms``: append the normalised objective terms to the observation (default
      False: the paper's state is the parameters alone, which are a Markov state here since
      the terms are a function of them).
    - ``failure_factor``: penalty of a failed evaluation in units of the initial total (default 2).
    - ``start_from_best``: episodes start from the best parameters so far rather than the
      initial ones (default False: the paper's fixed start).

    Raises:
        InputError: for a non-positive ``episode_length``, ``max_step`` outside (0, 1],
            ``start_jitter`` outside [0, 1], a ``failure_factor`` below 1, or initial
            parameters where the objective is not finite.
    """

    metadata = {"render_modes": []}

    def __init__(self, objective: TermsObjective, *, episode_length: int = 8, max_step: float = 0.1,
                 start_jitter: float = 0.0, observe_terms: bool = False, failure_factor: float = 2.0,
                 start_from_best: bool = False):
        if episode_length < 1:
            raise InputError(f"episode_length must be >= 1 step, got {episode_length}")
        if not 0.0 < max_step <= 1.0:
            raise InputError(f"max_step must be in (0, 1] (unit coordinates), got {max_step}")
        if not 0.0 <= start_jitter <= 1.0:
            raise InputError(f"start_jitter must be in [0, 1] (unit coordinates), got {start_jitter}")
        if failure_factor < 1.0:
            raise InputError(f"failure_factor must be >= 1 (a failure is no better than the start), "
                             f"got {failure_factor}")
        self.objective = objective
        self.episode_length = int(episode_length)
        self.max_step = float(max_step)
        self.start_jitter = float(start_jitter)
        self.observe_terms = bool(observe_terms)
        self.start_from_best = bool(start_from_best)
        self.initial_z = objective.params.to_unit()
        d = self.initial_z.size
        self.action_space = spaces.Box(-1.0, 1.0, (d,), np.float32)
        n_terms = len(OBSERVED_TERMS) if observe_terms else 0
        low = np.concatenate([np.zeros(d), -np.ones(n_terms)]).astype(np.float32)
        high = np.ones(d + n_terms, dtype=np.float32)
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

        self.evaluations = 0
        reference = self._evaluate(self.initial_z)
        if reference is None:
            raise InputError("the objective is not finite at the initial parameters (invalid, diverging "
                             f"or NaN terms): {objective.params!r}")
        #: Terms at the initial parameters: the observation's reference and the failure scale.
        self.reference_terms: ObjectiveTerms = reference
        self.failure_total = failure_factor * reference.total
        self.best_z = self.initial_z.copy()
        self.best_terms: ObjectiveTerms = reference
        self._z = self.initial_z.copy()
        self._terms: ObjectiveTerms = reference
        self._steps = 0

    # -- evaluation ---------------------------------------------------------------------------
    def _evaluate(self, z: np.ndarray) -> ObjectiveTerms | None:
        """Objective terms at unit coordinates ``z``, or None for invalid parameters, a diverging
        simulation or a non-finite total."""
        try:
            x = self.objective.params.from_unit(z).as_vector()
        except InputError:
            return None
        self.evaluations += 1
        try:
            terms = self.objective.terms(x[None, :])[0]
        except RuntimeError:  # integrators.simulator.SimulationDiverged and the batch's divergence
            return None
        return terms if np.isfinite(terms.total) else None

    def _record(self, z: np.ndarray, terms: ObjectiveTerms) -> None:
        """Make ``z`` current and remember it if it is the best so far."""
        self._z, self._terms = z, terms
        if terms.total < self.best_terms.total:
            self.best_z, self.best_terms = z.copy(), terms

    def _observation(self) -> np.ndarray:
        """z, then (with ``observe_terms``) the normalised terms, as float32."""
        if not self.observe_terms:
            return self._z.astype(np.float32)
        ratio = np.log10((self._terms.observed() + TERM_FLOOR) / (self.reference_terms.observed() + TERM_FLOOR))
        scaled = np.clip(ratio, -TERM_DECADES, TERM_DECADES) / TERM_DECADES
        return np.concatenate([self._z, scaled]).astype(np.float32)

    def _info(self, failed: bool) -> dict[str, Any]:
        """The info dict of ``reset`` and ``step`` (see the class docstring)."""
        return {"z": self._z.copy(), "terms": self._terms, "failed": failed, "best_total": self.best_terms.total}

    # -- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None,
              options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        """Start from the (jittered) initial or best parameters; ``options`` are not used."""
        super().reset(seed=seed)
        self._steps = 0
        z, terms = self.initial_z.copy(), self.reference_terms
        if self.start_from_best:
            z, terms = self.best_z.copy(), self.best_terms
        if self.start_jitter > 0.0:
            offset = self.np_random.uniform(-self.start_jitter, self.start_jitter, z.size)
            jittered = np.clip(z + offset, 0.0, 1.0)
            jittered_terms = self._evaluate(jittered)
            if jittered_terms is not None:  # else start from the initial parameters
                z, terms = jittered, jittered_terms
        self._record(z, terms)
        return self._observation(), self._info(False)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Apply ``dz = clip(action, -1, 1) * max_step``, simulate, reward ``-total``."""
        dz = np.clip(np.asarray(action, dtype=float), -1.0, 1.0) * self.max_step
        z = np.clip(self._z + dz, 0.0, 1.0)
        terms = self._evaluate(z)
        self._steps += 1
        truncated = self._steps >= self.episode_length
        if terms is None:
            return self._observation(), -float(self.failure_total), False, truncated, self._info(True)
        self._record(z, terms)
        return self._observation(), -float(terms.total), False, truncated, self._info(False)

    # -- results ------------------------------------------------------------------------------
    @property
    def best_params(self) -> ModelParameters:
        """The best parameters evaluated so far (the initial ones if nothing beat them)."""
        return self.objective.params.from_unit(self.best_z)

    def best(self) -> tuple[np.ndarray, ObjectiveTerms, int]:
        """(best unit coordinates, their terms, evaluations so far): what a vectorised trainer collects."""
        return self.best_z.copy(), self.best_terms, self.evaluations
