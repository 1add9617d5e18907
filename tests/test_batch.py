"""Batched rollouts equal single-environment rollouts bit for bit (each environment runs the single
rollout's compiled loop)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobra_model import ModelParameters, SidewindingGait
from cobra_model.errors import InputError
from integrators import kernels as K
from integrators.batch import BatchSimulator
from integrators.simulator import SimulationDiverged
from sysid.discrepancy.effects import EffectLibrary


@pytest.mark.parametrize("friction_step", ["explicit", "implicit"])
def test_batch_matches_single_rollouts(cobra, friction_step):
    params = [ModelParameters.nominal().with_values(mu_c=mu, mu_s=0.45, k2=k2).with_friction_step(friction_step)
              for mu, k2 in ((0.2, 20.0), (0.3, 30.0), (0.4, 60.0))]
    batch = BatchSimulator(cobra, params, threads=2)
    gait = SidewindingGait(0.5)
    table = gait.q_ref(np.arange(1001) * 1e-3)
    states = [s.rest_state(heading_rad=h) for s, h in zip(batch.sims, (0.0, 1.0, 2.0))]
    Q, V, _, _, _ = batch.rollout(states, np.repeat(table[:, None, :], 3, axis=1), 1.0)
    for e, (sim, st) in enumerate(zip(batch.sims, states)):
        tr = sim.rollout(st, table, 1.0)
        assert np.array_equal(Q[e], tr.q[-1]) and np.array_equal(V[e], tr.v[-1])
    assert not np.allclose(Q[0, :2] - states[0].q[:2], Q[2, :2] - states[2].q[:2])  # different physics


def test_environments_of_other_rigid_body_models_step_together(cobra):
    # environments of other rigid-body models (transmission inertia, a link mass) interleaved:
    # each still follows its own single rollout, and the outputs come back in the order given
    nominal = ModelParameters.nominal()
    params = [nominal, nominal.with_values(armature=0.05), nominal.with_values(mu_c=0.4),
              nominal.with_values(armature=0.05, k2=60.0)]
    params.append(EffectLibrary().transform(nominal, {"link_mass_error": 0.3}))
    params.append(EffectLibrary().transform(nominal, {"backlash": 0.02}))  # motor inertia off an open play
    batch = BatchSimulator(cobra, params, threads=2)
    table = SidewindingGait(0.65).q_ref(np.arange(501) * 1e-3)
    states = [s.rest_state(heading_rad=0.5 * e) for e, s in enumerate(batch.sims)]
    Q, V, Q_rec, M_rec, C_rec = batch.rollout(states, np.repeat(table[:, None, :], len(params), axis=1), 0.5,
                                       record_every=100)
    for e, (sim, st) in enumerate(zip(batch.sims, states)):
        tr = sim.rollout(st, table, 0.5, record_every=100)
        assert np.array_equal(Q[e], tr.q[-1]) and np.array_equal(V[e], tr.v[-1]), e
        assert np.array_equal(Q_rec[:, e], tr.q) and np.array_equal(M_rec[:, e], tr.q_meas), e
        assert np.array_equal(C_rec[1:, e], tr.current[1:]), e  # the batch's first record: no step yet, no current
    # the heavier transmission really is another model: its joints move otherwise; so does a gear play
    assert not np.allclose(V[0, 6:], V[1, 6:], atol=1e-3)
    assert not np.allclose(Q_rec[:, 0], Q_rec[:, -1], atol=1e-3)


def test_a_batch_needs_one_state_per_environment(cobra):
    batch = BatchSimulator(cobra, [ModelParameters.nominal()] * 2)
    with pytest.raises(InputError, match="2 initial states"):
        batch.rollout([batch.sims[0].rest_state()], np.zeros((1, 2, 11)), 0.01)


def test_a_batch_runs_on_the_threads_cobra_threads_gives_unless_told(cobra, monkeypatch):
    nominal = [ModelParameters.nominal()]
    monkeypatch.delenv("COBRA_THREADS", raising=False)
    assert BatchSimulator(cobra, nominal).threads == 2
    monkeypatch.setenv("COBRA_THREADS", "3")
    assert BatchSimulator(cobra, nominal).threads == 3 and BatchSimulator(cobra, nominal, threads=1).threads == 1
    for bad in ("0", "two", "-1", "1.5", "²"):  # "²" is a digit to str.isdigit, not to int()
        monkeypatch.setenv("COBRA_THREADS", bad)
        with pytest.raises(InputError, match=f"COBRA_THREADS='{bad}': expected a whole number of threads >= 1"):
            BatchSimulator(cobra, nominal)
    with pytest.raises(InputError, match="threads >= 1, got 0"):
        BatchSimulator(cobra, nominal, threads=0)


def test_a_masked_divergence_leaves_the_other_environments_bit_for_bit(cobra):
    # environment 1 starts far above the speed limit: it diverges at its first step
    params = [ModelParameters.nominal().with_values(mu_c=mu) for mu in (0.2, 0.3, 0.4)]
    batch = BatchSimulator(cobra, params, threads=2)
    states = [s.rest_state() for s in batch.sims]
    states[1] = dataclasses.replace(states[1], v=np.full_like(states[1].v, 1e4))
    table = SidewindingGait(0.5).q_ref(np.arange(301) * 1e-3)
    goals = np.repeat(table[:, None, :], 3, axis=1)
    with pytest.raises(SimulationDiverged, match=r"environments \[1\] of 3 diverged; environment 1: at t = 0\.\d+ s "
                                             r"velocity coordinate \d+ \(.*\) reached"):
        batch.rollout(states, goals, 0.3, record_every=10)
    Q, V, Q_rec, M_rec, C_rec = batch.rollout(states, goals, 0.3, record_every=10, divergence="mask")
    assert np.isnan(Q[1]).all() and np.isnan(V[1]).all()
    assert np.isnan(Q_rec[:, 1]).all() and np.isnan(M_rec[:, 1]).all() and np.isnan(C_rec[:, 1]).all()
    healthy = BatchSimulator(cobra, [params[0], params[2]], threads=2)
    Qh, Vh, Qh_rec, Mh_rec, _ = healthy.rollout([states[0], states[2]], goals[:, [0, 2]], 0.3, record_every=10)
    assert np.array_equal(Q[[0, 2]], Qh) and np.array_equal(V[[0, 2]], Vh)
    assert np.array_equal(Q_rec[:, [0, 2]], Qh_rec) and np.array_equal(M_rec[:, [0, 2]], Mh_rec)
    with pytest.raises(InputError, match="divergence must be"):
        batch.rollout(states, goals, 0.3, divergence="ignore")


def test_equal_environments_run_once_and_each_gets_its_single_rollout(cobra, monkeypatch):
    # environments 0, 2 and 4 are one rollout (the same parameter values, state and commands, as a
    # fit's trial rows and the candidates' starts repeat them); 1 differs only in its start, 3 only
    # in its rigid-body model (transmission inertia): those must not be merged
    nominal = ModelParameters.nominal()
    same = nominal.with_values(mu_c=nominal.value("mu_c"))  # another object, the same values
    params = [nominal, nominal, same, nominal.with_values(armature=0.05), same.with_values(k2=nominal.value("k2")),
              nominal]
    assert params[2] is not params[0] and params[4] is not params[2]
    batch = BatchSimulator(cobra, params, threads=2)
    starts = [0.0, 1.0, 0.0, 0.0, 0.0, 0.0]
    states = [s.rest_state(heading_rad=h) for s, h in zip(batch.sims, starts)]
    t = np.arange(401) * 1e-3
    tables = [SidewindingGait(0.5).q_ref(t)] * 5 + [SidewindingGait(0.65).q_ref(t)]  # 5: other commands
    ran = []
    kernel = K.batch_rollout_loop
    monkeypatch.setattr(K, "batch_rollout_loop", lambda *args: (ran.append(len(args[4])), kernel(*args))[1])
    Q, V, Q_rec, _, _ = batch.rollout(states, np.stack(tables, axis=1), 0.4, record_every=50)
    assert ran == [4]  # environments {0, 2, 4}, 1, 3 and 5 (each its own copy of the commands)
    for e, (sim, st, table) in enumerate(zip(batch.sims, states, tables)):
        tr = sim.rollout(st, table, 0.4, record_every=50)
        assert np.array_equal(Q[e], tr.q[-1]) and np.array_equal(V[e], tr.v[-1]) and np.array_equal(Q_rec[:, e], tr.q), e
    assert not np.array_equal(Q[0], Q[1]) and not np.array_equal(Q[0], Q[3]) and not np.array_equal(Q[0], Q[5])


def test_environments_of_different_durations_each_end_at_their_own(cobra):
    params = [ModelParameters.nominal().with_values(mu_c=mu) for mu in (0.2, 0.3, 0.4)]
    batch = BatchSimulator(cobra, params, threads=2)
    table = SidewindingGait(0.65).q_ref(np.arange(601) * 1e-3)
    states = [s.rest_state() for s in batch.sims]
    durations = [0.6, 0.25, 0.4]
    Q, V, Q_rec, M_rec, C_rec = batch.rollout(states, np.repeat(table[:, None, :], 3, axis=1), durations,
                                              record_every=50)
    assert Q_rec.shape[0] == 13  # the longest environment's records
    for e, (sim, st, d) in enumerate(zip(batch.sims, states, durations)):
        tr = sim.rollout(st, table, d, record_every=50)
        n = len(tr.q)
        assert np.array_equal(Q[e], tr.q[-1]) and np.array_equal(V[e], tr.v[-1]), e
        assert np.array_equal(Q_rec[:n, e], tr.q) and np.array_equal(M_rec[:n, e], tr.q_meas), e
        assert np.isnan(Q_rec[n:, e]).all() and np.isnan(M_rec[n:, e]).all() and np.isnan(C_rec[n:, e]).all(), e
    with pytest.raises(InputError, match=r"duration must be one value or one per environment \(3\)"):
        batch.rollout(states, np.repeat(table[:, None, :], 3, axis=1), [0.1, 0.2])
