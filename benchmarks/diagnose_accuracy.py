"""Discrepancy workflow accuracy: hidden effect vs named effect, gap before/after, wall time.

For each effect of the library (and for no effect), data are simulated with the effect at a
realistic magnitude plus parameter error, measured like the reference dataset (quantised
encoders, mocap noise and dropouts), and diagnosed with the nominal model. Also diagnoses the
shipped reference dataset. Run: ``.venv/bin/python benchmarks/diagnose_accuracy.py [--only NAME]``.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from cobra_model import CobraModel, ModelParameters
from integrators.simulator import Simulator
from sysid.dataset import DATA_DIR, RunPlan, load_manifest, record
from sysid.diagnose import DiagnoseConfig, diagnose
from sysid.effects import EffectLibrary
from sysid.runsets import read_runs

#: Realistic magnitudes of each hidden effect.
MAGNITUDES = {"joint_coulomb_friction": 0.3, "backlash": 0.02, "actuator_delay": 0.04, "torque_saturation": 2.5,
              "anisotropic_ground_friction": 2.0, "encoder_offset": 0.03, "link_mass_error": 0.8}
FREE = ["mu_c", "joint_damping", "motor_km"]


def make_data(effect: str | None, seed: int = 3):
    truth = ModelParameters.nominal().with_values(mu_c=0.24, joint_damping=0.16, motor_km=0.0098)
    if effect:
        truth = EffectLibrary().transform(truth, {effect: MAGNITUDES[effect]}, frozen=True)
    model = CobraModel.load()
    sim = Simulator(model, truth)
    rng = np.random.default_rng(seed)
    plans = [RunPlan(f"r{i}", f, 6.0, (rng.uniform(-1, 1), rng.uniform(-1, 1)), rng.uniform(0, 2 * np.pi), "train")
             for i, f in enumerate((0.35, 0.5, 0.65) * 3)]
    runs = [record(sim, p, rng, model) for p in plans]
    return runs[:6], runs[6:]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", default=None, help="one effect name, 'none' or 'reference'")
    args = parser.parse_args()
    cases = ["none", *MAGNITUDES, "reference"] if args.only is None else [args.only]
    print("| hidden effect | magnitude | named effect(s) | held-out final head error before -> after [m] | wall [s] |")
    print("|---|---:|---|---|---:|")
    for case in cases:
        if case == "reference":
            tr, va = load_manifest(DATA_DIR / "manifest.json")
            train, hold = read_runs(tr), read_runs(va)
            start, mag = ModelParameters.nominal(), "(hidden)"
        else:
            train, hold = make_data(None if case == "none" else case)
            start = ModelParameters.nominal().with_frozen(free=FREE)
            mag = "-" if case == "none" else f"{MAGNITUDES[case]:g}"
        t0 = time.perf_counter()
        d = diagnose(train, hold, params=start, config=DiagnoseConfig(max_effects=2))
        wall = time.perf_counter() - t0
        named = ", ".join(e["name"] for e in d.effects) or "none"
        b, a = d.gap_before["mean"]["head_final_error_m"], d.gap_after["mean"]["head_final_error_m"]
        print(f"| {case} | {mag} | {named} | {b:.4f} -> {a:.4f} | {wall:.0f} |", flush=True)


if __name__ == "__main__":
    main()
