"""The run of the ``cobra-run/1`` format: its columns and the validated :class:`Run` record.

A run is one experiment (see ``DATA_FORMAT.md``): the commanded joint trajectory ``q_ref``, the
measured joint angles ``q``, optional joint velocities and motor currents, and the motion-capture
tracks of the head (position and orientation) and of other bodies. A run file is ``NAME.csv``
with an optional ``NAME.json`` sidecar; :mod:`cobra_model.run_files` reads and writes them and
:mod:`cobra_model.resample` moves a run onto another time base.

Frames and units: SI and radians; positions are in the world frame (right-handed, ``z`` up,
ground at ``z = 0``); ``head_quat`` is the unit quaternion ``(w, x, y, z)`` rotating head-frame
vectors into the world frame. Motion-capture samples may be NaN where markers dropped out.

Every validation error is a :class:`cobra_model.errors.InputError` naming the file, the column
and/or the row (1-based, the header being row 1) and what was expected.
"""
from __future__ import annotations

import dataclasses
import difflib
import re
from collections.abc import Mapping, Sequence
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
#: Sidecar key saying what the commands did between two samples: ``"smooth"`` (the default: each
#: ``q_ref`` row samples a command that varied continuously, e.g. a gait computed at the servo's
#: rate and logged at 50 Hz) or ``"held"`` (each row is a goal written at its ``t`` and held by
#: the servos until the next row, as :mod:`hardware.recorder` streams a gait).
Q_REF_BETWEEN_SAMPLES = "q_ref_between_samples"
Q_REF_MODES = ("smooth", "held")
#: Relative tolerance on ``|q| - 1`` for a unit quaternion.
QUAT_NORM_TOL = 1e-3

_JOINT_PREFIXES = ("q_ref", "q", "dq", "current")
HEAD_POS_COLUMNS = ("head_x", "head_y", "head_z")
HEAD_QUAT_COLUMNS = ("head_qw", "head_qx", "head_qy", "head_qz")
JOINT_COLUMN_RE = re.compile(r"^(q_ref|q|dq|current)_(\d+)$")
_LINK_COLUMN_RE = re.compile(r"^link_(\d+)_([xyz])$")
_TIME_ALIASES = ("time", "times", "t_s", "time_s", "timestamp", "stamp")


def joint_columns(prefix: str) -> tuple[str, ...]:
    """Column names ``prefix_1 .. prefix_11`` (prefix ``q_ref``, ``q``, ``dq`` or ``current``)."""
    return tuple(f"{prefix}_{k}" for k in range(1, NUM_JOINTS + 1))


def body_columns(body: str) -> tuple[str, str, str]:
    """Position column names ``body_x, body_y, body_z`` of a tracked body."""
    return (f"{body}_x", f"{body}_y", f"{body}_z")


def _standard_columns() -> frozenset[str]:
    names: list[str] = ["t", *HEAD_POS_COLUMNS, *HEAD_QUAT_COLUMNS]
    for prefix in _JOINT_PREFIXES:
        names.extend(joint_columns(prefix))
    for body in BODY_NAMES:
        names.extend(body_columns(body))
    return frozenset(names)


STANDARD_COLUMNS = _standard_columns()


def reserved_name_problem(name: str) -> str | None:
    """Why ``name`` looks like a format column but is not a valid one, or ``None``."""
    match = JOINT_COLUMN_RE.match(name)
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


def closest_name(name: str, candidates: Sequence[str]) -> str | None:
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


def quaternion_problems(quat: np.ndarray) -> tuple[int, str] | None:
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
        problem = quaternion_problems(head_quat)
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
            if not isinstance(name, str) or not name or name in STANDARD_COLUMNS:
                raise InputError(
                    f"Run.extra: column name {name!r} is empty or clashes with a format column"
                )
            problem_text = reserved_name_problem(name)
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
        mode = meta.get(Q_REF_BETWEEN_SAMPLES, "smooth")
        if mode not in Q_REF_MODES:
            where = f"{Path(self.source).with_suffix('.json')}: " if self.source is not None else "Run.meta: "
            raise InputError(f"{where}\"{Q_REF_BETWEEN_SAMPLES}\" is {mode!r}; expected \"smooth\" (a "
                             f"continuously varying command, sampled) or \"held\" (goals held from one "
                             f"sample to the next)")
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
    def q_ref_held(self) -> bool:
        """Whether each ``q_ref`` row is a goal held until the next row (sidecar
        :data:`Q_REF_BETWEEN_SAMPLES` ``"held"``) rather than a sample of a smooth command."""
        return self.meta.get(Q_REF_BETWEEN_SAMPLES, "smooth") == "held"

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
