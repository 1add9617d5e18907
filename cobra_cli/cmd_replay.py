"""``cobra replay``: a measured run beside simulated ones, in the browser (meshcat).

Without ``--html`` a meshcat server bound to 127.0.0.1 serves the replay until Ctrl-C; with
``--html`` one self-contained HTML file (no network needed to view it) holds the whole replay.
"""
from __future__ import annotations

import argparse
import sys
import time
import webbrowser
from pathlib import Path

from cobra_cli.common import check_writable, load_params
from cobra_cli.progress import progress_bar
from cobra_model.errors import InputError
from cobra_model.model import CobraModel
from cobra_model.run import Run
from cobra_model.run_files import read_run
from integrators.simulate import simulate_like
from viz.replay import DEFAULT_FPS, serve_replay, write_replay_html


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay", help="replay a measured run beside simulated ones in the browser (meshcat)",
        description="Replay a measured run (solid robot, mocap markers, red trail and final-position "
                    "ball) beside simulated runs (translucent ghosts) in a meshcat scene: live from a "
                    "server on 127.0.0.1 until Ctrl-C, or as one self-contained HTML file (--html).")
    p.add_argument("measured", metavar="MEASURED.csv", help="the measured run (cobra-run/1)")
    p.add_argument("--against", action="append", default=[], metavar="SIM.csv",
                   help="a run to show as a ghost, e.g. a simulated reproduction (repeatable)")
    p.add_argument("--params", action="append", default=[], metavar="P.json",
                   help="reproduce the measured run in simulation with this parameter file and show "
                        "it as a ghost (repeatable)")
    p.add_argument("--html", metavar="OUT.html",
                   help="write a self-contained HTML file instead of starting a server")
    p.add_argument("--fps", type=float, default=DEFAULT_FPS,
                   help=f"animation frame rate [frames/s] (default {DEFAULT_FPS:g})")
    p.add_argument("--open", action="store_true", help="open the replay in the default web browser")
    p.add_argument("--force", action="store_true", help="overwrite an existing --html file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    out = check_writable(args.html, args.force) if args.html else None
    if not args.fps > 0:
        raise InputError(f"--fps must be > 0 frames/s, got {args.fps}")
    try:
        import viz._meshcat  # noqa: F401  (fail before any simulation if meshcat is missing)
    except ImportError as exc:
        print(f"cobra replay: error: {exc}", file=sys.stderr)
        return 2
    measured = read_run(args.measured)
    params = [(Path(path).stem, load_params(path)) for path in args.params]
    others: list[tuple[str, Run]] = [(Path(path).stem, read_run(path)) for path in args.against]
    if params:
        model = CobraModel.load()
        for name, prm in params:
            with progress_bar(f"simulating with {name}") as bar:
                others.append((f"{name} (simulated)",
                               simulate_like(measured, params=prm, model=model, progress=bar)))

    if out is not None:
        write_replay_html(measured, others, out, fps=args.fps)
        print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB); open it in any browser, no network needed")
        if args.open:
            webbrowser.open(out.resolve().as_uri())
        return 0

    with serve_replay(measured, others, fps=args.fps) as (url, scene):
        print(f"replaying {scene.duration:.2f} s ({scene.n_frames} frames, {len(scene.tracks)} runs) "
              f"at {url} - press Ctrl-C to stop", flush=True)
        if args.open:
            webbrowser.open(url)
        try:
            wait_for_interrupt()
        except KeyboardInterrupt:
            print("stopped the replay server", file=sys.stderr)
    return 0


def wait_for_interrupt() -> None:
    """Block until Ctrl-C (raises KeyboardInterrupt)."""
    while True:
        time.sleep(3600)
