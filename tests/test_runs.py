"""Tests of the ``cobra-run/1`` reader/writer and the :class:`Run` container."""
from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from cobra_model.errors import InputError
from cobra_model.resample import interpolate_quaternions, interpolate_rows, resample_run
from cobra_model.run import BODY_NAMES, FORMAT, NUM_JOINTS, Run, joint_columns
from cobra_model.run_files import read_run, write_run

HEADER = (
    ["t", *joint_columns("q_ref"), *joint_columns("q")]
    + ["head_x", "head_y", "head_z", "head_qw", "head_qx", "head_qy", "head_qz"]
)


def yaw_quats(angle: np.ndarray) -> np.ndarray:
    """Quaternions (w, x, y, z) of yaw rotations about z by ``angle`` [rad]."""
    return np.column_stack(
        [np.cos(angle / 2), np.zeros_like(angle), np.zeros_like(angle), np.sin(angle / 2)]
    )


def make_run(n: int = 40, **overrides: object) -> Run:
    """A small valid run sampled at 100 Hz."""
    t = np.arange(n) * 0.01
    phases = np.arange(NUM_JOINTS) * 0.3
    q_ref = 0.5 * np.sin(2 * np.pi * 0.5 * t[:, None] + phases)
    fields: dict[str, object] = dict(
        t=t,
        q_ref=q_ref,
        q=0.9 * q_ref,
        head_pos=np.column_stack([0.1 * t, 0.02 * np.sin(t), np.full(n, 0.045)]),
        head_quat=yaw_quats(0.2 * t),
    )
    fields.update(overrides)
    return Run(**fields)  # type: ignore[arg-type]


def good_rows(n: int = 8) -> list[list[str]]:
    """Cells of a valid file (``n`` data rows) as strings, for tests that corrupt one of them."""
    rows = []
    for i in range(n):
        t = f"{0.01 * i:.2f}"
        joints = [f"{0.1 * k + 0.001 * i:.4f}" for k in range(NUM_JOINTS)]
        rows.append([t, *joints, *joints, f"{0.001 * i}", "0.0", "0.045", "1.0", "0.0", "0.0", "0.0"])
    return rows


def write_csv(path: Path, header: list[str], rows: list[list[str]]) -> Path:
    path.write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n", encoding="utf-8")
    return path


def set_cell(rows: list[list[str]], row: int, column: str, value: str) -> None:
    """Set the cell at file row ``row`` (header = row 1) of ``column`` in ``HEADER``."""
    rows[row - 2][HEADER.index(column)] = value


# ---------------------------------------------------------------------------------------------
# Round trip.


def test_round_trip_keeps_everything(tmp_path: Path) -> None:
    n = 30
    base = make_run(n)
    head_pos = base.head_pos.copy()
    head_pos[5:9] = np.nan
    head_quat = base.head_quat.copy()
    head_quat[5:9] = np.nan
    tail = np.column_stack([0.1 * base.t - 0.5, np.zeros(n), np.full(n, 0.04)])
    tail[[0, 17]] = np.nan
    link6 = tail + 0.25
    link6[20:] = np.nan
    extra = {
        "label": np.array([f"s{i}" for i in range(n)], dtype=object),
        "odd": np.array(["0.10", "1e-3", "a,b", "", 'say "hi"', " spaced "] * 5, dtype=object),
    }
    meta = {"format": FORMAT, "source": "hardware", "gait": {"f_hz": 0.5, "phases": [0, 1.5]},
            "unknown_key": {"nested": [1, None, "x"]}, "notes": "ünïcode"}
    run = Run(
        t=base.t, q_ref=base.q_ref, q=base.q, head_pos=head_pos, head_quat=head_quat,
        dq=np.cos(base.q), current=np.full((n, NUM_JOINTS), 0.25),
        bodies={"tail": tail, "link_6": link6}, extra=extra, meta=meta,
    )
    out = write_run(run, tmp_path / "run.csv")
    assert out == tmp_path / "run.csv"
    back = read_run(out)
    for name in ("t", "q_ref", "q", "dq", "current", "head_pos", "head_quat"):
        np.testing.assert_array_equal(getattr(back, name), getattr(run, name), err_msg=name)
    assert list(back.bodies) == ["link_6", "tail"]
    for name in ("tail", "link_6"):
        np.testing.assert_array_equal(back.bodies[name], run.bodies[name])
    assert list(back.extra) == ["label", "odd"]
    for name, values in extra.items():
        assert back.extra[name].tolist() == values.tolist()
    assert back.meta == meta
    assert back.source == out


def test_file_round_trip_keeps_extra_strings_and_sidecar(tmp_path: Path) -> None:
    header = ["t", *HEADER[1:], "tail_x", "tail_y", "tail_z", "operator", "raw_adc"]
    rows = [r + ["0.5", "", "nan", "Ana", f"00{i}.50"] for i, r in enumerate(good_rows(5))]
    src = write_csv(tmp_path / "in.csv", header, rows)
    sidecar = {"format": FORMAT, "zz_custom": [1.25, {"a": None}], "params": {"mu": 0.300000001}}
    (tmp_path / "in.json").write_text(json.dumps(sidecar), encoding="utf-8")

    first = read_run(src)
    write_run(first, tmp_path / "out.csv")
    second = read_run(tmp_path / "out.csv")
    assert second.extra["raw_adc"].tolist() == [f"00{i}.50" for i in range(5)]
    assert second.extra["operator"].tolist() == ["Ana"] * 5
    assert json.loads((tmp_path / "out.json").read_text()) == sidecar
    np.testing.assert_array_equal(second.q, first.q)
    assert np.isnan(second.bodies["tail"][:, 1:]).all()
    # A second write of what was read gives the identical file.
    write_run(second, tmp_path / "again.csv")
    assert (tmp_path / "again.csv").read_text() == (tmp_path / "out.csv").read_text()


def test_written_column_order_and_empty_nan_cells(tmp_path: Path) -> None:
    n = 4
    base = make_run(n)
    head_pos = base.head_pos.copy()
    head_pos[2] = np.nan
    run = Run(
        t=base.t, q_ref=base.q_ref, q=base.q, head_pos=head_pos, head_quat=base.head_quat,
        current=np.zeros((n, NUM_JOINTS)), dq=np.ones((n, NUM_JOINTS)),
        bodies={"tail": np.zeros((n, 3)), "link_2": np.ones((n, 3))},
        extra={"z_first": np.array(list("abcd")), "a_second": np.arange(n) * 0.5},
    )
    path = write_run(run, tmp_path / "order")
    assert path.name == "order.csv"
    lines = path.read_text().splitlines()
    expected = (
        ["t", *joint_columns("q_ref"), *joint_columns("q"), *joint_columns("dq"),
         *joint_columns("current"), "head_x", "head_y", "head_z",
         "head_qw", "head_qx", "head_qy", "head_qz",
         "link_2_x", "link_2_y", "link_2_z", "tail_x", "tail_y", "tail_z", "z_first", "a_second"]
    )
    assert lines[0].split(",") == expected
    row3 = lines[3].split(",")
    assert row3[expected.index("head_x")] == "" and row3[expected.index("head_z")] == ""
    assert row3[-1] == "1.0" and row3[-2] == "c"


def test_write_refuses_to_overwrite_unless_forced(tmp_path: Path) -> None:
    run = make_run()
    write_run(run, tmp_path / "r.csv")
    with pytest.raises(FileExistsError, match="r.csv"):
        write_run(run, tmp_path / "r.csv")
    (tmp_path / "r.csv").unlink()
    with pytest.raises(FileExistsError, match="r.json"):
        write_run(run, tmp_path / "r.csv")
    assert not (tmp_path / "r.csv").exists()
    write_run(run.with_meta(notes="second"), tmp_path / "r.csv", force=True)
    assert read_run(tmp_path / "r.csv").meta["notes"] == "second"


def test_read_accepts_stem_or_sidecar_path_and_defaults_meta(tmp_path: Path) -> None:
    write_csv(tmp_path / "plain.csv", HEADER, good_rows())
    by_stem = read_run(tmp_path / "plain")
    by_sidecar = read_run(tmp_path / "plain.json")
    assert by_stem.meta == {"format": FORMAT} == by_sidecar.meta
    np.testing.assert_array_equal(by_stem.t, by_sidecar.t)


def test_mocap_gaps_empty_or_nan_are_accepted(tmp_path: Path) -> None:
    rows = good_rows()
    for column in ("head_x", "head_y", "head_z", "head_qw", "head_qx", "head_qy", "head_qz"):
        set_cell(rows, 3, column, "")
        set_cell(rows, 5, column, "nan")
    set_cell(rows, 6, "head_y", "NaN")
    run = read_run(write_csv(tmp_path / "gaps.csv", HEADER, rows))
    assert np.isnan(run.head_pos[[1, 3]]).all() and np.isnan(run.head_quat[[1, 3]]).all()
    assert np.isnan(run.head_pos[4, 1]) and np.isfinite(run.head_pos[4, [0, 2]]).all()
    assert np.isfinite(run.head_quat[[0, 2, 4]]).all()


def test_a_long_file_with_every_column_reads_back_whole(tmp_path: Path) -> None:
    """10 000 rows (200 s at 50 Hz) with every column the format has come back value for value
    and row for row. (How fast: ``benchmarks/run_io.py``, against ``np.loadtxt``.)"""
    n = 10_000
    base = make_run(n)
    run = Run(
        t=base.t, q_ref=np.round(base.q_ref, 6), q=np.round(base.q, 6),
        head_pos=np.round(base.head_pos, 6), head_quat=base.head_quat,
        dq=np.round(base.q * 3, 6), current=np.round(base.q_ref * 0.1, 6),
        bodies={"tail": np.round(base.head_pos - 1, 6)},
        extra={"marker": np.array([f"m{i}" for i in range(n)])},
    )
    path = write_run(run, tmp_path / "big.csv")
    assert len(path.read_text().splitlines()) == n + 1
    back = read_run(path)
    for name in ("t", "q_ref", "q", "dq", "current", "head_pos", "head_quat"):
        np.testing.assert_array_equal(getattr(back, name), getattr(run, name), err_msg=name)
    np.testing.assert_array_equal(back.bodies["tail"], run.bodies["tail"])
    assert back.extra["marker"].tolist() == run.extra["marker"].tolist()


# ---------------------------------------------------------------------------------------------
# Bad files: every error names the file and the column and/or row.

Corrupt = Callable[[list[str], list[list[str]]], None]


def _rename(old: str, new: str) -> Corrupt:
    def apply(header: list[str], rows: list[list[str]]) -> None:
        header[header.index(old)] = new

    return apply


def _drop(column: str) -> Corrupt:
    def apply(header: list[str], rows: list[list[str]]) -> None:
        j = header.index(column)
        del header[j]
        for row in rows:
            del row[j]

    return apply


def _add(column: str, value: str = "0.0") -> Corrupt:
    def apply(header: list[str], rows: list[list[str]]) -> None:
        header.append(column)
        for row in rows:
            row.append(value)

    return apply


def _cell(row: int, column: str, value: str) -> Corrupt:
    def apply(header: list[str], rows: list[list[str]]) -> None:
        rows[row - 2][header.index(column)] = value

    return apply


def _quat_row(row: int, values: list[str]) -> Corrupt:
    def apply(header: list[str], rows: list[list[str]]) -> None:
        for column, value in zip(("head_qw", "head_qx", "head_qy", "head_qz"), values):
            rows[row - 2][header.index(column)] = value

    return apply


def _both(*steps: Corrupt) -> Corrupt:
    def apply(header: list[str], rows: list[list[str]]) -> None:
        for step in steps:
            step(header, rows)

    return apply


def _ragged(header: list[str], rows: list[list[str]]) -> None:
    rows[3].append("1.0")


BAD_FILES: dict[str, tuple[Corrupt, list[str]]] = {
    "misspelled q_ref_1": (_rename("q_ref_1", "q_ref_l"), ["'q_ref_1'", "'q_ref_l'", "did you mean"]),
    "misspelled q_7 case": (_rename("q_7", "Q_7"), ["'q_7'", "'Q_7'", "did you mean"]),
    "time column named time": (_rename("t", "time"), ["'t'", "'time'", "did you mean"]),
    "missing head_qw": (_drop("head_qw"), ["missing required column 'head_qw'"]),
    "q_12 present": (_add("q_12"), ["'q_12'", "11 joints"]),
    "q_ref_0 present": (_add("q_ref_0"), ["'q_ref_0'", "11 joints"]),
    "q_11 missing": (_drop("q_11"), ["'q_11'", "found 10 q_* joint columns", "11 joints"]),
    "q_ref_2..q_ref_11 and q_5 missing": (_both(*(_drop(f"q_ref_{i}") for i in range(2, 12)), _drop("q_5")),
                                          ["missing required columns q_ref_2..q_ref_11, q_5 (found 1 q_ref_*"]),
    "current_12 present": (_add("current_12"), ["'current_12'", "11 joints"]),
    "partial dq group": (_both(_add("dq_1"), _add("dq_2")), ["dq_3", "all present or all absent"]),
    "partial body": (_both(_add("tail_x"), _add("tail_y")), ["tail_z", "'tail'"]),
    "invalid link body": (_add("link_1_x"), ["'link_1_x'", "link_2"]),
    "non-numeric q": (_cell(4, "q_3", "abc"), ["'q_3'", "row 4", "'abc'"]),
    "comma decimal in head": (_cell(5, "head_x", "0;5"), ["'head_x'", "row 5", "'0;5'"]),
    "empty t": (_cell(3, "t", ""), ["'t'", "row 3", "empty"]),
    "nan q_ref": (_cell(6, "q_ref_2", "nan"), ["'q_ref_2'", "row 6", "'nan'"]),
    "empty q": (_cell(9, "q_11", ""), ["'q_11'", "row 9"]),
    "inf q": (_cell(2, "q_1", "inf"), ["'q_1'", "row 2", "finite"]),
    "inf head": (_cell(7, "head_z", "-inf"), ["'head_z'", "row 7"]),
    "time repeats": (_cell(6, "t", "0.03"), ["'t'", "row 6", "strictly increasing"]),
    "time decreases": (_cell(9, "t", "0.01"), ["'t'", "row 9", "strictly increasing"]),
    "negative start": (_cell(2, "t", "-0.5"), ["'t'", "row 2", ">= 0"]),
    "non-unit quaternion": (_quat_row(7, ["1.0", "0.1", "0.0", "0.0"]), ["head_qw", "row 7", "norm"]),
    "partial quaternion": (_quat_row(4, ["", "0.0", "0.0", "0.0"]), ["head_qw", "row 4", "partly missing"]),
    "duplicate column": (_rename("q_2", "q_1"), ["'q_1'", "more than once"]),
    "ragged row": (_ragged, ["row 5", "cells"]),
    "empty column name": (_rename("q_ref_5", ""), ["column", "empty name"]),
}


@pytest.mark.parametrize("case", list(BAD_FILES))
def test_bad_csv_is_rejected_naming_the_problem(tmp_path: Path, case: str) -> None:
    corrupt, expected = BAD_FILES[case]
    header, rows = list(HEADER), good_rows()
    corrupt(header, rows)
    path = write_csv(tmp_path / "bad.csv", header, rows)
    with pytest.raises(InputError) as info:
        read_run(path)
    message = str(info.value)
    assert str(path) in message
    for text in expected:
        assert text in message, f"{text!r} not in {message!r}"


@pytest.mark.parametrize(
    ("content", "expected"),
    [("", "empty"), ("\n\n", "empty"), (",".join(HEADER) + "\n", "no data rows")],
    ids=["empty", "blank lines", "header only"],
)
def test_empty_or_header_only_file(tmp_path: Path, content: str, expected: str) -> None:
    path = tmp_path / "empty.csv"
    path.write_text(content)
    with pytest.raises(InputError, match=expected) as info:
        read_run(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize(
    ("sidecar", "expected"),
    [
        ("{\"format\": \"cobra-run/1\",}", ["not valid JSON", "line 1"]),
        ("not json at all", ["not valid JSON"]),
        ("{\"format\": \"cobra-run/2\"}", ["'cobra-run/2'", "expected 'cobra-run/1'"]),
        ("{\"source\": \"hardware\"}", ["\"format\" is missing", "'cobra-run/1'"]),
        ("[1, 2]", ["expected a JSON object"]),
        ("{\"format\": \"cobra-run/1\", \"q_ref_between_samples\": \"linear\"}",
         ["\"q_ref_between_samples\" is 'linear'", "expected \"smooth\"", "or \"held\""]),
    ],
    ids=["trailing comma", "garbage", "wrong format", "no format", "not an object", "unknown command mode"],
)
def test_bad_sidecar_is_rejected(tmp_path: Path, sidecar: str, expected: list[str]) -> None:
    write_csv(tmp_path / "run.csv", HEADER, good_rows())
    (tmp_path / "run.json").write_text(sidecar)
    with pytest.raises(InputError) as info:
        read_run(tmp_path / "run.csv")
    message = str(info.value)
    assert str(tmp_path / "run.json") in message
    for text in expected:
        assert text in message


def test_blank_lines_keep_file_row_numbers(tmp_path: Path) -> None:
    rows = good_rows()
    text = ",".join(HEADER) + "\n\n" + "\n".join(",".join(r) for r in rows[:3])
    text += "\n" + ",".join(rows[3][:1] + ["x"] + rows[3][2:]) + "\n"
    path = tmp_path / "blank.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=r"'q_ref_1', row 6"):
        read_run(path)


def test_missing_file_raises_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"^CSV file .*nope\.csv does not exist$"):
        read_run(tmp_path / "nope.csv")
    (tmp_path / "folder.csv").mkdir()
    with pytest.raises(InputError, match=r"folder\.csv: is a directory; expected a CSV file"):
        read_run(tmp_path / "folder.csv")


# ---------------------------------------------------------------------------------------------
# The Run container.


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [
        ({"q": np.zeros((40, 10))}, "Run.q: expected shape (40, 11)"),
        ({"head_pos": np.zeros((39, 3))}, "Run.head_pos"),
        ({"t": np.zeros(40)}, "not strictly increasing at sample 1"),
        ({"t": np.arange(40) * 0.01 - 0.1}, "t[0] >= 0"),
        ({"q_ref": np.full((40, 11), np.nan)}, "Run.q_ref: sample 0, joint 1 is not finite"),
        ({"head_quat": np.tile([2.0, 0, 0, 0], (40, 1))}, "Run.head_quat: sample 0"),
        ({"bodies": {"middle": np.zeros((40, 3))}}, "unknown body 'middle'"),
        ({"bodies": {"head": np.zeros((40, 3))}}, "unknown body 'head'"),
        ({"extra": {"q_1": np.zeros(40)}}, "clashes"),
        ({"extra": {"q_13": np.zeros(40)}}, "'q_13'"),
        ({"extra": {"e": np.zeros(39)}}, "Run.extra['e']"),
        ({"dq": np.full((40, 11), np.inf)}, "Run.dq"),
        ({"meta": {"format": "other"}}, "'other'"),
        ({"meta": {"q_ref_between_samples": "zoh"}}, "Run.meta: \"q_ref_between_samples\" is 'zoh'"),
    ],
)
def test_run_validation(overrides: dict[str, object], expected: str) -> None:
    with pytest.raises(InputError) as info:
        make_run(**overrides)
    assert expected in str(info.value)


def test_run_helpers() -> None:
    run = make_run(n=101)
    assert run.n_samples == 101
    assert run.duration == pytest.approx(1.0)
    assert run.dt_median == pytest.approx(0.01)
    assert run.meta == {"format": FORMAT}
    tagged = run.with_meta(source="simulation")
    assert tagged.meta == {"format": FORMAT, "source": "simulation"} and run.meta == {"format": FORMAT}
    part = run.slice_time(0.2, 0.5)
    assert part.t[0] == pytest.approx(0.2) and part.t[-1] == pytest.approx(0.5)
    assert part.q.shape == (31, NUM_JOINTS)
    with pytest.raises(InputError, match="no sample in"):
        run.slice_time(5.0, 6.0)
    assert BODY_NAMES[0] == "link_2" and BODY_NAMES[-1] == "tail" and len(BODY_NAMES) == 11


# ---------------------------------------------------------------------------------------------
# Interpolation.


def _interp_reference(t_new: np.ndarray, t: np.ndarray, y: np.ndarray, max_gap: int) -> np.ndarray:
    """Plain-loop reference of :func:`interpolate_rows` for one column."""
    valid = [i for i in range(len(t)) if np.isfinite(y[i])]
    out = np.full(len(t_new), np.nan)
    for m, tm in enumerate(t_new):
        for i in valid:
            if t[i] == tm:
                out[m] = y[i]
        if np.isfinite(out[m]):
            continue
        for lo, hi in zip(valid[:-1], valid[1:]):
            if t[lo] < tm < t[hi] and hi - lo - 1 <= max_gap:
                w = (tm - t[lo]) / (t[hi] - t[lo])
                out[m] = (1 - w) * y[lo] + w * y[hi]
    return out


@pytest.mark.parametrize("max_gap", [0, 1, 2, 5])
def test_interpolate_rows_matches_reference(max_gap: int) -> None:
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.5, 1.5, 60))
    y = rng.normal(size=60)
    y[[3, 10, 11, 20, 21, 22, 30, 31, 32, 33, 59]] = np.nan
    t_new = np.sort(np.concatenate([rng.uniform(t[0] - 1, t[-1] + 1, 200), t[::7]]))
    got = interpolate_rows(t_new, t, y[:, None], max_gap_samples=max_gap)[:, 0]
    np.testing.assert_allclose(got, _interp_reference(t_new, t, y, max_gap), rtol=0, atol=1e-12)


def test_interpolate_quaternions_aligns_signs_and_normalises() -> None:
    t = np.array([0.0, 1.0, 2.0, 3.0])
    quat = yaw_quats(np.array([0.0, 0.4, 0.8, 1.2]))
    quat[2] *= -1  # same rotation, opposite sign
    out = interpolate_quaternions(np.array([0.5, 1.5, 2.5]), t, quat)
    np.testing.assert_allclose(np.linalg.norm(out, axis=1), 1.0)
    out *= np.sign(out[:, :1])
    angles = 2 * np.arctan2(out[:, 3], out[:, 0])
    np.testing.assert_allclose(angles, [0.2, 0.6, 1.0], atol=1e-3)


def test_resample_run_on_sample_times_keeps_extra() -> None:
    run = make_run(20, extra={"e": np.array([str(i) for i in range(20)], dtype=object)})
    same = resample_run(run, run.t[::2])
    assert same.extra["e"].tolist() == [str(i) for i in range(0, 20, 2)]
    np.testing.assert_allclose(same.q, run.q[::2])
    between = resample_run(run, run.t[:-1] + 0.005)
    assert between.extra == {}
    np.testing.assert_allclose(between.q, 0.5 * (run.q[:-1] + run.q[1:]))
    with pytest.raises(InputError, match="no extrapolation"):
        resample_run(run, run.t + 0.005)


def test_the_gait_frequency_is_the_sidecars_else_the_commands_spectrum() -> None:
    from cobra_model.gait import SidewindingGait
    t = np.arange(0.0, 8.0, 0.02)
    gait = SidewindingGait(0.65)
    q_ref = gait.q_ref(t)
    run = make_run(t.size, t=t, q_ref=q_ref, q=q_ref)
    assert run.with_meta(gait=gait.to_json()).gait_frequency_hz == 0.65
    # no gait in the sidecar (an imported recording), or one without a number: the spectrum's peak,
    # within its resolution 1 / 8 s
    for meta in ({}, {"gait": {"frequency_hz": "fast"}}):
        assert abs(run.with_meta(**meta).gait_frequency_hz - 0.65) <= 1.0 / 8.0
