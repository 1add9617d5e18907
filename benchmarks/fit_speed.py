"""Identification speed and quality on the shipped reference dataset: least squares vs PPO.

Prints, in one run: objective evaluations per second one at a time vs batched; for each method
the wall time, the objective evaluations it used and the held-out final head error per gait
before (nominal) and after; and when PPO's best parameters first reached the least-squares
held-out error (summed over the held-out runs), if they did. PPO's progress goes to stderr. Run:
``.venv/bin/python benchmarks/fit_speed.py [--lsq-iterations N] [--ppo-timesteps N]``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from cobra_model import ModelParameters
from held_out import final_head_errors, ppo_progress, time_to_reach
from sysid.dataset import DATA_DIR, load_manifest
from sysid.lsq import fit_lsq
from sysid.objective import Objective
from sysid.report import evaluate_held_out
from sysid.splits import read_runs


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
    train_paths, val_paths = load_manifest(DATA_DIR / "manifest.json")
    train, validation = read_runs(train_paths), read_runs(val_paths)
    nominal = ModelParameters.nominal()
    objective = Objective(train, nominal)
    one, batched = evals_per_second(objective, 1), evals_per_second(objective, 10)
    print(f"# {len(train)} training runs, {len(validation)} held out; {len(nominal.free_names)} free parameters\n")
    print("| objective evaluation | evaluations / s |")
    print("|---|---:|")
    print(f"| one at a time | {one:.2f} |")
    print(f"| batched, 10 parameter vectors | {batched:.2f} ({batched / one:.1f}x) |\n")
    rows = []
    t0 = time.perf_counter()
    lsq = fit_lsq(Objective(train, nominal), max_iterations=args.lsq_iterations)
    rows.append(("least squares (CasADi)", time.perf_counter() - t0, lsq))
    from sysid.ppo import fit_ppo
    t0 = time.perf_counter()
    ppo = fit_ppo(Objective(train, nominal), total_timesteps=args.ppo_timesteps, seed=0,
                  progress=ppo_progress("PPO", args.ppo_timesteps))
    rows.append(("PPO (stable-baselines3)", time.perf_counter() - t0, ppo))
    held = {name: evaluate_held_out(validation, nominal, res.params) for name, _, res in rows}
    freqs = [h.freq_hz for h in next(iter(held.values()))]
    head = " | ".join(f"{f:g} Hz" for f in freqs)
    print(f"| method | wall [s] | evaluations | status | held-out final head error [m], nominal -> fitted: {head} |")
    print("|---|---:|---:|---|" + "---|" * len(freqs))
    for name, wall, res in rows:
        cells = " | ".join(f"{h.gap_before.to_json_dict()['head_final_error_m']:.3f} -> "
                           f"{h.gap_after.to_json_dict()['head_final_error_m']:.3f}" for h in held[name])
        print(f"| {name} | {wall:.0f} | {res.evaluations} | {res.status.value} | {cells} |")
    target = final_head_errors(validation, lsq.params).sum()
    reach = time_to_reach(validation, ppo.extra["best_history"], target)
    print(f"\nPPO reached the least-squares held-out error (summed final head error {target:.4f} m): "
          + (f"after {reach[0]:.0f} s ({reach[1]} timesteps)" if reach else
             f"not within {rows[1][1]:.0f} s ({ppo.extra['timesteps']} timesteps)"))


if __name__ == "__main__":
    main()
