"""How many physics steps a soft contact's time constant needs: our joints against MuJoCo's, by step.

The soft-constraint law relaxes a contact's approach velocity and penetration at the rate
``b = 2 / (d tc)``; the semi-implicit step takes that decay as ``1 - b dt`` per step instead of
``exp(-b dt)``, an error of about ``1 / N`` of each contact transient with ``N = tc / dt`` steps
per time constant (:func:`integrators.simulator.contact_resolved` sets the step from ``N``).
This benchmark measures where that error stops mattering for what a fit is judged on. The
held-out runs of ``benchmarks/mujoco_fit.py`` (8 s, three gaits, measured like the reference
dataset: quantised encoders, motion-capture noise) are made by MuJoCo's twin on its
default (20 ms) and its stiff (2 ms, MuJoCo stepping at 0.25 ms) contact, and reproduced by our
simulator under the soft-constraint law at MuJoCo's own values
(:func:`sysid.generators.mujoco_recording.twin_counterpart`, ``contact_time_constant`` =
MuJoCo's ``solref[0]``) at physics steps of 1, 0.5, 0.25 and 0.125 ms (the servo loop at 1 ms).
No fit: what is left at MuJoCo's values is the model's discretisation and structure, which a fit
can only trade against its parameters.

Reported per configuration and step: the joint RMSE over the encoders' rounding floor (the
bound of the base fit is 1.5 times it) and the final head error, worst and median over cases.
Seeds: :data:`DEV_SEEDS` were looked at while finding the effect (the stiff contact's 0.65 Hz
held-out joints of ``mujoco_fit_residual``); the reported figures come from ``--seeds``
(default :data:`EVAL_SEEDS`). Results: ``benchmarks/results/contact_step.{json,md}``; progress to
stderr.

Run: ``.venv/bin/python benchmarks/contact_step.py [--seeds 201,202,203] [--headings 0.3,2.0]
[--configs twin,stiff]``.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import time

import numpy as np

from _args import number_list
from _results import publish
from _robot import PARAMETER_ERROR, with_error
from mujoco_fit import GAITS_HZ, HEAD_BOUND_M, JOINT_BOUND_FACTOR, JOINT_FLOOR_RAD, holdout_plan
from cobra_model import CobraModel, ModelParameters
from cobra_model.gait import SidewindingGait
from integrators.simulate import simulate_like
from integrators.simulator import STEPS_PER_CONTACT_TIME_CONSTANT, SimSettings, Simulator
from sysid.gap.metrics import compare_runs, joint_rmse
from sysid.generators.mujoco_recording import (RECORD_DT_S, contact_configurations, describe, record_mujoco,
                                               true_trajectory, twin_counterpart, twin_options)

#: Seeds (with heading 0.3 rad) looked at while finding the effect; not reported.
DEV_SEEDS = (102, 103)
EVAL_SEEDS = (201, 202, 203)
HEADINGS_RAD = (0.3, 2.0)
#: Our physics steps [s]; the servo loop keeps its 1 ms period.
STEPS_S = (1e-3, 5e-4, 2.5e-4, 1.25e-4)
HOLDOUT_S = 8.0
#: Height [m] of the fall that measures the step error without ground.
AIR_HEIGHT_M = 400.0
#: MuJoCo's own step is compared with a step this many times finer.
MUJOCO_REFINE = 4


def held_out_runs(options, truth: ModelParameters, seed: int, heading: float, model: CobraModel) -> list:
    """The three held-out runs of ``benchmarks/mujoco_fit.py``'s case (seed, heading), made
    alone: same plans and start, their own noise draws (the same draws for the same seed, at
    any MuJoCo step: the logs' sample times do not depend on it)."""
    rng = np.random.default_rng(seed)
    return [record_mujoco(holdout_plan(f, heading, HOLDOUT_S), options, rng, model, truth) for f in GAITS_HZ]


def mean_joint_rms(a: np.ndarray, b: np.ndarray, skip: int = 0) -> float:
    """Mean over joints of the RMS difference [rad] of two (N, 11) joint-angle series sampled at
    the same times from 0, over their common samples from sample ``skip`` on."""
    n = min(len(a), len(b))
    return float(np.mean(np.sqrt(np.mean((a[skip:n] - b[skip:n]) ** 2, axis=0))))


def own_discretisation(options, truth: ModelParameters, heading: float, model: CobraModel) -> list[float]:
    """MuJoCo's own step error: for each held-out gait, the mean over joints of the RMS
    difference [rad] between MuJoCo's true joint angles at its step and at a
    :data:`MUJOCO_REFINE` times finer one (no measurement noise): how far the data move when the
    engine that made them resolves its contact finer."""
    fine = dataclasses.replace(options, timestep=options.timestep / MUJOCO_REFINE)
    plans = [holdout_plan(f, heading, HOLDOUT_S) for f in GAITS_HZ]
    return [mean_joint_rms(true_trajectory(plan, options, model, truth)[2],
                           true_trajectory(plan, fine, model, truth)[2]) for plan in plans]


def step_error_in_the_air(params: ModelParameters, model: CobraModel) -> dict[float, dict[float, float]]:
    """Our own step error without any ground: the robot falling from :data:`AIR_HEIGHT_M` through
    each held-out gait for :data:`HOLDOUT_S` s; per step and gait, the mean over joints of the RMS
    difference [rad] from the same fall at the finest step (after the gait's 1 s smooth start),
    what the servo, the motor and the joints alone owe to the step."""
    out: dict[float, dict[float, float]] = {dt: {} for dt in STEPS_S}
    for f in GAITS_HZ:
        joints = {}
        for dt in STEPS_S:
            sim = Simulator(model, params, SimSettings(dt=dt))
            rest = sim.rest_state()
            q = rest.q.copy()
            q[2] += AIR_HEIGHT_M
            traj = sim.rollout(sim.state(q), SidewindingGait(f).q_ref, HOLDOUT_S,
                               record_every=int(round(RECORD_DT_S / dt)))
            joints[dt] = traj.q[:, -model.n_joints:]
        for dt in STEPS_S:
            out[dt][f] = mean_joint_rms(joints[dt], joints[min(STEPS_S)], skip=int(round(1.0 / RECORD_DT_S)))
    return out


def model_error(ratio: float) -> float:
    """The model's own share [rad] of a joint RMSE that is ``ratio`` times the rounding floor:
    the encoders' rounding adds its floor in quadrature (independent of the model's error)."""
    return JOINT_FLOOR_RAD * float(np.sqrt(max(ratio ** 2 - 1.0, 0.0)))


def summary(rows: list[dict]) -> list[dict]:
    """Worst and median joint RMSE over the floor and final head error, per configuration and step."""
    out = []
    for config in dict.fromkeys(r["config"] for r in rows):
        for dt in STEPS_S:
            mine = [r for r in rows if r["config"] == config and r["dt_s"] == dt]
            if not mine:
                continue
            ratio = np.array([r["joint_rmse_over_floor"] for r in mine])
            head = np.array([r["head_final_m"] for r in mine])
            err = np.array([r["joint_model_error_rad"] for r in mine])
            out.append({"config": config, "dt_s": dt, "steps_per_time_constant": mine[0]["steps_per_time_constant"],
                        "joint_error_worst_rad": float(err.max()), "joint_error_median_rad": float(np.median(err)),
                        "step_error_worst_rad": float(max(r["joint_step_error_rad"] for r in mine)),
                        "runs": len(mine), "joint_over_floor_worst": float(ratio.max()),
                        "joint_over_floor_median": float(np.median(ratio)),
                        "joint_within_bound": int((ratio <= JOINT_BOUND_FACTOR).sum()),
                        "joint_over_floor_worst_by_gait": {f"{g:g}": float(max(r["joint_rmse_over_floor"] for r in mine
                                                                               if r["gait_hz"] == g))
                                                           for g in GAITS_HZ},
                        "head_final_worst_m": float(head.max()), "head_final_median_m": float(np.median(head))})
    return out


def own_summary(own_rows: list[dict]) -> list[dict]:
    """MuJoCo's own step error (:func:`own_discretisation`'s rows), worst and median per configuration."""
    out = []
    for config in dict.fromkeys(r["config"] for r in own_rows):
        mine = [r for r in own_rows if r["config"] == config]
        err = np.array([r["joint_step_error_rad"] for r in mine])
        out.append({"config": config, "mujoco_dt_s": mine[0]["mujoco_dt_s"],
                    "steps_per_time_constant": mine[0]["steps_per_time_constant"], "runs": len(mine),
                    "joint_error_worst_rad": float(err.max()), "joint_error_median_rad": float(np.median(err))})
    return out


def markdown(rows: list[dict], meta: dict) -> str:
    lines = ["# Physics steps per soft-contact time constant: our joints against MuJoCo's", "",
             f"Held-out runs of `mujoco_fit.py` ({HOLDOUT_S:g} s, gaits {', '.join(f'{g:g}' for g in GAITS_HZ)} Hz, "
             f"seeds {', '.join(map(str, meta['seeds']))} (looked at while finding the effect: "
             f"{', '.join(map(str, DEV_SEEDS))}), headings {', '.join(f'{h:g}' for h in meta['headings_rad'])} rad) "
             "reproduced under the soft-constraint law at MuJoCo's own values, no fit. Joint RMSE over the encoders' "
             f"rounding floor ({JOINT_FLOOR_RAD * 1e3:.3f} mrad; the base fit's bound is {JOINT_BOUND_FACTOR:g} x); "
             f"the rule in use takes at least {meta['rule_steps_per_time_constant']} steps per time constant.", "",
             "| MuJoCo contact | our step [ms] | steps per time constant | joint RMSE / floor: worst (median) | "
             "worst by gait | within the bound | the model's share [mrad]: worst (median) | "
             "our own step error [mrad]: worst | final head: worst (median) [m] |",
             "|---|---:|---:|---|---|---:|---|---:|---|"]
    for s in summary(rows):
        by_gait = ", ".join(f"{g} Hz {v:.2f}" for g, v in s["joint_over_floor_worst_by_gait"].items())
        lines.append(f"| {s['config']} | {s['dt_s'] * 1e3:g} | {s['steps_per_time_constant']:g} | "
                     f"{s['joint_over_floor_worst']:.2f} ({s['joint_over_floor_median']:.2f}) | {by_gait} | "
                     f"{s['joint_within_bound']}/{s['runs']} | {s['joint_error_worst_rad'] * 1e3:.2f} "
                     f"({s['joint_error_median_rad'] * 1e3:.2f}) | {s['step_error_worst_rad'] * 1e3:.2f} | "
                     f"{s['head_final_worst_m']:.3f} "
                     f"({s['head_final_median_m']:.3f}) |")
    lines += ["", "The model's share: the joint RMSE less the encoders' rounding floor, in quadrature. Our own step "
              f"error: our true joint angles at the step against ours at {min(STEPS_S) * 1e3:g} ms (no measurement). "
              "MuJoCo's own "
              f"step error: its true joint angles (no measurement) at its step against a {MUJOCO_REFINE} times finer "
              "one, per held-out gait and heading; what the data move when the engine that made them resolves its "
              "contact finer, and the joint RMSE over the floor a model that is exact at the finer step would show.",
              "", "| MuJoCo contact | MuJoCo's step [ms] | steps per time constant | against a finer step [mrad]: "
              "worst (median) | as joint RMSE / floor: worst |", "|---|---:|---:|---|---:|"]
    for s in meta["mujoco_own_step"]:
        worst = float(np.hypot(1.0, s["joint_error_worst_rad"] / JOINT_FLOOR_RAD))
        lines.append(f"| {s['config']} | {s['mujoco_dt_s'] * 1e3:g} | {s['steps_per_time_constant']:g} | "
                     f"{s['joint_error_worst_rad'] * 1e3:.2f} ({s['joint_error_median_rad'] * 1e3:.2f}) | {worst:.2f} |")
    lines += ["", f"Our own step error without any ground (falling from {AIR_HEIGHT_M:g} m through the gait: the servo, "
              f"the motor and the joints alone), against {min(STEPS_S) * 1e3:g} ms, after the 1 s smooth start:", "",
              "| our step [ms] | " + " | ".join(f"{g:g} Hz [mrad]" for g in GAITS_HZ) + " |",
              "|---:|" + "---:|" * len(GAITS_HZ)]
    for dt, by_gait in meta["step_error_in_the_air_rad"].items():
        lines.append(f"| {float(dt) * 1e3:g} | " + " | ".join(f"{e * 1e3:.2f}" for e in by_gait.values()) + " |")
    lines += ["", "MuJoCo's contacts: " + "; ".join(f"{c}: {d}" for c, d in meta["configs"].items()) + "."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    truth = with_error()
    configs = contact_configurations(twin_options(truth))
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--configs", default="twin,stiff",
                        help="MuJoCo contacts, pyramidal ones (the soft-constraint law is MuJoCo's pyramid; "
                             "default twin,stiff)")
    parser.add_argument("--seeds", default=",".join(map(str, EVAL_SEEDS)),
                        help=f"noise seeds (default {','.join(map(str, EVAL_SEEDS))}; {DEV_SEEDS} looked at while "
                             "finding the effect)")
    parser.add_argument("--headings", default=",".join(map(str, HEADINGS_RAD)), help="training headings [rad]")
    args = parser.parse_args(argv)
    chosen = [c for c in args.configs.split(",") if c]
    pyramidal = [c for c, options in configs.items() if options.cone == "pyramidal"]
    if not chosen or any(c not in pyramidal for c in chosen):
        parser.error(f"--configs: choose among the pyramidal configurations {', '.join(pyramidal)}, got {args.configs!r}")
    seeds = number_list(parser, "--seeds", args.seeds)
    headings = number_list(parser, "--headings", args.headings, float)
    model = CobraModel.load()
    rows: list[dict] = []
    own_rows: list[dict] = []
    t0 = time.perf_counter()
    cases = [(c, s, h) for c in chosen for s in seeds for h in headings]
    for k, (config, seed, heading) in enumerate(cases):
        options = configs[config]
        params = twin_counterpart(truth).with_contact_law("soft_constraint").with_values(
            contact_time_constant=options.solref[0])
        print(f"[{k + 1}/{len(cases)} {time.perf_counter() - t0:.0f} s] {config}, seed {seed}, heading {heading:g} rad",
              file=sys.stderr, flush=True)
        if seed == seeds[0]:  # no noise: one per heading
            for gait, own in zip(GAITS_HZ, own_discretisation(options, truth, heading, model)):
                own_rows.append({"config": config, "heading_rad": heading, "gait_hz": gait,
                                 "mujoco_dt_s": options.timestep,
                                 "steps_per_time_constant": options.solref[0] / options.timestep,
                                 "joint_step_error_rad": own})
        for run in held_out_runs(options, truth, seed, heading, model):
            sims = {dt: simulate_like(run, params=params, settings=SimSettings(dt=dt), model=model) for dt in STEPS_S}
            finest = sims[min(STEPS_S)]
            for dt, sim in sims.items():
                gap = compare_runs(run, sim)
                rows.append({"config": config, "seed": seed, "heading_rad": heading, "gait_hz": run.gait_frequency_hz,
                             "dt_s": dt, "steps_per_time_constant": options.solref[0] / dt,
                             "joint_rmse_rad": gap.mean_joint_rmse,
                             "joint_rmse_over_floor": gap.mean_joint_rmse / JOINT_FLOOR_RAD,
                             "joint_model_error_rad": model_error(gap.mean_joint_rmse / JOINT_FLOOR_RAD),
                             "joint_step_error_rad": float(np.mean(joint_rmse(finest, sim))),
                             "head_final_m": gap.head.final})
    air = step_error_in_the_air(twin_counterpart(truth).with_contact_law("soft_constraint"), model)
    meta = {"configs": {c: describe(configs[c]) for c in chosen},
            "step_error_in_the_air_rad": {f"{dt:g}": {f"{g:g}": e for g, e in by_gait.items()}
                                          for dt, by_gait in air.items()},
            "seeds": seeds, "dev_seeds": list(DEV_SEEDS),
            "headings_rad": headings, "steps_s": list(STEPS_S), "holdout_s": HOLDOUT_S, "truth": PARAMETER_ERROR,
            "joint_floor_rad": JOINT_FLOOR_RAD, "joint_bound_factor": JOINT_BOUND_FACTOR, "head_bound_m": HEAD_BOUND_M,
            "rule_steps_per_time_constant": STEPS_PER_CONTACT_TIME_CONSTANT, "summary": summary(rows),
            "mujoco_own_step": own_summary(own_rows), "mujoco_own_step_rows": own_rows,
            "wall_s": time.perf_counter() - t0}
    return publish("contact_step", rows, meta, markdown(rows, meta))


if __name__ == "__main__":
    raise SystemExit(main())
