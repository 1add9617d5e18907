"""Runs in the ``cobra-run/1`` format: the one place that reads and writes run files.

A run is one experiment (see ``DATA_FORMAT.md``): the commanded joint trajectory ``q_ref``, the
measured joint angles ``q``, optional joint velocities and motor currents, and the motion-capture
tracks of the head (position and orientation) and of other bodies. A run file is ``NAME.csv``
with an optional ``NAME.json`` sidecar.

Frames and units: SI and radians; positions are in the world frame (right-handed, ``z`` up,
ground at ``z = 0``); ``head_quat`` is the unit quaternion ``(w, x, y, z)`` rotating head-frame
vectors into the world frame. Motion-capture samples may be NaN where markers dropped out.

Every validation error is a :class:`cobra_model.errors.InputError` naming the file, the column
and/or the row (1-based, the header being row 1) and what was expected.
"""
from __future__ import annotations

import csv
import dataclasses
import difflib
import json
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cobra_model.errors import InputError
from cobra_model.gait import dominant_frequency_hz

#: The run format this module reads and writes (the sidecar's ``"format"`` value).
FORMAT = "cobra-run/1"
#: Number of actuated joints, numbered 1..11 from the head.
NUM_JOINTS = 11
#: Tracked bodies other than the head that a run may carry, in column order.
BODY_NAMES: tuple[str, ...] = tuple(f"link_{k}" for k in range(2, NUM_JOINTS + 1)) + ("tail",)
#: Relative tolerance on ``|q| - 1`` for a unit quaternion.
QUAT_NORM_TOL = 1e-3

_JOINT_PREFIXES = ("q_ref", "q", "dq", "current")
_HEAD_POS_COLUMNS = ("head_x", "head_y", "head_z")
_HEAD_QUAT_COLUMNS = ("head_qw", "head_qx", "head_qy", "head_qz")
_JOINT_COLUMN_RE = re.compile(r"^(q_ref|q|dq|current)_(\d+)$")
_LINK_COLUMN_RE = re.compile(r"^link_(\d+)_([xyz])$")
_TIME_ALIASES = ("time", "times", "t_s", "time_s", "timestamp", "stamp")


def joint_columns(prefix: str) -> tuple[str, ...]:
    """Column names ``prefix_1 .. prefix_11`` (prefix ``q_ref``, ``q``, ``dq`` or ``current``)."""
    return tuple(f"{prefix}_{k}" for k in range(1, NUM_JOINTS + 1))


def body_columns(body: str) -> tuple[str, str, str]:
    """Position column names ``body_x, body_y, body_z`` of a tracked body."""
    return (f"{body}_x", f"{body}_y", f"{body}_z")


def _standard_columns() -> frozenset[str]:
    names: list[str] = ["t", *_HEAD_POS_COLUMNS, *_HEAD_QUAT_COLUMNS]
    for prefix in _JOINT_PREFIXES:
        names.extend(joint_columns(prefix))
    for body in BODY_NAMES:
        names.extend(body_columns(body))
    return frozenset(names)


_STANDARD_COLUMNS = _standard_columns()


def _reserved_name_problem(name: str) -> str | None:
    """Why ``name`` looks like a format column but is not a valid one, or ``None``."""
    match = _JOINT_COLUMN_RE.match(name)
    if match and not 1 <= int(match.group(2)) <= NUM_JOINTS:
        prefix = match.group(1)
        return (
            f"COBRA has {NUM_JOINTS} joints: expected {prefix}_1..{prefix}_{NUM_JOINTS}, "
            f"found joint number {int(match.group(2))}"
        )
    match = _LINK_COLUMN_RE.match(name)
    if match and not 2 <= int(match.group(1)) <= NUM_JOINTS:
        return f"tracked bodies are link_2..link_{NUM_JOINTS} and tail (link_1 is the head)"
    return None


def _closest_name(name: str, candidates: Sequence[str]) -> str | None:
    """The candidate column name that ``name`` was probably misspelled as, or ``None``."""
    lowered = {c.lower(): c for c in candidates}
    if name.lower() in lowered:
        return lowered[name.lower()]
    if name == "t":
        aliases = [a for a in _TIME_ALIASES if a in lowered]
        if aliases:
            return lowered[aliases[0]]
    close = difflib.get_close_matches(name.lower(), list(lowered), n=1, cutoff=0.6)
    return lowered[close[0]] if close else None


# ---------------------------------------------------------------------------------------------
# Validation shared by Run and the file reader.


def first_non_increasing(t: np.ndarray) -> int | None:
    """Index ``i`` of the first sample with ``t[i] <= t[i-1]``; ``None`` if strictly increasing."""
    bad = np.flatnonzero(np.diff(t) <= 0)
    return int(bad[0]) + 1 if bad.size else None


def _quaternion_problems(quat: np.ndarray) -> tuple[int, str] | None:
    """First row of ``quat`` (N, 4) that is partly missing or not unit: ``(row, problem)``."""
    missing = np.isnan(quat)
    partial = np.flatnonzero(missing.any(axis=1) & ~missing.all(axis=1))
    norm_err = np.abs(np.linalg.norm(np.where(missing, 0.0, quat), axis=1) - 1.0)
    non_unit = np.flatnonzero(~missing.any(axis=1) & ~(norm_err <= QUAT_NORM_TOL))
    candidates = []
    if partial.size:
        candidates.append(
            (int(partial[0]), "quaternion partly missing: give all of w, x, y, z or none")
        )
    if non_unit.size:
        i = int(non_unit[0])
        norm = np.linalg.norm(quat[i])
        candidates.append((i, f"quaternion norm {norm:.6g} is not 1 (tolerance {QUAT_NORM_TOL:g})"))
    return min(candidates) if candidates else None


def _as_float_array(name: str, value: Any, shape: tuple[int, ...]) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise InputError(f"Run.{name}: expected a float array of shape {shape}: {exc}") from exc
    if arr.shape != shape:
        raise InputError(f"Run.{name}: expected shape {shape}, got {arr.shape}")
    return arr


def _check_finite_or_nan(name: str, arr: np.ndarray) -> None:
    """Reject infinite entries of a (N, K) array whose missing samples are NaN."""
    bad = np.flatnonzero(np.isinf(arr).any(axis=1))
    if bad.size:
        raise InputError(f"Run.{name}: sample {int(bad[0])} is infinite; expected a number or NaN")


@dataclass(frozen=True)
class Run:
    """One experiment in the ``cobra-run/1`` format, validated on construction.

    Attributes:
        t: (N,) time [s], finite, strictly increasing, ``t[0] >= 0``.
        q_ref: (N, 11) commanded joint angles [rad], finite.
        q: (N, 11) measured joint angles [rad], finite.
        head_pos: (N, 3) head module origin in the world frame [m]; NaN where mocap dropped out.
        head_quat: (N, 4) head orientation ``(w, x, y, z)``, world from head; unit (to 1e-3) or a
            whole row of NaN where mocap dropped out.
        dq: (N, 11) measured joint velocities [rad/s] or ``None``; NaN marks a missing sample.
        current: (N, 11) measured motor currents [A] or ``None``; NaN marks a missing sample.
        bodies: other tracked bodies, name in :data:`BODY_NAMES` -> (N, 3) world position [m],
            NaN gaps allowed.
        extra: extra columns, name -> (N,) array; values read from a file are kept as the
            original cell strings (dtype object) so that they are written back unchanged.
        meta: the JSON sidecar; ``"format"`` is always ``"cobra-run/1"``, unknown keys are kept.
        source: the CSV file the run was read from, if any.

    Arrays are converted to float64 but not copied; treat them as read-only.

    Raises:
        InputError: on wrong shapes, non-finite ``t``/``q_ref``/``q``, non-increasing time,
            negative start time, non-unit quaternions, unknown body names or an extra column
            whose name clashes with a format column.
    """

    t: np.ndarray
    q_ref: np.ndarray
    q: np.ndarray
    head_pos: np.ndarray
    head_quat: np.ndarray
    dq: np.ndarray | None = None
    current: np.ndarray | None = None
    bodies: Mapping[str, np.ndarray] = field(default_factory=dict)
    extra: Mapping[str, np.ndarray] = field(default_factory=dict)
    meta: Mapping[str, Any] = field(default_factory=lambda: {"format": FORMAT})
    source: Path | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size == 0:
            raise InputError(f"Run.t: expected a non-empty 1-D array of times, got shape {t.shape}")
        n = t.size
        if not np.isfinite(t).all():
            bad = int(np.flatnonzero(~np.isfinite(t))[0])
            raise InputError(f"Run.t: sample {bad} is not finite")
        if t[0] < 0:
            raise InputError(f"Run.t: first sample is {t[0]:g} s; expected t[0] >= 0")
        i = first_non_increasing(t)
        if i is not None:
            raise InputError(
                f"Run.t: time not strictly increasing at sample {i} "
                f"({t[i - 1]:g} s then {t[i]:g} s)"
            )
        set_ = object.__setattr__
        set_(self, "t", t)
        for name in ("q_ref", "q"):
            arr = _as_float_array(name, getattr(self, name), (n, NUM_JOINTS))
            bad = np.argwhere(~np.isfinite(arr))
            if bad.size:
                i, j = bad[0]
                raise InputError(
                    f"Run.{name}: sample {i}, joint {j + 1} is not finite; {name} may not have gaps"
                )
            set_(self, name, arr)
        for name in ("dq", "current"):
            if getattr(self, name) is not None:
                arr = _as_float_array(name, getattr(self, name), (n, NUM_JOINTS))
                _check_finite_or_nan(name, arr)
                set_(self, name, arr)
        head_pos = _as_float_array("head_pos", self.head_pos, (n, 3))
        _check_finite_or_nan("head_pos", head_pos)
        set_(self, "head_pos", head_pos)
        head_quat = _as_float_array("head_quat", self.head_quat, (n, 4))
        _check_finite_or_nan("head_quat", head_quat)
        problem = _quaternion_problems(head_quat)
        if problem is not None:
            raise InputError(f"Run.head_quat: sample {problem[0]}: {problem[1]}")
        set_(self, "head_quat", head_quat)

        bodies: dict[str, np.ndarray] = {}
        for name, pos in self.bodies.items():
            if name not in BODY_NAMES:
                raise InputError(
                    f"Run.bodies: unknown body {name!r}; expected one of "
                    f"{', '.join(BODY_NAMES)} (the head has its own fields)"
                )
            arr = _as_float_array(f"bodies[{name!r}]", pos, (n, 3))
            _check_finite_or_nan(f"bodies[{name!r}]", arr)
            bodies[name] = arr
        set_(self, "bodies", {name: bodies[name] for name in BODY_NAMES if name in bodies})

        extra: dict[str, np.ndarray] = {}
        for name, values in self.extra.items():
            if not isinstance(name, str) or not name or name in _STANDARD_COLUMNS:
                raise InputError(
                    f"Run.extra: column name {name!r} is empty or clashes with a format column"
                )
            problem_text = _reserved_name_problem(name)
            if problem_text is not None:
                raise InputError(f"Run.extra: column {name!r}: {problem_text}")
            arr = np.asarray(values)
            if arr.shape != (n,):
                raise InputError(f"Run.extra[{name!r}]: expected shape ({n},), got {arr.shape}")
            extra[name] = arr
        set_(self, "extra", extra)

        meta = dict(self.meta)
        fmt = meta.setdefault("format", FORMAT)
        if fmt != FORMAT:
            raise InputError(f"Run.meta: \"format\" is {fmt!r}; expected {FORMAT!r}")
        set_(self, "meta", meta)
        if self.source is not None:
            set_(self, "source", Path(self.source))

    @property
    def n_samples(self) -> int:
        """Number of samples N."""
        return int(self.t.size)

    @property
    def duration(self) -> float:
        """``t[-1] - t[0]`` [s]."""
        return float(self.t[-1] - self.t[0])

    @property
    def gait_frequency_hz(self) -> float:
        """The gait frequency [Hz]: the sidecar's ``gait.frequency_hz`` when it names one, else
        the peak of the commands' spectrum (:func:`cobra_model.gait.dominant_frequency_hz`)."""
        gait = self.meta.get("gait")
        if isinstance(gait, Mapping) and isinstance(gait.get("frequency_hz"), (int, float)):
            return float(gait["frequency_hz"])
        return dominant_frequency_hz(self.t, self.q_ref)

    @property
    def dt_median(self) -> float:
        """Median sample interval [s]; NaN for a single-sample run."""
        return float(np.median(np.diff(self.t))) if self.t.size > 1 else float("nan")

    def with_meta(self, **changes: Any) -> Run:
        """A copy whose sidecar metadata has ``changes`` merged in (keys replaced, others kept)."""
        return dataclasses.replace(self, meta={**self.meta, **changes})

    def select(self, index: np.ndarray) -> Run:
        """A copy keeping the samples ``index`` (an integer index array or a boolean mask)."""

        def pick(arr: np.ndarray | None) -> np.ndarray | None:
            return None if arr is None else arr[index]

        return dataclasses.replace(
            self,
            t=self.t[index],
            q_ref=self.q_ref[index],
            q=self.q[index],
            head_pos=self.head_pos[index],
            head_quat=self.head_quat[index],
            dq=pick(self.dq),
            current=pick(self.current),
            bodies={name: pos[index] for name, pos in self.bodies.items()},
            extra={name: values[index] for name, values in self.extra.items()},
        )

    def slice_time(self, t0: float, t1: float) -> Run:
        """A copy keeping the samples with ``t0 <= t <= t1`` [s]; times are not shifted.

        Raises:
            InputError: if no sample lies in ``[t0, t1]``.
        """
        mask = (self.t >= t0) & (self.t <= t1)
        if not mask.any():
            raise InputError(
                f"{self._name()}: no sample in [{t0:g}, {t1:g}] s; "
                f"the run spans [{self.t[0]:g}, {self.t[-1]:g}] s"
            )
        return self.select(mask)

    def _name(self) -> str:
        return str(self.source) if self.source is not None else "run"


# ---------------------------------------------------------------------------------------------
# Interpolation onto another time base.


def _brackets(
    t_new: np.ndarray, t: np.ndarray, valid: np.ndarray, max_gap_samples: int | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Bracketing valid samples of ``t`` for each time of ``t_new``.

    Returns ``(lo, hi, w, ok)``: indices into ``t`` of the valid samples on either side, the
    weight of ``hi`` in ``[0, 1]`` and whether a value exists (inside the valid span, and the two
    valid samples are separated by at most ``max_gap_samples`` invalid ones, or the time hits a
    valid sample exactly). ``max_gap_samples=None`` bridges any gap.
    """
    idx = np.flatnonzero(valid)
    m = t_new.size
    if idx.size == 0:
        zeros = np.zeros(m, dtype=int)
        return zeros, zeros, np.zeros(m), np.zeros(m, dtype=bool)
    tv = t[idx]
    if idx.size == 1:
        ok = t_new == tv[0]
        zeros = np.zeros(m, dtype=int)
        return idx[zeros], idx[zeros], np.zeros(m), ok
    k = np.clip(np.searchsorted(tv, t_new, side="right") - 1, 0, idx.size - 2)
    t_lo, t_hi = tv[k], tv[k + 1]
    w = np.clip((t_new - t_lo) / (t_hi - t_lo), 0.0, 1.0)
    inside = (t_new >= tv[0]) & (t_new <= tv[-1])
    exact = (t_new == t_lo) | (t_new == t_hi)
    if max_gap_samples is None:
        close = np.ones(m, dtype=bool)
    else:
        close = (idx[k + 1] - idx[k] - 1) <= max_gap_samples
    return idx[k], idx[k + 1], w, inside & (close | exact)


def interpolate_rows(
    t_new: np.ndarray, t: np.ndarray, y: np.ndarray, *, max_gap_samples: int | None = None
) -> np.ndarray:
    """Linear interpolation of the rows of ``y`` (N, K) sampled at ``t`` (N,) onto ``t_new`` (M,).

    A row of ``y`` containing a NaN is a missing sample. The result is NaN outside the span of the
    valid samples and between two valid samples separated by more than ``max_gap_samples``
    missing ones (``None``: always bridge). Units are those of ``y``.
    """
    valid = np.isfinite(y).all(axis=1)
    lo, hi, w, ok = _brackets(t_new, t, valid, max_gap_samples)
    out = (1.0 - w)[:, None] * y[lo] + w[:, None] * y[hi]
    out[~ok] = np.nan
    return out


def interpolate_quaternions(
    t_new: np.ndarray, t: np.ndarray, quat: np.ndarray, *, max_gap_samples: int | None = None
) -> np.ndarray:
    """Normalised linear interpolation (nlerp) of unit quaternions ``quat`` (N, 4), any order.

    The later quaternion of each pair is sign-aligned with the earlier one (``q`` and ``-q`` are the
    same rotation) before blending, and the result is renormalised. Gaps are handled as in
    :func:`interpolate_rows`.
    """
    valid = np.isfinite(quat).all(axis=1)
    lo, hi, w, ok = _brackets(t_new, t, valid, max_gap_samples)
    q0, q1 = quat[lo], quat[hi]
    q1 = np.where((np.einsum("ij,ij->i", q0, q1) < 0)[:, None], -q1, q1)
    out = (1.0 - w)[:, None] * q0 + w[:, None] * q1
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    out = out / np.where(norm > 0, norm, 1.0)
    out[~ok] = np.nan
    return out


def resample_run(run: Run, t_new: np.ndarray, *, max_gap_samples: int = 2) -> Run:
    """``run`` linearly interpolated onto the times ``t_new`` (M,) [s].

    Joint signals are interpolated across their (rare) NaN samples; motion capture is left NaN
    across dropouts longer than ``max_gap_samples`` samples, quaternions use nlerp. Extra columns
    are kept when every time of ``t_new`` is a sample time of ``run`` and dropped otherwise (their
    values are strings and cannot be interpolated).

    Raises:
        InputError: if ``t_new`` reaches outside ``[run.t[0], run.t[-1]]``.
    """
    t_new = np.asarray(t_new, dtype=float)
    if t_new.size and (t_new[0] < run.t[0] or t_new[-1] > run.t[-1]):
        raise InputError(
            f"{run._name()}: cannot resample onto [{t_new[0]:g}, {t_new[-1]:g}] s; "
            f"the run spans [{run.t[0]:g}, {run.t[-1]:g}] s (no extrapolation)"
        )

    def joints(arr: np.ndarray | None) -> np.ndarray | None:
        return None if arr is None else interpolate_rows(t_new, run.t, arr)

    def mocap(arr: np.ndarray) -> np.ndarray:
        return interpolate_rows(t_new, run.t, arr, max_gap_samples=max_gap_samples)

    pos = np.searchsorted(run.t, t_new)
    pos_c = np.minimum(pos, run.t.size - 1)
    on_samples = bool(np.all(run.t[pos_c] == t_new))
    return dataclasses.replace(
        run,
        t=t_new,
        q_ref=joints(run.q_ref),
        q=joints(run.q),
        dq=joints(run.dq),
        current=joints(run.current),
        head_pos=mocap(run.head_pos),
        head_quat=interpolate_quaternions(
            t_new, run.t, run.head_quat, max_gap_samples=max_gap_samples
        ),
        bodies={name: mocap(p) for name, p in run.bodies.items()},
        extra={name: v[pos_c] for name, v in run.extra.items()} if on_samples else {},
    )


# ---------------------------------------------------------------------------------------------
# Reading.


@dataclass(frozen=True)
class CsvTable:
    """A comma-separated file with one header row, held as raw cell strings.

    Attributes:
        path: the file.
        header: column names in file order (surrounding whitespace stripped).
        cells: column name -> the column's cells, one string per data row.
        rows: (M,) 1-based row number in the file of each data row (the header is row 1).
    """

    path: Path
    header: tuple[str, ...]
    cells: Mapping[str, tuple[str, ...]]
    rows: np.ndarray

    def floats(self, column: str, *, allow_missing: bool = False) -> np.ndarray:
        """The cells of ``column`` as float64 (M,).

        With ``allow_missing`` an empty or ``nan`` cell is NaN; otherwise it is an error.

        Raises:
            InputError: naming the column and the row of the first non-numeric, missing
                (unless allowed) or infinite cell.
        """
        cells = self.cells[column]
        try:
            values = np.array(cells, dtype=float)
        except ValueError:
            values = self._parse_slowly(column, cells, allow_missing)
        bad = ~np.isfinite(values) if not allow_missing else np.isinf(values)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            if allow_missing:
                expected = "a finite number, or empty/nan for a missing sample"
            else:
                expected = "a finite number (this column may not have gaps)"
            raise InputError(
                f"{self.path}: column {column!r}, row {self.rows[i]}: value {cells[i]!r}; "
                f"expected {expected}"
            )
        return values

    def times(self, column: str = "t") -> np.ndarray:
        """The cells of ``column`` as times [s]: finite, strictly increasing, first one >= 0.

        Raises:
            InputError: naming the column and the offending row.
        """
        t = self.floats(column)
        if t[0] < 0:
            raise InputError(
                f"{self.path}: column {column!r}, row {self.rows[0]}: first time is {t[0]:g} s; "
                f"expected >= 0"
            )
        i = first_non_increasing(t)
        if i is not None:
            raise InputError(
                f"{self.path}: column {column!r}, row {self.rows[i]}: time {t[i]:g} s is not after "
                f"the previous row's {t[i - 1]:g} s; expected strictly increasing time"
            )
        return t

    def _parse_slowly(
        self, column: str, cells: Sequence[str], allow_missing: bool
    ) -> np.ndarray:
        """Cell-by-cell parse, only reached when the fast path found an unparsable cell."""
        out = np.empty(len(cells))
        for i, cell in enumerate(cells):
            if not cell.strip():
                if allow_missing:
                    out[i] = np.nan
                    continue
                raise InputError(
                    f"{self.path}: column {column!r}, row {self.rows[i]}: empty cell; "
                    f"expected a number (this column may not have gaps)"
                )
            try:
                out[i] = float(cell)
            except ValueError:
                raise InputError(
                    f"{self.path}: column {column!r}, row {self.rows[i]}: {cell!r} is not a "
                    f"number; expected a decimal number with '.' as decimal point"
                ) from None
        return out

    def unknown_columns(self) -> list[str]:
        """Header names that are not columns of the ``cobra-run/1`` format, in file order."""
        return [name for name in self.header if name not in _STANDARD_COLUMNS]

    def check_reserved_names(self) -> None:
        """Reject column names that look like format columns but are not (``q_12``, ``link_1_x``).

        Raises:
            InputError: naming the column and the valid range.
        """
        for name in self.header:
            problem = _reserved_name_problem(name)
            if problem is not None:
                raise InputError(f"{self.path}: column {name!r}: {problem}")

    def require(self, columns: Iterable[str]) -> None:
        """Check that every name of ``columns`` is in the header.

        Raises:
            InputError: listing the missing columns, each with the closest unknown header name
                when one looks like a misspelling (difflib), and the joint count found when
                joint columns are missing.
        """
        missing = [name for name in columns if name not in self.cells]
        if not missing:
            return
        unknown = self.unknown_columns()
        parts = []
        for name in missing:
            guess = _closest_name(name, unknown)
            text = f"missing required column {name!r}"
            if guess is not None:
                text += f" (the file has {guess!r}: did you mean {name!r}?)"
            parts.append(text)
        shown = "; ".join(parts[:12]) + ("; ..." if len(parts) > 12 else "")
        joint_note = self._joint_count_note(missing)
        raise InputError(f"{self.path}: {shown}{joint_note}")

    def _joint_count_note(self, missing: Sequence[str]) -> str:
        for name in missing:
            match = _JOINT_COLUMN_RE.match(name)
            if match:
                prefix = match.group(1)
                found = [c for c in joint_columns(prefix) if c in self.cells]
                return (
                    f" (found {len(found)} {prefix}_* joint columns; COBRA has {NUM_JOINTS} "
                    f"joints: {prefix}_1..{prefix}_{NUM_JOINTS})"
                )
        return ""

    def group_present(self, columns: Sequence[str], what: str) -> bool:
        """Whether an all-or-nothing group of optional columns is present.

        Raises:
            InputError: if only part of the group is present, naming the missing columns.
        """
        present = [c for c in columns if c in self.cells]
        if present and len(present) < len(columns):
            missing = [c for c in columns if c not in self.cells]
            raise InputError(
                f"{self.path}: {what} columns must be all present or all absent: the file has "
                f"{', '.join(present)} but is missing {', '.join(missing)}"
            )
        return bool(present)


def read_csv_table(path: str | Path) -> CsvTable:
    """Read a comma-separated file with one header row into raw cell strings.

    Blank lines are skipped (row numbers still count them). A UTF-8 byte-order mark is accepted.

    Raises:
        FileNotFoundError: if the file does not exist.
        InputError: for an empty file, a header without data rows, an empty or duplicated column
            name, or a row whose number of cells differs from the header's.
    """
    path = Path(path)
    with path.open(newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh))
    numbered = [(i + 1, row) for i, row in enumerate(rows) if row]
    if not numbered:
        raise InputError(f"{path}: file is empty; expected a header row and data rows")
    header_row, header_cells = numbered[0]
    header = tuple(name.strip() for name in header_cells)
    for j, name in enumerate(header):
        if not name:
            raise InputError(f"{path}: row {header_row}: column {j + 1} has an empty name")
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise InputError(f"{path}: column {name!r} appears more than once in the header")
        seen.add(name)
    data = numbered[1:]
    if not data:
        raise InputError(f"{path}: header only, no data rows; expected at least one sample")
    width = len(header)
    for number, row in data:
        if len(row) != width:
            raise InputError(
                f"{path}: row {number} has {len(row)} cells; the header has {width} columns"
            )
    columns = list(zip(*(row for _, row in data)))
    return CsvTable(
        path=path,
        header=header,
        cells=dict(zip(header, columns)),
        rows=np.array([number for number, _ in data]),
    )


def _sidecar_path(csv_path: Path) -> Path:
    return csv_path.with_suffix(".json")


def run_csv_path(path: Path) -> Path:
    """The CSV a run path names: ``NAME.csv`` itself, or for a sidecar ``NAME.json`` or a bare
    ``NAME`` the ``NAME.csv`` beside it (what :func:`read_run` and :func:`write_run` accept)."""
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return path
    if suffix == ".json":
        return path.with_suffix(".csv")
    return path.with_name(path.name + ".csv")


def read_meta(path: Path) -> dict[str, Any]:
    """Read and check a run's JSON sidecar.

    Raises:
        InputError: if the file is not valid JSON, not a JSON object, or its ``"format"`` is not
            ``"cobra-run/1"``.
    """
    text = path.read_text(encoding="utf-8")
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(
            f"{path}: not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg}); "
            f"expected an object like {{\"format\": \"{FORMAT}\"}}"
        ) from None
    if not isinstance(meta, dict):
        raise InputError(f"{path}: expected a JSON object, got {type(meta).__name__}")
    if meta.get("format") != FORMAT:
        found = repr(meta["format"]) if "format" in meta else "missing"
        raise InputError(f"{path}: \"format\" is {found}; expected {FORMAT!r}")
    return meta


def read_run(path: str | Path) -> Run:
    """Read a run: ``NAME.csv`` and, when it exists, its sidecar ``NAME.json``.

    ``path`` may name the CSV, the sidecar, or ``NAME`` without a suffix.

    Raises:
        FileNotFoundError: if the CSV does not exist.
        InputError: naming the file, column and/or row for anything that is not ``cobra-run/1``:
            missing or misspelled required columns, a joint count other than 11, non-numeric
            cells, gaps in ``t``/``q_ref_*``/``q_*``, non-increasing time, a negative start time,
            non-unit quaternions, an empty file, or a bad sidecar.
    """
    csv_path = run_csv_path(Path(path))
    sidecar = _sidecar_path(csv_path)
    meta = read_meta(sidecar) if sidecar.exists() else {"format": FORMAT}
    table = read_csv_table(csv_path)
    table.check_reserved_names()
    table.require(
        ["t", *joint_columns("q_ref"), *joint_columns("q"), *_HEAD_POS_COLUMNS, *_HEAD_QUAT_COLUMNS]
    )

    def block(columns: Sequence[str], *, allow_missing: bool = False) -> np.ndarray:
        return np.column_stack([table.floats(c, allow_missing=allow_missing) for c in columns])

    t = table.times("t")
    head_quat = block(_HEAD_QUAT_COLUMNS, allow_missing=True)
    problem = _quaternion_problems(head_quat)
    if problem is not None:
        raise InputError(
            f"{csv_path}: columns head_qw..head_qz, row {table.rows[problem[0]]}: {problem[1]}"
        )
    optional = {
        prefix: block(joint_columns(prefix), allow_missing=True)
        for prefix in ("dq", "current")
        if table.group_present(joint_columns(prefix), f"{prefix}_*")
    }
    bodies = {
        body: block(body_columns(body), allow_missing=True)
        for body in BODY_NAMES
        if table.group_present(body_columns(body), f"tracked body {body!r}")
    }
    return Run(
        t=t,
        q_ref=block(joint_columns("q_ref")),
        q=block(joint_columns("q")),
        head_pos=block(_HEAD_POS_COLUMNS, allow_missing=True),
        head_quat=head_quat,
        dq=optional.get("dq"),
        current=optional.get("current"),
        bodies=bodies,
        extra={name: np.array(table.cells[name], dtype=object) for name in table.unknown_columns()},
        meta=meta,
        source=csv_path,
    )


# ---------------------------------------------------------------------------------------------
# Writing.


def _format_floats(arr: np.ndarray) -> list[str]:
    """Shortest round-trip text of each value; NaN becomes an empty cell."""
    return ["" if x != x else repr(x) for x in arr.tolist()]


def _format_extra(values: np.ndarray) -> list[str]:
    if values.dtype.kind in "fc":
        return ["nan" if x != x else str(x) for x in values.tolist()]
    return [str(x) for x in values.tolist()]


def json_default(value: Any) -> Any:
    """``json.dump`` fallback for the sidecar: arrays and numpy scalars as lists/numbers, paths as text."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def write_run(run: Run, path: str | Path, *, force: bool = False) -> Path:
    """Write ``run`` as ``NAME.csv`` plus the sidecar ``NAME.json``; returns the CSV path.

    Columns: ``t, q_ref_1..11, q_1..11, [dq_*], [current_*], head_x..z, head_qw..qz``, the bodies
    in :data:`BODY_NAMES` order, then the extra columns in their order. Floats are written with
    the shortest text that reads back to the same float64; missing mocap samples are empty cells;
    extra columns are written as their strings. Parent directories are created.

    Raises:
        FileExistsError: if the CSV or the sidecar exists and ``force`` is false (nothing is
            written then).
        InputError: if the metadata cannot be written as JSON.
    """
    csv_path = run_csv_path(Path(path))
    sidecar = _sidecar_path(csv_path)
    if not force:
        for target in (csv_path, sidecar):
            if target.exists():
                raise FileExistsError(f"{target} already exists; pass force=True to overwrite it")
    try:
        meta_text = json.dumps(dict(run.meta), indent=2, default=json_default) + "\n"
    except (TypeError, ValueError) as exc:
        raise InputError(f"{sidecar}: run metadata is not JSON serialisable: {exc}") from exc

    header: list[str] = ["t", *joint_columns("q_ref"), *joint_columns("q")]
    blocks: list[np.ndarray] = [run.t[:, None], run.q_ref, run.q]
    for prefix, arr in (("dq", run.dq), ("current", run.current)):
        if arr is not None:
            header.extend(joint_columns(prefix))
            blocks.append(arr)
    header.extend((*_HEAD_POS_COLUMNS, *_HEAD_QUAT_COLUMNS))
    blocks.extend((run.head_pos, run.head_quat))
    for body, pos in run.bodies.items():
        header.extend(body_columns(body))
        blocks.append(pos)
    numeric = np.hstack(blocks)
    columns = [_format_floats(col) for col in numeric.T]
    columns.extend(_format_extra(np.asarray(values)) for values in run.extra.values())
    header.extend(run.extra)

    csv_path.parent.mkdir(parents=True, exist_ok=True)
    with csv_path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(header)
        writer.writerows(zip(*columns))
    sidecar.write_text(meta_text, encoding="utf-8")
    return csv_path
