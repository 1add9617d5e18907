"""Recovery benchmark: known parameters, reference-dataset measurement noise, a guess 30-50 % off.

Data: 9 runs (three per gait, 6 s) of a robot with known parameters, measured like the shipped
dataset (quantised encoders, mocap noise and dropouts); 6 train, 3 held out (one per gait). Every
parameter of the nominal table is free; the starting guess is each true value scaled by a
factor drawn from +-[30 %, 50 %] (seeded). Prints, per parameter, the truth, the guess, the
least-squares estimate, its error and identifiability flag, then the held-out head-error gap
closed by least squares and by PPO. Run: ``.venv/bin/python benchmarks/recovery.py``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from cobra_model import CobraModel, ModelParameters
from integrators.simulator import Simulator
from sysid.dataset import RunPlan, record
from sysid.lsq import fit_lsq
from sysid.objective import Objective
from sysid.report import evaluate_held_out

TRUTH = ModelParameters.nominal().with_values(armature=0.04, joint_damping=0.2, motor_km=0.0095, k1=1.5e4,
                                              k2=40.0, mu_c=0.25, mu_s=0.38, mu_v=1.0, v_s=0.03)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lsq-iterations", type=int, default=12)
    parser.add_argument("--ppo-timesteps", type=int, default=256)
    args = parser.parse_args()
    rng = np.random.default_rng(11)
    model = CobraModel.load()
    sim = Simulator(model, TRUTH)
    plans = [RunPlan(f"r{i}", f, 6.0, (rng.uniform(-1, 1), rng.uniform(-1, 1)), rng.uniform(0, 2 * np.pi), "train")
             for i, f in enumerate((0.35, 0.5, 0.65) * 3)]
    runs = [record(sim, p, rng, model) for p in plans]
    train, held = runs[:6], runs[6:]
    factors = rng.uniform(0.3, 0.5, len(TRUTH)) * rng.choice([-1, 1], len(TRUTH))
    guess_values = {p.name: float(np.clip(p.value * (1 + f), p.min, p.max)) for p, f in zip(TRUTH, factors)}
    guess_values["mu_s"] = max(guess_values["mu_s"], guess_values["mu_c"])
    guess = TRUTH.with_values(**guess_values)
    t0 = time.perf_counter()
    lsq = fit_lsq(Objective(train, guess), max_iterations=args.lsq_iterations)
    wall = time.perf_counter() - t0
    print(f"least squares: {lsq.status.value}, {lsq.evaluations} evaluations, {wall:.0f} s\n")
    print("| parameter | truth | guess | fitted | error | 95 % interval | identifiable |")
    print("|---|---:|---:|---:|---:|---|---|")
    for r in lsq.report:
        err = (r.value - TRUTH.value(r.name)) / TRUTH.value(r.name)
        print(f"| {r.name} | {TRUTH.value(r.name):.4g} | {r.initial:.4g} | {r.value:.4g} | {100 * err:+.2f} % | "
              f"[{r.ci_low:.4g}, {r.ci_high:.4g}] | {r.reason} |")
    from sysid.ppo import fit_ppo
    t0 = time.perf_counter()
    ppo = fit_ppo(Objective(train, guess), total_timesteps=args.ppo_timesteps, seed=0)
    wall_ppo = time.perf_counter() - t0
    print("\n| method | wall [s] | held-out final head error [m], guess -> fitted (per gait) | gap closed |")
    print("|---|---:|---|---:|")
    for name, res, w in (("least squares", lsq, wall), ("PPO", ppo, wall_ppo)):
        h = evaluate_held_out(held, guess, res.params)
        before = np.array([x.gap_before.to_json_dict()["head_final_error_m"] for x in h])
        after = np.array([x.gap_after.to_json_dict()["head_final_error_m"] for x in h])
        cells = ", ".join(f"{b:.3f} -> {a:.3f}" for b, a in zip(before, after))
        print(f"| {name} | {w:.0f} | {cells} | {100 * (1 - after.sum() / before.sum()):.0f} % |")


if __name__ == "__main__":
    main()
