"""Identification speed and quality on the shipped reference dataset: least squares vs PPO.

Measures, in one run: objective evaluations per second one at a time vs batched; for each method
the wall time, the objective evaluations it used and the held-out final head error per gait
before (nominal) and after; and when PPO's best parameters first reached the least-squares
held-out error (summed over the held-out runs), if they did. PPO runs with seed 0 (the seed its
settings were chosen on: ``sysid.identification.ppo.PPOSettings``). Writes the tables to
``benchmarks/results/fit_speed.{json,md}`` and prints them; PPO's progress goes to stderr. Run
alone on the machine (it times itself):
``.venv/bin/python benchmarks/fit_speed.py [--lsq-iterations N] [--ppo-timesteps N]``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from _results import write_results
from cobra_model import ModelParameters
from held_out import final_head_errors, ppo_progress, time_to_reach
from sysid.generators.dataset import DATA_DIR, load_manifest
from sysid.identification.lsq import fit_lsq
from sysid.identification.objective import Objective
from sysid.gap.report import evaluate_held_out
from sysid.identification.splits import read_runs


def evals_per_second(objective: Objective, k: int) -> float:
    x0 = objective.params.as_vector()
    X = np.repeat(x0[None], k, axis=0) * np.linspace(0.98, 1.02, k)[:, None]
    X = np.clip(X, *objective.params.bounds())
    objective.residuals(X[:1])          # compile
    t0 = time.perf_counter()
    objective.residuals(X)
    return k / (time.perf_counter() - t0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lsq-iterations", type=int, default=8, help="per horizon stage")
    parser.add_argument("--ppo-timesteps", type=int, default=1024)
    args = parser.parse_args()
    for name in ("lsq_iterations", "ppo_timesteps"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    train_paths, val_paths = load_manifest(DATA_DIR / "manifest.json")
    train, validation = read_runs(train_paths), read_runs(val_paths)
    nominal = ModelParameters.nominal()
    objective = Objective(train, nominal)
    one, batched = evals_per_second(objective, 1), evals_per_second(objective, 10)
    lines = ["# Identification speed on the reference dataset", "",
             f"{len(train)} training runs, {len(validation)} held out; {len(nominal.free_names)} free parameters; "
             f"least squares with {args.lsq_iterations} Jacobians per horizon stage at most, PPO "
             f"{args.ppo_timesteps} timesteps (seed 0).", "",
             "| objective evaluation | evaluations / s |", "|---|---:|",
             f"| one at a time | {one:.2f} |", f"| batched, 10 parameter vectors | {batched:.2f} ({batched / one:.1f}x) |",
             ""]
    rows = []
    t0 = time.perf_counter()
    lsq = fit_lsq(Objective(train, nominal), max_iterations=args.lsq_iterations)
    rows.append(("lsq", "least squares (CasADi)", time.perf_counter() - t0, lsq))
    from sysid.identification.ppo import fit_ppo
    t0 = time.perf_counter()
    ppo = fit_ppo(Objective(train, nominal), total_timesteps=args.ppo_timesteps, seed=0,
                  progress=ppo_progress("PPO", args.ppo_timesteps))
    rows.append(("ppo", "PPO (stable-baselines3)", time.perf_counter() - t0, ppo))
    held = {key: evaluate_held_out(validation, nominal, res.params) for key, _, _, res in rows}
    freqs = [h.freq_hz for h in next(iter(held.values()))]
    head = " | ".join(f"{f:g} Hz" for f in freqs)
    lines += [f"| method | wall [s] | evaluations | status | held-out final head error [m], nominal -> fitted: "
              f"{head} |", "|---|---:|---:|---|" + "---|" * len(freqs)]
    records = []
    for key, name, wall, res in rows:
        pairs = [(h.gap_before.head.final, h.gap_after.head.final) for h in held[key]]
        cells = " | ".join(f"{b:.3f} -> {a:.3f}" for b, a in pairs)
        lines.append(f"| {name} | {wall:.0f} | {res.evaluations} | {res.status.value} | {cells} |")
        records.append({"key": key, "method": name, "wall_s": wall, "evaluations": res.evaluations, "status": res.status.value,
                        "held_out_final_head_m": {f"{f:g}": {"nominal": b, "fitted": a}
                                                  for f, (b, a) in zip(freqs, pairs)}})
    target = final_head_errors(validation, lsq.params).sum()
    reach = time_to_reach(validation, ppo.extra["best_history"], target)
    lines += ["", f"PPO reached the least-squares held-out error (summed final head error {target:.4f} m): "
              + (f"after {reach[0]:.0f} s ({reach[1]} timesteps)" if reach else
                 f"not within {rows[1][2]:.0f} s ({ppo.extra['timesteps']} timesteps)")]
    meta = {"train_runs": len(train), "held_out_runs": len(validation), "free": list(nominal.free_names),
            "lsq_iterations_per_stage": args.lsq_iterations, "ppo_timesteps": args.ppo_timesteps, "ppo_seed": 0,
            "evaluations_per_s": {"one": one, "batched_10": batched}, "lsq_target_summed_final_head_m": target,
            "ppo_reached_lsq": {"seconds": reach[0], "timesteps": reach[1]} if reach else None}
    md = "\n".join(lines)
    write_results("fit_speed", records, meta, md)
    print(md)


if __name__ == "__main__":
    main()
