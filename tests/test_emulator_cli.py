"""``cobra emulate`` and ``cobra record`` from their command lines (parsed by their own modules)."""
from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Iterator

import pytest

from cobra_cli import cmd_compare, cmd_emulate, cmd_record
from cobra_model.errors import InputError
from cobra_model.run_files import read_run
from hardware.config import EXAMPLE_CONFIG as EXAMPLE

REPO = Path(__file__).resolve().parent.parent


def parse(module, argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="cobra")
    module.add_parser(parser.add_subparsers(dest="command"))
    return parser.parse_args(argv)


#: ``cobra emulate`` as its own process, its parser built by its module (as ``cobra`` does).
EMULATE = """
import argparse, sys
from cobra_cli import cmd_emulate
parser = argparse.ArgumentParser(prog="cobra")
cmd_emulate.add_parser(parser.add_subparsers(dest="command"))
args = parser.parse_args(sys.argv[1:])
sys.exit(args.func(args))
"""


@pytest.fixture
def emulate(tmp_path: Path) -> Iterator:
    """Start ``cobra emulate`` (ideal servos) in a child process; yields a function returning
    the port link and the first lines it printed. Stopped with Ctrl-C (SIGINT) at the end."""
    procs: list[subprocess.Popen] = []

    def start(*extra: str) -> tuple[Path, list[str]]:
        link = tmp_path / "cobra-bus"
        proc = subprocess.Popen(
            [sys.executable, "-c", EMULATE, "emulate", "--port-link", str(link), "--plant", "kinematic",
             "--report-every", "0", *extra],
            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(proc)
        lines = [proc.stdout.readline(), proc.stdout.readline()]
        assert link.is_symlink(), (lines, proc.stderr.read() if proc.poll() is not None else "")
        return link, lines

    yield start
    for proc in procs:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0, err
        assert "real-time factor" in out


def test_dry_run_prints_what_would_be_sent(capsys) -> None:
    args = parse(cmd_record, ["record", "--config", str(EXAMPLE), "--freq", "0.5", "--duration", "20", "--dry-run"])
    assert args.func(args) == 0
    out = capsys.readouterr().out
    assert "port /dev/ttyUSB0 at 1000000 baud" in out
    assert "ping IDs 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11 and expect model number 1100" in out
    assert "Operating Mode (11) = 3 (position)" in out
    assert "Position P Gain (84) = 800" in out
    assert "record: 20 s at 50 Hz = 1000 cycles" in out
    assert "      0   0.000     0.0    0.0" in out  # straight at t = 0 (smooth start)
    assert "  2048   2048" in out


def test_record_refuses_to_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "run.csv"
    out.write_text("precious")
    args = parse(cmd_record, ["record", "--config", str(EXAMPLE), "--out", str(out)])
    with pytest.raises(FileExistsError, match="run.csv already exists; pass --force"):
        args.func(args)
    assert out.read_text() == "precious"


def test_record_on_the_emulator(tmp_path: Path, emulate, capsys) -> None:
    link, lines = emulate()
    assert lines[0].startswith("pty: /dev/pts/")
    assert lines[1] == f"link: {link} -> {lines[0][5:].strip()}\n"
    out = tmp_path / "emu.csv"
    args = parse(cmd_record, ["record", "--config", str(EXAMPLE), "--port", str(link), "--freq", "0.5",
                              "--duration", "1", "--settle", "0.2", "--out", str(out)])
    assert args.func(args) == 0
    printed = capsys.readouterr().out
    assert "torque off on all 11 servos" in printed
    run = read_run(out)
    assert run.meta["source"] == "emulator" and run.n_samples > 40
    # the summary's failed reads are the driver's, as the sidecar keeps them
    assert f", {run.meta['comm']['reads_failed']} failed reads\n" in printed, printed
    # a fresh recording has no motion capture: `cobra compare` gives the joint metrics only
    plots = tmp_path / "plots"
    args = parse(cmd_compare, ["compare", str(out), "--json", "--plots", str(plots)])
    assert args.func(args) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out)
    assert report["head_omitted"].startswith("no sample has a head pose in both runs (a joint-only run")
    assert report["head_final_error_m"] is None
    # the ideal emulated servos lag by 30 ms, the simulated ones more: a few centiradians apart
    assert 0.001 < report["joint_rmse_rad"]["mean"] < 0.1
    assert "no head figures" in captured.err
    assert sorted(p.name for p in plots.iterdir()) == ["joints_5_6.png", "replay.html", "window_correlation.png"]


def test_record_stops_on_an_emulated_overload_then_refuses_to_connect(tmp_path: Path, emulate, capsys) -> None:
    link, _ = emulate("--fault", "overload:3@0.5")
    out = tmp_path / "overload.csv"
    argv = ["record", "--config", str(EXAMPLE), "--port", str(link), "--duration", "2", "--settle", "0",
            "--out", str(out)]
    args = parse(cmd_record, argv)
    assert args.func(args) == 1
    err = capsys.readouterr().err
    assert "cobra record: stopped: joint 3 (ID 3) reported a hardware error: overload" in err
    assert read_run(out).meta["notes"][0].startswith("partial run: joint 3 (ID 3) reported")
    # The servo keeps its error until rebooted: the next recording does not start.
    args = parse(cmd_record, [*argv[:-1], str(tmp_path / "again.csv")])
    assert args.func(args) == 1
    assert "joint 3 (ID 3): hardware error (overload); reboot or power-cycle the servo" in capsys.readouterr().err
    assert not (tmp_path / "again.csv").exists()


def test_emulate_refuses_to_replace_a_file(tmp_path: Path) -> None:
    target = tmp_path / "not-a-link"
    target.write_text("keep")
    args = parse(cmd_emulate, ["emulate", "--port-link", str(target), "--plant", "kinematic"])
    with pytest.raises(FileExistsError, match="not-a-link exists and is not a symlink; refusing to replace it"):
        args.func(args)
    assert target.read_text() == "keep"


@pytest.mark.parametrize("option, message", [
    (["--duration", "0"], "--duration must be > 0 s of wall time, got 0.0"),
    (["--duration", "-1"], "--duration must be > 0 s of wall time, got -1.0"),
    (["--report-every", "-5"], "--report-every must be >= 0 s (0: never), got -5.0"),
])
def test_emulate_refuses_a_duration_or_report_period_out_of_range(option: list[str], message: str) -> None:
    """Before this check ``--duration 0`` served forever and a negative one stopped at once, both
    without a word; it is checked before a pseudo-terminal is opened."""
    args = parse(cmd_emulate, ["emulate", "--plant", "kinematic", *option])
    with pytest.raises(InputError, match=re.escape(message)):
        args.func(args)


def test_record_stopped_by_sigterm_turns_torque_off_and_exits_143(tmp_path: Path, emulate) -> None:
    # `cobra record` as a user runs it, stopped as `timeout` or a process manager would stop it.
    link, _ = emulate()
    out = tmp_path / "term.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "cobra_cli.main", "record", "--config", str(EXAMPLE), "--port", str(link),
         "--duration", "20", "--settle", "0", "--out", str(out)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    while not (line := proc.stdout.readline()).startswith("recording"):
        assert line, proc.stderr.read()
    time.sleep(0.5)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    assert "cobra record: stopped: terminated (SIGTERM); torque off on all 11 servos" in stderr
    assert "(partial run)" in stdout
    run = read_run(out)
    assert run.meta["notes"] == ["partial run: terminated (SIGTERM)"]
    assert run.meta["stop"]["status"] == "terminated"
    assert 0.2 < run.t[-1] < 5.0 and run.n_samples == run.meta["comm"]["samples"]
