"""Tests of ``cobra compare`` (in-process through ``cobra_cli.main.main``) and of ``sysid.gap.plots``."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cobra_cli.cmd_compare import PLOT_FILES
from cobra_cli.main import main
from cobra_model.gait import SidewindingGait
from cobra_model.run import NUM_JOINTS, Run
from cobra_model.run_files import write_run
from integrators.simulate import simulate_gait
from sysid.gap.metrics import compare_runs
from sysid.gap.plots import (
    plot_error_bars,
    plot_head_errors,
    plot_head_paths,
    plot_joint_responses,
    plot_window_correlation,
)

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Where a CSV row of a run is broken in the malformed-file test (header is row 1).
BROKEN_ROW = 3


@pytest.fixture(scope="module")
def gait_run() -> Run:
    """A short simulated sidewinding run (2 s at 0.5 Hz) standing in for a measured one."""
    return simulate_gait(SidewindingGait(0.5), 2.0)


@pytest.fixture(scope="module")
def run_csv(gait_run: Run, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_run(gait_run, tmp_path_factory.mktemp("runs") / "measured.csv")


def assert_replay(path: Path) -> None:
    """The 3-D replay page: one self-contained HTML file holding the meshcat scene."""
    text = path.read_text()
    assert text.lstrip().lower().startswith("<!doctype html") or "<html" in text[:200].lower(), path
    assert len(text) > 10_000 and "meshcat" in text.lower()


def assert_png(path: Path) -> None:
    assert path.is_file(), path
    data = path.read_bytes()
    assert len(data) > 1000 and data.startswith(PNG_SIGNATURE), path


def assert_one_line_error(err: str, *needles: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("cobra compare: error:") and "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def test_run_against_itself_has_zero_errors(run_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["compare", str(run_csv), str(run_csv), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["head_final_error_m"] == 0.0
    assert report["head_mean_error_m"] == 0.0
    assert report["joint_rmse_rad"]["per_joint"] == [0.0] * NUM_JOINTS
    assert report["joint_rmse_rad"]["mean"] == 0.0
    assert [entry["joint"] for entry in report["cpg_error"]] == list(range(1, NUM_JOINTS + 1))
    for entry in report["cpg_error"]:
        assert (entry["amplitude"], entry["frequency"], entry["phase"]) == (0.0, 0.0, 0.0)
    assert report["window_correlation"]["mean"] == pytest.approx(1.0)
    assert "no resampling" in report["resampled"]
    assert report["inputs"]["simulated"] == str(run_csv)


def test_single_run_is_simulated_and_json_has_the_keys(
    run_csv: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["compare", str(run_csv), "--json", "--window", "1.0"]) == 0
    report = json.loads(capsys.readouterr().out)
    for key in ("head_final_error_m", "head_mean_error_m", "joint_rmse_rad", "cpg_error",
                "window_correlation", "resampled"):
        assert key in report
    assert len(report["joint_rmse_rad"]["per_joint"]) == NUM_JOINTS
    assert {"per_joint", "mean"} <= set(report["joint_rmse_rad"])
    assert [entry["joint"] for entry in report["cpg_error"]] == list(range(1, NUM_JOINTS + 1))
    assert all({"amplitude", "frequency", "phase"} <= set(e) for e in report["cpg_error"])
    assert {"mean", "min", "max"} <= set(report["window_correlation"])
    assert report["window_correlation"]["window_s"] == 1.0
    assert report["inputs"] == {"measured": str(run_csv), "simulated": None, "params": "nominal"}
    # The run was simulated with the nominal parameters, so reproducing it closes the gap.
    assert report["head_final_error_m"] < 0.01
    assert report["joint_rmse_rad"]["mean"] < 0.01


def test_table_says_what_was_compared_and_resampled(
    run_csv: Path, gait_run: Run, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    coarse = write_run(gait_run.select(np.arange(0, gait_run.n_samples, 2)), tmp_path / "c.csv")
    assert main(["compare", str(coarse), str(run_csv)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"compare {coarse} (measured) with {run_csv} (simulated)")
    assert "head final error (x-y)" in out
    resampled = [line for line in out.splitlines() if line.startswith("resampled:")]
    assert len(resampled) == 1 and "interpolated" in resampled[0]


def test_plots_are_written_and_not_overwritten_without_force(
    run_csv: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plots = tmp_path / "figures" / "compare"
    assert main(["compare", str(run_csv), "--plots", str(plots)]) == 0
    capsys.readouterr()
    written = sorted(plots.iterdir())
    assert [p.name for p in written] == sorted(PLOT_FILES.values())
    for path in written:
        if path.suffix == ".png":
            assert_png(path)
        else:
            assert_replay(path)
    before = {p: p.stat().st_mtime_ns for p in written}

    assert main(["compare", str(run_csv), str(run_csv), "--plots", str(plots)]) == 2
    assert_one_line_error(capsys.readouterr().err, str(plots / "head_path.png"), "--force")
    assert {p: p.stat().st_mtime_ns for p in written} == before

    assert main(["compare", str(run_csv), str(run_csv), "--plots", str(plots), "--force",
                 "--json"]) == 0
    captured = capsys.readouterr()
    json.loads(captured.out)  # the figure list goes to stderr, stdout stays JSON
    assert "wrote 5 figures" in captured.err
    for path in written:
        if path.suffix == ".png":
            assert_png(path)
        else:
            assert_replay(path)


def test_missing_file_is_a_one_line_error(tmp_path: Path, run_csv: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nope.csv"
    assert main(["compare", str(missing)]) == 2
    assert_one_line_error(capsys.readouterr().err, str(missing))
    assert main(["compare", str(run_csv), str(missing)]) == 2
    assert_one_line_error(capsys.readouterr().err, str(missing))


def test_malformed_csv_is_a_one_line_error(run_csv: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    lines = run_csv.read_text().splitlines()
    cells = lines[BROKEN_ROW - 1].split(",")
    cells[1] = "abc"
    lines[BROKEN_ROW - 1] = ",".join(cells)
    broken = tmp_path / "broken.csv"
    broken.write_text("\n".join(lines) + "\n")
    assert main(["compare", str(broken), str(run_csv)]) == 2
    assert_one_line_error(capsys.readouterr().err, str(broken), "q_ref_1", f"row {BROKEN_ROW}")

    no_q = tmp_path / "no_q.csv"
    no_q.write_text("t,x\n0,1\n")
    assert main(["compare", str(run_csv), str(no_q)]) == 2
    assert_one_line_error(capsys.readouterr().err, str(no_q), "missing required column")


@pytest.mark.parametrize(
    ("options", "needle"),
    [
        (["--window", "0"], "--window"),
        (["--window", "nan"], "--window"),
        (["SELF", "--params", "p.json"], "--params"),
    ],
)
def test_bad_options_are_one_line_errors(run_csv: Path, options: list[str], needle: str,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    argv = [str(run_csv) if o == "SELF" else o for o in options]
    assert main(["compare", str(run_csv), *argv]) == 2
    assert_one_line_error(capsys.readouterr().err, needle)


def test_missing_params_file_names_it(run_csv: Path, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    params = tmp_path / "missing_params.json"
    assert main(["compare", str(run_csv), "--params", str(params)]) == 2
    assert_one_line_error(capsys.readouterr().err, str(params))


def test_plots_refuse_a_file_as_directory(run_csv: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["compare", str(run_csv), str(run_csv), "--plots", str(run_csv)]) == 2
    assert_one_line_error(capsys.readouterr().err, "--plots", "not a directory")


# ---------------------------------------------------------------------------------------------
# The plotting functions for many runs and reports (used by the fit and diagnose reports).


def test_plots_of_several_runs_and_reports(gait_run: Run, tmp_path: Path) -> None:
    shifted = Run(t=gait_run.t, q_ref=gait_run.q_ref, q=gait_run.q + 0.05,
                  head_pos=gait_run.head_pos + [0.02, -0.01, 0.0], head_quat=gait_run.head_quat)
    no_mocap = Run(t=gait_run.t, q_ref=gait_run.q_ref, q=gait_run.q,
                   head_pos=np.full_like(gait_run.head_pos, np.nan),
                   head_quat=np.full_like(gait_run.head_quat, np.nan))
    runs = [("measured", gait_run), ("untuned", shifted), ("lost", no_mocap)]
    reports = [("untuned", compare_runs(gait_run, shifted)), ("tuned", compare_runs(gait_run, gait_run))]
    assert_png(plot_head_paths(runs, tmp_path / "paths.png"))
    assert_png(plot_joint_responses(runs[:2], tmp_path / "joints.png", joints=(2, 5, 6)))
    assert_png(plot_head_errors(reports, tmp_path / "errors.png"))
    assert_png(plot_window_correlation(reports, tmp_path / "corr.png"))
    table = {"0.35 Hz": {"untuned": 0.41, "tuned": 0.12},
             "0.5 Hz": {"untuned": 0.52, "tuned": 0.2},
             "0.65 Hz": {"tuned": 0.3}}
    assert_png(plot_error_bars(table, tmp_path / "sub" / "bars.png", "final head error [m]"))
