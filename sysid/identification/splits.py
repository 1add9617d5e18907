"""Command-line run sets: run files, or a dataset manifest giving its train/validation split."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

from cobra_model.errors import InputError
from cobra_model.run import Run
from cobra_model.run_files import read_run, run_csv_path
from sysid.generators.dataset import load_manifest


def expand(paths: Sequence[str]) -> tuple[list[Path], list[Path]]:
    """(train, validation) run paths: a ``manifest.json`` contributes its split, a run file trains.

    Raises:
        InputError: naming a path that is neither a manifest nor a run (``NAME``, ``NAME.csv``).
    """
    train: list[Path] = []
    validation: list[Path] = []
    for item in paths:
        p = Path(item)
        if not (p.exists() or run_csv_path(p).exists()):
            raise InputError(f"{item}: no such run CSV or dataset manifest.json")
        if p.suffix == ".json" and p.is_file():
            t, v = load_manifest(p)
            train += t
            validation += v
        else:
            train.append(p)
    return train, validation


def read_runs(paths: Sequence[Path]) -> list[Run]:
    """Read and validate every run (errors name the file)."""
    return [read_run(p) for p in paths]


def spread_over_gaits(runs: Sequence[Run], n: int) -> list[Run]:
    """Up to ``n`` of ``runs`` taken round-robin over their gait frequencies, in order (all of
    them if ``n`` <= 0 or ``n`` >= their number): a subset that keeps every gait."""
    if n <= 0 or n >= len(runs):
        return list(runs)
    by_f: dict[float, list[Run]] = {}
    for r in runs:
        by_f.setdefault(r.gait_frequency_hz, []).append(r)
    out: list[Run] = []
    while len(out) < n:
        for lst in by_f.values():
            if lst and len(out) < n:
                out.append(lst.pop(0))
    return out
