"""Which contact law follows MuJoCo's: our compliant ground or the soft-constraint law.

``contact_time_constant.py`` shows that MuJoCo's path moves with its contact time constant
(``solref[0]``) and that our compliant ground (a spring-damper normal force with a
Coulomb/Stribeck law on it) follows MuJoCo's stiff contact (1-2 ms) but not its default soft one
(20 ms). This benchmark tests the structural explanation: MuJoCo's contact is a soft constraint
on its friction pyramid's edges, normal and friction together, solved for all contacts at once
(``ModelParameters.with_contact_law("soft_constraint")``, :func:`integrators.kernels.soft_contact_acceleration`).

Both laws run in our 1 ms step, or the finer one the simulator takes by default for a soft
contact (at least ``STEPS_PER_CONTACT_TIME_CONSTANT`` steps per time constant: 0.25 ms at 2 ms),
with the same servos, motors, joints and geometry, at MuJoCo's values
(:func:`sysid.generators.mujoco_recording.twin_counterpart`) and are compared with MuJoCo's twin
on the same gait from the same rest pose: the final head distance after ``--duration`` s and the
RMS difference of the joint angles (50 Hz samples after the gait's 1 s smooth start; the
encoders' rounding floor, 0.44 mrad, is the scale issue 16 judges a fit by). A run falling from
200 m, where neither engine's ground is reached, checks that the actuators agree, so that what
remains is the contact. The cost
of a step of each law is timed in the same run.

No noise and no fit: deterministic, no seeds. Results: ``benchmarks/results/contact_law.{json,md}``.
Run: ``.venv/bin/python benchmarks/contact_law.py [--duration 6] [--gaits 0.35,0.5,0.65]``.
"""
from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np

from _results import write_results
from _robot import PARAMETER_ERROR, with_error
from contact_time_constant import HEADING_RAD, MUJOCO_STEP_S, parse_run_args, start_configuration
from mujoco_fit import JOINT_FLOOR_RAD
from cobra_model import CobraModel, ModelParameters
from cobra_model.gait import SidewindingGait
from integrators import kernels as K
from integrators import mujoco_twin
from integrators.simulator import Simulator
from sysid.generators.mujoco_recording import rollout, twin_counterpart, twin_options

#: MuJoCo's contact time constants [s]: near rigid, and its default.
TIME_CONSTANTS_S = (0.002, 0.02)
SAMPLE_S = 0.02
SMOOTH_START_S = 1.0
LAWS = ("compliant", "soft_constraint")


#: Height [m] from which the no-ground runs fall: no point reaches the ground in the run.
AIR_HEIGHT_M = 200.0


def ours(model: CobraModel, params: ModelParameters, gait: SidewindingGait,
         duration: float, q0: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Our configurations (``params``' contact law, the simulator's default step for it) every
    :data:`SAMPLE_S` from rest at ``q0``, the wall time per step [us] and the step [s]."""
    sim = Simulator(model, params)
    settings = sim.settings
    t0 = time.perf_counter()
    traj = sim.rollout(sim.state(q0), gait.q_ref, duration, record_every=int(round(SAMPLE_S / settings.dt)))
    return traj.q, (time.perf_counter() - t0) / (duration / settings.dt) * 1e6, settings.dt


def mujoco(model: CobraModel, truth: ModelParameters, gait: SidewindingGait, duration: float, q0: np.ndarray,
           tc: float) -> np.ndarray:
    """MuJoCo's configurations every :data:`SAMPLE_S` (Pinocchio's convention)."""
    options = dataclasses.replace(twin_options(truth), solref=(tc, 1.0), timestep=MUJOCO_STEP_S)
    mj = mujoco_twin.build(model.urdf_path, options, truth)
    _, q, _ = rollout(mj, q0, gait.q_ref, duration, record_every=int(round(SAMPLE_S / MUJOCO_STEP_S)),
                      error_limit_rad=mujoco_twin.servo_error_limit(options))
    return q


def compare(q_ours: np.ndarray, q_mujoco: np.ndarray) -> tuple[float, float]:
    """Final head distance [m] and joint RMS difference after the smooth start [rad]."""
    n = min(len(q_ours), len(q_mujoco))
    start = int(round(SMOOTH_START_S / SAMPLE_S))
    joints = q_ours[start:n, 7:] - q_mujoco[start:n, 7:]
    return float(np.linalg.norm(q_ours[n - 1, :2] - q_mujoco[n - 1, :2])), float(np.sqrt(np.mean(joints**2)))


def main(argv: list[str] | None = None) -> int:
    duration, gaits = parse_run_args(__doc__.splitlines()[0], argv)
    model = CobraModel.load()
    truth = with_error()
    params = twin_counterpart(truth)
    rows, cost = [], {law: [] for law in LAWS}
    t_all = time.perf_counter()
    for f in gaits:
        gait = SidewindingGait(f)
        q0 = start_configuration(model, gait)
        print(f"[{time.perf_counter() - t_all:5.0f} s] {f:g} Hz, no ground", file=sys.stderr, flush=True)
        q_air = q0 + np.eye(len(q0))[2] * AIR_HEIGHT_M
        _, joints_air = compare(ours(model, params, gait, duration, q_air)[0],
                                mujoco(model, truth, gait, duration, q_air, 0.02))
        for tc in TIME_CONSTANTS_S:
            print(f"[{time.perf_counter() - t_all:5.0f} s] {f:g} Hz, {tc * 1e3:g} ms: MuJoCo, then both laws",
                  file=sys.stderr, flush=True)
            q_mj = mujoco(model, truth, gait, duration, q0, tc)
            row = {"gait_hz": f, "time_constant_s": tc, "mujoco_displacement_m": float(np.linalg.norm(q_mj[-1, :2] - q0[:2])),
                   "joint_rms_no_ground_rad": joints_air}
            for law in LAWS:
                law_params = params.with_values(contact_time_constant=tc).with_contact_law(law)
                q_law, us, row[f"{law}_step_s"] = ours(model, law_params, gait, duration, q0)
                row[f"{law}_head_to_mujoco_m"], row[f"{law}_joint_rms_rad"] = compare(q_law, q_mj)
                cost[law].append(us)
            rows.append(row)
    meta = {"duration_s": duration, "heading_rad": HEADING_RAD, "truth": PARAMETER_ERROR,
            "mujoco_step_s": MUJOCO_STEP_S,
            "solimp": list(K.SOFT_SOLIMP), "sample_s": SAMPLE_S, "joint_floor_rad": JOINT_FLOOR_RAD,
            "us_per_step": {law: float(np.median(v)) for law, v in cost.items()},
            "wall_s": time.perf_counter() - t_all}
    md = markdown(rows, meta)
    write_results("contact_law", rows, meta, md)
    print(md)
    return 0


def markdown(rows: list[dict], meta: dict) -> str:
    """The per-gait, per-time-constant table."""
    floor = meta["joint_floor_rad"]
    lines = ["# Which contact law follows MuJoCo's", "",
             f"Runs of {meta['duration_s']:g} s from rest, heading {meta['heading_rad']:g} rad, no noise, our "
             "parameters at MuJoCo's values (`twin_counterpart`), our 1 ms step (the soft constraint at 2 ms: "
             f"{1e3 * min(r['soft_constraint_step_s'] for r in rows):g} ms, the simulator's default for a soft contact "
             "that fast). Head: final head distance from "
             f"MuJoCo's. Joints: RMS joint-angle difference from MuJoCo's after the 1 s smooth start, in mrad "
             f"and in units of the encoders' rounding floor ({floor * 1e3:.2f} mrad). No ground: both engines "
             "falling from 200 m, no ground reached (the actuators alone).", "",
             "| gait [Hz] | MuJoCo time constant [ms] | MuJoCo head moved [m] | compliant: head [m] | "
             "soft constraint: head [m] | compliant: joints [mrad] (x floor) | soft constraint: joints [mrad] "
             "(x floor) | no ground: joints [mrad] |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        joints = [f"{r[f'{law}_joint_rms_rad'] * 1e3:.2f} ({r[f'{law}_joint_rms_rad'] / floor:.1f})" for law in LAWS]
        lines.append(f"| {r['gait_hz']:g} | {r['time_constant_s'] * 1e3:g} | {r['mujoco_displacement_m']:.3f} | "
                     f"{r['compliant_head_to_mujoco_m']:.3f} | {r['soft_constraint_head_to_mujoco_m']:.3f} | "
                     f"{joints[0]} | {joints[1]} | {r['joint_rms_no_ground_rad'] * 1e3:.3f} |")
    us = meta["us_per_step"]
    lines += ["", f"Cost of a step (median over the runs, this machine): compliant {us['compliant']:.1f} us, "
                  f"soft constraint {us['soft_constraint']:.1f} us."]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
