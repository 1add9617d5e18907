"""Batched rollouts kept for reuse within a scope: a later request for a rollout already run (or
for the first part of one) is answered from it, bit for bit what running it again would give.

A rollout is deterministic in what the batch hands its kernel (the rigid-body model, the
actuator and ground arrays, the step, gains and contact law, the initial state and servo state,
the goal sequence), so a request that matches a kept rollout in all of those, for no more steps
than it ran, has its answer in that rollout's records: the records up to its own last step,
and its final state as the record at that step (so the step count must be a whole number of
record periods, or the kept rollout's own). A diagnosis asks for such rollouts again and again
(the held-out runs of a model it already judged, the same start of a fit in a later stage), so
:func:`sysid.discrepancy.diagnose.diagnose` runs inside :func:`memoised_rollouts`. Outside such
a scope nothing is kept.

Each kept rollout holds a reference to its rigid-body model, whose identity is part of the key
(models are one object per value), so the identity is never reused while the entry lives.
"""
from __future__ import annotations

from collections import OrderedDict
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from typing import Iterator

import numpy as np


@dataclass(frozen=True)
class KeptRollout:
    """One rollout as the batch ran it.

    Attributes:
        steps: physics steps it ran.
        goals: (n_ticks, nj) [rad] the goal ticks it read (ticks ``0 .. (steps - 1) // substeps``, and more).
        record: (steps // every + 1, nq + nv + nj) its records (NaN after a divergence).
        q, v: its final configuration (nq,) and velocity (nv,).
        status, failed_at: the kernel's status and the step it stopped at.
        work: its workspace row at the end (the contact points of a divergence message).
        model: the rigid-body model it stepped (kept alive: its identity is in the key).
    """

    steps: int
    goals: np.ndarray
    record: np.ndarray
    q: np.ndarray
    v: np.ndarray
    status: int
    failed_at: int
    work: np.ndarray
    model: object


class RolloutMemo:
    """Kept rollouts by key (everything but the goal sequence and the step count), the most
    recently used last; at most ``max_rollouts`` rollouts (a 6 s rollout recorded at 10 Hz
    holds 23 kB of records; the goal ticks are shared by the rollouts of a sequence), the
    least recently used dropped first."""

    def __init__(self, max_rollouts: int = 4000):
        if max_rollouts < 1:
            raise ValueError(f"max_rollouts must be >= 1, got {max_rollouts}")
        self.max_rollouts = max_rollouts
        self._kept: OrderedDict[tuple, list[KeptRollout]] = OrderedDict()
        self._count = 0
        self.hits = 0
        self.misses = 0

    def find(self, key: tuple, goals: np.ndarray, steps: int, every: int, substeps: int) -> KeptRollout | None:
        """A kept rollout that answers a request of ``steps`` steps recorded every ``every``
        steps with the goal sequence ``goals`` (n_ticks, nj), or None: same key, at least as many
        steps (exactly as many unless ``steps`` is a multiple of ``every``: the final state is
        then a record) and the same goal ticks where a rollout of ``steps`` steps reads them
        (ticks ``0 .. (steps - 1) // substeps``: its last step only integrates and records)."""
        kept = self._kept.get(key)
        if kept is not None:
            m = (steps - 1) // substeps + 1 if steps > 0 else 0
            for r in kept:
                if (r.steps == steps or (r.steps > steps and steps % every == 0)) \
                        and np.array_equal(r.goals[:m], goals[:m]):
                    self._kept.move_to_end(key)
                    self.hits += 1
                    return r
        self.misses += 1
        return None

    def keep(self, key: tuple, rollout: KeptRollout) -> None:
        """Keep ``rollout`` under ``key``, dropping the least recently used beyond the bound."""
        self._kept.setdefault(key, []).append(rollout)
        self._kept.move_to_end(key)
        self._count += 1
        while self._count > self.max_rollouts:
            _, dropped = self._kept.popitem(last=False)
            self._count -= len(dropped)


_ACTIVE: ContextVar[RolloutMemo | None] = ContextVar("rollout_memo", default=None)


def active_memo() -> RolloutMemo | None:
    """The memo of the innermost :func:`memoised_rollouts` scope, or None outside one."""
    return _ACTIVE.get()


@contextmanager
def memoised_rollouts(max_rollouts: int = 4000) -> Iterator[RolloutMemo]:
    """A scope in which batched rollouts are kept and reused (:class:`RolloutMemo`); nested
    scopes share the outer one's memo."""
    outer = _ACTIVE.get()
    if outer is not None:
        yield outer
        return
    memo = RolloutMemo(max_rollouts)
    token = _ACTIVE.set(memo)
    try:
        yield memo
    finally:
        _ACTIVE.reset(token)
