"""How far MuJoCo's contact time constant moves the robot, and how far our ground can follow.

Issue 16's base fit is judged on MuJoCo-made runs. This benchmark separates what a fit can
recover from what our model cannot express: the same gait, from the same rest pose, is run in
MuJoCo's twin (:mod:`sysid.generators.mujoco_recording`, no effect added) at contact time constants
(``solref[0]``) from 1 ms to 40 ms, and in our simulator at MuJoCo's own values (sliding friction
``mu_c = mu_s``, the diamond of the pyramidal cone ``friction_cone`` at its bound, capsule ends
``contact_rounding`` = the module radius, no viscous ground term, the stiffest ground of the
parameter table). For each gait the table gives MuJoCo's head displacement after ``--duration``
s at each time constant, the distance of our final head position from MuJoCo's, and the
closest our simulator gets to MuJoCo's over a one-at-a-time sweep of its ground parameters
(``SWEEP``) around MuJoCo's values. A PNG plots the final-head distance against the time constant.

No noise and no fit: both engines are deterministic, so there are no seeds. MuJoCo runs at
0.25 ms steps for every time constant (it needs a time constant of at least two steps).
Results: ``benchmarks/results/contact_time_constant.{json,md,png}``; progress to stderr.

Run: ``.venv/bin/python benchmarks/contact_time_constant.py [--duration 6] [--gaits 0.35,0.5,0.65]``.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from _results import RESULTS_DIR, write_results
from _args import number_list
from _robot import PARAMETER_ERROR, with_error
from cobra_model import CobraModel, ModelParameters
from cobra_model.gait import SidewindingGait
from integrators import mujoco_twin
from integrators.simulator import Simulator
from sysid.generators.mujoco_recording import rollout, twin_counterpart, twin_options

#: MuJoCo's contact time constants [s] (its default is 0.02 s).
TIME_CONSTANTS_S = (0.001, 0.002, 0.005, 0.01, 0.02, 0.04)
MUJOCO_STEP_S = 0.00025
HEADING_RAD = 0.3


#: Changes of our ground parameters, one at a time, around :func:`sysid.generators.mujoco_recording.twin_counterpart` (the
#: sliding friction moves both coefficients, static friction stays at least the sliding one).
SWEEP: tuple[dict[str, float], ...] = (
    {"k1": 2e3}, {"k1": 1e4}, {"k2": 10.0}, {"k2": 50.0}, {"mu_c": 0.18, "mu_s": 0.18}, {"mu_c": 0.3, "mu_s": 0.3},
    {"mu_s": 0.36}, {"mu_s": 0.48}, {"mu_s": 0.36, "v_s": 0.01}, {"mu_s": 0.36, "v_s": 0.2}, {"mu_v": 0.5},
    {"mu_v": 2.0}, {"friction_cone": 0.0}, {"friction_cone": 0.5}, {"contact_rounding": 0.0},
    {"contact_rounding": 0.02},
)


def our_final_head(model: CobraModel, params: ModelParameters, gait: SidewindingGait, duration_s: float,
                   q0: np.ndarray) -> np.ndarray:
    """Final head (x, y) [m] of our simulator from rest at ``q0``."""
    sim = Simulator(model, params)
    traj = sim.rollout(sim.state(q0), gait.q_ref, duration_s, record_every=int(round(duration_s / sim.settings.dt)))
    return traj.q[-1, :2].copy()


def start_configuration(model: CobraModel, gait: SidewindingGait) -> np.ndarray:
    """The rest pose both engines start from: the gait's first command, heading :data:`HEADING_RAD`
    (as ``record_mujoco``)."""
    return Simulator(model).rest_state(gait.q_ref(np.zeros(1))[0], heading_rad=HEADING_RAD).q


def parse_run_args(description: str, argv: list[str] | None) -> tuple[float, list[float]]:
    """``--duration`` [s] and ``--gaits`` [Hz] of the contact benchmarks, checked."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--duration", type=float, default=6.0, help="run length [s] (default 6)")
    parser.add_argument("--gaits", default="0.35,0.5,0.65", help="gait frequencies [Hz]")
    args = parser.parse_args(argv)
    if not args.duration > 1.0:
        parser.error(f"--duration must exceed the gait's 1 s smooth start, got {args.duration} s")
    gaits = number_list(parser, "--gaits", args.gaits, float)
    if any(not f > 0 for f in gaits):
        parser.error(f"--gaits: expected positive frequencies [Hz], got {args.gaits!r}")
    return args.duration, gaits


def main(argv: list[str] | None = None) -> int:
    duration, gaits = parse_run_args(__doc__.splitlines()[0], argv)
    model = CobraModel.load()
    truth = with_error()
    ours = twin_counterpart(truth)
    rows = []
    t_all = time.perf_counter()
    for f in gaits:
        gait = SidewindingGait(f)
        q0 = start_configuration(model, gait)
        start = q0[:2]
        print(f"[{time.perf_counter() - t_all:5.0f} s] {f:g} Hz: our simulator and its sweep", file=sys.stderr,
              flush=True)
        at_values = our_final_head(model, ours, gait, duration, q0)
        swept = [at_values] + [our_final_head(model, ours.with_values(**change), gait, duration, q0)
                               for change in SWEEP]
        for tc in TIME_CONSTANTS_S:
            print(f"[{time.perf_counter() - t_all:5.0f} s] {f:g} Hz: MuJoCo, time constant {tc * 1e3:g} ms",
                  file=sys.stderr, flush=True)
            options = dataclasses.replace(twin_options(truth), solref=(tc, 1.0), timestep=MUJOCO_STEP_S)
            mj = mujoco_twin.build(model.urdf_path, options, truth)
            _, q, _ = rollout(mj, q0, gait.q_ref, duration, record_every=int(round(duration / MUJOCO_STEP_S)),
                              error_limit_rad=mujoco_twin.servo_error_limit(options))
            final = q[-1, :2]
            rows.append({"gait_hz": f, "time_constant_s": tc, "mujoco_displacement_m": (final - start).tolist(),
                         "ours_displacement_m": (at_values - start).tolist(),
                         "distance_at_mujoco_values_m": float(np.linalg.norm(at_values - final)),
                         "closest_of_sweep_m": float(min(np.linalg.norm(s - final) for s in swept))})
    meta = {"duration_s": duration, "heading_rad": HEADING_RAD, "truth": PARAMETER_ERROR,
            "mujoco_step_s": MUJOCO_STEP_S,
            "ours": {n: ours.value(n)
                     for n in ("mu_c", "mu_s", "mu_v", "friction_cone", "contact_rounding", "k1", "k2")},
            "sweep": list(SWEEP), "wall_s": time.perf_counter() - t_all}
    md = markdown(rows, meta)
    write_results("contact_time_constant", rows, meta, md)
    plot(rows, RESULTS_DIR / "contact_time_constant.png")
    print(md)
    return 0


def markdown(rows: list[dict], meta: dict) -> str:
    """The per-gait, per-time-constant table."""
    lines = ["# MuJoCo's contact time constant against our ground", "",
             f"Runs of {meta['duration_s']:g} s from rest, heading {meta['heading_rad']:g} rad, no noise. Ours at "
             f"MuJoCo's values: " + ", ".join(f"{k} {v:g}" for k, v in meta["ours"].items()) + ". "
             "Sweep, one change at a time: "
             + "; ".join(", ".join(f"{k} {v:g}" for k, v in c.items()) for c in meta["sweep"]) + ".",
             "", "| gait [Hz] | MuJoCo time constant [ms] | MuJoCo head displacement (x, y) [m] | "
             "ours at MuJoCo's values: final head distance [m] | closest of our sweep [m] |",
             "|---:|---:|---|---:|---:|"]
    for r in rows:
        dx, dy = r["mujoco_displacement_m"]
        lines.append(f"| {r['gait_hz']:g} | {r['time_constant_s'] * 1e3:g} | ({dx:.3f}, {dy:.3f}) | "
                     f"{r['distance_at_mujoco_values_m']:.3f} | {r['closest_of_sweep_m']:.3f} |")
    return "\n".join(lines)


def plot(rows: list[dict], path) -> None:
    """Final head distance (ours at MuJoCo's values, and the closest of the sweep) against the time constant."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for f in dict.fromkeys(r["gait_hz"] for r in rows):
        sub = [r for r in rows if r["gait_hz"] == f]
        tc = [r["time_constant_s"] * 1e3 for r in sub]
        line, = ax.plot(tc, [r["distance_at_mujoco_values_m"] for r in sub], "o-", label=f"{f:g} Hz, MuJoCo's values")
        ax.plot(tc, [r["closest_of_sweep_m"] for r in sub], "s--", color=line.get_color(),
                label=f"{f:g} Hz, closest of sweep")
    ax.axhline(0.05, color="k", lw=0.8, ls=":", label="5 cm bound")
    ax.set_xscale("log")
    ax.set_xlabel("MuJoCo contact time constant solref[0] [ms]")
    ax.set_ylabel("final head distance, ours vs MuJoCo [m]")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
