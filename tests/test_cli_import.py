"""Tests of ``cobra import-optitrack`` (in-process through ``cobra_cli.main.main``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cobra_cli.cmd_import_optitrack import parse_map
from cobra_cli.main import main
from cobra_model.errors import InputError
from cobra_model.run_files import read_run

DATA = Path(__file__).parent / "data"
TAKE = DATA / "motive_take_small.csv"
JOINTS = DATA / "joints_small.csv"
#: Samples of the joint log (0 .. 0.24 s at 100 Hz), all inside the take (0 .. 0.2417 s).
JOINT_SAMPLES = 25


def import_argv(out: Path, *options: str) -> list[str]:
    """The shipped small take (0.24 s, shorter than a gait cycle) with a given clock offset
    (0 s unless ``options`` give one): too short for the offset to be estimated."""
    offset = [] if "--time-offset" in options else ["--time-offset", "0"]
    return ["import-optitrack", str(TAKE), "--joints", str(JOINTS), "--out", str(out), *offset, *options]


def assert_one_line_error(err: str, *needles: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("cobra import-optitrack: error:") and "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def test_import_writes_a_readable_run(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run.csv"
    assert main(import_argv(out)) == 0
    stdout = capsys.readouterr().out
    assert stdout.startswith(f"wrote {out} ({JOINT_SAMPLES} samples")
    assert "head -> head" in stdout and "tail -> tail" in stdout
    assert "head tracked in 88% of samples" in stdout
    run = read_run(out)
    assert run.n_samples == JOINT_SAMPLES
    assert run.meta["source"] == "hardware"
    assert list(run.bodies) == ["tail"]
    # The head is lost in Motive frames 10-12 (0.083 .. 0.1 s): joint-log samples 8-10.
    np.testing.assert_array_equal(np.flatnonzero(np.isnan(run.head_pos).any(axis=1)), [8, 9, 10])
    # The take is Y-up: Motive's z = -0.3 m becomes the world's y = 0.3 m.
    assert run.head_pos[0] == pytest.approx([0.1, 0.3, 0.05])


def test_map_and_time_offset(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "mapped.csv"
    assert main(import_argv(out, "--map", "head=head,Tail=LINK_6", "--time-offset", "0.1")) == 0
    capsys.readouterr()
    run = read_run(out)
    assert list(run.bodies) == ["link_6"]
    assert run.meta["optitrack"]["mapping"] == {"head": "head", "tail": "link_6"}
    # Joint-log times t with t + 0.1 s inside the take: 0 .. 0.14 s.
    assert run.t[0] == 0.0 and run.t[-1] == pytest.approx(0.14)


def test_existing_output_needs_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run.csv"
    assert main(import_argv(out)) == 0
    assert main(import_argv(out)) == 2
    assert_one_line_error(capsys.readouterr().err, str(out.with_suffix(".json")), "--force")
    assert main(import_argv(out, "--force")) == 0


@pytest.mark.parametrize(
    "value",
    ["head=link_1", "head", "=head", "head=", "head=tail=x", "head=head,head=tail", "Nope=head"],
)
def test_bad_map_names_the_option(value: str, tmp_path: Path,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run.csv"
    assert main(import_argv(out, "--map", value)) == 2
    assert_one_line_error(capsys.readouterr().err, "--map")
    assert not out.exists()


def test_two_bodies_on_one_target_names_the_option(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    assert main(import_argv(tmp_path / "run.csv", "--map", "tail=head")) == 0
    capsys.readouterr()
    assert main(import_argv(tmp_path / "r2.csv", "--map", "tail=head", "--map", "head=head")) == 2
    assert_one_line_error(capsys.readouterr().err, "--map", "'head'")


def test_parse_map_accepts_repeated_and_comma_separated_values() -> None:
    assert parse_map(["A=head, B = Tail", "C=link_11"]) == {"A": "head", "B": "tail", "C": "link_11"}
    assert parse_map([]) == {}
    with pytest.raises(InputError, match="link_12"):
        parse_map(["A=link_12"])


@pytest.mark.parametrize(
    ("options", "needle"),
    [
        (["--time-offset", "inf"], "--time-offset"),
        (["--time-offset", "5"], "does not overlap"),
    ],
)
def test_bad_time_offset(options: list[str], needle: str, tmp_path: Path,
                         capsys: pytest.CaptureFixture[str]) -> None:
    assert main(import_argv(tmp_path / "run.csv", *options)) == 2
    assert_one_line_error(capsys.readouterr().err, needle)


def test_without_an_offset_a_take_too_short_to_match_is_an_error_naming_both(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run.csv"
    assert main(["import-optitrack", str(TAKE), "--joints", str(JOINTS), "--out", str(out)]) == 2
    assert_one_line_error(capsys.readouterr().err, f"{TAKE} spans [0, 0.241667] s and {JOINTS} spans [0, 0.24] s",
                          "no shift leaves one gait cycle")
    assert not out.exists()


def test_bad_files_are_one_line_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "run.csv"
    missing = tmp_path / "missing_take.csv"
    assert main(["import-optitrack", str(missing), "--joints", str(JOINTS), "--out", str(out)]) == 2
    assert_one_line_error(capsys.readouterr().err, str(missing))

    assert main(["import-optitrack", str(JOINTS), "--joints", str(JOINTS), "--out", str(out)]) == 2
    assert_one_line_error(capsys.readouterr().err, str(JOINTS), "Format Version")

    bad_joints = tmp_path / "joints.csv"
    bad_joints.write_text("t,q_1,q_2\n0,0,0\n")
    assert main(["import-optitrack", str(TAKE), "--joints", str(bad_joints), "--out", str(out)]) == 2
    assert_one_line_error(capsys.readouterr().err, str(bad_joints), "q_3")

    assert main(import_argv(tmp_path / "run.txt")) == 2
    assert_one_line_error(capsys.readouterr().err, "--out", ".csv")
    assert main(import_argv(tmp_path / "no_dir" / "run.csv")) == 2
    assert_one_line_error(capsys.readouterr().err, "no_dir")
    assert not out.exists()
