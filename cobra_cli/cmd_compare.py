"""``cobra compare``: the sim-to-real gap between a measured run and a simulated one.

With one run, the run is first reproduced in simulation (its initial pose and ``q_ref`` columns,
:func:`integrators.simulate.simulate_like`) with the given or the nominal parameters.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from cobra_cli.common import add_contact_option, load_params
from cobra_cli.progress import progress_bar
from cobra_model.errors import InputError
from cobra_model.run import Run
from cobra_model.run_files import read_run
from integrators.simulate import simulate_like
from sysid.gap.metrics import DEFAULT_WINDOW_S, GapReport, compare_runs

#: Files written by ``--plots DIR``: figure key -> file name (PNGs and the 3-D replay).
PLOT_FILES: dict[str, str] = {
    "head_path": "head_path.png",
    "head_error": "head_error.png",
    "joints": "joints_5_6.png",
    "window_correlation": "window_correlation.png",
    "replay": "replay.html",
}


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``cobra compare`` and its options."""
    p = sub.add_parser(
        "compare", help="sim-to-real gap between a measured and a simulated run",
        description="Compare a measured run with a simulated one: head position error (x-y), "
                    "per-joint RMSE, CPG (sine-fit) errors and sliding-window correlation. With "
                    "only MEASURED, the run is reproduced in simulation first (same initial pose "
                    "and commands).")
    p.add_argument("measured", metavar="MEASURED.csv", help="measured run (cobra-run/1)")
    p.add_argument("simulated", metavar="SIMULATED.csv", nargs="?",
                   help="simulated run (default: simulate MEASURED with --params)")
    p.add_argument("--params", metavar="P.json",
                   help="parameter file for the simulation (default: nominal parameters); "
                        "only without SIMULATED")
    add_contact_option(p, "simulate")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.add_argument("--plots", metavar="DIR",
                   help=f"write PNG figures into DIR (created if missing): "
                        f"{', '.join(PLOT_FILES.values())}")
    p.add_argument("--window", type=float, default=DEFAULT_WINDOW_S, metavar="S",
                   help=f"sliding-correlation window [s] (default {DEFAULT_WINDOW_S:g})")
    p.add_argument("--force", action="store_true", help="overwrite existing PNGs in DIR")
    p.set_defaults(func=run)


def plot_paths(directory: str | Path, force: bool) -> dict[str, Path]:
    """The PNG paths ``--plots DIR`` writes, checked before any work is done.

    Raises:
        InputError: if ``directory`` exists and is not a directory.
        FileExistsError: if a PNG exists and ``force`` is false (naming the files and --force).
    """
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise InputError(f"--plots {directory}: exists and is not a directory")
    paths = {key: directory / name for key, name in PLOT_FILES.items()}
    existing = [str(path) for path in paths.values() if path.exists()]
    if existing and not force:
        verb = "exists" if len(existing) == 1 else "exist"
        raise FileExistsError(f"{', '.join(existing)} already {verb}; pass --force to overwrite")
    return paths


def write_plots(measured: Run, simulated: Run, report: GapReport,
                paths: dict[str, Path]) -> list[Path]:
    """Draw the comparison figures into ``paths`` (keys of :data:`PLOT_FILES`); returns the files."""
    # Imported here so that matplotlib does not slow down every other `cobra` command.
    from sysid.gap import plots

    from viz.replay import write_replay_html

    pair = [("measured", measured), ("simulated", simulated)]
    written = []
    if not report.head_omitted:
        written += [plots.plot_head_paths(pair, paths["head_path"]),
                    plots.plot_head_errors([("simulated", report)], paths["head_error"])]
    written += [plots.plot_joint_responses(pair, paths["joints"]),
                plots.plot_window_correlation([("simulated", report)], paths["window_correlation"])]
    written.append(write_replay_html(measured, [("simulated", simulated)], paths["replay"]))
    return written


def run(args: argparse.Namespace) -> int:
    """Compare the runs (simulating the measured one if needed); print the report, draw the plots."""
    if not (np.isfinite(args.window) and args.window > 0):
        raise InputError(f"--window must be a positive number of seconds, got {args.window}")
    if args.simulated is not None and (args.params is not None or args.contact is not None
                                       or args.friction_step is not None):
        raise InputError("--params, --contact and --friction-step are only used when SIMULATED.csv is not given "
                         "(the measured run is then simulated with them)")
    paths = plot_paths(args.plots, args.force) if args.plots else None
    measured = read_run(args.measured)
    inputs: dict[str, Any] = {"measured": str(measured.source)}
    if args.simulated is not None:
        simulated = read_run(args.simulated)
        inputs["simulated"] = str(simulated.source)
        heading = f"compare {measured.source} (measured) with {simulated.source} (simulated)"
    else:
        params = load_params(args.params, args.contact, args.friction_step)
        with progress_bar("simulating") as bar:
            simulated = simulate_like(measured, params=params, progress=bar)
        inputs["simulated"] = None
        inputs["params"] = args.params or "nominal"
        heading = (f"compare {measured.source} (measured) with its simulation "
                   f"({f'parameters {args.params}' if args.params else 'nominal parameters'}, "
                   f"{params.contact_law} contact law)")
    report = compare_runs(measured, simulated, window_s=args.window)
    if args.json:
        print(json.dumps({**report.to_json_dict(), "inputs": inputs}, indent=2))
    else:
        print(heading)
        print(report.format_table())
    if paths is not None:
        written = write_plots(measured, simulated, report, paths)
        # Keep stdout pure JSON with --json; the file list is a diagnostic then.
        if report.head_omitted:
            print("no head figures: the measured run has no head pose (the replay shows its joints on the "
                  "simulated head pose)", file=sys.stderr if args.json else sys.stdout)
        print(f"wrote {len(written)} figures: {', '.join(map(str, written))}",
              file=sys.stderr if args.json else sys.stdout)
    return 0
