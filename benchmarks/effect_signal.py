"""How strongly each hidden effect of the confusion matrix shows in its runs, against the noise.

The confusion matrix (``benchmarks/diagnose_matrix.py``) hides each library effect at a realistic
magnitude and at one near its detection limit (:func:`~benchmarks.diagnose_matrix.near_limit`:
a quarter of the way from where the effect starts to act to its realistic one). Whether a magnitude is
*near* the limit or *past* it depends on the runs: a torque limit above every torque the gait
demands does nothing at all. This script measures, on the matrix's own run design
(:func:`~benchmarks.diagnose_matrix.make_runs`: two 0.5/0.65 Hz training runs and one 0.5 Hz
held-out run of 3 s, the same parameter error), what each hidden effect changes in the measured
data, independently of any diagnosis method:

- the RMS change of the encoder readings over the three runs, in units of the encoders'
  quantisation floor (one count of 4096 per turn, RMS = count / sqrt(12) = 0.44 mrad);
- the largest change of the final head position (x, y), in units of the motion capture's
  noise on one planar sample (0.5 mm per axis: 0.71 mm).

Each effect's runs are made with and without the effect from the same seed (the same poses and
noise draws), so the difference is the effect's alone (up to the quantisation of the readings).
A ratio below 1 on both channels means the effect moves the data by less than its noise: no
method can be asked to name it from these runs.

Writes ``benchmarks/results/effect_signal.{json,md}``.
Run: ``.venv/bin/python benchmarks/effect_signal.py [--engines sim,mujoco] [--seeds 37,38,39]``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._results import write_results  # noqa: E402
from benchmarks._args import number_list  # noqa: E402
from benchmarks.diagnose_matrix import ENGINES, EVAL_SEEDS, Job, make_runs, near_limit  # noqa: E402
from cobra_model import CobraModel  # noqa: E402
from cobra_model.run import Run  # noqa: E402
from sysid.identification.objective import SENSOR_NOISE  # noqa: E402
from sysid.discrepancy.effects import EffectLibrary  # noqa: E402
from sysid.generators.dataset import MOCAP_NOISE_M  # noqa: E402

#: RMS of the encoders' quantisation error [rad]: one count, uniformly distributed.
ENCODER_FLOOR_RAD = SENSOR_NOISE["joints"]
#: RMS of the motion capture's error on one planar (x, y) head position [m].
HEAD_FLOOR_M = MOCAP_NOISE_M * np.sqrt(2)
DURATION_S = 3.0


def signal(hidden: list[Run], base: list[Run]) -> tuple[float, float]:
    """(RMS change of the encoder readings [rad] over all runs, largest change of the final head
    (x, y) [m]) of the runs ``hidden`` against the same runs ``base`` without the effect."""
    dq = np.concatenate([(h.q - b.q).ravel() for h, b in zip(hidden, base)])
    dh = max(float(np.linalg.norm(h.head_pos[-1, :2] - b.head_pos[-1, :2])) for h, b in zip(hidden, base))
    return float(np.sqrt(np.mean(dq ** 2))), dh


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--engines", default=",".join(ENGINES), help=f"engines (default {','.join(ENGINES)})")
    parser.add_argument("--seeds", default=",".join(map(str, EVAL_SEEDS)),
                        help=f"data seeds (default the matrix's {','.join(map(str, EVAL_SEEDS))})")
    args = parser.parse_args(argv)
    engines = [e for e in args.engines.split(",") if e]
    unknown = sorted(set(engines) - set(ENGINES))
    if unknown:
        parser.error(f"--engines: unknown {unknown}; known: {', '.join(ENGINES)}")
    seeds = number_list(parser, "--seeds", args.seeds)
    model, library = CobraModel.load(), EffectLibrary()
    rows = []
    for engine in engines:
        for seed in seeds:
            base = make_runs(Job(engine, None, None, "null", seed, DURATION_S), model)
            for effect in library.names:
                for level, magnitude in (("realistic", library[effect].realistic), ("near_limit", near_limit(effect, DURATION_S))):
                    joints, head = signal(make_runs(Job(engine, effect, magnitude, level, seed, DURATION_S), model), base)
                    rows.append({"engine": engine, "effect": effect, "level": level, "magnitude": magnitude,
                                 "unit": "" if library[effect].parameter.unit == "1" else library[effect].parameter.unit, "seed": seed, "joints_rms_rad": joints,
                                 "joints_over_floor": joints / ENCODER_FLOOR_RAD, "head_final_m": head,
                                 "head_over_floor": head / HEAD_FLOOR_M})
                    print(f"{engine} seed {seed} {effect} {level} {magnitude:g}: joints {joints * 1e3:.2f} mrad "
                          f"({joints / ENCODER_FLOOR_RAD:.1f} x floor), head {head * 1e3:.1f} mm "
                          f"({head / HEAD_FLOOR_M:.1f} x floor)", flush=True)
    lines = [f"What each hidden effect of the confusion matrix changes in its runs (two 0.5/0.65 Hz training runs and "
             f"a 0.5 Hz held-out run of {DURATION_S:g} s, `benchmarks/diagnose_matrix.py`'s design; seeds "
             f"{', '.join(map(str, seeds))}), against the runs without it from the same seed: RMS change of the "
             f"encoder readings over floor ({ENCODER_FLOOR_RAD * 1e3:.2f} mrad, one count's quantisation) and "
             f"largest final head change over floor ({HEAD_FLOOR_M * 1e3:.2f} mm, motion capture on one planar "
             f"sample). Range over the seeds.", "",
             "| engine | effect | level | magnitude | joints [mrad] | joints / floor | final head [mm] | head / floor |",
             "|---|---|---|---:|---:|---:|---:|---:|"]
    for engine in engines:
        for effect in dict.fromkeys(r["effect"] for r in rows if r["engine"] == engine):
            for level in ("realistic", "near_limit"):
                sel = [r for r in rows if (r["engine"], r["effect"], r["level"]) == (engine, effect, level)]
                def span(key: str, scale: float = 1.0, fmt: str = ".2f") -> str:
                    lo, hi = min(r[key] for r in sel) * scale, max(r[key] for r in sel) * scale
                    return f"{lo:{fmt}}" if f"{lo:{fmt}}" == f"{hi:{fmt}}" else f"{lo:{fmt}}-{hi:{fmt}}"
                magnitude = f"{sel[0]['magnitude']:g} {sel[0]['unit']}".rstrip()
                lines.append(f"| {engine} | {effect} | {level} | {magnitude} | {span('joints_rms_rad', 1e3)} | "
                             f"{span('joints_over_floor', fmt='.1f')} | {span('head_final_m', 1e3, '.1f')} | "
                             f"{span('head_over_floor', fmt='.1f')} |")
    meta = {"duration_s": DURATION_S, "seeds": seeds, "engines": engines, "encoder_floor_rad": ENCODER_FLOOR_RAD,
            "head_floor_m": HEAD_FLOOR_M}
    json_path, md_path = write_results("effect_signal", rows, meta, "# Hidden effects' signal in the confusion "
                                       "matrix's runs\n\n" + "\n".join(lines))
    print("\n".join(lines))
    print(f"wrote {json_path} and {md_path}")


if __name__ == "__main__":
    main()
