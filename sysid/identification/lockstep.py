"""Several independent computations over objectives, their evaluations batched together.

A computation written as a generator yields :class:`Evaluate` requests (an objective and the
rows at which its residuals are wanted) and receives the residuals, or has the evaluation's
error raised at its ``yield``. :func:`run` drives one alone, each request the objective's own
evaluation; :func:`run_together` drives several in lock-step: at each turn the pending
requests of every computation that can share a batched rollout
(:func:`sysid.identification.objective.shares_batch`) step in one.

Why: a least-squares trial step or a held-out cost is one environment per run, a batch of a
few environments, which leaves a thread idle once its share is done and pays each call's
overhead for little physics. Independent fits that take their steps together (the discrepancy
workflow's candidate effects, each refitted from its own start) fill one batch instead. Every
environment steps exactly as it would alone
(:func:`~sysid.identification.objective.simulate_together`), so results are bit-for-bit those of
running the computations one after the other.
"""
from __future__ import annotations

from collections.abc import Generator
from dataclasses import dataclass
from typing import Callable, Sequence, TypeVar

import numpy as np

from cobra_model.errors import InputError
from integrators.batch import Divergence
from integrators.simulator import SimulationDiverged
from sysid.identification.objective import Objective, residual_vector, shares_batch, simulate_together

T = TypeVar("T")


@dataclass(frozen=True)
class Evaluate:
    """A request: ``objective``'s residuals at the rows of ``X`` (free-parameter values in
    physical units), with ``divergence`` as in :meth:`Objective.residuals`."""

    objective: Objective
    X: np.ndarray
    divergence: Divergence = "raise"


#: A computation: yields requests, receives each one's (k, m) residuals, returns its result.
Steps = Generator[Evaluate, np.ndarray, T]


def run(steps: Steps[T]) -> T:
    """The result of one computation, each of its requests evaluated on its own."""
    return _drive([steps], lambda requests: [_alone(r) for r in requests])[0]


def unless_diverged(steps: Steps[T], diverged: Callable[[SimulationDiverged], None] = lambda exc: None
                    ) -> Steps[T | None]:
    """``steps``' result, or None when a simulation it asked for diverged and it did not handle
    that itself (a fit whose start no simulation follows), after ``diverged(error)`` (to report
    it): for computations run side by side as alternatives (:func:`run_together`), where one
    that cannot start leaves the others."""
    try:
        return (yield from steps)
    except SimulationDiverged as exc:
        diverged(exc)
        return None


def run_together(computations: Sequence[Steps], finished: Callable[[int], None] = lambda i: None) -> list:
    """The results of several computations (in their order), stepped in lock-step: at each
    turn, the pending requests that can share a batch are one batched rollout. ``finished(i)``
    is called when computation ``i`` has its result (progress)."""
    return _drive(computations, _evaluate_together, finished)


def _drive(computations: Sequence[Steps], evaluate: Callable[[Sequence[Evaluate]], list],
           finished: Callable[[int], None] = lambda i: None) -> list:
    results: list = [None] * len(computations)
    pending: dict[int, Evaluate] = {}

    def advance(i: int, outcome: np.ndarray | BaseException | None) -> None:
        try:
            if isinstance(outcome, BaseException):
                pending[i] = computations[i].throw(outcome)
            elif outcome is None:
                pending[i] = next(computations[i])
            else:
                pending[i] = computations[i].send(outcome)
        except StopIteration as stop:
            pending.pop(i, None)
            results[i] = stop.value
            finished(i)

    for i in range(len(computations)):
        advance(i, None)
    while pending:
        order = sorted(pending)
        outcomes = evaluate([pending[i] for i in order])
        for i, outcome in zip(order, outcomes):
            advance(i, outcome)
    return results


def _alone(request: Evaluate) -> np.ndarray | Exception:
    """The request's residuals from its own objective, or the error that evaluation raised."""
    try:
        return request.objective.residuals(request.X, request.divergence)
    except (InputError, RuntimeError) as exc:
        return exc


def _evaluate_together(requests: Sequence[Evaluate]) -> list[np.ndarray | Exception]:
    """Each request's residuals (or error), the requests that can share a batch in one.

    Objectives spread over several workers are evaluated on their own; a request with a row
    that is no valid parameter vector gets its error, and a batch that fails to start (a
    parameter set no simulator takes) is evaluated request by request, each getting its own
    result or error. A batch steps with divergence masked; a request that wanted ``"raise"``
    and has a diverged row is evaluated again on its own, so that it gets the error (naming
    what blew up) it would have got alone.
    """
    out: list[np.ndarray | Exception | None] = [None] * len(requests)
    groups: list[list[int]] = []
    for i, req in enumerate(requests):
        if req.objective.executor.workers != 1:
            out[i] = _alone(req)
            continue
        try:
            for x in np.atleast_2d(req.X):
                req.objective.params.update_from_vector(x)
        except InputError as exc:
            out[i] = exc
            continue
        group = next((g for g in groups if shares_batch(requests[g[0]].objective.spec, req.objective.spec)), None)
        if group is None:
            groups.append([i])
        else:
            group.append(i)
    for group in groups:
        jobs = [(requests[i].objective.spec, np.atleast_2d(np.asarray(requests[i].X, dtype=float))) for i in group]
        try:
            sims = simulate_together(jobs, divergence="mask")
        except (InputError, RuntimeError):  # a parameter set no simulator takes: each request alone
            for i in group:
                out[i] = _alone(requests[i])
            continue
        for i, (spec, X), done in zip(group, jobs, sims):
            if requests[i].divergence == "raise" and any(s.diverged for s in done):
                out[i] = _alone(requests[i])  # which counts its evaluations
            else:
                requests[i].objective.evaluations += len(X)
                out[i] = np.array([residual_vector(spec, s) for s in done])
    return out
