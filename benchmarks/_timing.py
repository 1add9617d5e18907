"""Wall-time measurement shared by the speed benchmarks."""
from __future__ import annotations

import time
from typing import Callable

import numpy as np


def best_of_rounds(paths: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Each of ``paths`` once per round for ``repeats`` rounds, in turn, after one warm-up call
    each (compiles, fills caches); the best round's wall time [s] of each.

    Rounds rather than back-to-back repeats: this host's speed drifts over seconds (a virtual
    machine beside others), so the repeats of one path taken together can all fall in a slow
    phase that its peer's missed (the same code's soft-law ratio read 0.53 to 0.73 in runs minutes
    apart, 2026-11-27). Spread over the whole run, each path's best sees the same phases."""
    for run in paths.values():
        run()
    best = dict.fromkeys(paths, np.inf)
    for _ in range(repeats):
        for name, run in paths.items():
            t0 = time.perf_counter()
            run()
            best[name] = min(best[name], time.perf_counter() - t0)
    return best
