"""Which part of MuJoCo's contact moves the robot's path: its soft frictional constraint.

``contact_time_constant.py`` shows that MuJoCo's path moves with its contact time constant
(``solref[0]``) and that our ground, a spring-damper normal force with a Coulomb/Stribeck law
on it, follows MuJoCo's stiff contact (1-2 ms) but not its default soft one (20 ms). This
benchmark tests the structural explanation: MuJoCo's contact is a soft constraint on its
friction pyramid's edges, normal and friction together (:mod:`integrators.mujoco_contact`).

Those rows are put into our step (:func:`integrators.mujoco_contact.pyramid_rollout`) and
compared with MuJoCo's twin and with our simulator at MuJoCo's values (the diamond of the pyramid,
``twin_counterpart``), on the same gait from the same rest pose. At MuJoCo's near-rigid 2 ms the
rows, MuJoCo and our simulator must agree (they describe the same rigid contact): that checks
the rows.

No noise and no fit: deterministic, no seeds. Results: ``benchmarks/results/contact_law.{json,md}``.
Run: ``.venv/bin/python benchmarks/contact_law.py [--duration 6] [--gaits 0.35,0.5,0.65]``.
"""
from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np

from _results import write_results
from contact_time_constant import (HEADING_RAD, MUJOCO_STEP_S, TRUTH, our_final_head, parse_run_args,
                                   start_configuration)
from cobra_model import CobraModel, ModelParameters
from cobra_model.gait import SidewindingGait
from integrators import mujoco_twin
from integrators.mujoco_contact import PGS_SWEEPS, SOLIMP, pyramid_rollout
from sysid.generators.mujoco_recording import rollout, twin_counterpart, twin_options

#: MuJoCo's contact time constants [s]: near rigid, and its default.
TIME_CONSTANTS_S = (0.002, 0.02)


def main(argv: list[str] | None = None) -> int:
    duration, gaits = parse_run_args(__doc__.splitlines()[0], argv)
    model = CobraModel.load()
    truth = ModelParameters.nominal().with_values(**TRUTH)
    rows, ours = [], twin_counterpart(truth)
    t_all = time.perf_counter()
    for f in gaits:
        gait = SidewindingGait(f)
        q0 = start_configuration(model, gait)
        simulator = our_final_head(model, ours, gait, duration, q0)
        for tc in TIME_CONSTANTS_S:
            print(f"[{time.perf_counter() - t_all:5.0f} s] {f:g} Hz, {tc * 1e3:g} ms: MuJoCo, then its soft "
                  f"constraint in our step", file=sys.stderr, flush=True)
            options = dataclasses.replace(twin_options(truth), solref=(tc, 1.0), timestep=MUJOCO_STEP_S)
            mj = mujoco_twin.build(model.urdf_path, options, truth)
            _, qm, _ = rollout(mj, q0, gait.q_ref, duration, record_every=int(round(duration / MUJOCO_STEP_S)),
                               error_limit_rad=mujoco_twin.servo_error_limit(options))
            mujoco = qm[-1, :2]
            soft = pyramid_rollout(model, ours, gait, duration, q0, tc)
            rows.append({"gait_hz": f, "time_constant_s": tc,
                         "mujoco_displacement_m": float(np.linalg.norm(mujoco - q0[:2])),
                         "ours_to_mujoco_m": float(np.linalg.norm(simulator - mujoco)),
                         "soft_constraint_to_mujoco_m": float(np.linalg.norm(soft - mujoco)),
                         "soft_constraint_to_ours_m": float(np.linalg.norm(soft - simulator))})
    meta = {"duration_s": duration, "heading_rad": HEADING_RAD, "truth": TRUTH, "mujoco_step_s": MUJOCO_STEP_S,
            "solimp": SOLIMP, "pgs_sweeps": PGS_SWEEPS, "our_step_s": 1e-3,
            "wall_s": time.perf_counter() - t_all}
    md = markdown(rows, meta)
    write_results("contact_law", rows, meta, md)
    print(md)
    return 0


def markdown(rows: list[dict], meta: dict) -> str:
    """The per-gait, per-time-constant table."""
    lines = ["# MuJoCo's soft frictional constraint in our step", "",
             f"Runs of {meta['duration_s']:g} s from rest, heading {meta['heading_rad']:g} rad, no noise; final head "
             "distances. Ours: our simulator at MuJoCo's values (`twin_counterpart`). Soft constraint: MuJoCo's "
             "pyramid-edge rows with its time constant, in our 1 ms step.", "",
             "| gait [Hz] | MuJoCo time constant [ms] | MuJoCo head moved [m] | ours to MuJoCo [m] | "
             "soft constraint to MuJoCo [m] | soft constraint to ours [m] |",
             "|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['gait_hz']:g} | {r['time_constant_s'] * 1e3:g} | {r['mujoco_displacement_m']:.3f} | "
                     f"{r['ours_to_mujoco_m']:.3f} | {r['soft_constraint_to_mujoco_m']:.3f} | "
                     f"{r['soft_constraint_to_ours_m']:.3f} |")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
