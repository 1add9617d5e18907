"""The compiled kernels against Pinocchio: contact points, J^T F and the manifold integration."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from cobra_model.model import RobotModel
from cobra_model.parameters import ModelParameters
from integrators import kernels as K
from integrators.simulator import Simulator


def _random_state(model, rng, z=0.02):
    q = pin.randomConfiguration(model.pin_model, -np.ones(model.nq), np.ones(model.nq))
    if model.chain.floating:
        q[2] = z
    q[model.nq - model.n_joints:] = rng.uniform(-1.2, 1.2, model.n_joints)
    return q, rng.normal(0, 0.5, model.nv)


def _forces(sim, q, v):
    tau = np.zeros(sim.model.nv)
    X, F = np.empty_like(sim._X), np.empty_like(sim._F)
    duty = np.zeros(sim.model.n_joints)
    off = np.zeros(sim.model.n_joints, dtype=np.bool_)
    status = K.generalized_forces(q, v, duty, off, sim.act, sim.scal, sim.ground, sim.model.chain.floating,
                                  sim._chain_i, sim._chain_R, sim._chain_f, sim._feat_i, sim._feat_f, tau,
                                  np.empty(sim.model.n_joints), X, F)
    return status, tau, X, F


@pytest.mark.parametrize("seed", range(5))
def test_contact_points_and_generalized_force_match_pinocchio(cobra, seed):
    rng = np.random.default_rng(seed)
    params = ModelParameters.nominal().with_values(joint_damping=1e-4)
    sim = Simulator(cobra, params)
    q, v = _random_state(sim.model, rng)
    status, tau, X, F = _forces(sim, q, v)
    assert np.allclose(X, sim.model.contact_points(q), atol=1e-12)
    assert np.any(F[:, 2] > 0), "the random state should touch the ground"
    J = sim.model.contact_jacobian(q)
    tau_joints_damping = np.zeros(sim.model.nv)
    tau_joints_damping[6:] = -1e-4 * v[6:]
    assert np.allclose(tau, J.T @ F.ravel() + tau_joints_damping, atol=1e-10)


@pytest.mark.parametrize("seed", range(5))
def test_integrate_equals_pinocchio(cobra, seed):
    rng = np.random.default_rng(seed)
    q, v = _random_state(cobra, rng)
    a = rng.normal(0, 50, cobra.nv)
    dt = 1e-3
    q_out, v_out = np.empty(cobra.nq), np.empty(cobra.nv)
    K.integrate(q, v, a, dt, True, q_out, v_out)
    assert np.allclose(v_out, v + dt * a, atol=1e-15)
    ref = pin.integrate(cobra.pin_model, q, dt * v_out)
    sign = np.sign(ref[6] * q_out[6]) or 1.0   # a quaternion and its negative are one rotation
    assert np.allclose(q_out[:3], ref[:3], atol=1e-14)
    assert np.allclose(q_out[3:7], sign * ref[3:7], atol=1e-14)
    assert np.allclose(q_out[7:], ref[7:], atol=1e-14)


def test_ground_law_pointwise(cobra):
    """Normal force never negative, no adhesion, friction power never positive (random states)."""
    rng = np.random.default_rng(7)
    sim = Simulator(cobra)
    for _ in range(200):
        q, v = _random_state(sim.model, rng, z=rng.uniform(-0.01, 0.06))
        v *= rng.uniform(0.1, 5.0)
        _, _, X, F = _forces(sim, q, v)
        assert np.all(F[:, 2] >= 0)
        assert np.all(F[X[:, 2] >= 0] == 0)
        vel = sim.model.contact_velocities(q, v)
        friction_power = np.einsum("ij,ij->i", F[:, :2], vel[:, :2])
        assert np.all(friction_power <= 1e-12)


def test_unsupported_joint_is_reported(erd_dir):
    urdf = erd_dir / "double_pendulum_description" / "urdf" / "double_pendulum_continuous.urdf"
    with pytest.raises(ValueError, match="supports revolute joints"):
        RobotModel.from_urdf(urdf, floating=False)
