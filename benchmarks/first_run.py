"""First run on a machine: what numba's compilation of the kernels costs a user, per contact law.

The simulator's loops are compiled by numba on their first call and kept on disk (``cache=True``),
so a user's first rollout of a contact law pays its compilation once. Each row runs in a fresh
Python process with an empty ``NUMBA_CACHE_DIR`` (cold), then once more on the cache that run
filled (warm, the peer: what every later run pays):

- for each contact law (the compliant ground, with its friction explicit and implicit, and the
  soft-constraint law on the pyramid and on the elliptic cone): the first 0.1 s single rollout
  (``Simulator.rollout``) and then the first batched rollout of two environments
  (``BatchSimulator.rollout``, what a fit runs), each timed in that process;
- ``cobra simulate --duration 1`` (the README's first command after the demo), the whole
  command's wall time, under the default compliant ground.

Each law runs alone in its own empty cache, as a user of that law meets it; the kernels the
laws share (the step, the ground, the actuator) are compiled in each of those runs.

Writes ``benchmarks/results/first_run.{json,md}``.
Run: ``.venv/bin/python benchmarks/first_run.py``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._results import write_results  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
#: (row label, contact law, friction step) of each row.
LAWS = (("compliant", "compliant", "explicit"), ("compliant, implicit friction", "compliant", "implicit"),
        ("soft_constraint (pyramid)", "soft_constraint", "explicit"),
        ("soft_elliptic (elliptic cone)", "soft_elliptic", "explicit"))

#: What the child process runs: a single rollout then a batch, each timed; prints JSON.
CHILD = """
import json, sys, time
t0 = time.perf_counter()
import numpy as np
from cobra_model import CobraModel, ModelParameters
from integrators import Simulator
from integrators.batch import BatchSimulator
law, step = sys.argv[1], sys.argv[2]
params = ModelParameters.nominal().with_contact_law(law).with_friction_step(step)
model = CobraModel.load()
sim = Simulator(model, params)
state = sim.rest_state()
goals = np.zeros((200, model.n_joints))
t1 = time.perf_counter()
sim.rollout(state, goals, 0.1)
t2 = time.perf_counter()
BatchSimulator(model, [params, params]).rollout([state, state], np.repeat(goals[:, None], 2, axis=1), 0.1)
t3 = time.perf_counter()
print(json.dumps({"import_s": t1 - t0, "single_s": t2 - t1, "batch_s": t3 - t2}))
"""


def child_env(cache: Path) -> dict[str, str]:
    """This environment with numba's cache in ``cache`` and the checkout importable."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    return env


def run_child(args: list[str], cache: Path) -> tuple[float, str]:
    """Wall time [s] and stdout of ``python args`` with numba's cache in ``cache``; a failure
    raises with the child's output."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, *args], env=child_env(cache), cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args[:3])} failed:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return wall, done.stdout


def main(argv: list[str] | None = None) -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args(argv)
    rows: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="first_run_") as tmp:
        for label, law, step in LAWS:
            cache = Path(tmp) / f"{law}_{step}"
            cache.mkdir()
            for state in ("cold", "warm"):
                print(f"[{label}] {state} ...", file=sys.stderr, flush=True)
                wall, out = run_child(["-c", CHILD, law, step], cache)
                rows.append({"case": label, "law": law, "friction_step": step, "cache": state, "wall_s": wall,
                             **json.loads(out.strip().splitlines()[-1])})
        cache = Path(tmp) / "cli"
        cache.mkdir()
        for state in ("cold", "warm"):
            print(f"[cobra simulate] {state} ...", file=sys.stderr, flush=True)
            out_csv = Path(tmp) / f"sim_{state}.csv"
            wall, _ = run_child(["-c", "import sys; from cobra_cli.main import main; sys.exit(main())", "simulate",
                                 "--duration", "1", "--out", str(out_csv)], cache)
            rows.append({"case": "cobra simulate --duration 1", "law": "compliant", "friction_step": "explicit",
                         "cache": state, "wall_s": wall})
    by = {(r["case"], r["cache"]): r for r in rows}
    lines = ["# First run: numba's compilation of the kernels, per contact law", "",
             "Each row a fresh process; cold: an empty `NUMBA_CACHE_DIR`, warm: the cache the cold run filled.", "",
             "| case | first single rollout cold [s] | warm [s] | first batch cold [s] | warm [s] "
             "| process cold [s] | warm [s] | cold / warm |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for case in dict.fromkeys(r["case"] for r in rows):
        c, w = by[case, "cold"], by[case, "warm"]
        cells = [f"{c[k]:.1f} | {w[k]:.2f}" if k in c else "- | -" for k in ("single_s", "batch_s")]
        lines.append(f"| {case} | {' | '.join(cells)} | {c['wall_s']:.1f} | {w['wall_s']:.1f} "
                     f"| {c['wall_s'] / w['wall_s']:.1f}x |")
    markdown = "\n".join(lines)
    print(markdown)
    write_results("first_run", rows, {"single_rollout_s": 0.1, "batch_envs": 2, "cli_duration_s": 1.0}, markdown)


if __name__ == "__main__":
    main()
