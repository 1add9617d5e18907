"""A first rollout compiles its own contact law only (``integrators.kernels.LAW_LOOPS``).

In a fresh process with an empty numba cache, a compliant-ground rollout and batch must not
compile any soft-constraint or implicit-friction solver (each law's loop prunes the others'
branches), and the batch must reuse the single rollout's compiled loop rather than compile a
second copy of it. Either regression puts tens of seconds back on every user's first run and on
each test worker (``docs/benchmarks.md``, "The first rollout on a machine compiles the kernels").
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parent.parent

CHILD = """
import json
import numpy as np
import integrators.kernels as K
from cobra_model import CobraModel, ModelParameters
from integrators import Simulator
from integrators.batch import BatchSimulator
model, params = CobraModel.load(), ModelParameters.nominal()
sim = Simulator(model, params)
state = sim.rest_state()
goals = np.zeros((20, model.n_joints))
sim.rollout(state, goals, 0.01)
BatchSimulator(model, [params, params]).rollout([state, state], np.repeat(goals[:, None], 2, axis=1), 0.01)
solvers = ("soft_contact_acceleration", "soft_elliptic_acceleration", "implicit_friction_acceleration",
           "soft_pyramid_loop", "soft_elliptic_loop", "compliant_implicit_loop")
print(json.dumps({"compiled": [n for n in solvers if getattr(K, n).signatures],
                  "compliant_loops": len(K.compliant_loop.signatures),
                  "batch_from_cache": K.compliant_batch.stats.cache_hits.total()}))
"""


def test_a_compliant_rollout_and_batch_compile_no_other_law_and_one_loop(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    done = subprocess.run([sys.executable, "-c", CHILD], env=env, cwd=tmp_path, capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    report = json.loads(done.stdout.strip().splitlines()[-1])
    assert report["batch_from_cache"] == 0  # compiled here, so the count below is this process's own
    assert report["compiled"] == []
    assert report["compliant_loops"] == 1
