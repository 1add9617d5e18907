"""MuJoCo-made runs for the base-fit tests (``test_mujoco_fit*.py``): the twin's runs at MuJoCo's
values (seed 5, the development seed of ``benchmarks/mujoco_fit.py``), one module so that each
contact configuration's test file can go to its own pytest-xdist worker."""
from __future__ import annotations

import numpy as np

from cobra_model.parameters import ModelParameters
from integrators.simulate import simulate_like
from sysid.gap.metrics import compare_runs
from sysid.generators.dataset import RunPlan
from sysid.generators.mujoco_recording import record_mujoco, twin_options
from sysid.identification.lsq import fit_lsq
from benchmarks._robot import with_error

GAITS = (0.35, 0.5, 0.65)  # Hz


def truth() -> ModelParameters:
    """The nominal parameters at MuJoCo's values (:data:`benchmarks._robot.PARAMETER_ERROR`)."""
    return with_error()


def record(cobra, options, rng, name, duration, xy, heading):
    """One MuJoCo run per gait frequency, ``duration`` s long from ``xy`` [m] at ``heading`` [rad]."""
    return [record_mujoco(RunPlan(f"{name}{f}", f, duration, xy, heading, name), options, rng, cobra, truth())
            for f in GAITS]


def runs_of(cobra, options_of):
    """Three 3 s training runs and three 6 s held-out runs at another heading (seed 5, the
    development seed of benchmarks/mujoco_fit.py)."""
    options = options_of(twin_options(truth()))
    rng = np.random.default_rng(5)
    return (record(cobra, options, rng, "t", 3.0, (0.0, 0.0), 0.3),
            record(cobra, options, rng, "h", 6.0, (0.5, -0.5), 1.3), options)


def validation_runs(cobra, options):
    """Three 3 s validation runs at heading 0.8 rad with their own noise: what chooses the law."""
    return record(cobra, options, np.random.default_rng(5 + 10_000), "v", 3.0, (-0.5, 0.5), 0.8)


def fit(objective):
    """The tests' least-squares fit: 1.5 s windows, at most 8 iterations."""
    return fit_lsq(objective, horizons_s=(1.5,), max_iterations=8)


def gaps_of(runs, named_params):
    """Each named parameter set's gap (``compare_runs``'s JSON) on each of ``runs``."""
    return {name: [compare_runs(run, simulate_like(run, params=p)).to_json_dict() for run in runs]
            for name, p in named_params.items()}
