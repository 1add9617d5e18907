"""Reading and writing ``cobra-run/1`` files: the one place that parses and formats them.

A run file is ``NAME.csv`` (one header row, SI units) with an optional ``NAME.json`` sidecar (see
``DATA_FORMAT.md``). Every validation error is a :class:`cobra_model.errors.InputError` naming the
file, the column and/or the row (1-based, the header being row 1) and what was expected.
"""
from __future__ import annotations

import csv
import json
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cobra_model.errors import InputError
from cobra_model.run import (
    BODY_NAMES,
    FORMAT,
    HEAD_POS_COLUMNS,
    HEAD_QUAT_COLUMNS,
    JOINT_COLUMN_RE,
    NUM_JOINTS,
    STANDARD_COLUMNS,
    Run,
    body_columns,
    closest_name,
    first_non_increasing,
    joint_columns,
    quaternion_problems,
    reserved_name_problem,
)

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
        return [name for name in self.header if name not in STANDARD_COLUMNS]

    def check_reserved_names(self) -> None:
        """Reject column names that look like format columns but are not (``q_12``, ``link_1_x``).

        Raises:
            InputError: naming the column and the valid range.
        """
        for name in self.header:
            problem = reserved_name_problem(name)
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
        parts, plain = [], []
        for name in missing:
            guess = closest_name(name, unknown)
            if guess is None:
                plain.append(name)
            else:
                parts.append(f"missing required column {name!r} (the file has {guess!r}: did you mean {name!r}?)")
        if len(plain) == 1:
            parts.insert(0, f"missing required column {plain[0]!r}")
        elif plain:
            parts.insert(0, f"missing required columns {', '.join(joint_ranges(plain))}")
        shown = "; ".join(parts[:12]) + ("; ..." if len(parts) > 12 else "")
        joint_note = self._joint_count_note(missing)
        raise InputError(f"{self.path}: {shown}{joint_note}")

    def _joint_count_note(self, missing: Sequence[str]) -> str:
        for name in missing:
            match = JOINT_COLUMN_RE.match(name)
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


def joint_ranges(names: Sequence[str]) -> list[str]:
    """``names`` with each run of consecutive joint columns of one prefix shortened to its ends
    (``q_ref_1``, ..., ``q_ref_11`` -> ``q_ref_1..q_ref_11``), other names as they are, in order."""
    spans: list[str | tuple[str, int, int]] = []  # a name, or (prefix, first joint, last joint)
    for name in names:
        match = JOINT_COLUMN_RE.match(name)
        if match is None:
            spans.append(name)
            continue
        prefix, joint = match.group(1), int(match.group(2))
        last = spans[-1] if spans else None
        if isinstance(last, tuple) and last[0] == prefix and last[2] + 1 == joint:
            spans[-1] = (prefix, last[1], joint)
        else:
            spans.append((prefix, joint, joint))
    return [span if isinstance(span, str)
            else f"{span[0]}_{span[1]}" + (f"..{span[0]}_{span[2]}" if span[2] > span[1] else "")
            for span in spans]


def read_csv_rows(path: Path) -> list[list[str]]:
    """Every row of a comma-separated file as cell strings (a UTF-8 byte-order mark accepted).

    Raises:
        FileNotFoundError: if the file does not exist (naming it, as
            :meth:`cobra_model.parameters.ModelParameters.load` does).
        InputError: for a directory.
    """
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            return list(csv.reader(fh))
    except FileNotFoundError:
        raise FileNotFoundError(f"CSV file {path} does not exist") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory; expected a CSV file") from None


def read_csv_table(path: str | Path) -> CsvTable:
    """Read a comma-separated file with one header row into raw cell strings.

    Blank lines are skipped (row numbers still count them). A UTF-8 byte-order mark is accepted.

    Raises:
        FileNotFoundError: if the file does not exist (naming it, as
            :meth:`cobra_model.parameters.ModelParameters.load` does).
        InputError: for a directory, an empty file, a header without data rows, an empty or
            duplicated column name, or a row whose number of cells differs from the header's.
    """
    path = Path(path)
    rows = read_csv_rows(path)
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
        ["t", *joint_columns("q_ref"), *joint_columns("q"), *HEAD_POS_COLUMNS, *HEAD_QUAT_COLUMNS]
    )

    def block(columns: Sequence[str], *, allow_missing: bool = False) -> np.ndarray:
        return np.column_stack([table.floats(c, allow_missing=allow_missing) for c in columns])

    t = table.times("t")
    head_quat = block(HEAD_QUAT_COLUMNS, allow_missing=True)
    problem = quaternion_problems(head_quat)
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
        head_pos=block(HEAD_POS_COLUMNS, allow_missing=True),
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
    header.extend((*HEAD_POS_COLUMNS, *HEAD_QUAT_COLUMNS))
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
