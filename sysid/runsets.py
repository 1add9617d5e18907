"""Command-line run sets: run files, or a dataset manifest giving its train/validation split."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

from cobra_model.errors import InputError
from cobra_model.runs import Run, read_run


def expand(paths: Sequence[str]) -> tuple[list[Path], list[Path]]:
    """(train, validation) run paths: a ``manifest.json`` contributes its split, a run file trains."""
    train: list[Path] = []
    validation: list[Path] = []
    for item in paths:
        p = Path(item)
        if p.suffix == ".json" and p.is_file():
            try:
                data = json.loads(p.read_text())
            except json.JSONDecodeError as exc:
                raise InputError(f"{p}: not valid JSON ({exc})") from None
            if not isinstance(data, dict) or "train" not in data:
                raise InputError(f"{p}: a dataset manifest needs \"train\" (and \"validation\") lists of run files")
            train += [p.parent / n for n in data["train"]]
            validation += [p.parent / n for n in data.get("validation", [])]
        else:
            train.append(p)
    return train, validation


def read_runs(paths: Sequence[Path]) -> list[Run]:
    """Read and validate every run (errors name the file)."""
    return [read_run(p) for p in paths]
