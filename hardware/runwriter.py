"""Crash-safe, row-by-row writer of a run in the ``cobra-run/1`` format.

:func:`cobra_model.runs.write_run` writes a finished run in one go; a recording must instead
survive a crash, a Ctrl-C or a pulled cable with every sample received so far on disk. This
writer therefore:

* writes the header at creation and each sample as one complete line, flushed at once, with
  ``os.fsync`` at most every ``fsync_interval_s`` (and at close);
* writes the JSON sidecar at creation with a note ``"partial run: recording did not finish
  ..."``, so a file left by a killed process still reads as a (partial) run, and replaces it
  atomically at :meth:`IncrementalRunWriter.close` with the final metadata and notes.

The column layout is exactly that of :func:`cobra_model.runs.write_run` for a run with joint
velocities and currents and no other tracked bodies: ``t, q_ref_1..11, q_1..11, dq_1..11,
current_1..11, head_x, head_y, head_z, head_qw, head_qx, head_qy, head_qz``. Motion capture is
merged later, so the ``head_*`` cells are left empty (missing samples).
"""
from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from cobra_model.errors import InputError
from cobra_model.runs import FORMAT, NUM_JOINTS, body_columns, joint_columns, json_default

#: Head orientation columns (w, x, y, z), as in ``DATA_FORMAT.md``.
HEAD_QUAT_COLUMNS = ("head_qw", "head_qx", "head_qy", "head_qz")
#: Every column written, in order.
COLUMNS: tuple[str, ...] = (
    "t", *joint_columns("q_ref"), *joint_columns("q"), *joint_columns("dq"), *joint_columns("current"),
    *body_columns("head"), *HEAD_QUAT_COLUMNS,
)
#: Sidecar note of a run whose recorder never closed it (crash, kill, power loss).
UNFINISHED_NOTE = ("partial run: recording did not finish (the recorder stopped without closing "
                   "the run: crash, kill or power loss); every row on disk was received")
_EMPTY_MOCAP = "," * (len(body_columns("head")) + len(HEAD_QUAT_COLUMNS))


def sidecar_path(csv_path: Path) -> Path:
    """``NAME.json`` beside ``NAME.csv``."""
    return csv_path.with_suffix(".json")


def check_run_path(path: str | Path, *, force: bool) -> Path:
    """Validate an output run path before anything is started.

    Raises:
        InputError: the name does not end in ``.csv``.
        FileExistsError: the CSV or its sidecar exists and ``force`` is false.
    """
    path = Path(path)
    if path.suffix.lower() != ".csv":
        raise InputError(f"{path}: a run file name must end in .csv (its sidecar is NAME.json)")
    if not force:
        for target in (path, sidecar_path(path)):
            if target.exists():
                raise FileExistsError(f"{target} already exists; pass --force to overwrite it")
    return path


def _cells(values: np.ndarray) -> str:
    return ",".join(repr(float(x)) for x in values)


class IncrementalRunWriter:
    """Append samples to ``NAME.csv`` as they arrive, keeping ``NAME.json`` valid throughout.

    Args:
        path: the CSV file (``.csv``); parent directories are created.
        meta: sidecar metadata (``"format"`` is added); must be JSON-serialisable.
        force: overwrite an existing run instead of refusing.
        fsync_interval_s: longest time [s] between two ``os.fsync`` of the CSV.

    Raises:
        FileExistsError: the run exists and ``force`` is false.
        InputError: bad file name.
    """

    def __init__(self, path: str | Path, meta: Mapping[str, Any], *, force: bool = False,
                 fsync_interval_s: float = 0.5) -> None:
        self.path = check_run_path(path, force=force)
        self.sidecar = sidecar_path(self.path)
        self.meta: dict[str, Any] = {**meta, "format": FORMAT}
        #: Samples written (exact after :meth:`close`).
        self.rows = 0
        self._fsync_interval_s = fsync_interval_s
        self._last_sync = 0.0
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._write_sidecar({**self.meta, "notes": [*self.meta.get("notes", []), UNFINISHED_NOTE]})
        self._fh = self.path.open("w" if force else "x", encoding="utf-8", newline="")
        self._fh.write(",".join(COLUMNS) + "\n")
        self._sync()

    def append(self, t: float, q_ref: np.ndarray, q: np.ndarray, dq: np.ndarray, current: np.ndarray) -> None:
        """Write one sample: time [s], commanded and measured angles [rad], velocities [rad/s]
        and currents [A], each (11,). The line is flushed to the OS at once.
        """
        for name, arr in (("q_ref", q_ref), ("q", q), ("dq", dq), ("current", current)):
            if np.shape(arr) != (NUM_JOINTS,):
                raise ValueError(f"{name}: expected shape ({NUM_JOINTS},), got {np.shape(arr)}")
        line = ",".join((repr(float(t)), _cells(q_ref), _cells(q), _cells(dq), _cells(current))) + _EMPTY_MOCAP
        self._fh.write(line + "\n")
        self._fh.flush()
        self.rows += 1
        if time.monotonic() - self._last_sync >= self._fsync_interval_s:
            self._sync()

    def count_rows(self) -> int:
        """Sync the file and count the samples on disk (``rows``): a signal between writing a
        line and counting it must not make the sidecar disagree with the file."""
        self._sync()
        with self.path.open("r", encoding="utf-8") as fh:
            self.rows = sum(1 for _ in fh) - 1
        return self.rows

    def close(self, *, notes: Sequence[str] = (), meta: Mapping[str, Any] | None = None) -> None:
        """Flush and sync the CSV, then replace the sidecar with the final metadata.

        Args:
            notes: sidecar ``"notes"`` (e.g. ``"partial run: <reason>"`` when stopped early).
            meta: keys merged into the metadata given at creation.
        """
        if self._fh.closed:
            return
        self.count_rows()
        self._fh.close()
        self.meta.update(meta or {})
        final = {**self.meta, "notes": [*self.meta.get("notes", []), *notes]}
        if not final["notes"]:
            del final["notes"]
        self._write_sidecar(final)

    def _sync(self) -> None:
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._last_sync = time.monotonic()

    def _write_sidecar(self, meta: Mapping[str, Any]) -> None:
        """Write the sidecar atomically (temporary file, fsync, rename)."""
        tmp = self.sidecar.with_name(self.sidecar.name + ".tmp")
        with tmp.open("w", encoding="utf-8") as fh:
            json.dump(meta, fh, indent=2, default=json_default)
            fh.write("\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, self.sidecar)
