"""Identification speed and quality on the shipped reference dataset: least squares vs PPO.

Measures, in one run: objective evaluations per second one at a time vs batched; least squares
(CasADi) from the nominal parameters, and PPO from the same start under a wall-time budget
(default 600 s, issue 18's bar) for each reported seed; for each the wall time, the parameter
vectors simulated and the held-out final head error per gait before (nominal) and after; and the
summed held-out final head error against wall time along each method's path (least squares'
accepted iterates, PPO's best-so-far after every rollout), with when each came within 10 % of
least squares' final figure. PPO's settings were chosen with seed 0 (:data:`DEVELOPMENT_SEEDS`);
the reported seeds are others. Writes ``benchmarks/results/fit_speed.{json,md,png}`` and prints
the table; progress goes to stderr. Run alone on the machine (it times itself):
``.venv/bin/python benchmarks/fit_speed.py [--lsq-iterations N] [--ppo-budget S] [--ppo-seeds 1,2]``.
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from typing import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import ScalarFormatter

from _results import RESULTS_DIR, write_results
from _args import number_list
from cobra_model import ModelParameters
from cobra_model.run import Run
from held_out import final_head_errors, ppo_progress
from sysid.generators.dataset import DATA_DIR, load_manifest
from sysid.identification.lsq import fit_lsq
from sysid.identification.objective import Objective
from sysid.identification.splits import read_runs

#: Seeds PPO's settings were chosen on (``sysid.identification.ppo.PPOSettings``): not reported.
DEVELOPMENT_SEEDS: tuple[int, ...] = (0,)
#: "Within 10 % of least squares": the summed held-out error at most this times least squares'.
WITHIN = 1.1


def evals_per_second(objective: Objective, k: int) -> float:
    x0 = objective.params.as_vector()
    X = np.repeat(x0[None], k, axis=0) * np.linspace(0.98, 1.02, k)[:, None]
    X = np.clip(X, *objective.params.bounds())
    objective.residuals(X[:1])          # compile
    t0 = time.perf_counter()
    objective.residuals(X)
    return k / (time.perf_counter() - t0)


def held_out_path(runs: Sequence[Run], path: Sequence[tuple[float, int, ModelParameters]]
                  ) -> list[tuple[float, np.ndarray]]:
    """(seconds, final head error [m] of each held-out run) at every point of a method's path."""
    return [(float(sec), final_head_errors(runs, params)) for sec, _, params in path]


def first_within(curve: Sequence[tuple[float, float]], bound_m: float) -> float | None:
    """The first time [s] on ``curve`` at which the error is at most ``bound_m``; None if never."""
    return next((sec for sec, err in curve if err <= bound_m), None)


def plot(curves: dict[str, list[tuple[float, float]]], bound_m: float, budget_s: float) -> None:
    fig = Figure(figsize=(7.0, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for label, curve in curves.items():
        sec, err = np.array(curve).T
        ax.plot(sec, 100 * err, drawstyle="steps-post", marker=".", label=label)
    ax.axhline(100 * bound_m, color="k", linestyle="--", linewidth=0.8, label=f"{WITHIN:g} x least squares' final")
    ax.axvline(budget_s, color="grey", linestyle=":", linewidth=0.8, label=f"{budget_s:g} s")
    ax.set_xscale("symlog", linthresh=10.0)
    ax.set_xlim(left=0.0)
    ax.set_yscale("log")
    ax.yaxis.set_major_formatter(ScalarFormatter())
    ax.yaxis.set_minor_formatter(ScalarFormatter())
    ax.set_xlabel("wall time [s]")
    ax.set_ylabel("summed held-out final head error [cm]")
    ax.set_title("Reference dataset: held-out error against wall time")
    ax.legend(fontsize="small")
    fig.savefig(RESULTS_DIR / "fit_speed.png", dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lsq-iterations", type=int, default=8, help="per horizon stage")
    parser.add_argument("--ppo-budget", type=float, default=600.0, help="PPO wall-time budget per seed [s]")
    parser.add_argument("--ppo-seeds", default="1,2", help="comma-separated PPO seeds to report")
    args = parser.parse_args()
    seeds = number_list(parser, "--ppo-seeds", args.ppo_seeds)
    if args.lsq_iterations < 1 or args.ppo_budget <= 0:
        parser.error("--lsq-iterations must be >= 1 and --ppo-budget > 0")
    train_paths, val_paths = load_manifest(DATA_DIR / "manifest.json")
    train, validation = read_runs(train_paths), read_runs(val_paths)
    nominal = ModelParameters.nominal()
    objective = Objective(train, nominal)
    one, batched = evals_per_second(objective, 1), evals_per_second(objective, 10)

    from sysid.identification.ppo import PPOSettings, fit_ppo
    settings = PPOSettings()
    rows = []
    t0 = time.perf_counter()
    lsq = fit_lsq(Objective(train, nominal), max_iterations=args.lsq_iterations)
    rows.append(("lsq", "least squares (CasADi)", time.perf_counter() - t0, lsq, lsq.extra["iterates"]))
    for seed in seeds:
        t0 = time.perf_counter()
        ppo = fit_ppo(Objective(train, nominal), budget_seconds=args.ppo_budget, total_timesteps=10**9, seed=seed,
                      progress=ppo_progress(f"PPO seed {seed}", 10**9), settings=settings)
        path = [(0.0, 0, nominal), *ppo.extra["best_history"], (ppo.seconds, ppo.extra["timesteps"], ppo.params)]
        rows.append((f"ppo_seed_{seed}", f"PPO (stable-baselines3), seed {seed}", time.perf_counter() - t0, ppo, path))

    # every parameter set is simulated once: a path's last point is the method's result
    before = final_head_errors(validation, nominal)
    paths = {key: held_out_path(validation, path) for key, _, _, _, path in rows}
    curves = {name: [(sec, float(err.sum())) for sec, err in paths[key]] for key, name, _, _, _ in rows}
    target = float(paths["lsq"][-1][1].sum())
    bound = WITHIN * target
    envs = rows[-1][3].extra["n_envs"]
    freqs = [r.gait_frequency_hz for r in validation]
    head = " | ".join(f"{f:g} Hz" for f in freqs)
    lines = ["# Identification speed on the reference dataset", "",
             f"{len(train)} training runs, {len(validation)} held out; {len(nominal.free_names)} free parameters; "
             f"least squares with {args.lsq_iterations} Jacobians per horizon stage at most; PPO for "
             f"{args.ppo_budget:g} s per seed, {settings.episode_runs} training runs per evaluation (spread over the "
             f"gaits), {envs} environments per batched evaluation, seeds {seeds} (settings chosen on seed "
             f"{list(DEVELOPMENT_SEEDS)}, not reported).", "",
             "| objective evaluation (all training runs) | evaluations / s |", "|---|---:|",
             f"| one at a time | {one:.2f} |", f"| batched, 10 parameter vectors | {batched:.2f} ({batched / one:.1f}x) |",
             "",
             f"| method | wall [s] | parameter vectors simulated | status | held-out final head error [m], nominal -> "
             f"fitted: {head} | summed [m] | x least squares | within {100 * (WITHIN - 1):.0f} % of least squares after |",
             "|---|---:|---:|---|" + "---|" * len(freqs) + "---:|---:|---:|"]
    records = []
    for (key, name, wall, res, _), curve in zip(rows, curves.values()):
        pairs = list(zip(before.tolist(), paths[key][-1][1].tolist()))
        summed = float(sum(a for _, a in pairs))
        reach = first_within(curve, bound)
        cells = " | ".join(f"{b:.3f} -> {a:.3f}" for b, a in pairs)
        lines.append(f"| {name} | {wall:.0f} | {res.evaluations} | {res.status.value} | {cells} | {summed:.4f} | "
                     f"{summed / target:.2f} | {f'{reach:.0f} s' if reach is not None else 'not reached'} |")
        records.append({"key": key, "method": name, "wall_s": wall, "evaluations": res.evaluations,
                        "status": res.status.value, "held_out_summed_m": summed, "ratio_to_lsq": summed / target,
                        "within_10pct_after_s": reach,
                        "held_out_final_head_m": {f"{f:g}": {"nominal": b, "fitted": a}
                                                  for f, (b, a) in zip(freqs, pairs)},
                        "held_out_path": curve})
    lines += ["", "Held-out error against wall time: `fit_speed.png` (least squares' accepted iterates, PPO's "
              "best-so-far after every rollout)."]
    plot(curves, bound, args.ppo_budget)
    meta = {"train_runs": len(train), "held_out_runs": len(validation), "free": list(nominal.free_names),
            "lsq_iterations_per_stage": args.lsq_iterations, "ppo_budget_s": args.ppo_budget, "ppo_seeds": seeds,
            "development_seeds": list(DEVELOPMENT_SEEDS), "ppo_settings": dataclasses.asdict(settings),
            "ppo_envs": envs,
            "evaluations_per_s": {"one": one, "batched_10": batched}, "lsq_summed_final_head_m": target}
    md = "\n".join(lines)
    write_results("fit_speed", records, meta, md)
    print(md)


if __name__ == "__main__":
    main()
