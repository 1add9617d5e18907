"""Tests of the OptiTrack Motive CSV importer and the merge with a joint log."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cobra_model.errors import InputError
from cobra_model.run import NUM_JOINTS, joint_columns
from cobra_model.run_files import read_run, write_run
from cobra_model.motive import (
    Y_UP_TO_Z_UP,
    merge_take_and_joints,
    quat_from_matrix,
    quat_multiply,
    read_joint_log,
    read_joint_source,
    read_motive_csv,
    resolve_mapping,
)
from cobra_model.run import Run

DATA = Path(__file__).parent / "data"
S = np.sqrt(0.5)

#: A hand-made Motive 1.23 export at 10 Hz: head yaws 90 deg about Motive's up axis (Y), the
#: tail rolls 90 deg about Motive's Z; head lost in frame 3, tail lost in frames 2-3; a marker of
#: the head rigid body and a loose marker that must be ignored.
MOTIVE_INFO = (
    "Format Version,1.23,Take Name,fixture,Take Notes,,Capture Frame Rate,10.000000,"
    "Export Frame Rate,10.000000,Capture Start Time,2024-03-01 10.00.00.000 AM,"
    "Total Frames in Take,6,Total Exported Frames,6,Rotation Type,Quaternion,"
    "Length Units,{units},Coordinate Space,Global{up}"
)
MOTIVE_HEADER = """
,Type,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body Marker,Rigid Body Marker,Rigid Body Marker,Rigid Body Marker,Marker,Marker,Marker
,Name,Head,Head,Head,Head,Head,Head,Head,Head,tail,tail,tail,tail,tail,tail,tail,tail,Head:Marker1,Head:Marker1,Head:Marker1,Head:Marker1,Unlabeled 1000,Unlabeled 1000,Unlabeled 1000
,ID,1,1,1,1,1,1,1,1,2,2,2,2,2,2,2,2,1,1,1,1,1000,1000,1000
,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,Position,Position,Position,Rotation,Rotation,Rotation,Rotation,Mean Marker Error,Position,Position,Position,Marker Quality,Position,Position,Position
Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,X,Y,Z,X,Y,Z,W,,X,Y,Z,,X,Y,Z"""
#: Head: quaternion (x, y, z, w) of a yaw of 90 deg about +Y, position (1 + 0.1 k, 2, 3 + 0.2 k).
#: Tail: position (k, 0.5, -1), rotation 90 deg about +Z, columns Position before Rotation.
MOTIVE_ROWS = [
    "0,0.000000,0,0.707107,0,0.707107,1.0,2.0,3.0,0.0001,0,0.5,-1,0,0,0.707107,0.707107,0.0002,1,2,3,1,9,9,9",
    "1,0.100000,0,0.707107,0,0.707107,1.1,2.0,3.2,0.0001,1,0.5,-1,0,0,0.707107,0.707107,0.0002,1,2,3,1,9,9,9",
    "2,0.200000,0,0.707107,0,0.707107,1.2,2.0,3.4,0.0001,,,,,,,,,1,2,3,1,,,",
    "3,0.300000,,,,,,,,,,,,,,,,,,,,,9,9,9",
    "4,0.400000,0,0.707107,0,0.707107,1.4,2.0,3.8,0.0001,4,0.5,-1,0,0,0.707107,0.707107,0.0002,1,2,3,1,9,9,9",
    "5,0.500000,0,0.707107,0,0.707107,1.5,2.0,4.0,0.0001,5,0.5,-1,0,0,0.707107,0.707107,0.0002,1,2,3,1,9,9,9",
]


def motive_text(*, units: str = "Meters", up: str = "", rows: list[str] | None = None) -> str:
    info = MOTIVE_INFO.format(units=units, up=up)
    return "\n".join([info, MOTIVE_HEADER, *(MOTIVE_ROWS if rows is None else rows)]) + "\n"


@pytest.fixture
def motive_file(tmp_path: Path) -> Path:
    path = tmp_path / "take.csv"
    path.write_text(motive_text())
    return path


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion (w, x, y, z), straight from the textbook formula."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def assert_same_rotation(q: np.ndarray, expected: np.ndarray) -> None:
    """Quaternions equal up to sign."""
    sign = 1.0 if np.dot(q, expected) >= 0 else -1.0
    np.testing.assert_allclose(sign * q, expected, atol=2e-6)


# ---------------------------------------------------------------------------------------------
# Reading Motive exports.


def test_y_up_take_is_converted_to_z_up(motive_file: Path) -> None:
    take = read_motive_csv(motive_file)
    assert list(take.bodies) == ["Head", "tail"]  # markers ignored
    assert take.frame_rate == 10.0 and take.up_axis == "Y" and take.length_units == "Meters"
    np.testing.assert_allclose(take.times, np.arange(6) * 0.1)
    np.testing.assert_array_equal(take.frames, np.arange(6))

    head = take.bodies["Head"]
    # (x, y, z)_motive = (1 + 0.1 k, 2, 3 + 0.2 k) -> (x, -z, y)_world
    k = np.array([0, 1, 2, 4, 5])
    np.testing.assert_allclose(head.positions[k], np.column_stack([1 + 0.1 * k, -(3 + 0.2 * k), np.full(5, 2.0)]))
    assert np.isnan(head.positions[3]).all() and np.isnan(head.quats[3]).all()
    # A yaw about Motive's up axis (+Y) is a yaw about the world's +z.
    for i in k:
        assert_same_rotation(head.quats[i], np.array([S, 0, 0, S]))

    tail = take.bodies["tail"]
    np.testing.assert_allclose(tail.positions[[0, 1, 4, 5]], [[0, 1, 0.5], [1, 1, 0.5], [4, 1, 0.5], [5, 1, 0.5]])
    assert np.isnan(tail.positions[2:4]).all() and np.isnan(tail.quats[2:4]).all()
    # A rotation about Motive's +Z is one about the world's -y (z_motive = -y_world).
    assert_same_rotation(tail.quats[0], np.array([S, 0, -S, 0]))


def test_orientation_conversion_is_one_rotation_matrix(motive_file: Path) -> None:
    take = read_motive_csv(motive_file)
    raw_motive = {"Head": np.array([S, 0, S, 0]), "tail": np.array([S, 0, 0, S])}  # (w, x, y, z)
    for name, q_motive in raw_motive.items():
        expected = Y_UP_TO_Z_UP @ quat_to_matrix(q_motive) @ Y_UP_TO_Z_UP.T
        np.testing.assert_allclose(quat_to_matrix(take.bodies[name].quats[0]), expected, atol=3e-6)
    # The world vector of a body axis transforms like a position.
    body_x = quat_to_matrix(take.bodies["Head"].quats[0])[:, 0]
    np.testing.assert_allclose(body_x, Y_UP_TO_Z_UP @ quat_to_matrix(raw_motive["Head"])[:, 0], atol=3e-6)


def test_quaternion_helpers() -> None:
    np.testing.assert_allclose(quat_from_matrix(np.eye(3)), [1, 0, 0, 0])
    np.testing.assert_allclose(quat_from_matrix(Y_UP_TO_Z_UP), [S, S, 0, 0])
    rng = np.random.default_rng(5)
    for q in rng.normal(size=(20, 4)):
        q /= np.linalg.norm(q)
        assert_same_rotation(quat_from_matrix(quat_to_matrix(q)), q)
    p, q = rng.normal(size=(2, 4))
    np.testing.assert_allclose(
        quat_to_matrix(quat_multiply(p, q) / np.linalg.norm(p) / np.linalg.norm(q)),
        quat_to_matrix(p / np.linalg.norm(p)) @ quat_to_matrix(q / np.linalg.norm(q)),
        atol=1e-12,
    )


def test_z_up_take_is_not_rotated(tmp_path: Path) -> None:
    path = tmp_path / "z.csv"
    path.write_text(motive_text(up=",Up Axis,Z"))
    take = read_motive_csv(path)
    assert take.up_axis == "Z"
    np.testing.assert_allclose(take.bodies["Head"].positions[0], [1.0, 2.0, 3.0])
    assert_same_rotation(take.bodies["Head"].quats[0], np.array([S, 0, S, 0]))


@pytest.mark.parametrize(("units", "scale"), [("Millimeters", 1e-3), ("Centimeters", 1e-2), ("Meters", 1.0)])
def test_length_units_are_converted(tmp_path: Path, units: str, scale: float) -> None:
    path = tmp_path / "u.csv"
    path.write_text(motive_text(units=units))
    take = read_motive_csv(path)
    np.testing.assert_allclose(take.bodies["Head"].positions[0], scale * np.array([1.0, -3.0, 2.0]))
    assert take.length_units == units


def _replace_row(index: int, row: str) -> list[str]:
    rows = list(MOTIVE_ROWS)
    rows[index] = row
    return rows


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", ["empty"]),
        ("t,q_1\n0,0\n", ["row 1", "Format Version"]),
        (motive_text().replace("Rotation Type,Quaternion", "Rotation Type,XYZ"), ["'XYZ'", "Quaternion"]),
        (motive_text(units="Inches"), ["'Inches'", "Meters"]),
        (motive_text(up=",Up Axis,X"), ["'X'", "Up Axis"]),
        (motive_text().replace("Coordinate Space,Global", "Coordinate Space,Local"), ["'Local'"]),
        (motive_text().replace("Frame,Time", "Frm,Time"), ["'Frame"]),
        (motive_text(rows=_replace_row(2, MOTIVE_ROWS[2].replace("1.2,", "1;2,", 1))),
         ["'Head Position X'", "row 10", "'1;2'"]),
        (motive_text(rows=_replace_row(4, MOTIVE_ROWS[4].replace("0.400000", "0.100000"))),
         ["'Time (Seconds)'", "row 12"]),
        (motive_text(rows=_replace_row(1, MOTIVE_ROWS[1].replace("0.707107,0.707107,0.0002", "0.9,0.9,0.0002"))),
         ["'tail'", "row 9", "norm"]),
        (motive_text().replace("Rigid Body,", "Bone,"), ["no 'Rigid Body' columns"]),
        (motive_text(rows=[]), ["no frames"]),
        (motive_text().replace(",tail,tail,tail,tail,", ",Head,Head,Head,Head,"), ["'Head'", "unique"]),
    ],
    ids=["empty", "not motive", "euler", "inches", "up x", "local", "no frame row", "non-numeric",
         "time goes back", "non-unit quaternion", "no rigid bodies", "no frames", "duplicate name"],
)
def test_bad_motive_exports(tmp_path: Path, text: str, expected: list[str]) -> None:
    path = tmp_path / "bad_take.csv"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        read_motive_csv(path)
    message = str(info.value)
    assert str(path) in message
    for part in expected:
        assert part in message, f"{part!r} not in {message!r}"


# ---------------------------------------------------------------------------------------------
# Joint logs.


def _joint_log(path: Path, *, with_ref: bool, n: int = 11, dt: float = 0.05, header_fix: dict[str, str] | None = None) -> Path:
    t = np.arange(n) * dt
    q = 0.1 * np.arange(1, NUM_JOINTS + 1) * np.sin(t[:, None])
    header = ["t", *joint_columns("q")] + ([*joint_columns("q_ref")] if with_ref else []) + ["motor_temp"]
    header = [(header_fix or {}).get(h, h) for h in header]
    cols = [t[:, None], q] + ([q + 0.01] if with_ref else []) + [np.full((n, 1), 31.5)]
    data = np.hstack(cols)
    lines = [",".join(header)] + [",".join(f"{v:.9g}" for v in row) for row in data]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_missing_take_or_joint_log_is_named(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match=r"^CSV file .*take\.csv does not exist$"):
        read_motive_csv(tmp_path / "take.csv")
    with pytest.raises(FileNotFoundError, match=r"^CSV file .*joints\.csv does not exist$"):
        read_joint_log(tmp_path / "joints.csv")


def test_read_plain_joint_log(tmp_path: Path) -> None:
    t, q, q_ref = read_joint_log(_joint_log(tmp_path / "j.csv", with_ref=False))
    assert t.shape == (11,) and q.shape == (11, NUM_JOINTS) and q_ref is None
    t2, q2, q_ref2 = read_joint_log(_joint_log(tmp_path / "j2.csv", with_ref=True))
    assert q_ref2 is not None
    np.testing.assert_allclose(q_ref2, q2 + 0.01)


def test_read_joint_log_from_a_run(tmp_path: Path) -> None:
    merged = merge_take_and_joints(
        read_motive_csv(DATA / "motive_take_small.csv"), read_joint_log(DATA / "joints_small.csv")
    )
    path = write_run(merged, tmp_path / "hw.csv")
    t, q, q_ref = read_joint_log(path)
    np.testing.assert_array_equal(t, merged.t)
    np.testing.assert_array_equal(q, merged.q)
    assert q_ref is not None
    np.testing.assert_array_equal(q_ref, merged.q_ref)


@pytest.mark.parametrize(
    ("kwargs", "expected"),
    [
        ({"header_fix": {"q_3": "Q3"}}, ["'q_3'", "'Q3'", "did you mean"]),
        ({"header_fix": {"motor_temp": "q_12"}}, ["'q_12'", "11 joints"]),
        ({"header_fix": {"q_11": "motor_current"}}, ["'q_11'", "11 joints"]),
        ({"header_fix": {"q_ref_4": "ref4"}, "with_ref": True}, ["q_ref_4", "all present or all absent"]),
        ({"dt": -0.05}, ["'t'", "row 4"]),
    ],
    ids=["misspelled", "q_12", "q_11 missing", "partial q_ref", "time backwards"],
)
def test_bad_joint_logs(tmp_path: Path, kwargs: dict, expected: list[str]) -> None:
    kwargs = {"with_ref": False, **kwargs}
    if kwargs.get("dt", 0) < 0:
        path = _joint_log(tmp_path / "bad.csv", with_ref=False)
        lines = path.read_text().splitlines()
        lines[2] = "0.5" + lines[2][lines[2].index(","):]
        path.write_text("\n".join(lines) + "\n")
    else:
        path = _joint_log(tmp_path / "bad.csv", **kwargs)
    with pytest.raises(InputError) as info:
        read_joint_log(path)
    message = str(info.value)
    assert str(path) in message
    for part in expected:
        assert part in message, f"{part!r} not in {message!r}"


# ---------------------------------------------------------------------------------------------
# Merging.


def test_merge_interpolates_without_crossing_dropouts(motive_file: Path, tmp_path: Path) -> None:
    take = read_motive_csv(motive_file)
    joints = read_joint_log(_joint_log(tmp_path / "j.csv", with_ref=False, n=13, dt=0.05))
    run = merge_take_and_joints(take, joints)
    # Joint times 0, 0.05, ..., 0.6; the take spans [0, 0.5] s.
    np.testing.assert_allclose(run.t, np.arange(11) * 0.05)
    expected_head = np.column_stack([1 + run.t, -(3 + 2 * run.t), np.full(11, 2.0)])
    lost = np.isnan(run.head_pos).any(axis=1)
    # Head lost at frame 3 (0.3 s): 0.25, 0.3, 0.35 s have no value; 0.2 s is an exact frame.
    np.testing.assert_array_equal(np.flatnonzero(lost), [5, 6, 7])
    np.testing.assert_allclose(run.head_pos[~lost], expected_head[~lost])
    assert np.isnan(run.head_quat[lost]).all()
    for q in run.head_quat[~lost]:
        assert_same_rotation(q, np.array([S, 0, 0, S]))
    tail = run.bodies["tail"]
    np.testing.assert_array_equal(np.flatnonzero(np.isnan(tail).any(axis=1)), [3, 4, 5, 6, 7])
    np.testing.assert_allclose(tail[[0, 1, 2, 8]], [[0, 1, 0.5], [0.5, 1, 0.5], [1, 1, 0.5], [4, 1, 0.5]])
    np.testing.assert_array_equal(run.q_ref, run.q)
    assert any("q_ref is set equal to q" in note for note in run.meta["notes"])
    assert run.meta["optitrack"]["mapping"] == {"Head": "head", "tail": "tail"}
    assert run.meta["source"] == "hardware"


def test_merge_quaternions_by_nlerp(tmp_path: Path) -> None:
    rows = [
        f"{k},{0.1 * k:.6f},0,{np.sin(a / 2):.9f},0,{np.cos(a / 2):.9f},0,0,0,0"
        for k, a in enumerate([0.0, 0.4, 0.8])
    ]
    info = MOTIVE_INFO.format(units="Meters", up="")
    header = "\n".join([
        "", ",Type," + ",".join(["Rigid Body"] * 8), ",Name," + ",".join(["head"] * 8),
        ",ID," + ",".join(["1"] * 8),
        ",," + ",".join(["Rotation"] * 4 + ["Position"] * 3 + ["Mean Marker Error"]),
        "Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,",
    ])
    path = tmp_path / "spin.csv"
    path.write_text("\n".join([info, header, *rows]) + "\n")
    take = read_motive_csv(path)
    t = np.array([0.05, 0.15])
    joints = (t, np.zeros((2, NUM_JOINTS)), np.ones((2, NUM_JOINTS)))
    run = merge_take_and_joints(take, joints)
    yaw = 2 * np.arctan2(run.head_quat[:, 3], run.head_quat[:, 0])
    np.testing.assert_allclose(yaw, [0.2, 0.6], atol=2e-3)
    np.testing.assert_array_equal(run.q_ref, 1.0)
    assert not any("q_ref is set equal" in note for note in run.meta["notes"])


def test_merge_with_time_offset_and_user_mapping(motive_file: Path) -> None:
    take = read_motive_csv(motive_file)
    t = np.arange(5) * 0.1 + 2.0  # controller clock 2.0 s = take clock 0.0 s
    joints = (t, np.zeros((5, NUM_JOINTS)), None)
    run = merge_take_and_joints(take, joints, mapping={"tail": "link_6", "head": "head"}, time_offset=-2.0)
    np.testing.assert_allclose(run.t, t)
    np.testing.assert_allclose(run.head_pos[1], [1.1, -3.2, 2.0])
    assert list(run.bodies) == ["link_6"]
    assert run.meta["optitrack"]["time_offset_s"] == -2.0


def test_mapping_rules_and_errors(motive_file: Path) -> None:
    take = read_motive_csv(motive_file)
    assert resolve_mapping(take) == {"Head": "head", "tail": "tail"}
    assert resolve_mapping(take, {"tail": "head"}) == {"tail": "head"}
    with pytest.raises(InputError, match=r"'tial'.*did you mean 'tail'"):
        resolve_mapping(take, {"tial": "tail"})
    with pytest.raises(InputError, match="'neck'"):
        resolve_mapping(take, {"tail": "neck"})
    with pytest.raises(InputError, match="all map to 'link_3'"):
        resolve_mapping(take, {"tail": "link_3", "Head": "link_3"})
    with pytest.raises(InputError, match="no rigid body maps to 'head'"):
        resolve_mapping(take, {"Head": "link_2"})
    with pytest.raises(InputError, match="does not overlap"):
        merge_take_and_joints(take, (np.array([3.0, 4.0]), np.zeros((2, NUM_JOINTS)), None))


def test_small_data_files_merge_and_round_trip(tmp_path: Path) -> None:
    take = read_motive_csv(DATA / "motive_take_small.csv")
    assert list(take.bodies) == ["head", "tail"] and take.times.size == 30
    joints = read_joint_log(DATA / "joints_small.csv")
    assert joints[2] is not None
    run = merge_take_and_joints(take, joints)
    assert run.n_samples == 25
    lost = np.flatnonzero(np.isnan(run.head_pos).any(axis=1))
    np.testing.assert_array_equal(lost, [8, 9, 10])  # frames 10-12 lost: 0.08 .. 0.10 s
    assert np.isnan(run.bodies["tail"]).any()
    path = write_run(run, tmp_path / "merged.csv")
    back = read_run(path)
    np.testing.assert_array_equal(back.head_pos, run.head_pos)
    assert back.meta == run.meta


def test_a_recording_merged_with_a_take_keeps_everything_it_held(tmp_path: Path) -> None:
    """A ``cobra record`` file merged with the take loses nothing the recorder wrote: velocities,
    currents, the read-latency column and the sidecar (above all that its goals were held,
    which decides how the run is reproduced)."""
    t, q, q_ref = read_joint_log(DATA / "joints_small.csv")
    n = t.size
    rng = np.random.default_rng(4)
    recorded = Run(t=t, q_ref=q_ref, q=q, dq=rng.normal(size=(n, NUM_JOINTS)), current=rng.normal(size=(n, NUM_JOINTS)),
                   head_pos=np.full((n, 3), np.nan), head_quat=np.full((n, 4), np.nan),
                   extra={"read_latency_s": rng.uniform(0.001, 0.003, n)},
                   meta={"source": "emulator", "q_ref_between_samples": "held", "notes": ["bench run"],
                         "timing": {"achieved_rate_hz": 49.9}})
    path = write_run(recorded, tmp_path / "rec.csv")
    assert isinstance(read_joint_source(DATA / "joints_small.csv"), tuple)  # a plain joint log
    recording = read_joint_source(path)
    assert isinstance(recording, Run)
    take = read_motive_csv(DATA / "motive_take_small.csv")
    # shifted so that the take covers only part of the recording: the kept rows are its rows
    run = merge_take_and_joints(take, recording, time_offset=0.05)
    keep = np.isin(t, run.t)
    assert 5 < run.n_samples == keep.sum() < n
    np.testing.assert_array_equal(run.dq, recorded.dq[keep])
    np.testing.assert_array_equal(run.current, recorded.current[keep])
    np.testing.assert_array_equal(run.extra["read_latency_s"].astype(float), recorded.extra["read_latency_s"][keep])
    assert run.q_ref_held and run.meta["source"] == "emulator" and run.meta["timing"] == {"achieved_rate_hz": 49.9}
    assert run.meta["notes"][0] == "bench run" and run.meta["notes"][1].startswith("merged OptiTrack take")
    assert np.isfinite(run.head_pos).any() and run.meta["optitrack"]["frame_rate_hz"] == take.frame_rate
    back = read_run(write_run(run, tmp_path / "merged.csv"))
    assert back.q_ref_held and back.current is not None and "read_latency_s" in back.extra
