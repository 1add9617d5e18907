"""Simulation speed: this simulator vs MuJoCo on the same URDF and gait, plus batched rollouts.

10 s of the 0.5 Hz sidewinding gait at dt = 1 ms. MuJoCo gets the same URDF with a free joint,
cylinder-plane contacts (its soft-constraint contact model, the comparable one) and position
servos linearised from the same Dynamixel loop; both read their commands from a precomputed
table, so the Python loop costs are alike. The batched rollout steps N environments with
different ground parameters (shared armature) through Pinocchio's ``abaInParallel``.

Run: ``.venv/bin/python benchmarks/sim_speed.py`` (prints a Markdown table).
"""
from __future__ import annotations

import time

import mujoco
import numpy as np

from cobra_model import CobraModel, ModelParameters, SidewindingGait
from integrators import Simulator, mujoco_twin
from integrators.batch import BatchSimulator

DURATION = 10.0
DT = 1e-3
REPEATS = 3


def time_ours(model: CobraModel, table: np.ndarray) -> float:
    sim = Simulator(model)
    st = sim.rest_state()
    sim.rollout(st, table[:50], 0.05)     # compile
    best = np.inf
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        sim.rollout(st, table, DURATION, record_every=10)
        best = min(best, time.perf_counter() - t0)
    return best / (DURATION / DT)


def time_mujoco(model: CobraModel, table: np.ndarray) -> float:
    mj = mujoco_twin.build(model.urdf_path, mujoco_twin.TwinOptions(timestep=DT))
    best = np.inf
    for _ in range(REPEATS):
        d = mujoco.MjData(mj)
        d.qpos[2] = 0.045
        n = int(DURATION / DT)
        t0 = time.perf_counter()
        for i in range(n):
            d.ctrl[:] = table[i]
            mujoco.mj_step(mj, d)
        best = min(best, time.perf_counter() - t0)
    return best / (DURATION / DT)


def time_batch(model: CobraModel, table: np.ndarray, n_env: int, seconds: float = 2.0) -> float:
    params = [ModelParameters.nominal().with_values(mu_c=0.2 + 0.2 * i / n_env, mu_s=0.45) for i in range(n_env)]
    batch = BatchSimulator(model, params, threads=2)
    states = [s.rest_state() for s in batch.sims]
    n = int(seconds / DT)
    goals = np.ascontiguousarray(np.repeat(table[: n + 1, None, :], n_env, axis=1))
    batch.rollout(states, goals[:10], 0.005)   # compile
    t0 = time.perf_counter()
    batch.rollout(states, goals, seconds)
    return (time.perf_counter() - t0) / (n * n_env)


def main() -> None:
    model = CobraModel.load()
    table = SidewindingGait(0.5).q_ref(np.arange(int(DURATION / DT) + 1) * DT)
    ours = time_ours(model, table)
    mj = time_mujoco(model, table)
    rows = [("this simulator (Pinocchio ABA + numba kernels), 1 env", ours, DT / ours),
            ("MuJoCo mj_step, same URDF and gait, 1 env", mj, DT / mj)]
    print(f"# 10 s sidewinding at dt = {DT * 1e3:g} ms, best of {REPEATS}\n")
    print("| simulator | us / step | real-time factor |")
    print("|---|---:|---:|")
    for name, per_step, rtf in rows:
        print(f"| {name} | {per_step * 1e6:.1f} | {rtf:.0f}x |")
    print(f"\nratio this / MuJoCo (time per step): **{ours / mj:.2f}** (target <= 0.6)\n")
    print("| batched rollout (2 threads) | us / env-step |")
    print("|---|---:|")
    for n_env in (16, 64, 256):
        print(f"| {n_env} environments | {time_batch(model, table, n_env) * 1e6:.2f} |")
    print("\n(target <= 4 us per environment-step on 2 cores)")


if __name__ == "__main__":
    main()
