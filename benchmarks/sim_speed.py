"""Simulation speed: every rollout path a user calls, against MuJoCo on the same URDF and gait.

10 s of the 0.5 Hz sidewinding gait at dt = 1 ms, best of ``REPEATS`` rounds in which every
path, MuJoCo's among them, runs once in turn (:func:`interleaved_best`). MuJoCo gets the same
URDF with a free joint, the URDF's collision cylinders touching the ground only (no
self-collision: our simulator has none), its default integrator, and position servos
linearised from the same Dynamixel loop, reading a precomputed command table. Our paths:

- the compiled core: ``Simulator.rollout`` with a command table, recording every 10th step;
- ``Simulator.rollout`` with the gait's ``q_ref`` callable, recording every step (the README's
  quick tour);
- ``simulate_gait`` (what ``cobra simulate`` runs: a run sampled at 100 Hz with tracked bodies);
- ``simulate_like`` of a 10 s run (what ``cobra compare`` runs);
- ``Simulator.rollout`` with the ``q_ref`` callable under the soft-constraint laws, MuJoCo's
  contact on the friction pyramid and on the elliptic cone (what ``cobra simulate --contact``
  and ``cobra compare`` run with a parameter file fitted under those laws); the elliptic law is
  also set against MuJoCo on its elliptic cone (``cone="elliptic"``), the same contact
  problem (MuJoCo's default is the pyramid);
- ``Simulator.rollout`` with the ``q_ref`` callable and the compliant ground's friction taken
  implicitly (``ModelParameters.with_friction_step("implicit")``, ``cobra simulate
  --friction-step implicit``: the sign regularised at 1 mm/s), for what it costs (no target: not
  the default);
- the batched rollout of the objective (``BatchSimulator``), per environment-step;
- the momentum-form step (``SimSettings(scheme="momentum")``, bounded energy error), on the
  core's path, for what it costs (no target: it is not the fits' step);
- each soft-constraint law with the robot lying still on all its 24 ends (zero commands: the
  contact solve's largest problem, 96 rows on the pyramid), against MuJoCo lying still on the
  same cone, for what it costs (no target: the gait is the benchmark's case).

Writes ``benchmarks/results/sim_speed.{json,md}``.
Run: ``.venv/bin/python benchmarks/sim_speed.py``.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._results import write_results  # noqa: E402
from benchmarks._timing import best_of_rounds  # noqa: E402
from cobra_model import CobraModel, ModelParameters, SidewindingGait  # noqa: E402
from integrators import Simulator, mujoco_twin  # noqa: E402
from integrators.simulator import SimSettings  # noqa: E402
from integrators.batch import BatchSimulator  # noqa: E402
from integrators.simulate import simulate_gait, simulate_like  # noqa: E402

DURATION = 10.0
DT = 1e-3
REPEATS = 5


def interleaved_best(runs: dict[str, Callable[[], object]]) -> dict[str, float]:
    """Each of ``runs`` (10 s of simulation each) once per round for ``REPEATS`` rounds, in turn
    (:func:`benchmarks._timing.best_of_rounds`); the best round per 1 ms step [s] of each."""
    return {name: t / (DURATION / DT) for name, t in best_of_rounds(runs, REPEATS).items()}


def mujoco_run(model: CobraModel, table: np.ndarray, self_collision: bool = False,
               cone: str = "pyramidal") -> Callable[[], None]:
    """10 s of MuJoCo stepping the command table, from the same start, as a callable (friction
    ``cone``: MuJoCo's default pyramid, or the elliptic cone)."""
    mj = mujoco_twin.build(model.urdf_path,
                           mujoco_twin.TwinOptions(timestep=DT, self_collision=self_collision, cone=cone))
    n = int(DURATION / DT)

    def run() -> None:
        d = mujoco.MjData(mj)
        d.qpos[2] = 0.045
        for i in range(n):
            d.ctrl[:] = table[i]
            mujoco.mj_step(mj, d)
    return run


def time_batch(model: CobraModel, table: np.ndarray, n_env: int, seconds: float = 2.0) -> float:
    params = [ModelParameters.nominal().with_values(mu_c=0.2 + 0.2 * i / n_env, mu_s=0.45) for i in range(n_env)]
    batch = BatchSimulator(model, params, threads=2)
    states = [s.rest_state() for s in batch.sims]
    n = int(seconds / DT)
    goals = np.ascontiguousarray(np.repeat(table[: n + 1, None, :], n_env, axis=1))
    batch.rollout(states, goals[:10], 0.005)   # compile
    best = np.inf
    for _ in range(REPEATS):  # best of REPEATS, as the paths: one run can fall in a slow phase of the host
        t0 = time.perf_counter()
        batch.rollout(states, goals, seconds)
        best = min(best, time.perf_counter() - t0)
    return best / (n * n_env)


def main(argv: list[str] | None = None) -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)  # --help; no options
    model = CobraModel.load()
    gait = SidewindingGait(0.5)
    table = gait.q_ref(np.arange(int(DURATION / DT) + 1) * DT)
    sim = Simulator(model)
    soft = {law: Simulator(model, ModelParameters.nominal().with_contact_law(law))
            for law in ("soft_constraint", "soft_elliptic")}
    momentum = Simulator(model, settings=SimSettings(scheme="momentum"))
    implicit = Simulator(model, ModelParameters.nominal().with_friction_step("implicit"))
    st = sim.rest_state(gait.q_ref(0.0))
    reference = simulate_gait(gait, DURATION, model=model)
    still = np.zeros_like(table)
    lying = [(f"{law} contact law, lying still on all its ends (zero commands)", cone,
              lambda s=s: s.rollout(s.rest_state(still[0]), still, DURATION))
             for (law, s), cone in zip(soft.items(), ("pyramidal", "elliptic"))]
    paths = [
        ("core: Simulator.rollout, command table, record every 10th step",
         lambda: sim.rollout(st, table, DURATION, record_every=10), 0.3),
        ("Simulator.rollout, q_ref callable, record every step", lambda: sim.rollout(st, gait.q_ref, DURATION), 0.5),
        ("simulate_gait (cobra simulate), 100 Hz run with tracked bodies",
         lambda: simulate_gait(gait, DURATION, model=model), 0.5),
        ("simulate_like of a 10 s run (cobra compare)", lambda: simulate_like(reference, model=model), 0.5),
        *((f"Simulator.rollout, q_ref callable, record every step, {law} contact law",
           lambda s=s: s.rollout(st, gait.q_ref, DURATION), 0.5) for law, s in soft.items()),
        ("Simulator.rollout, q_ref callable, record every step, friction taken implicitly (friction_step='implicit')",
         lambda: implicit.rollout(st, gait.q_ref, DURATION), None),
        ("momentum-form step (scheme='momentum'): Simulator.rollout, command table, record every 10th step",
         lambda: momentum.rollout(st, table, DURATION, record_every=10), None),
    ]
    runs = {"mujoco": mujoco_run(model, table), "mujoco_self": mujoco_run(model, table, self_collision=True),
            "mujoco_elliptic": mujoco_run(model, table, cone="elliptic"),
            **{name: run for name, run, _ in paths},
            **{f"mujoco_still_{cone}": mujoco_run(model, still, cone=cone) for _, cone, _ in lying},
            **{name: run for name, _, run in lying}}
    best = interleaved_best(runs)
    mj, mj_self, mj_elliptic = best["mujoco"], best["mujoco_self"], best["mujoco_elliptic"]
    rows = [{"path": name, "us_per_step": 1e6 * best[name], "ratio_to_mujoco": best[name] / mj, "target_ratio": target}
            for name, _, target in paths]
    for r in rows:
        if "soft_elliptic" in r["path"]:  # the same contact problem in MuJoCo: its elliptic cone
            r["ratio_to_mujoco_elliptic"] = 1e-6 * r["us_per_step"] / mj_elliptic
    still_rows = [{"path": name, "us_per_step": 1e6 * best[name],
                   "mujoco_still_us_per_step": 1e6 * best[f"mujoco_still_{cone}"], "mujoco_cone": cone,
                   "ratio_to_mujoco_still": best[name] / best[f"mujoco_still_{cone}"]} for name, cone, _ in lying]
    batch = [{"environments": n, "us_per_env_step": 1e6 * time_batch(model, table, n)} for n in (16, 64, 256)]
    lines = [f"10 s of 0.5 Hz sidewinding at dt = {DT * 1e3:g} ms, best of {REPEATS} rounds (each path once per "
             "round, in turn, MuJoCo's among them); MuJoCo: same URDF, "
             "cylinders touching the ground only, default integrator, linearised servos, command table.", "",
             "| path | us / step | ratio to MuJoCo | target ratio |", "|---|---:|---:|---:|"]
    target = lambda r: "" if r["target_ratio"] is None else f"<= {r['target_ratio']:g}"  # noqa: E731
    same_cone = lambda r: (f" ({r['ratio_to_mujoco_elliptic']:.3f} to MuJoCo's elliptic cone)"  # noqa: E731
                           if "ratio_to_mujoco_elliptic" in r else "")
    lines += [f"| {r['path']} | {r['us_per_step']:.1f} | {r['ratio_to_mujoco']:.3f}{same_cone(r)} | {target(r)} |"
              for r in rows]
    lines += [f"| MuJoCo mj_step (ground contacts only) | {1e6 * mj:.1f} | 1 | |",
              f"| MuJoCo mj_step with self-collision among the cylinders | {1e6 * mj_self:.1f} | "
              f"{mj_self / mj:.2f} | |",
              f"| MuJoCo mj_step on the elliptic friction cone (ground contacts only) | {1e6 * mj_elliptic:.1f} | "
              f"{mj_elliptic / mj:.2f} | |", "",
              "| lying still on all 24 ends (zero commands) | us / step | MuJoCo lying still, same cone | ratio |",
              "|---|---:|---:|---:|"]
    lines += [f"| {r['path']} | {r['us_per_step']:.1f} | {r['mujoco_still_us_per_step']:.1f} ({r['mujoco_cone']}) | "
              f"{r['ratio_to_mujoco_still']:.3f} |" for r in still_rows]
    lines += ["", "| batched rollout (BatchSimulator, 2 threads) | us / env-step | target |", "|---|---:|---:|"]
    lines += [f"| {b['environments']} environments | {b['us_per_env_step']:.2f} | "
              f"{'<= 2' if b['environments'] == 256 else ''} |" for b in batch]
    text = "\n".join(lines)
    write_results("sim_speed", rows + still_rows + batch, {"duration_s": DURATION, "dt_s": DT, "repeats": REPEATS,
                                              "mujoco_us_per_step": 1e6 * mj,
                                              "mujoco_self_collision_us_per_step": 1e6 * mj_self,
                                              "mujoco_elliptic_us_per_step": 1e6 * mj_elliptic}, text)
    print(text)


if __name__ == "__main__":
    main()
