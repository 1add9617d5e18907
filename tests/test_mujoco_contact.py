"""What in MuJoCo's soft contact our ground lacks (issue 16): its frictional constraint.

On MuJoCo's default contact (time constant 20 ms) our simulator at MuJoCo's values ends a 3 s,
0.5 Hz run 5.7 cm from MuJoCo's head; the same step with MuJoCo's soft constraint on the
friction pyramid's edges (:mod:`integrators.mujoco_contact`) ends 1.1 cm from it (6 s runs, three
gaits: ``benchmarks/results/contact_law.md``). The test asserts that the rows close most of the
gap, so the structural difference is named by a measurement, not by a fit.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobra_model import ModelParameters
from cobra_model.gait import SidewindingGait
from integrators import mujoco_twin
from integrators.mujoco_contact import impedance, pyramid_rollout
from integrators.simulator import Simulator
from sysid.generators.mujoco_recording import rollout, twin_counterpart, twin_options


def test_impedance_is_mujocos_default_solimp():
    assert impedance(np.array([0.0]))[0] == pytest.approx(0.9)
    assert impedance(np.array([-0.0005]))[0] == pytest.approx(0.925)       # the midpoint
    assert impedance(np.array([-0.002]))[0] == pytest.approx(0.95)          # beyond the width


@pytest.mark.slow
def test_mujocos_soft_frictional_constraint_closes_most_of_the_gap(cobra):
    truth = ModelParameters.nominal().with_values(mu_c=0.24, joint_damping=0.16, motor_km=0.0098)
    ours = twin_counterpart(truth)
    gait, duration = SidewindingGait(0.5), 3.0
    q0 = Simulator(cobra).rest_state(gait.q_ref(np.zeros(1))[0], heading_rad=0.3).q
    options = dataclasses.replace(twin_options(truth), solref=(0.02, 1.0), timestep=0.00025)
    mj = mujoco_twin.build(cobra.urdf_path, options, truth)
    _, qm, _ = rollout(mj, q0, gait.q_ref, duration, record_every=int(round(duration / 0.00025)),
                       error_limit_rad=mujoco_twin.servo_error_limit(options))
    mujoco = qm[-1, :2]
    sim = Simulator(cobra, ours)
    simulator = sim.rollout(sim.state(q0), gait.q_ref, duration, record_every=3000).q[-1, :2]
    rows = pyramid_rollout(cobra, ours, gait, duration, q0, 0.02)
    assert np.linalg.norm(mujoco - q0[:2]) > 0.3                                       # it sidewinds
    assert np.linalg.norm(simulator - mujoco) > 0.04                                    # the gap (5.7 cm)
    assert np.linalg.norm(rows - mujoco) < 0.4 * np.linalg.norm(simulator - mujoco)     # closed (1.1 cm)
