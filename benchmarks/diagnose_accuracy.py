"""Discrepancy workflow accuracy: hidden effect(s) vs named effect(s), gap before/after, wall time.

For each effect of the library, for two pairs of effects hidden together and for no effect,
data are simulated with the effect(s) at a realistic magnitude plus parameter error, measured
like the reference dataset (quantised encoders, mocap noise and dropouts, jittered log), and
diagnosed with the nominal model (``mu_c``, ``joint_damping`` and ``motor_km`` free and 9-60 %
off). Also diagnoses the shipped reference dataset. ``--detection-limit`` instead halves each
effect's magnitude (its distance from the inactive value) until the workflow no longer names it
first (one round per diagnosis), then bisects between the last magnitude named and the first
missed, and gives where the limit lies. The data seeds 3 and 41 were used while the workflow was
developed (:data:`DEV_SEEDS`); the reported figures come from ``--seeds`` (default 42), and the
script refuses a development seed. Tables: ``benchmarks/results/diagnose_accuracy.{json,md}``
(``diagnose_detection_limit.*`` with ``--detection-limit``), also printed; progress to stderr.
Run: ``.venv/bin/python benchmarks/diagnose_accuracy.py [--seeds 42,...] [--cases NAME,...]
[--detection-limit [--halvings N] [--bisections N]]``.
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Callable

import numpy as np

from _results import write_results
from _args import number_list
from _robot import with_error
from cobra_model import CobraModel, ModelParameters
from integrators.simulator import Simulator
from sysid.generators.dataset import DATA_DIR, RunPlan, load_manifest, record
from sysid.discrepancy.diagnose import DiagnoseConfig, Diagnosis, diagnose
from sysid.discrepancy.effects import EffectLibrary
from sysid.identification.splits import read_runs

LIBRARY = EffectLibrary()
#: Realistic magnitudes of each hidden effect (SI units of its main parameter, ``Effect.realistic``).
MAGNITUDES = {e.name: e.realistic for e in LIBRARY}
#: Effects hidden together.
PAIRS = ("joint_coulomb_friction+anisotropic_ground_friction", "actuator_delay+link_mass_error")
#: The parameters the robot has off nominal (``_robot.PARAMETER_ERROR``), fitted from nominal.
FREE = ["mu_c", "joint_damping", "motor_km"]
#: Data seeds used while the workflow was developed: never reported. Seed 41 was the reported seed
#: until 2026-12-04, when its torque-limit case showed the refit after naming stopping short from
#: far starts (``sysid.discrepancy.diagnose.final_refit``) and was studied to fix it.
DEV_SEEDS = (3, 41)


def make_data(effects: dict[str, float], seed: int):
    """6 training and 3 held-out runs of a robot with parameter error and ``effects`` hidden."""
    truth = with_error()
    if effects:
        truth = LIBRARY.transform(truth, effects, frozen=True)
    model = CobraModel.load()
    sim = Simulator(model, truth)
    rng = np.random.default_rng(seed)
    plans = [RunPlan(f"r{i}", f, 6.0, (rng.uniform(-1, 1), rng.uniform(-1, 1)), rng.uniform(0, 2 * np.pi), "train")
             for i, f in enumerate((0.35, 0.5, 0.65) * 3)]
    runs = [record(sim, p, rng, model) for p in plans]
    return runs[:6], runs[6:]


def progress_for(case: str) -> Callable[[str], None]:
    """A progress callback that prints ``[case  elapsed s] message`` to stderr."""
    t0 = time.perf_counter()
    return lambda msg: print(f"[{case} {time.perf_counter() - t0:5.0f} s] {msg}", file=sys.stderr, flush=True)


def run_case(effects: dict[str, float], max_effects: int, seed: int) -> tuple[Diagnosis, float]:
    progress = progress_for("+".join(f"{k}={v:g}" for k, v in effects.items()) or "none")
    train, hold = make_data(effects, seed)
    t0 = time.perf_counter()
    d = diagnose(train, hold, params=ModelParameters.nominal().with_frozen(free=FREE),
                 config=DiagnoseConfig(max_effects=max_effects), progress=progress)
    return d, time.perf_counter() - t0


def scaled(name: str, factor: float) -> float:
    """The realistic magnitude of ``name`` moved ``factor`` of the way from its inactive value."""
    inactive = LIBRARY[name].parameter.value
    return inactive + factor * (MAGNITUDES[name] - inactive)


def accuracy(cases: list[str], seeds: list[int]) -> None:
    """Diagnose every case at every seed (the reference dataset once); write and print the table."""
    rows = []
    for case in cases:
        for seed in ([None] if case == "reference" else seeds):
            if case == "reference":
                tr, va = load_manifest(DATA_DIR / "manifest.json")
                t0 = time.perf_counter()
                d = diagnose(read_runs(tr), read_runs(va), params=ModelParameters.nominal(),
                             config=DiagnoseConfig(max_effects=2), progress=progress_for("reference"))
                wall, hidden = time.perf_counter() - t0, {}
            else:
                hidden = {} if case == "none" else {name: MAGNITUDES[name] for name in case.split("+")}
                d, wall = run_case(hidden, 2, seed)
            named = [e.name for e in d.effects]
            rows.append({"case": case, "seed": seed, "hidden": hidden, "named": named,
                         "all_named": case != "reference" and sorted(named) == sorted(hidden),
                         "structural": [sd.name for sd in d.structural],
                         "head_final_before_m": d.gap_before.head_final_error_m,
                         "head_final_after_m": d.gap_after.head_final_error_m, "wall_s": wall})
    lines = ["# The discrepancy workflow on hidden effects, pairs of effects and the reference dataset", "",
             f"Seeds {', '.join(map(str, seeds))} (developed on {', '.join(map(str, DEV_SEEDS))}); 6 training and 3 "
             f"held-out 6 s runs per case, parameter error on {', '.join(FREE)}, two rounds.", "",
             "| hidden effect(s) | seed | magnitude | named effect(s) | structural | held-out final head error "
             "before -> after [m] | wall [s] |", "|---|---:|---:|---|---|---|---:|"]
    for r in rows:
        mag = ", ".join(f"{v:g}" for v in r["hidden"].values()) or ("(hidden)" if r["case"] == "reference" else "-")
        lines.append(f"| {r['case'].replace('+', ' + ')} | {r['seed'] if r['seed'] is not None else '-'} | {mag} | "
                     f"{', '.join(r['named']) or 'none'} | {', '.join(r['structural']) or '-'} | "
                     f"{r['head_final_before_m']:.4f} -> {r['head_final_after_m']:.4f} | {r['wall_s']:.0f} |")
    judged = [r for r in rows if r["case"] != "reference"]
    pairs = [r for r in judged if "+" in r["case"]]
    lines += ["", f"Every hidden effect named, and nothing else: {sum(r['all_named'] for r in judged)} of {len(judged)} "
              f"cases; pairs: {sum(r['all_named'] for r in pairs)} of {len(pairs)}."]
    markdown = "\n".join(lines)
    write_results("diagnose_accuracy", rows, {"seeds": seeds, "dev_seeds": list(DEV_SEEDS), "free": FREE,
                                              "magnitudes": MAGNITUDES, "pairs": list(PAIRS)}, markdown)
    print(markdown)


def detection_row(name: str, factor: float, seed: int, rows: list[dict]) -> bool:
    """Diagnose ``name`` hidden at ``factor`` of its realistic magnitude, add its row to
    ``rows``, and return whether it was named first."""
    value = scaled(name, factor)
    d, _ = run_case({name: value}, 1, seed)
    first = d.rounds[0][0] if d.rounds and d.rounds[0] else None
    rows.append({"effect": name, "magnitude": value, "named_first": d.effects[0].name if d.effects else None,
                 "best_candidate": first.name if first else None,
                 "held_out_cost_reduction": first.held_out_improvement if first else None,
                 "head_final_before_m": d.gap_before.head_final_error_m,
                 "head_final_after_m": d.gap_after.head_final_error_m})
    print(f"[{name}] {value:.4g}: named {rows[-1]['named_first']}", file=sys.stderr, flush=True)
    return rows[-1]["named_first"] == name


def detection_limit(names: list[str], halvings: int, bisections: int, seed: int) -> None:
    """Per effect: halve its magnitude up to ``halvings`` times; at the first one missed, bisect
    ``bisections`` times between it and the last named (the realistic magnitude counts as named:
    the accuracy table shows it is). Then a summary of where each limit lies; written and printed."""
    rows: list[dict] = []
    limits = []
    for name in names:
        named_f, missed_f = 1.0, None
        for k in range(1, halvings + 1):
            if detection_row(name, 0.5 ** k, seed, rows):
                named_f = 0.5 ** k
            else:
                missed_f = 0.5 ** k
                break
        for _ in range(bisections if missed_f is not None else 0):
            f = 0.5 * (named_f + missed_f)
            if detection_row(name, f, seed, rows):
                named_f = f
            else:
                missed_f = f
        limits.append((name, scaled(name, named_f), None if missed_f is None else scaled(name, missed_f)))
    lines = ["# Detection limit of each effect", "", f"Seed {seed} (developed on {', '.join(map(str, DEV_SEEDS))}); "
             "one round per diagnosis.", "", "| effect | magnitude | named first | held-out cost reduction "
             "(best candidate) | held-out final head error before -> after [m] |", "|---|---:|---|---:|---|"]
    for r in rows:
        red = "-" if r["held_out_cost_reduction"] is None else f"{100 * r['held_out_cost_reduction']:.0f} %"
        lines.append(f"| {r['effect']} | {r['magnitude']:.4g} | {r['named_first'] or 'none'} | {red} "
                     f"({r['best_candidate'] or '-'}) | {r['head_final_before_m']:.4f} -> {r['head_final_after_m']:.4f} |")
    lines += ["", "| effect | weakest named | strongest missed |", "|---|---:|---:|"]
    lines += [f"| {name} | {named:.4g} | {'-' if missed is None else f'{missed:.4g}'} |" for name, named, missed in limits]
    markdown = "\n".join(lines)
    write_results("diagnose_detection_limit", rows, {"seed": seed, "dev_seeds": list(DEV_SEEDS),
                                                     "halvings": halvings, "bisections": bisections,
                                                     "limits": [list(x) for x in limits]}, markdown)
    print(markdown)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="42", help="comma-separated data seeds (default 42; the first one "
                        "for --detection-limit)")
    parser.add_argument("--cases", default=None,
                        help="comma-separated: effect names, NAME+NAME pairs, 'none', 'reference' (default: all)")
    parser.add_argument("--detection-limit", action="store_true",
                        help="halve each effect's magnitude until it is no longer named first")
    parser.add_argument("--halvings", type=int, default=4, help="most halvings per effect (--detection-limit)")
    parser.add_argument("--bisections", type=int, default=2,
                        help="bisections between the last magnitude named and the first missed (--detection-limit)")
    args = parser.parse_args()
    seeds = number_list(parser, "--seeds", args.seeds)
    if set(seeds) & set(DEV_SEEDS):
        parser.error(f"--seeds: give at least one seed, none of the development seeds {DEV_SEEDS}; got {args.seeds!r}")
    for option in ("halvings", "bisections"):
        if getattr(args, option) < 0:
            parser.error(f"--{option} must be >= 0, got {getattr(args, option)}")
    if args.detection_limit:
        names = args.cases.split(",") if args.cases else list(MAGNITUDES)
        unknown = [name for name in names if name not in MAGNITUDES]
        if unknown:
            parser.error(f"--cases: unknown effect(s) {unknown}; known: {', '.join(MAGNITUDES)}")
        detection_limit(names, args.halvings, args.bisections, seeds[0])
        return
    cases = args.cases.split(",") if args.cases else ["none", *MAGNITUDES, *PAIRS, "reference"]
    for case in cases:
        if case not in ("none", "reference"):
            for name in case.split("+"):
                if name not in MAGNITUDES:
                    parser.error(f"--cases: unknown case {name!r}; known: none, reference, {', '.join(MAGNITUDES)}")
    accuracy(cases, seeds)


if __name__ == "__main__":
    main()
