"""``cobra demo``: the main job on the shipped data (what ``make demo`` runs)."""
from __future__ import annotations

import argparse
import time

import numpy as np

from cobra_cli.progress import progress_bar
from cobra_model.gait import PAPER_FREQUENCIES_HZ, SidewindingGait
from cobra_model.model import CobraModel
from integrators.runs import simulate_gait


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="run the main job on the shipped data",
                       description="Simulate the paper's three sidewinding gaits and report the head motion.")
    p.add_argument("--duration", type=float, default=10.0, help="simulated time per gait [s] (default 10)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    model = CobraModel.load()
    print(f"COBRA: {model.n_joints} joints, {model.total_mass:.2f} kg, {len(model.features)} contact points")
    print(f"sidewinding gait, nominal parameters, {args.duration:.0f} s per gait:")
    print(f"  {'f [Hz]':>7s} {'head end x [m]':>15s} {'head end y [m]':>15s} {'distance [m]':>13s} "
          f"{'speed [m/s]':>12s} {'wall [s]':>9s}")
    for f in PAPER_FREQUENCIES_HZ:
        t0 = time.perf_counter()
        with progress_bar(f"{f} Hz") as bar:
            run_ = simulate_gait(SidewindingGait(f), args.duration, model=model, progress=bar)
        wall = time.perf_counter() - t0
        d = run_.head_pos[-1, :2] - run_.head_pos[0, :2]
        dist = float(np.hypot(*d))
        print(f"  {f:7.2f} {run_.head_pos[-1, 0]:15.3f} {run_.head_pos[-1, 1]:15.3f} {dist:13.3f} "
              f"{dist / args.duration:12.3f} {wall:9.2f}")
    return 0
