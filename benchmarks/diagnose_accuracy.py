"""Discrepancy workflow accuracy: hidden effect(s) vs named effect(s), gap before/after, wall time.

For each effect of the library, for two pairs of effects hidden together and for no effect,
data are simulated with the effect(s) at a realistic magnitude plus parameter error, measured
like the reference dataset (quantised encoders, mocap noise and dropouts, jittered log), and
diagnosed with the nominal model (``mu_c``, ``joint_damping`` and ``motor_km`` free and 9-60 %
off). Also diagnoses the shipped reference dataset. ``--detection-limit`` instead halves each
effect's magnitude (its distance from the inactive value) until the workflow no longer names it
first (one round per diagnosis), then bisects between the last magnitude named and the first
missed, and prints where the limit lies. Progress goes to stderr, the Markdown tables to stdout.
Run: ``.venv/bin/python benchmarks/diagnose_accuracy.py [--cases NAME,...] [--detection-limit
[--halvings N] [--bisections N]]``.
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Callable

import numpy as np

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
FREE = ["mu_c", "joint_damping", "motor_km"]


def make_data(effects: dict[str, float], seed: int = 3):
    """6 training and 3 held-out runs of a robot with parameter error and ``effects`` hidden."""
    truth = ModelParameters.nominal().with_values(mu_c=0.24, joint_damping=0.16, motor_km=0.0098)
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


def run_case(effects: dict[str, float], max_effects: int) -> tuple[Diagnosis, float]:
    progress = progress_for("+".join(f"{k}={v:g}" for k, v in effects.items()) or "none")
    train, hold = make_data(effects)
    t0 = time.perf_counter()
    d = diagnose(train, hold, params=ModelParameters.nominal().with_frozen(free=FREE),
                 config=DiagnoseConfig(max_effects=max_effects), progress=progress)
    return d, time.perf_counter() - t0


def scaled(name: str, factor: float) -> float:
    """The realistic magnitude of ``name`` moved ``factor`` of the way from its inactive value."""
    inactive = LIBRARY[name].parameter.value
    return inactive + factor * (MAGNITUDES[name] - inactive)


def accuracy(cases: list[str]) -> None:
    print("| hidden effect(s) | magnitude | named effect(s) | held-out final head error before -> after [m] "
          "| wall [s] |")
    print("|---|---:|---|---|---:|")
    for case in cases:
        if case == "reference":
            tr, va = load_manifest(DATA_DIR / "manifest.json")
            t0 = time.perf_counter()
            d = diagnose(read_runs(tr), read_runs(va), params=ModelParameters.nominal(),
                         config=DiagnoseConfig(max_effects=2), progress=progress_for("reference"))
            wall, mag = time.perf_counter() - t0, "(hidden)"
        else:
            hidden = {} if case == "none" else {name: MAGNITUDES[name] for name in case.split("+")}
            d, wall = run_case(hidden, 2)
            mag = ", ".join(f"{v:g}" for v in hidden.values()) or "-"
        named = ", ".join(e.name for e in d.effects) or "none"
        b, a = d.gap_before.head_final_error_m, d.gap_after.head_final_error_m
        print(f"| {case.replace('+', ' + ')} | {mag} | {named} | {b:.4f} -> {a:.4f} | {wall:.0f} |", flush=True)


def detection_row(name: str, factor: float) -> bool:
    """Diagnose ``name`` hidden at ``factor`` of its realistic magnitude, print its row, and
    return whether it was named first."""
    value = scaled(name, factor)
    d, _ = run_case({name: value}, 1)
    first = d.rounds[0][0] if d.rounds and d.rounds[0] else None
    named = bool(d.effects) and d.effects[0].name == name
    b, a = d.gap_before.head_final_error_m, d.gap_after.head_final_error_m
    print(f"| {name} | {value:.4g} | {'yes' if named else 'no (' + (d.effects[0].name if d.effects else 'none') + ')'}"
          f" | {100 * first.held_out_improvement:.0f} % ({first.name}) | {b:.4f} -> {a:.4f} |", flush=True)
    return named


def detection_limit(names: list[str], halvings: int, bisections: int) -> None:
    """Per effect: halve its magnitude up to ``halvings`` times; at the first one missed, bisect
    ``bisections`` times between it and the last named (the realistic magnitude counts as named:
    the accuracy table shows it is). Then a summary of where each limit lies."""
    print("| effect | magnitude | named first | held-out cost reduction | held-out final head error "
          "before -> after [m] |")
    print("|---|---:|---|---:|---|")
    limits = []
    for name in names:
        named_f, missed_f = 1.0, None
        for k in range(1, halvings + 1):
            if detection_row(name, 0.5 ** k):
                named_f = 0.5 ** k
            else:
                missed_f = 0.5 ** k
                break
        for _ in range(bisections if missed_f is not None else 0):
            f = 0.5 * (named_f + missed_f)
            if detection_row(name, f):
                named_f = f
            else:
                missed_f = f
        limits.append((name, scaled(name, named_f), None if missed_f is None else scaled(name, missed_f)))
    print("\n| effect | weakest named | strongest missed |\n|---|---:|---:|")
    for name, named, missed in limits:
        print(f"| {name} | {named:.4g} | {'-' if missed is None else f'{missed:.4g}'} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", default=None,
                        help="comma-separated: effect names, NAME+NAME pairs, 'none', 'reference' (default: all)")
    parser.add_argument("--detection-limit", action="store_true",
                        help="halve each effect's magnitude until it is no longer named first")
    parser.add_argument("--halvings", type=int, default=4, help="most halvings per effect (--detection-limit)")
    parser.add_argument("--bisections", type=int, default=2,
                        help="bisections between the last magnitude named and the first missed (--detection-limit)")
    args = parser.parse_args()
    for option in ("halvings", "bisections"):
        if getattr(args, option) < 0:
            parser.error(f"--{option} must be >= 0, got {getattr(args, option)}")
    if args.detection_limit:
        names = args.cases.split(",") if args.cases else list(MAGNITUDES)
        unknown = [name for name in names if name not in MAGNITUDES]
        if unknown:
            parser.error(f"--cases: unknown effect(s) {unknown}; known: {', '.join(MAGNITUDES)}")
        detection_limit(names, args.halvings, args.bisections)
        return
    cases = args.cases.split(",") if args.cases else ["none", *MAGNITUDES, *PAIRS, "reference"]
    for case in cases:
        if case not in ("none", "reference"):
            for name in case.split("+"):
                if name not in MAGNITUDES:
                    parser.error(f"--cases: unknown case {name!r}; known: none, reference, {', '.join(MAGNITUDES)}")
    accuracy(cases)


if __name__ == "__main__":
    main()
