"""What the gear play's impacts owe to the physics step: convergence, and branches in the play's width.

The gear play (the ``backlash`` effect, :func:`integrators.kernels.gear_step`) joins motor and
output in a plastic impact when the motor reaches a tooth flank. A step finds that the gap
crossed the play during it; :func:`integrators.kernels.gear_impacts` hands the impact's momentum
to the joined bodies at once and moves their positions by the part of the step after the
crossing. Until it did (the eighty-third stop) the momentum was a torque over the next step: an
impact a step late, after the servo and the ground had acted on the rates before it, and a play
a fraction of a step's travel wider or narrower could move an impact by a whole step; a
sidewinding body in stick and slip on the ground can carry that into another head path.
``benchmarks/diagnose_accuracy.py``'s backlash case showed it: the fitted play named right, its
held-out final head 21.5 -> 29.5 mm (32.8 -> 0.8 mm since).

This benchmark measures it on true trajectories (no measurement, no fit) of the robot of
``diagnose_accuracy.py`` (its truth: ``mu_c``, ``joint_damping``, ``motor_km`` off nominal), each
gait 0.35, 0.5, 0.65 Hz for 6 s from rest, with no play and with plays of 0.005 rad (the
confusion matrix's near-limit magnitude), 0.02 rad (the library's realistic one) and 0.04 rad:

- **convergence**: the final head (the floating head's horizontal position) and the joints
  (the mean over joints of the RMS difference of the angles sampled at 50 Hz) at each physics step
  against the same run at the finest step;
- **branches**: at each step, how far the final head moves when the play is 0.25 % or 0.5 %
  wider or narrower (the largest of the four against the run at the play itself), and, as a
  smooth parameter's yardstick, when the joint damping is. A step that resolves the impacts
  moves the head by a play's change about as much as by the damping's.

No seeds: the runs are deterministic and, on the flat, isotropic ground, the same from any start
position and heading up to a rigid motion, so every distance here is. The case looked at while
finding the effect is the realistic play at 0.65 Hz (``diagnose_accuracy.py``'s third held-out run
of seed 42); the other plays and gaits were not. Results:
``benchmarks/results/gear_play_step.{json,md}``; progress to stderr.

Run: ``.venv/bin/python benchmarks/gear_play_step.py [--plays 0.005,0.02,0.04]``.
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from _args import number_list
from _results import publish
from contact_step import mean_joint_rms
from _robot import PARAMETER_ERROR, with_error
from diagnose_accuracy import LIBRARY
from cobra_model import CobraModel, ModelParameters
from cobra_model.gait import SidewindingGait
from integrators.simulator import SimSettings, Simulator

#: Gear plays [rad] (half-widths): the confusion matrix's near-limit, the realistic, twice it.
PLAYS_RAD = (0.005, 0.02, 0.04)
#: The case looked at while finding the effect (play [rad], gait [Hz]).
DEV_CASE = (0.02, 0.65)
GAITS_HZ = (0.35, 0.5, 0.65)
DURATION_S = 6.0
#: Our physics steps [s] (the servo loop keeps its 1 ms period); the last is the reference.
STEPS_S = (1e-3, 5e-4, 2.5e-4, 1.25e-4)
#: Relative changes of the play, and of the joint damping beside it, for the branches.
PLAY_CHANGES = (-0.005, -0.0025, 0.0025, 0.005)
SAMPLE_DT_S = 0.02


def run(model: CobraModel, params: ModelParameters, dt: float, gait_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """The final head position (x, y) [m] and the joint angles (N, 11) [rad] at 50 Hz of one true
    run from rest at the origin."""
    sim = Simulator(model, params, SimSettings(dt=dt))
    gait = SidewindingGait(gait_hz)
    state = sim.rest_state(gait.q_ref(0.0))
    traj = sim.rollout(state, gait.q_ref, DURATION_S, record_every=int(round(SAMPLE_DT_S / dt)))
    return traj.q[-1, :2].copy(), traj.q[:, -model.n_joints:].copy()


def summary(rows: list[dict]) -> list[dict]:
    """Worst and median per play and step, over the gaits."""
    out = []
    for play in dict.fromkeys(r["play_rad"] for r in rows):
        for dt in STEPS_S[:-1]:
            mine = [r for r in rows if r["play_rad"] == play and r["dt_s"] == dt]
            head = np.array([r["head_to_finest_m"] for r in mine])
            joints = np.array([r["joints_to_finest_rad"] for r in mine])
            damping = np.array([r["head_damping_moved_m"] for r in mine])
            entry = {"play_rad": play, "dt_s": dt, "runs": len(mine),
                     "head_to_finest_worst_m": float(head.max()), "head_to_finest_median_m": float(np.median(head)),
                     "joints_to_finest_worst_rad": float(joints.max()),
                     "joints_to_finest_median_rad": float(np.median(joints)),
                     "head_damping_moved_worst_m": float(damping.max()),
                     "head_damping_moved_median_m": float(np.median(damping))}
            if play > 0:
                branch = np.array([r["head_branch_m"] for r in mine])
                entry.update(head_branch_worst_m=float(branch.max()), head_branch_median_m=float(np.median(branch)))
            out.append(entry)
    return out


def markdown(meta: dict) -> str:
    changes = ", ".join(f"{c * 100:+g} %" for c in PLAY_CHANGES)
    lines = ["# The gear play's impacts and the physics step", "",
             f"True runs ({DURATION_S:g} s from rest, gaits {', '.join(f'{g:g}' for g in GAITS_HZ)} Hz; looked at "
             f"while finding the effect: the play {DEV_CASE[0]:g} rad at {DEV_CASE[1]:g} Hz) of `diagnose_accuracy.py`'s "
             "robot, no measurement, no fit. "
             f"Against the same run at {min(STEPS_S) * 1e3:g} ms: the final head's horizontal distance and the joints' "
             f"RMS difference at 50 Hz (mean over joints). Branches: the largest move of the final head when the play "
             f"changes by {changes}, at the same step, and, for comparison, when the joint damping does.", "",
             "| gear play [rad] | our step [ms] | final head to the finest step: worst (median) [mm] | "
             "joints to the finest step: worst (median) [mrad] | final head moved by a play 0.25-0.5 % off: "
             "worst (median) [mm] | by the damping 0.25-0.5 % off: worst (median) [mm] |", "|---:|---:|---|---|---|---|"]
    for s in meta["summary"]:
        branch = (f"{s['head_branch_worst_m'] * 1e3:.1f} ({s['head_branch_median_m'] * 1e3:.1f})"
                  if "head_branch_worst_m" in s else "-")
        lines.append(f"| {s['play_rad']:g} | {s['dt_s'] * 1e3:g} | {s['head_to_finest_worst_m'] * 1e3:.1f} "
                     f"({s['head_to_finest_median_m'] * 1e3:.1f}) | {s['joints_to_finest_worst_rad'] * 1e3:.2f} "
                     f"({s['joints_to_finest_median_rad'] * 1e3:.2f}) | {branch} | "
                     f"{s['head_damping_moved_worst_m'] * 1e3:.1f} ({s['head_damping_moved_median_m'] * 1e3:.1f}) |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plays", default=",".join(map(str, PLAYS_RAD)),
                        help=f"gear plays [rad] (default {','.join(map(str, PLAYS_RAD))})")
    args = parser.parse_args(argv)
    plays = number_list(parser, "--plays", args.plays, float)
    if any(not 0.0 < b <= 0.05 for b in plays):
        parser.error(f"--plays: each in (0, 0.05] rad (the backlash effect's plausible range), got {args.plays!r}")
    model = CobraModel.load()
    truth = with_error()
    rows: list[dict] = []
    t0 = time.perf_counter()
    cases = [(g, b) for g in GAITS_HZ for b in (0.0, *plays)]
    for k, (gait_hz, b) in enumerate(cases):
        print(f"[{k + 1}/{len(cases)} {time.perf_counter() - t0:.0f} s] {gait_hz:g} Hz, play {b:g} rad",
              file=sys.stderr, flush=True)
        params = LIBRARY.transform(truth, {"backlash": b}) if b else truth
        runs = {dt: run(model, params, dt, gait_hz) for dt in STEPS_S}
        head_ref, joints_ref = runs[min(STEPS_S)]
        for dt in STEPS_S[:-1]:
            head, joints = runs[dt]
            damped = [run(model, params.with_values(joint_damping=truth.joint_damping * (1 + c)), dt, gait_hz)[0]
                      for c in PLAY_CHANGES]
            row = {"gait_hz": gait_hz, "play_rad": b, "dt_s": dt,
                   "head_to_finest_m": float(np.linalg.norm(head - head_ref)),
                   "joints_to_finest_rad": mean_joint_rms(joints, joints_ref),
                   "head_damping_moved_m": float(max(np.linalg.norm(m - head) for m in damped))}
            if b:
                moved = [run(model, LIBRARY.transform(truth, {"backlash": b * (1 + c)}), dt, gait_hz)[0]
                         for c in PLAY_CHANGES]
                row["head_branch_m"] = float(max(np.linalg.norm(m - head) for m in moved))
            rows.append(row)
    meta = {"plays_rad": plays, "dev_case": {"play_rad": DEV_CASE[0], "gait_hz": DEV_CASE[1]}, "truth": PARAMETER_ERROR,
            "steps_s": list(STEPS_S), "play_changes": list(PLAY_CHANGES), "duration_s": DURATION_S,
            "summary": summary(rows), "wall_s": time.perf_counter() - t0}
    return publish("gear_play_step", rows, meta, markdown(meta))


if __name__ == "__main__":
    raise SystemExit(main())
