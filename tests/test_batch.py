"""Batched rollouts equal single-environment rollouts (the fast path against the plain one)."""
from __future__ import annotations

import numpy as np
import pytest

from cobra_model import ModelParameters, SidewindingGait
from cobra_model.errors import InputError
from integrators.batch import BatchSimulator


def test_batch_matches_single_rollouts(cobra):
    params = [ModelParameters.nominal().with_values(mu_c=mu, mu_s=0.45, k2=k2)
              for mu, k2 in ((0.2, 20.0), (0.3, 30.0), (0.4, 60.0))]
    batch = BatchSimulator(cobra, params, threads=2)
    gait = SidewindingGait(0.5)
    table = gait.q_ref(np.arange(1001) * 1e-3)
    states = [s.rest_state(heading_rad=h) for s, h in zip(batch.sims, (0.0, 1.0, 2.0))]
    Q, V, _, _ = batch.rollout(states, np.repeat(table[:, None, :], 3, axis=1), 1.0)
    for e, (sim, st) in enumerate(zip(batch.sims, states)):
        tr = sim.rollout(st, table, 1.0)
        assert np.allclose(Q[e], tr.q[-1], atol=1e-12)
        assert np.allclose(V[e], tr.v[-1], atol=1e-10)
    assert not np.allclose(Q[0, :2] - states[0].q[:2], Q[2, :2] - states[2].q[:2])  # different physics


def test_batch_requires_shared_armature(cobra):
    p = ModelParameters.nominal()
    with pytest.raises(InputError, match="armature"):
        BatchSimulator(cobra, [p, p.with_values(armature=0.05)])
