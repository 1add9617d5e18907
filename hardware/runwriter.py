"""Crash-safe, row-by-row writer of a run in the ``cobra-run/1`` format.

:func:`cobra_model.run_files.write_run` writes a finished run in one go; a recording must instead
survive a crash, a Ctrl-C or a pulled cable with every sample received so far on disk. This
writer therefore:

* writes the header at creation and each sample as one complete line, flushed at once; a
  thread of its own calls ``os.fsync`` every ``fsync_interval_s`` when lines were written (and
  :meth:`IncrementalRunWriter.close` once more), so that the caller, a control loop, never
  waits for the device (an SD card's fsync can take hundreds of milliseconds, longer than the
  servos' Bus Watchdog);
* writes the JSON sidecar at creation with a note ``"partial run: recording did not finish
  ..."``, so a file left by a killed process still reads as a (partial) run, and replaces it
  atomically at :meth:`IncrementalRunWriter.close` with the final metadata and notes;
* when a line cannot be written (a full disk, a failing device), cuts the file back to the last
  complete line and raises :class:`RunWriteError`; a sidecar that cannot be replaced at close
  is left as it was (it still says the recording did not finish).

The column layout is exactly that of :func:`cobra_model.run_files.write_run` for a run with joint
velocities and currents, no other tracked bodies and one extra column: ``t, q_ref_1..11, q_1..11,
dq_1..11, current_1..11, head_x, head_y, head_z, head_qw, head_qx, head_qy, head_qz,
read_latency_s``. Motion capture is merged later, so the ``head_*`` cells are left empty (missing
samples). ``read_latency_s`` (DATA_FORMAT.md allows extra columns) is how long after ``t`` (the
goal sent) the sample's present state was received [s]: the state describes the joints at some
time in ``[t, t + read_latency_s]``, so a reading the host delayed can be told from a joint that
lagged.
"""
from __future__ import annotations

import errno
import json
import os
import threading
from pathlib import Path
from typing import Any, BinaryIO, Mapping, Sequence

import numpy as np

from cobra_model.errors import InputError
from cobra_model.run import FORMAT, NUM_JOINTS, body_columns, joint_columns
from cobra_model.run_files import json_default

#: Head orientation columns (w, x, y, z), as in ``DATA_FORMAT.md``.
HEAD_QUAT_COLUMNS = ("head_qw", "head_qx", "head_qy", "head_qz")
#: Extra column: goal sent -> present state received, per sample [s].
READ_LATENCY_COLUMN = "read_latency_s"
#: Every column written, in order.
COLUMNS: tuple[str, ...] = (
    "t", *joint_columns("q_ref"), *joint_columns("q"), *joint_columns("dq"), *joint_columns("current"),
    *body_columns("head"), *HEAD_QUAT_COLUMNS, READ_LATENCY_COLUMN,
)
#: Sidecar note of a run whose recorder never closed it (crash, kill, power loss).
UNFINISHED_NOTE = ("partial run: recording did not finish (the recorder stopped without closing "
                   "the run: crash, kill or power loss); every row on disk was received")
_EMPTY_MOCAP = "," * (len(body_columns("head")) + len(HEAD_QUAT_COLUMNS))


class RunWriteError(Exception):
    """A sample could not be written (full disk, failing device); the file holds every sample
    before it, complete."""


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
        #: Whether :meth:`close` replaced the sidecar (False: it could not be written).
        self.sidecar_updated = False
        #: Why the sidecar could not be replaced, or None.
        self.sidecar_error: str | None = None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._write_sidecar({**self.meta, "notes": [*self.meta.get("notes", []), UNFINISHED_NOTE]})
        # unbuffered: a line is one write, so nothing half-written waits in a buffer
        self._fh = self._open("wb" if force else "xb")
        self._committed = 0  # bytes of complete lines on disk
        self._write_line(",".join(COLUMNS))
        self._sync()
        self._written = threading.Event()  # lines written since the syncing thread's last fsync
        self._closing = threading.Event()
        self._sync_error: OSError | None = None
        self._syncer = threading.Thread(target=self._sync_every, args=(fsync_interval_s,),
                                        name=f"fsync {self.path.name}", daemon=True)
        self._syncer.start()

    def _open(self, mode: str) -> BinaryIO:
        """The CSV file, unbuffered binary (a seam for tests that make the disk fail)."""
        return self.path.open(mode, buffering=0)

    def _write_line(self, line: str) -> None:
        """Write one complete line or, failing, cut the file back to the last complete one."""
        data = (line + "\n").encode("ascii")
        view = memoryview(data)
        try:
            while view:
                view = view[self._fh.write(view):]
        except OSError as exc:
            try:
                os.ftruncate(self._fh.fileno(), self._committed)
            except OSError:
                pass
            what = "the disk is full" if exc.errno in (errno.ENOSPC, errno.EDQUOT) else "the write failed"
            raise RunWriteError(f"cannot write sample {self.rows + 1} to {self.path}: {what} ({exc.strerror}); "
                                f"the file keeps the {self.rows} samples before it") from exc
        self._committed += len(data)

    def append(self, t: float, q_ref: np.ndarray, q: np.ndarray, dq: np.ndarray, current: np.ndarray,
               read_latency_s: float) -> None:
        """Write one sample: time [s], commanded and measured angles [rad], velocities [rad/s]
        and currents [A], each (11,), and how long after ``t`` the state was received [s]. The
        line is handed to the OS at once.

        Raises:
            RunWriteError: the line could not be written (the file keeps the samples before it),
                or the syncing thread's last fsync failed (a failing device).
        """
        if self._sync_error is not None:
            raise RunWriteError(f"cannot sync {self.path} to the device ({self._sync_error.strerror or self._sync_error}); "
                                f"{self.rows} samples written, the last ones possibly not on disk")
        for name, arr in (("q_ref", q_ref), ("q", q), ("dq", dq), ("current", current)):
            if np.shape(arr) != (NUM_JOINTS,):
                raise ValueError(f"{name}: expected shape ({NUM_JOINTS},), got {np.shape(arr)}")
        line = (",".join((repr(float(t)), _cells(q_ref), _cells(q), _cells(dq), _cells(current)))
                + _EMPTY_MOCAP + "," + repr(float(read_latency_s)))
        self._write_line(line)
        self.rows += 1
        self._written.set()

    def count_rows(self) -> int:
        """Sync the file and count the samples on disk (``rows``): a signal between writing a
        line and counting it must not make the sidecar disagree with the file."""
        try:
            self._sync()
        except OSError:
            pass  # a failing device: count what it holds
        with self.path.open("r", encoding="utf-8") as fh:
            self.rows = sum(1 for _ in fh) - 1
        return self.rows

    def close(self, *, notes: Sequence[str] = (), meta: Mapping[str, Any] | None = None) -> None:
        """Flush and sync the CSV, then replace the sidecar with the final metadata.

        Args:
            notes: sidecar ``"notes"`` (e.g. ``"partial run: <reason>"`` when stopped early).
            meta: keys merged into the metadata given at creation.

        A sidecar that cannot be written (full disk) is left as it was, still noting that the
        recording did not finish (``sidecar_updated`` False, ``sidecar_error`` why).
        """
        if self._fh.closed:
            return
        self._closing.set()
        self._syncer.join()
        self.count_rows()
        self._fh.close()
        self.meta.update(meta or {})
        final = {**self.meta, "notes": [*self.meta.get("notes", []), *notes]}
        if not final["notes"]:
            del final["notes"]
        try:
            self._write_sidecar(final)
        except OSError as exc:
            self.sidecar_error = f"{self.sidecar} could not be updated ({exc.strerror or exc})"
            return
        self.sidecar_updated = True

    def _sync(self) -> None:
        os.fsync(self._fh.fileno())

    def _sync_every(self, interval_s: float) -> None:
        """The syncing thread: fsync the CSV every ``interval_s`` [s] while lines come, until
        :meth:`close`; a failed fsync ends it and is raised by the next :meth:`append`."""
        while not self._closing.wait(interval_s):
            if self._written.is_set():
                self._written.clear()
                try:
                    self._sync()
                except OSError as exc:
                    self._sync_error = exc
                    return

    def _write_sidecar(self, meta: Mapping[str, Any]) -> None:
        """Write the sidecar atomically (temporary file, fsync, rename)."""
        tmp = self.sidecar.with_name(self.sidecar.name + ".tmp")
        try:
            with tmp.open("w", encoding="utf-8") as fh:
                json.dump(meta, fh, indent=2, default=json_default)
                fh.write("\n")
                fh.flush()
                os.fsync(fh.fileno())
        except OSError:
            tmp.unlink(missing_ok=True)
            raise
        os.replace(tmp, self.sidecar)
