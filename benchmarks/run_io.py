"""Run-file speed: reading and writing a long ``cobra-run/1`` file, against NumPy's own parser.

One run of ``--rows`` samples (default 10 000: 200 s logged at 50 Hz, or 100 s at 100 Hz) with
every column the format has: commands, joints, joint velocities, motor currents, head pose, one
tracked body and a string column, 56 columns in all, values rounded to 6 decimals as a recorder
writes them. Best of ``--repeats`` rounds, each path once per round in turn:

- :func:`cobra_model.run_files.read_run` (checks every column and row, reads the sidecar);
- :func:`cobra_model.run_files.write_run` (writes the file and its sidecar, ``force=True``);
- the peer, ``np.loadtxt`` on the same file's numeric columns (NumPy's C parser, no checks);
- Python's ``csv.reader`` over the same file, the floor of any reader built on it (as ours is).

Writes ``benchmarks/results/run_io.{json,md}``.
Run: ``.venv/bin/python benchmarks/run_io.py [--rows 10000] [--repeats 5]``.
"""
from __future__ import annotations

import argparse
import csv
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._results import write_results  # noqa: E402
from benchmarks._timing import best_of_rounds  # noqa: E402
from cobra_model.run import NUM_JOINTS, Run  # noqa: E402
from cobra_model.run_files import read_run, write_run  # noqa: E402


def long_run(n: int) -> Run:
    """A run of ``n`` samples at 50 Hz with every column of the format (values rounded to 6
    decimals): the sidewinding-like commands and joints [rad], velocities [rad/s], currents [A],
    the head's path [m] and yaw quaternion, a tracked tail [m] and a string marker."""
    t = np.arange(n) * 0.02
    q_ref = 0.5 * np.sin(2 * np.pi * 0.5 * t[:, None] + 0.3 * np.arange(NUM_JOINTS))
    yaw = 0.2 * t
    head = np.column_stack([0.01 * t, 0.02 * np.sin(t), np.full(n, 0.045)])
    quat = np.column_stack([np.cos(yaw / 2), np.zeros(n), np.zeros(n), np.sin(yaw / 2)])
    return Run(t=np.round(t, 6), q_ref=np.round(q_ref, 6), q=np.round(0.9 * q_ref, 6),
               head_pos=np.round(head, 6), head_quat=quat, dq=np.round(0.9 * np.cos(q_ref), 6),
               current=np.round(0.1 * q_ref, 6), bodies={"tail": np.round(head - 1.0, 6)},
               extra={"marker": np.array(["x"] * n)})


def csv_rows(path: Path) -> int:
    """Rows of ``path`` through ``csv.reader`` into a list (what our reader starts from)."""
    with path.open(newline="", encoding="utf-8") as fh:
        return len(list(csv.reader(fh)))


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=10_000, help="samples in the run (default 10000)")
    parser.add_argument("--repeats", type=int, default=5, help="rounds; the best is kept (default 5)")
    args = parser.parse_args(argv)
    if args.rows < 2 or args.repeats < 1:
        parser.error(f"--rows must be >= 2 and --repeats >= 1, got {args.rows} and {args.repeats}")

    run = long_run(args.rows)
    with tempfile.TemporaryDirectory() as tmp:
        path = write_run(run, Path(tmp) / "long.csv")
        header = path.read_text(encoding="utf-8").split("\n", 1)[0].split(",")
        numeric = [i for i, name in enumerate(header) if name != "marker"]
        back = read_run(path)
        np.testing.assert_array_equal(back.q, run.q)  # a benchmark of a reader that reads wrong proves nothing
        print(f"{args.rows} rows x {len(header)} columns, {path.stat().st_size / 1e6:.1f} MB; "
              f"{args.repeats} rounds ...", file=sys.stderr)
        best = best_of_rounds({
            "read_run": lambda: read_run(path),
            "write_run": lambda: write_run(run, Path(tmp) / "out.csv", force=True),
            "np.loadtxt": lambda: np.loadtxt(path, delimiter=",", skiprows=1, usecols=numeric),
            "csv.reader": lambda: csv_rows(path),
        }, args.repeats)
        size_mb = path.stat().st_size / 1e6

    peer = best["np.loadtxt"]
    labels = {
        "read_run": "read_run (checks every column and row, reads the sidecar)",
        "write_run": "write_run (file and sidecar)",
        "np.loadtxt": "np.loadtxt, numeric columns (peer)",
        "csv.reader": "csv.reader into a list (floor of a csv-module reader)",
    }
    rows = [{"path": name, "seconds": best[name], "us_per_row": 1e6 * best[name] / args.rows,
             "ratio_to_loadtxt": best[name] / peer} for name in best]
    lines = [f"One run of {args.rows} rows x {len(header)} columns ({size_mb:.1f} MB), best of {args.repeats} "
             "rounds (each path once per round, in turn).", "",
             "| path | s | us / row | ratio to np.loadtxt |", "|---|---:|---:|---:|"]
    lines += [f"| {labels[r['path']]} | {r['seconds']:.3f} | {r['us_per_row']:.1f} | {r['ratio_to_loadtxt']:.2f} |"
              for r in rows]
    markdown = "\n".join(lines)
    print(markdown)
    write_results("run_io", rows, {"rows": args.rows, "columns": len(header), "repeats": args.repeats,
                                   "size_mb": size_mb}, markdown)


if __name__ == "__main__":
    main()
