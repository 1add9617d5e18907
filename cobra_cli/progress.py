"""Progress display for long jobs (a tqdm bar on stderr)."""
from __future__ import annotations

from contextlib import contextmanager
from typing import Callable, Iterator

from tqdm import tqdm


@contextmanager
def progress_bar(desc: str, total: float = 1.0, unit: str = "") -> Iterator[Callable[[float], None]]:
    """Yield a callback taking the fraction done (0..1) and drawing a bar on stderr (if a terminal)."""
    with tqdm(total=100, desc=desc, unit=unit or "%", leave=False, dynamic_ncols=True,
              disable=None) as bar:  # disable=None: no bar when stderr is not a terminal
        def update(fraction: float) -> None:
            target = int(round(100 * min(max(fraction, 0.0), 1.0)))
            if target > bar.n:
                bar.update(target - bar.n)
        yield update
