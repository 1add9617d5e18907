"""Coverage benchmark: do least squares' 95 % intervals hold the true parameters 95 % of the time?

Each recovery makes synthetic runs with known parameters on this project's simulator, fits
them, and checks, per free parameter, whether the 95 % interval holds the truth, for the
interval with white residuals assumed (Gauss-Newton ``sigma^2 (J^T J)^-1`` plus the start pose:
``ci_low_iid``/``ci_high_iid``, the estimator before issue 16) and for the HAC sandwich
(``ci_low``/``ci_high``, :mod:`sysid.identification.intervals`) of the same fit.

One recovery (seed ``s``, everything drawn from ``numpy.random.default_rng(s)``):

- truth: :data:`BASE_TRUTH` (``benchmarks/recovery.py``'s robot) with each free parameter
  scaled by ``1 + U(-5 %, 5 %)``, so that coverage is not a property of one parameter vector;
- data: three runs of 3 s (one per gait, 0.35 / 0.5 / 0.65 Hz), random start position and
  heading, measured like the reference dataset (:func:`sysid.generators.dataset.record`: quantised 50 Hz
  encoders, 0.5 mm motion-capture noise, dropouts);
- fit: :data:`FREE` (``mu_c``, ``joint_damping``, ``motor_km``: the parameters
  ``tests/test_lsq.py`` recovers, identified by head path and joints alike) from a guess
  ``1 +- U(5 %, 10 %)`` off, whole runs only (no horizon continuation: it exists to reach the
  right basin from 30-50 % off) and converged to ``cost_tol = 1e-6`` so that the optimiser's
  stopping error does not mix with the intervals' calibration.

Two scenarios, the second a stress case for the estimator:

- ``reference``: the reference dataset's measurement model, as above;
- ``coloured``: plus an Ornstein-Uhlenbeck drift on every motion-capture position (head and
  tracked bodies, each axis, std :data:`DRIFT_STD_M` = 1 mm, correlation time
  :data:`DRIFT_TAU_S` = 0.3 s): motion-capture errors that wander over a few hundred
  milliseconds rather than jump from frame to frame (a marker occluded and the rigid body
  re-solved), i.e. residuals correlated over several of the objective's 10 Hz samples. It is
  not a measured property of COBRA's motion capture.

Seeds: :data:`DEV_SEEDS` were used while the estimator was written (and to check this script);
the reported figures come from :data:`REPORT_SEEDS` only, which were not looked at before.
Results: ``benchmarks/results/coverage.json`` and ``coverage.md`` (the script is not called
``coverage.py``: run as a script its folder comes first on ``sys.path``, where that name would
shadow the ``coverage`` package that numba imports). Run:
``.venv/bin/python benchmarks/interval_coverage.py [--recoveries N] [--scenarios reference,coloured] [--dev]``.
"""
from __future__ import annotations

import argparse
import dataclasses
import time

import numba
import numpy as np

from _results import write_results
from cobra_model import CobraModel, ModelParameters
from cobra_model.run import Run
from integrators.simulator import Simulator
from sysid.generators.dataset import RunPlan, record
from sysid.identification.lsq import FitResult, fit_lsq
from sysid.identification.objective import Objective

BASE_TRUTH = ModelParameters.nominal().with_values(armature=0.04, joint_damping=0.2, motor_km=0.0095, k1=1.5e4,
                                                   k2=40.0, mu_c=0.25, mu_s=0.38, mu_v=1.0, v_s=0.03)
FREE: tuple[str, ...] = ("joint_damping", "motor_km", "mu_c")
GAITS_HZ: tuple[float, ...] = (0.35, 0.5, 0.65)
RUN_S = 3.0
DRIFT_STD_M = 1e-3
DRIFT_TAU_S = 0.3
SCENARIOS: tuple[str, ...] = ("reference", "coloured")
#: Seeds used while developing the estimator and this script (reported figures never use them).
DEV_SEEDS: tuple[int, ...] = tuple(range(1000, 1012))
#: Seeds of the reported figures, first used for the results file.
REPORT_SEEDS: tuple[int, ...] = tuple(range(2000, 2040))
#: Nominal coverage of the intervals.
NOMINAL = 0.95


def drift(rng: np.random.Generator, t: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Ornstein-Uhlenbeck samples at times ``t`` [s] (stationary std DRIFT_STD_M [m], correlation
    time DRIFT_TAU_S [s]), one independent process per trailing index of ``shape``."""
    out = np.empty((len(t),) + shape)
    out[0] = rng.normal(0.0, DRIFT_STD_M, shape)
    for k in range(1, len(t)):
        phi = np.exp(-(t[k] - t[k - 1]) / DRIFT_TAU_S)
        out[k] = phi * out[k - 1] + np.sqrt(1 - phi * phi) * rng.normal(0.0, DRIFT_STD_M, shape)
    return out


def with_drift(run: Run, rng: np.random.Generator) -> Run:
    """``run`` with a motion-capture drift (:func:`drift`) added to the head and every tracked
    body's planar position (gaps stay gaps)."""
    head = run.head_pos.copy()
    head[:, :2] += drift(rng, run.t, (2,))
    bodies = {name: np.column_stack([pos[:, :2] + drift(rng, run.t, (2,)), pos[:, 2:]])
              for name, pos in run.bodies.items()}
    return dataclasses.replace(run, head_pos=head, bodies=bodies)


def recovery(seed: int, scenario: str, model: CobraModel) -> tuple[dict, FitResult]:
    """One recovery (module docstring): a table row and the fit."""
    rng = np.random.default_rng(seed)
    truth = BASE_TRUTH.with_values(**{n: BASE_TRUTH.value(n) * (1 + rng.uniform(-0.05, 0.05)) for n in FREE})
    sim = Simulator(model, truth)
    plans = [RunPlan(f"s{seed}_{i}", f, RUN_S, (float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1))),
                     float(rng.uniform(0, 2 * np.pi)), "train") for i, f in enumerate(GAITS_HZ)]
    runs = [record(sim, p, rng, model) for p in plans]
    if scenario == "coloured":
        runs = [with_drift(r, rng) for r in runs]
    guess = truth.with_values(**{n: truth.value(n) * (1 + rng.choice([-1, 1]) * rng.uniform(0.05, 0.10))
                                 for n in FREE}).with_frozen(free=list(FREE))
    fit = fit_lsq(Objective(runs, guess, threads=1), horizons_s=(), cost_tol=1e-6, step_tol=1e-7)
    params = {}
    for r in fit.report:
        x = truth.value(r.name)
        params[r.name] = {"truth": x, "fitted": r.value, "ci_iid": [r.ci_low_iid, r.ci_high_iid],
                          "ci_hac": [r.ci_low, r.ci_high], "covered_iid": bool(r.ci_low_iid <= x <= r.ci_high_iid),
                          "covered_hac": bool(r.ci_low <= x <= r.ci_high),
                          "width_ratio_hac_iid": (r.ci_high - r.ci_low) / (r.ci_high_iid - r.ci_low_iid)}
    w = fit.residual_whiteness
    row = {"scenario": scenario, "seed": seed, "status": fit.status.name, "seconds": fit.seconds,
           "evaluations": fit.evaluations, "cost": fit.cost, "residuals": fit.residual_count,
           "interval_method": fit.interval_method, "whiteness": w.to_json_dict() if w else None, "params": params}
    return row, fit


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score 95 % interval of a proportion ``k / n``."""
    if n == 0:
        return float("nan"), float("nan")
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def summary(rows: list[dict]) -> list[dict]:
    """Coverage per scenario and parameter, and over all of a scenario's parameters."""
    out = []
    for scenario in dict.fromkeys(r["scenario"] for r in rows):
        mine = [r for r in rows if r["scenario"] == scenario]
        for name in list(FREE) + ["all"]:
            cells = [p for r in mine for n, p in r["params"].items() if name in ("all", n)]
            n = len(cells)
            entry = {"scenario": scenario, "parameter": name, "intervals": n, "recoveries": len(mine)}
            for kind in ("iid", "hac"):
                k = sum(c[f"covered_{kind}"] for c in cells)
                entry[f"coverage_{kind}"] = k / n if n else float("nan")
                entry[f"coverage_{kind}_wilson95"] = list(wilson(k, n))
            entry["median_width_ratio_hac_iid"] = float(np.median([c["width_ratio_hac_iid"] for c in cells]))
            entry["not_white"] = sum(1 for r in mine if r["whiteness"] and not r["whiteness"]["white"])
            out.append(entry)
    return out


def markdown(table: list[dict], seeds: list[int], dev: bool, wall_s: float) -> str:
    lines = [f"# Coverage of the 95 % intervals ({'DEVELOPMENT seeds' if dev else 'reported seeds'} "
             f"{seeds[0]}-{seeds[-1]}, {len(seeds)} recoveries per scenario)", "",
             f"Free parameters {', '.join(FREE)}; three runs of {RUN_S:g} s per recovery; "
             f"benchmark wall time {wall_s:.0f} s. `iid`: Gauss-Newton interval, white residuals assumed "
             "(the estimator before issue 16); `HAC`: Newey-West sandwich (`sysid/identification/intervals.py`), now reported. "
             "Coverage with its Wilson 95 % interval (intervals of one recovery are not independent, so "
             "the overall Wilson interval is optimistic).", "",
             "| scenario | parameter | intervals | coverage iid | coverage HAC | median width HAC / iid | "
             "fits with residuals not white |", "|---|---|---:|---|---|---:|---:|"]
    for e in table:
        cov = {k: f"{100 * e[f'coverage_{k}']:.0f} % [{100 * e[f'coverage_{k}_wilson95'][0]:.0f}, "
                  f"{100 * e[f'coverage_{k}_wilson95'][1]:.0f}]" for k in ("iid", "hac")}
        lines.append(f"| {e['scenario']} | {e['parameter']} | {e['intervals']} | {cov['iid']} | {cov['hac']} | "
                     f"{e['median_width_ratio_hac_iid']:.2f} | {e['not_white']} / {e['recoveries']} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recoveries", type=int, default=20, help="per scenario (default 20)")
    parser.add_argument("--scenarios", default=",".join(SCENARIOS), help="comma-separated, of " + ", ".join(SCENARIOS))
    parser.add_argument("--dev", action="store_true", help="use the development seeds (results named coverage_dev)")
    args = parser.parse_args()
    scenarios = [s.strip() for s in args.scenarios.split(",") if s.strip()]
    if not scenarios or any(s not in SCENARIOS for s in scenarios):
        parser.error(f"--scenarios: choose from {', '.join(SCENARIOS)}")
    pool = DEV_SEEDS if args.dev else REPORT_SEEDS
    if not 1 <= args.recoveries <= len(pool):
        parser.error(f"--recoveries: 1 to {len(pool)}")
    seeds = list(pool[:args.recoveries])
    # one thread everywhere: the batch's threads and numba's prange workers (which the batch's
    # ``threads`` does not govern) meet at a barrier every physics step and crawl on a shared machine
    numba.set_num_threads(1)
    model = CobraModel.load()
    t0 = time.perf_counter()
    rows: list[dict] = []
    print(f"{len(seeds)} recoveries per scenario, seeds {seeds[0]}-{seeds[-1]} "
          f"({'development' if args.dev else 'reported'}); free {', '.join(FREE)}", flush=True)
    print("| scenario | seed | status | s | " + " | ".join(f"{n} err / iid / HAC" for n in FREE) +
          " | whiteness p, lag-1 | bandwidth |", flush=True)
    for scenario in scenarios:
        for k, seed in enumerate(seeds):
            row, fit = recovery(seed, scenario, model)
            rows.append(row)
            cells = []
            for n, p in row["params"].items():
                cells.append(f"{100 * (p['fitted'] / p['truth'] - 1):+.2f} % "
                             f"{'in' if p['covered_iid'] else 'OUT'} {'in' if p['covered_hac'] else 'OUT'}")
            w = row["whiteness"]
            print(f"| {scenario} [{k + 1}/{len(seeds)}] | {seed} | {row['status']} | {row['seconds']:.1f} | "
                  + " | ".join(cells) + f" | {w['p_value']:.2g}, {w['lag1_autocorrelation']:+.2f} | "
                  f"{fit.interval_method.split('bandwidth ')[-1].split(',')[0]} |", flush=True)
    wall = time.perf_counter() - t0
    table = summary(rows)
    text = markdown(table, seeds, args.dev, wall)
    print("\n" + text)
    meta = {"free": list(FREE), "base_truth": BASE_TRUTH.to_json_dict(), "gaits_hz": list(GAITS_HZ),
            "run_s": RUN_S, "scenarios": scenarios, "drift_std_m": DRIFT_STD_M, "drift_tau_s": DRIFT_TAU_S,
            "development_seeds": list(DEV_SEEDS), "reported_seeds": list(REPORT_SEEDS),
            "seeds_used": seeds, "seeds_kind": "development" if args.dev else "reported",
            "wall_seconds": wall, "summary": table}
    json_path, md_path = write_results("coverage_dev" if args.dev else "coverage", rows, meta, text)
    print(f"wrote {json_path} and {md_path}")


if __name__ == "__main__":
    main()
