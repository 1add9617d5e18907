"""How the head path is weighted against the joints: the discrepancy workflow's
(sysid.discrepancy.diagnose.balanced_weights) and feasible weighted least squares'
(Objective.residual_weights).

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
from cobra_model.errors import InputError
from sysid.discrepancy.diagnose import DiagnoseConfig, balanced_weights, channel_weights
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
    channels = Objective(runs, PARAMS, weights).channel_residuals(PARAMS.as_vector())
    head, joints = channels["head"], channels["joints"]
    return float(head @ head), float(joints @ joints), float(np.sqrt(np.mean(head ** 2))) * weights.head_scale_m


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


def test_residual_weights_at_the_truth_are_the_sensors_noise(runs):
    """At the parameters that made the runs the model leaves only noise: the head's scale is the
    motion capture's 0.5 mm per axis (measured 0.48-0.57 mm on seeds 5-7), the joints' the
    encoders' rounding, 2 pi / 4096 / sqrt 12 = 0.44 mrad (measured 0.41-0.42). Bounds: a third
    either way for the head (80 residuals, the start pose's noise on top), a quarter for the joints
    (440 residuals)."""
    w = Objective(runs, PARAMS).residual_weights(PARAMS.as_vector())
    assert 0.35e-3 < w.head_scale_m < 0.8e-3
    assert 0.75 * 0.443e-3 < w.joint_scale_rad < 1.25 * 0.443e-3
    assert (w.sample_hz, w.final_head, w.cpg) == (Weights().sample_hz, Weights().final_head, Weights().cpg)


def test_residual_weights_give_each_channel_unit_variance(runs):
    """A head drifting sideways by 0.3 m and joints read 5 mrad off: each channel's scale becomes
    its RMS residual, so that under the new weights both have unit RMS."""
    moved = [dataclasses.replace(drifted(r, 0.3), q=r.q + 0.005) for r in runs]
    objective = Objective(moved, PARAMS)
    x = PARAMS.as_vector()
    w = objective.residual_weights(x)
    assert w.head_scale_m > 0.05 and 0.004 < w.joint_scale_rad < 0.006
    for name, r in objective.with_weights(w).channel_residuals(x).items():
        assert np.sqrt(np.mean(r ** 2)) == pytest.approx(1.0, rel=1e-9), name


def test_the_diagnosis_fits_motor_currents_when_every_run_has_them(runs):
    """``DiagnoseConfig.use_current``: None fits the currents when every run logged them, True
    demands them (naming the run that lacks them), False leaves them out."""
    model = CobraModel.load()
    sim = Simulator(model, PARAMS)
    logged = [record(sim, RunPlan("c", 0.5, 2.0, (0.0, 0.0), 0.3, "train"), np.random.default_rng(5), model,
                     log_current=True)]
    assert channel_weights(logged + logged, DiagnoseConfig()).use_current
    assert not channel_weights(logged + runs, DiagnoseConfig()).use_current
    assert not channel_weights(logged, DiagnoseConfig(use_current=False)).use_current
    with pytest.raises(InputError, match="without motor currents"):
        channel_weights(logged + runs, DiagnoseConfig(use_current=True))
