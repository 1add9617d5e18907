"""How the discrepancy workflow weights the head path against the joints (sysid.discrepancy.diagnose.balanced_weights).

Two 2 s runs made by this simulator at the parameters the objective is evaluated at: what is left
is the sensors' noise (quantised encoders, mocap noise), far below the default scales, so the
weights must stay the defaults. A head path that drifts sideways by decimetres (what another
engine's ground leaves unexplained) must have its channel down-weighted, no further than its own
RMS residual; joints that outweigh the head, and runs without a head measurement, leave the
weights alone.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobra_model import CobraModel, ModelParameters
from integrators.simulator import Simulator
from sysid.generators.dataset import RunPlan, record
from sysid.discrepancy.diagnose import balanced_weights
from sysid.identification.objective import Objective, Weights

PARAMS = ModelParameters.nominal().with_frozen(free=["mu_c"])


@pytest.fixture(scope="module")
def runs() -> list:
    model = CobraModel.load()
    sim = Simulator(model, PARAMS)
    rng = np.random.default_rng(5)
    plans = [RunPlan("a", 0.5, 2.0, (0.0, 0.0), 0.3, "train"), RunPlan("b", 0.65, 2.0, (0.4, -0.2), 2.0, "train")]
    return [record(sim, p, rng, model) for p in plans]


def channel_costs(runs: list, weights: Weights) -> tuple[float, float, float]:
    """Summed cost of the head channel and of the joint channel, and the head's RMS residual [m]."""
    objective = Objective(runs, PARAMS, weights)
    r = objective.residuals(PARAMS.as_vector()[None])[0]
    gaps = objective.head_gaps()
    head = np.concatenate([b[:, :2].ravel() for b in objective.residual_blocks()])
    head = head[~gaps[head]]
    joints = np.concatenate([b[:, 2:].ravel() for b in objective.residual_blocks()])
    return float(r[head] @ r[head]), float(r[joints] @ r[joints]), float(np.sqrt(np.mean(r[head] ** 2))) * weights.head_scale_m


def drifted(run, drift_m: float):
    """``run`` with its measured head path pushed sideways, growing linearly to ``drift_m`` [m]."""
    s = (run.t - run.t[0]) / (run.t[-1] - run.t[0])
    head = run.head_pos.copy()
    head[:, 1] += drift_m * s
    return dataclasses.replace(run, head_pos=head)


def test_noise_alone_keeps_the_default_scales(runs):
    w = balanced_weights(Objective(runs, PARAMS), PARAMS.as_vector())
    assert w == Weights()


def test_an_unexplained_head_drift_is_down_weighted_to_at_most_its_rms(runs):
    moved = [drifted(r, 0.3) for r in runs]
    head0, joints0, rms = channel_costs(moved, Weights())
    assert head0 > 100 * joints0  # the drift outweighs the joints' evidence a hundredfold
    w = balanced_weights(Objective(moved, PARAMS), PARAMS.as_vector())
    assert w.joint_scale_rad == Weights().joint_scale_rad
    assert Weights().head_scale_m < w.head_scale_m <= rms * (1 + 1e-9)
    head1, joints1, _ = channel_costs(moved, w)
    # either both channels weigh the same, or the head sits at unit variance per residual
    assert head1 == pytest.approx(joints1, rel=1e-6) or w.head_scale_m == pytest.approx(rms, rel=1e-9)
    assert head1 < head0


def test_joints_that_outweigh_the_head_keep_the_weights(runs):
    """A joint-side residual (every reading 0.05 rad off) is evidence of a joint effect: the joints
    are not down-weighted, and the head keeps its scale."""
    off = [dataclasses.replace(r, q=r.q + 0.05) for r in runs]
    head, joints, _ = channel_costs(off, Weights())
    assert joints > 10 * head
    assert balanced_weights(Objective(off, PARAMS), PARAMS.as_vector()) == Weights()


def test_runs_without_a_head_measurement_keep_the_weights(runs):
    blind = [dataclasses.replace(r, head_pos=np.full_like(r.head_pos, np.nan), head_quat=np.full_like(r.head_quat, np.nan))
             for r in runs]
    assert balanced_weights(Objective(blind, PARAMS), PARAMS.as_vector()) == Weights()
