"""Import OptiTrack Motive CSV exports and merge them with a joint log into a run.

Motive's CSV export (format version 1.23) looks like this::

    Format Version,1.23,Take Name,walk,...,Export Frame Rate,120.000000,...,Length Units,Meters,...

    ,Type,Rigid Body,Rigid Body,...,Rigid Body Marker,...
    ,Name,head,head,...,head:Marker1,...
    ,ID,1,1,...
    ,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,...
    Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,...
    0,0.000000,0.001,...

Quaternions are stored ``X, Y, Z, W`` and rotate rigid-body vectors into Motive's world frame;
frames where a rigid body lost tracking have empty cells. Only ``Rigid Body`` columns are read
(markers, marker errors and qualities are ignored).

Motive's world is Y-up unless the first row has ``Up Axis,Z``. This project's world is right-handed
and Z-up, so a Y-up take is re-expressed with the one rotation ``R =`` :data:`Y_UP_TO_Z_UP`
(``x_world = x_motive``, ``y_world = -z_motive``, ``z_world = y_motive``): positions
``p_world = R p_motive`` and orientations ``R_world_body = R R_motive_body R^T``. The right factor
relabels the rigid body's own axes the same way: Motive aligns them with its world axes when the
rigid body is created, so a body created level keeps the identity orientation and a yaw about
Motive's up axis becomes a yaw about ``z``. Lengths in millimetres or centimetres are converted to
metres.
"""
from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cobra_model.errors import InputError
from cobra_model.resample import interpolate_quaternions, interpolate_rows
from cobra_model.run import (
    BODY_NAMES,
    FORMAT,
    NUM_JOINTS,
    QUAT_NORM_TOL,
    Run,
    first_non_increasing,
    joint_columns,
)
from cobra_model.run_files import CsvTable, read_csv_rows, read_csv_table, read_run

#: Rotation from Motive's Y-up world to this project's Z-up world (+90 deg about x).
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
#: Metres per Motive length unit (keys lower-case).
LENGTH_UNITS_M: Mapping[str, float] = {"meters": 1.0, "centimeters": 0.01, "millimeters": 0.001}
#: Names a rigid body may be mapped to.
TARGET_NAMES: tuple[str, ...] = ("head", *BODY_NAMES)


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p * q`` of quaternions ``(w, x, y, z)``, broadcast over leading axes."""
    pw, px, py, pz = np.moveaxis(np.asarray(p, dtype=float), -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
        ],
        axis=-1,
    )


def quat_from_matrix(rot: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)``, ``w >= 0``, of a rotation matrix (Shepperd's method)."""
    m = np.asarray(rot, dtype=float)
    trace = np.trace(m)
    k = int(np.argmax([trace, m[0, 0], m[1, 1], m[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + trace)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i = k - 1
        j, l = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[l, l])
        vec = np.empty(3)
        vec[i] = 0.25 * s
        vec[j] = (m[j, i] + m[i, j]) / s
        vec[l] = (m[l, i] + m[i, l]) / s
        q = [(m[l, j] - m[j, l]) / s, *vec]
    quat = np.asarray(q)
    quat /= np.linalg.norm(quat)
    return quat if quat[0] >= 0 else -quat


@dataclass(frozen=True)
class RigidBodyTrack:
    """One Motive rigid body over a take, in this project's world frame (Z up).

    Attributes:
        name: the rigid body's name in Motive.
        positions: (N, 3) world position of the rigid body's pivot [m]; NaN where tracking was lost.
        quats: (N, 4) orientation ``(w, x, y, z)``, world from body; NaN where tracking was lost
            (or everywhere if the export has no rotation columns for this body).
    """

    name: str
    positions: np.ndarray
    quats: np.ndarray


@dataclass(frozen=True)
class MotiveTake:
    """A Motive CSV export converted to this project's frame and units.

    Attributes:
        times: (N,) time of each exported frame on Motive's clock [s].
        frames: (N,) Motive frame numbers.
        bodies: Motive rigid-body name -> track, in file order.
        frame_rate: export frame rate [Hz] (NaN if the header does not give it).
        up_axis: Motive's up axis in the file, ``"Y"`` or ``"Z"``.
        length_units: Motive's length unit in the file (converted to metres here).
        info: the key/value pairs of the file's first row.
        source: the file read.
    """

    times: np.ndarray
    frames: np.ndarray
    bodies: Mapping[str, RigidBodyTrack]
    frame_rate: float
    up_axis: str
    length_units: str
    info: Mapping[str, str]
    source: Path


def _info_row(path: Path, row: list[str]) -> dict[str, str]:
    cells = [c.strip() for c in row]
    if not cells or cells[0] != "Format Version":
        raise InputError(
            f"{path}: row 1: expected an OptiTrack Motive CSV export starting with "
            f"'Format Version', found {cells[:1]}"
        )
    return {key: value for key, value in zip(cells[0::2], cells[1::2]) if key}


def _header_row(path: Path, rows: list[list[str]], stop: int, label: str) -> list[str]:
    for row in rows[1:stop]:
        if len(row) > 1 and row[1].strip() == label:
            return [c.strip() for c in row]
    raise InputError(
        f"{path}: no header row with {label!r} in its second cell before the 'Frame' row; "
        f"expected a Motive 1.23 export"
    )


def _quaternions(path: Path, name: str, xyzw: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Motive ``(x, y, z, w)`` columns (N, 4) -> normalised ``(w, x, y, z)``, NaN rows kept."""
    quat = xyzw[:, [3, 0, 1, 2]]
    missing = np.isnan(quat).any(axis=1)
    quat[missing] = np.nan
    norm = np.linalg.norm(quat, axis=1)
    bad = np.flatnonzero(~missing & ~(np.abs(norm - 1.0) <= QUAT_NORM_TOL))
    if bad.size:
        i = int(bad[0])
        raise InputError(
            f"{path}: rigid body {name!r}, Rotation columns, row {rows[i]}: quaternion norm "
            f"{norm[i]:.6g}; expected a unit quaternion (tolerance {QUAT_NORM_TOL:g})"
        )
    return quat / norm[:, None]


def read_motive_csv(path: str | Path) -> MotiveTake:
    """Read an OptiTrack Motive CSV export (format 1.23) of rigid bodies.

    Positions are converted to metres and, for a Y-up take, rotated into the Z-up world with
    :data:`Y_UP_TO_Z_UP`; quaternions are reordered to ``(w, x, y, z)``, normalised and conjugated
    by the same rotation (see the module docstring). Lost-tracking frames are NaN.

    Raises:
        FileNotFoundError: if the file does not exist (:func:`cobra_model.run_files.read_csv_rows`).
        InputError: naming the file, column and/or row, for a directory, a file that is not a Motive export, a
            rotation type other than quaternions, a local coordinate space, an unknown length unit
            or up axis, no rigid bodies, non-numeric cells, non-increasing time or a non-unit
            quaternion.
    """
    path = Path(path)
    rows = read_csv_rows(path)
    if not rows:
        raise InputError(f"{path}: file is empty; expected an OptiTrack Motive CSV export")
    info = _info_row(path, rows[0])
    scale, rot, up_axis, units, frame_rate = _export_settings(path, info)
    table, labels, time_col, columns = _motive_table(path, rows)
    times = table.floats(labels[time_col])
    bad = first_non_increasing(times)
    if bad is not None:
        raise InputError(
            f"{path}: column {labels[time_col]!r}, row {table.rows[bad]}: time {times[bad]:g} s is "
            f"not after the previous frame's {times[bad - 1]:g} s"
        )
    return MotiveTake(
        times=times,
        frames=table.floats(labels[0]).astype(int),
        bodies=_rigid_bodies(table, labels, columns, times.size, scale, rot),
        frame_rate=frame_rate,
        up_axis=up_axis,
        length_units=units,
        info=info,
        source=path,
    )


def _export_settings(path: Path, info: dict[str, str]) -> tuple[float, np.ndarray, str, str, float]:
    """(metres per length unit, rotation into the Z-up world, up axis, length unit, frame rate
    [Hz]) from the export's first row; errors name the setting a take this reader cannot use has."""
    rotation_type = info.get("Rotation Type", "Quaternion")
    if rotation_type.lower() != "quaternion":
        raise InputError(
            f"{path}: Rotation Type is {rotation_type!r}; expected 'Quaternion' "
            f"(re-export from Motive with quaternion rotations)"
        )
    space = info.get("Coordinate Space", "Global")
    if space.lower() != "global":
        raise InputError(f"{path}: Coordinate Space is {space!r}; expected 'Global'")
    units = info.get("Length Units", "Meters")
    if units.lower() not in LENGTH_UNITS_M:
        raise InputError(
            f"{path}: Length Units is {units!r}; expected one of Meters, Centimeters, Millimeters"
        )
    up_axis = info.get("Up Axis", "Y").upper()
    if up_axis not in ("Y", "Z"):
        raise InputError(f"{path}: Up Axis is {info['Up Axis']!r}; expected 'Y' or 'Z'")
    try:
        frame_rate = float(info.get("Export Frame Rate", "nan"))
    except ValueError:
        raise InputError(
            f"{path}: Export Frame Rate {info['Export Frame Rate']!r} is not a number"
        ) from None
    rot = Y_UP_TO_Z_UP if up_axis == "Y" else np.eye(3)
    return LENGTH_UNITS_M[units.lower()], rot, up_axis, units, frame_rate


#: A rigid body's columns by (``"Position"``/``"Rotation"``, axis): their indices in the export.
BodyColumns = dict[tuple[str, str], int]


def _motive_table(path: Path, rows: list[list[str]]) -> tuple[CsvTable, list[str], int, dict[str, BodyColumns]]:
    """The frames below the header rows as a table, its column labels, the time column's index
    and each rigid body's columns by (``"Position"``/``"Rotation"``, axis)."""
    frame_idx = next(
        (i for i, row in enumerate(rows) if row and row[0].strip() == "Frame"), None
    )
    if frame_idx is None or frame_idx < 2:
        raise InputError(f"{path}: no 'Frame,Time (Seconds),...' header row found")
    fields = [c.strip() for c in rows[frame_idx]]
    kinds = [c.strip() for c in rows[frame_idx - 1]]
    types = _header_row(path, rows, frame_idx, "Type")
    names = _header_row(path, rows, frame_idx, "Name")
    width = len(fields)
    kinds, types, names = (r + [""] * (width - len(r)) for r in (kinds, types, names))
    time_col = next((j for j, f in enumerate(fields) if f.lower().startswith("time")), None)
    if time_col is None:
        raise InputError(f"{path}: row {frame_idx + 1}: no 'Time (Seconds)' column")

    columns: dict[str, BodyColumns] = {}
    for j in range(width):
        if types[j].lower() == "rigid body" and kinds[j] in ("Rotation", "Position"):
            slots = columns.setdefault(names[j], {})
            key = (kinds[j], fields[j].upper())
            if key in slots:
                raise InputError(
                    f"{path}: rigid body {names[j]!r} has two {kinds[j]} {fields[j]} columns "
                    f"(columns {slots[key] + 1} and {j + 1}); rigid-body names must be unique"
                )
            slots[key] = j
    if not columns:
        raise InputError(f"{path}: no 'Rigid Body' columns; expected at least the head rigid body")

    data = [(i + 1, row) for i, row in enumerate(rows[frame_idx + 1 :], start=frame_idx + 1) if row]
    if not data:
        raise InputError(f"{path}: no frames after the header rows")
    for number, row in data:
        if len(row) > width and any(c.strip() for c in row[width:]):
            raise InputError(f"{path}: row {number} has {len(row)} cells; the header has {width}")
    padded = [(row + [""] * width)[:width] for _, row in data]
    cell_columns = list(zip(*padded))
    # Frame and time columns keep their own name; others are "<name> <kind> <axis>".
    labels = [
        fields[j] if j <= time_col else f"{names[j]} {kinds[j]} {fields[j]}".strip()
        for j in range(width)
    ]
    table = CsvTable(
        path=path,
        header=tuple(labels),
        cells={labels[j]: cell_columns[j] for j in range(width)},
        rows=np.array([number for number, _ in data]),
    )
    return table, labels, time_col, columns


def _rigid_bodies(table: CsvTable, labels: list[str], columns: dict[str, BodyColumns], n_frames: int, scale: float,
                  rot: np.ndarray) -> dict[str, RigidBodyTrack]:
    """Each rigid body's positions [m] and quaternions (w, x, y, z) in the Z-up world."""
    q_rot = quat_from_matrix(rot)
    q_rot_inv = q_rot * np.array([1.0, -1.0, -1.0, -1.0])
    bodies: dict[str, RigidBodyTrack] = {}
    for name, cols in columns.items():
        pos_cols = [cols.get(("Position", axis)) for axis in "XYZ"]
        if None in pos_cols:
            raise InputError(f"{table.path}: rigid body {name!r} has no Position X, Y, Z columns")
        pos = np.column_stack([table.floats(labels[j], allow_missing=True) for j in pos_cols])
        pos[np.isnan(pos).any(axis=1)] = np.nan
        rot_cols = [cols.get(("Rotation", axis)) for axis in "XYZW"]
        if None in rot_cols:
            quats = np.full((n_frames, 4), np.nan)
        else:
            xyzw = np.column_stack([table.floats(labels[j], allow_missing=True) for j in rot_cols])
            quats = quat_multiply(
                quat_multiply(q_rot, _quaternions(table.path, name, xyzw, table.rows)), q_rot_inv
            )
        bodies[name] = RigidBodyTrack(name=name, positions=scale * pos @ rot.T, quats=quats)
    return bodies


#: A plain joint log: times (N,) [s], joint angles (N, 11) [rad], commanded angles (N, 11) [rad] or None.
JointArrays = tuple[np.ndarray, np.ndarray, np.ndarray | None]


def read_joint_source(path: str | Path) -> Run | JointArrays:
    """Read a joint log: a ``cobra-run/1`` run (what ``cobra record`` writes) as the run, so that
    :func:`merge_take_and_joints` keeps everything it holds, or a plain CSV
    ``t, q_1..q_11[, q_ref_*]`` as its arrays.

    A file whose header has ``head_x`` is read as a run (:func:`cobra_model.run_files.read_run`);
    otherwise ``t`` and ``q_1..q_11`` are required, ``q_ref_1..q_ref_11`` optional (all or none)
    and other columns ignored.

    Raises:
        FileNotFoundError: if the file does not exist.
        InputError: as for run files: missing/misspelled columns, wrong joint count, non-numeric
            or missing cells, non-increasing time (naming file, column and row).
    """
    path = Path(path)
    table = read_csv_table(path)
    if "head_x" in table.cells:
        return read_run(path)
    table.check_reserved_names()
    table.require(["t", *joint_columns("q")])
    t = table.times("t")
    q = np.column_stack([table.floats(c) for c in joint_columns("q")])
    q_ref = None
    if table.group_present(joint_columns("q_ref"), "q_ref_*"):
        q_ref = np.column_stack([table.floats(c) for c in joint_columns("q_ref")])
    return t, q, q_ref


def joint_arrays(source: Run | JointArrays) -> JointArrays:
    """``(t, q, q_ref)`` of a joint log as :func:`read_joint_source` returns it."""
    return (source.t, source.q, source.q_ref) if isinstance(source, Run) else source


def read_joint_log(path: str | Path) -> JointArrays:
    """``(t, q, q_ref)`` of the joint log at ``path`` (:func:`read_joint_source`): times (N,) [s],
    joint angles (N, 11) [rad] and commanded angles (N, 11) [rad] or ``None`` when the log has none."""
    return joint_arrays(read_joint_source(path))


def resolve_mapping(take: MotiveTake, mapping: Mapping[str, str] | None = None) -> dict[str, str]:
    """Motive rigid-body name -> run body name (``head``, ``link_2`` .. ``link_11``, ``tail``).

    Rigid bodies named like a run body (case-insensitive, exact otherwise) map to it. ``mapping``
    ``{"MotiveName": "head", ...}`` adds or overrides entries (its keys match Motive names exactly
    or, failing that, case-insensitively); a default entry whose target the user mapping claims is
    dropped.

    Raises:
        InputError: for an unknown Motive name or target, two rigid bodies mapped to one target,
            or no rigid body mapped to ``head``.
    """
    available = list(take.bodies)
    where = str(take.source)
    resolved: dict[str, str] = {}
    for key, target in (mapping or {}).items():
        name = key if key in take.bodies else next(
            (b for b in available if b.lower() == key.lower()), None
        )
        if name is None:
            close = difflib.get_close_matches(key, available, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise InputError(
                f"{where}: mapping names rigid body {key!r}, which is not in the take{hint}; "
                f"the take has {', '.join(map(repr, available))}"
            )
        if target.lower() not in TARGET_NAMES:
            raise InputError(
                f"mapping {key!r} -> {target!r}: expected a target among head, "
                f"link_2..link_{NUM_JOINTS}, tail"
            )
        resolved[name] = target.lower()
    claimed = set(resolved.values())
    for name in available:
        if name not in resolved and name.lower() in TARGET_NAMES and name.lower() not in claimed:
            resolved[name] = name.lower()
    targets = list(resolved.values())
    for target in set(targets):
        if targets.count(target) > 1:
            sources = [n for n, t in resolved.items() if t == target]
            raise InputError(
                f"{where}: rigid bodies {', '.join(map(repr, sources))} all map to {target!r}; "
                f"pass a mapping that picks one"
            )
    if "head" not in resolved.values():
        raise InputError(
            f"{where}: no rigid body maps to 'head'; the take has "
            f"{', '.join(map(repr, available))}; pass a mapping like {{'<name>': 'head'}}"
        )
    return resolved


def merge_take_and_joints(
    take: MotiveTake,
    joints: Run | JointArrays,
    *,
    mapping: Mapping[str, str] | None = None,
    time_offset: float = 0.0,
) -> Run:
    """Merge a Motive take and a joint log (:func:`read_joint_source`) into a hardware run.

    A joint log that is a run (what ``cobra record`` wrote) keeps everything else it holds on the
    merged samples: joint velocities, motor currents, extra columns (the recorder's
    ``read_latency_s``) and its sidecar (the gait, bus, timing, stop, notes and whether its goals
    were held, which decides how the run is reproduced); the take's information is added.

    The run's times are the joint-log times ``t`` whose take time ``t + time_offset`` [s] lies in
    the take's span; they stay on the joint log's clock (the command's phase is preserved). Rigid
    bodies are mapped with :func:`resolve_mapping`; their positions are interpolated linearly and
    the head quaternion by sign-aligned nlerp onto those times, never across a lost-tracking
    frame (NaN there). The sidecar's ``notes`` (a list of strings, as the hardware recorder writes
    them) say what was merged and, when the log has no ``q_ref``, that ``q_ref`` is set to ``q``.

    Raises:
        InputError: if the joint log does not overlap the take, has the wrong shape, or the
            mapping is invalid (see :func:`resolve_mapping`).
    """
    recording = joints if isinstance(joints, Run) else None
    t, q, q_ref = (None if a is None else np.asarray(a, dtype=float) for a in joint_arrays(joints))
    if t is None or q is None or t.ndim != 1 or q.shape != (t.size, NUM_JOINTS):
        raise InputError(
            f"joint log: expected t (N,) and q (N, {NUM_JOINTS}), got "
            f"{None if t is None else t.shape} and {None if q is None else q.shape}"
        )
    resolved = resolve_mapping(take, mapping)
    t_take = t + time_offset
    keep = (t_take >= take.times[0]) & (t_take <= take.times[-1])
    if not keep.any():
        raise InputError(
            f"joint log spans [{t[0]:g}, {t[-1]:g}] s (+ time offset {time_offset:g} s), "
            f"which does not overlap the take {take.source} spanning "
            f"[{take.times[0]:g}, {take.times[-1]:g}] s"
        )
    tq = t_take[keep]

    def positions(name: str) -> np.ndarray:
        return interpolate_rows(tq, take.times, take.bodies[name].positions, max_gap_samples=0)

    head_name = next(name for name, target in resolved.items() if target == "head")
    bodies = {target: positions(name) for name, target in resolved.items() if target != "head"}
    notes = [
        f"merged OptiTrack take {take.info.get('Take Name', take.source.name)!r} "
        f"({take.source.name}, {take.frame_rate:g} Hz, {take.up_axis}-up, {take.length_units}) "
        f"with a joint log: {int(keep.sum())} of {t.size} joint-log samples inside the take, "
        f"time offset {time_offset:g} s; motion capture interpolated linearly (quaternions by "
        f"nlerp) onto the joint-log times, NaN across lost-tracking frames",
    ]
    if q_ref is None:
        q_ref = q
        notes.append("the joint log has no q_ref_* columns: q_ref is set equal to q")
    elif q_ref.shape != q.shape:
        raise InputError(f"joint log: q_ref has shape {q_ref.shape}; expected {q.shape}")
    kept = dict(recording.meta) if recording is not None else {}
    earlier = kept.get("notes", [])
    meta = {
        **kept,
        "format": FORMAT,
        "source": kept.get("source", "hardware"),
        "notes": [*(earlier if isinstance(earlier, list) else [str(earlier)]), *notes],
        "optitrack": {
            "file": str(take.source),
            "take_name": take.info.get("Take Name", ""),
            "frame_rate_hz": take.frame_rate,
            "up_axis": take.up_axis,
            "length_units": take.length_units,
            "mapping": resolved,
            "time_offset_s": float(time_offset),
        },
    }
    return Run(
        t=t[keep],
        q_ref=q_ref[keep],
        q=q[keep],
        head_pos=positions(head_name),
        head_quat=interpolate_quaternions(
            tq, take.times, take.bodies[head_name].quats, max_gap_samples=0
        ),
        bodies=bodies,
        dq=None if recording is None or recording.dq is None else recording.dq[keep],
        current=None if recording is None or recording.current is None else recording.current[keep],
        extra={} if recording is None else {name: values[keep] for name, values in recording.extra.items()},
        meta=meta,
    )

