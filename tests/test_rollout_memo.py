"""A rollout answered from another (a longer one of the same batch, or one kept in a memoised
scope) is bit for bit the rollout run on its own."""
from __future__ import annotations

import numpy as np
import pytest

from cobra_model import ModelParameters, SidewindingGait
from integrators import kernels as K
from integrators.batch import BatchSimulator
from integrators.rollout_memo import RolloutMemo, active_memo, memoised_rollouts
from integrators.simulator import SimSettings, SimulationDiverged
from sysid.identification.objective import recorded_span

TABLE = SidewindingGait(0.65).q_ref(np.arange(601) * 1e-3)


def counting_kernel(monkeypatch) -> list[int]:
    """The number of rollouts each call of the batch kernel runs."""
    ran: list[int] = []
    kernel = K.batch_rollout_loop
    monkeypatch.setattr(K, "batch_rollout_loop", lambda *args: (ran.append(len(args[4])), kernel(*args))[1])
    return ran


def alone(cobra, params, duration, every, table=TABLE, settings=None):
    """One environment's rollout in a batch of its own, outside any memoised scope."""
    assert active_memo() is None
    batch = BatchSimulator(cobra, [params], settings)
    return batch.rollout([batch.sims[0].rest_state()], table[:, None, :], duration, record_every=every,
                         divergence="mask")


def same(a, b) -> bool:
    """Two rollouts' outputs equal bit for bit (NaN where either has NaN)."""
    return all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b))


def test_a_shorter_environment_takes_the_longer_ones_records(cobra, monkeypatch):
    # 0.2 s is a whole number of record periods: environment 1 is environment 0's first part;
    # 0.25 s is not (its final state would fall between records): environment 2 runs on its own
    nominal = ModelParameters.nominal()
    batch = BatchSimulator(cobra, [nominal] * 3)
    state = batch.sims[0].rest_state()
    ran = counting_kernel(monkeypatch)
    out = batch.rollout([state] * 3, TABLE[:, None, :], [0.4, 0.2, 0.25], record_every=100,
                        goal_index=np.zeros(3, dtype=int))
    assert ran == [2]
    monkeypatch.undo()
    for e, d in enumerate((0.4, 0.2, 0.25)):
        own = alone(cobra, nominal, d, 100)
        n = len(own[2])
        assert np.array_equal(out[0][e], own[0][0]) and np.array_equal(out[1][e], own[1][0]), d
        assert all(np.array_equal(o[:n, e], w[:, 0]) for o, w in zip(out[2:], own[2:])), d
        assert np.isnan(out[2][n:, e]).all(), d


def test_a_memoised_scope_answers_repeated_and_shorter_requests(cobra, monkeypatch):
    nominal = ModelParameters.nominal()
    other = nominal.with_values(mu_c=nominal.value("mu_c"))  # another object, the same values
    later = TABLE.copy()
    later[350:] += 0.1  # other commands from 0.35 s on
    edge = TABLE.copy()
    edge[200:] += 0.1  # from the tick at 0.2 s on, which a 0.2 s rollout does not read (its last step only integrates)
    expected = {(d, k): alone(cobra, nominal, d, 50, t) for d in (0.2, 0.4)
                for k, t in (("gait", TABLE), ("later", later), ("edge", edge))}
    ran = counting_kernel(monkeypatch)
    with memoised_rollouts() as memo:
        assert active_memo() is memo
        with memoised_rollouts() as inner:  # a nested scope shares the outer memo
            assert inner is memo
        first = BatchSimulator(cobra, [nominal])
        state = first.sims[0].rest_state()
        assert same(first.rollout([state], TABLE[:, None, :], 0.4, record_every=50), expected[0.4, "gait"])
        again = BatchSimulator(cobra, [other])
        assert same(again.rollout([state], TABLE[:, None, :], 0.4, record_every=50), expected[0.4, "gait"])
        assert same(again.rollout([state], TABLE[:, None, :], 0.2, record_every=50), expected[0.2, "gait"])
        # the commands differ only after 0.2 s: the kept rollout answers; to 0.4 s it does not
        assert same(again.rollout([state], later[:, None, :], 0.2, record_every=50), expected[0.2, "later"])
        assert same(again.rollout([state], later[:, None, :], 0.4, record_every=50), expected[0.4, "later"])
        assert same(again.rollout([state], edge[:, None, :], 0.2, record_every=50), expected[0.2, "edge"])
        # another record period is another rollout
        again.rollout([state], TABLE[:, None, :], 0.2, record_every=40)
    assert ran == [1, 1, 1] and memo.hits == 4
    assert active_memo() is None


def test_a_kept_rollout_that_diverged_answers_by_its_failure_step(cobra):
    # at a speed limit of 1 rad/s the gait's joint 2 passes it at step 253 (its integration):
    # a request of 252 steps ran clean, one of 253 diverged there, as each does on its own
    nominal, slow = ModelParameters.nominal(), SimSettings(max_speed=1.0)
    expected = {d: alone(cobra, nominal, d, 1, settings=slow) for d in (0.252, 0.253)}
    with memoised_rollouts() as memo:
        batch = BatchSimulator(cobra, [nominal], slow)
        state = batch.sims[0].rest_state()
        kept = batch.rollout([state], TABLE[:, None, :], 0.6, record_every=1, divergence="mask")
        assert np.isnan(kept[0]).all()
        for d, diverged in ((0.252, False), (0.253, True)):
            served = batch.rollout([state], TABLE[:, None, :], d, record_every=1, divergence="mask")
            assert same(served, expected[d]) and np.isnan(served[0]).all() == diverged, d
        with pytest.raises(SimulationDiverged, match=r"at t = 0\.2530 s velocity coordinate 7 \(joint_2\)"):
            batch.rollout([state], TABLE[:, None, :], 0.3, record_every=1)
    assert memo.hits == 3


def test_a_memo_keeps_at_most_its_bound():
    memo = RolloutMemo(max_rollouts=2)
    for k in range(3):
        memo.keep((k,), object())
    assert list(memo._kept) == [(1,), (2,)]
    with pytest.raises(ValueError, match="max_rollouts must be >= 1"):
        RolloutMemo(0)


def test_a_run_is_simulated_for_whole_record_periods_covering_its_samples():
    rng = np.random.default_rng(0)
    for duration in [5.98, 6.0, 6.0 + 1e-12, 2.9, 11.0, *rng.uniform(0.5, 12.0, 200)]:
        span = recorded_span(duration, 100, 1e-3)
        steps = int(np.rint(span / 1e-3))
        last = np.arange(steps // 100 + 1)[-1] * 100 * 1e-3  # the last record time, as simulate_together has it
        assert steps % 100 == 0 and last >= duration and last - duration < 0.1, duration
    assert recorded_span(6.0, 100, 1e-3) == pytest.approx(6.0) and recorded_span(5.98, 100, 1e-3) == pytest.approx(6.0)
