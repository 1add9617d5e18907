"""The compiled kernels against Pinocchio: contact points, J^T F and the manifold integration."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from cobra_model.model import RobotModel
from cobra_model.parameters import ModelParameters
from integrators import kernels as K
from integrators.simulator import Simulator
from invariants import double_pendulum, solo


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
                                  np.empty(sim.model.n_joints), X, F, np.empty_like(sim._kin_R),
                                  np.empty_like(sim._kin_v), np.zeros((K.N_GEAR, sim.model.n_joints)))
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


def _assert_ground_invariants(sim: Simulator, rng: np.random.Generator, n: int, sample=None) -> None:
    """Normal force never negative, no adhesion, friction power never positive (random states:
    ``sample(rng)`` -> (q, v), default :func:`_random_state` at a random height)."""
    rounding = sim.ground[K.G_ROUND]
    sample = sample or (lambda rng: _random_state(sim.model, rng, z=rng.uniform(-0.01, 0.06)))
    touching = 0
    for _ in range(n):
        q, v = sample(rng)
        v *= rng.uniform(0.1, 5.0)
        _, _, X, F = _forces(sim, q, v)  # a state deeper than max_depth is flagged, its forces still hold
        touching += int(np.any(F[:, 2] > 0))
        assert np.all(F[:, 2] >= 0)
        assert np.all(F[X[:, 2] >= 0] == 0)
        assert np.allclose(X, sim.model.contact_points(q, rounding), atol=1e-12)
        vel = sim.model.contact_velocities(q, v, rounding)
        friction_power = np.einsum("ij,ij->i", F[:, :2], vel[:, :2])
        assert np.all(friction_power <= 1e-12)
    assert touching >= n // 4, f"only {touching} of {n} random states touch the ground"


def test_ground_law_pointwise(cobra):
    _assert_ground_invariants(Simulator(cobra), np.random.default_rng(7), 200)


@pytest.mark.parametrize("shape", [{"friction_cone": 0.5}, {"friction_cone": 0.9, "contact_rounding": 0.045},
                                   {"contact_rounding": 0.02}])
def test_ground_law_pointwise_with_shape_parameters(cobra, shape):
    """The cone-shaped limit and rounded ends keep the invariants of the paper's law, and the
    kernel's contact points are the model's (Pinocchio's) with the same rounding."""
    _assert_ground_invariants(Simulator(cobra, ModelParameters.nominal().with_values(**shape)),
                              np.random.default_rng(8), 100)


@pytest.mark.parametrize("angle", [0.0, 0.3, np.pi / 4, 1.2])
def test_cone_weights_put_the_full_slip_force_on_the_limit_surface(angle):
    """At full slip the Coulomb force lies on the unit q-ball, q = 1/cone, and opposes the slip
    as much as that ball allows (maximum dissipation); cone 0 is the paper's box exactly."""
    v1, v2 = np.cos(angle), np.sin(angle)          # 1 m/s >> eps: tanh = sign
    assert K.cone_weights(v1, v2, 0.01, 0.0) == (1.0, 1.0)
    w1, w2 = K.cone_weights(v1, v2, 0.01, 0.5)
    assert np.hypot(w1, w2) == pytest.approx(1.0, abs=1e-12)            # circle, isotropic
    assert np.arctan2(w2, w1) == pytest.approx(angle, abs=1e-12)        # force against the slip
    for cone in (0.3, 0.7, 0.9):
        q_norm = 1.0 / cone
        w1, w2 = K.cone_weights(v1, v2, 0.01, cone)
        assert (w1 ** q_norm + w2 ** q_norm) ** (1 / q_norm) == pytest.approx(1.0, abs=1e-9)
        # no other point of the ball dissipates more power against this slip
        phi = np.linspace(0, np.pi / 2, 2001)
        c, s = np.cos(phi), np.sin(phi)
        ball = np.stack([c, s]) / (c ** q_norm + s ** q_norm) ** (1 / q_norm)
        assert w1 * v1 + w2 * v2 >= np.max(ball[0] * v1 + ball[1] * v2) - 1e-9
    # toward the diamond (MuJoCo's pyramid with body-aligned edges) the force goes to the vertex
    w1, w2 = K.cone_weights(1.0, 0.6, 0.01, 0.95)
    assert w1 > 0.99 and w2 < 1e-4


def test_friction_cone_zero_is_the_paper_law(cobra):
    rng = np.random.default_rng(9)
    box = Simulator(cobra)
    explicit = Simulator(cobra, ModelParameters.nominal().with_values(friction_cone=0.0))
    circle = Simulator(cobra, ModelParameters.nominal().with_values(friction_cone=0.5))
    q, v = _random_state(cobra, rng, z=0.0)
    _, tau_box, _, F_box = _forces(box, q, v)
    assert np.array_equal(_forces(explicit, q, v)[1], tau_box)
    _, _, _, F_circle = _forces(circle, q, v)
    touching = F_box[:, 2] > 0
    assert touching.any()
    # the circle is inside the box: never more friction than the per-axis law
    assert np.all(np.hypot(*F_circle[:, :2].T) <= np.hypot(*F_box[:, :2].T) + 1e-12)


def test_unsupported_joint_is_reported(erd_dir):
    urdf = erd_dir / "double_pendulum_description" / "urdf" / "double_pendulum_continuous.urdf"
    with pytest.raises(ValueError, match="supports revolute joints"):
        RobotModel.from_urdf(urdf, floating=False)


def test_ground_law_pointwise_on_robots_this_project_did_not_write(erd_dir):
    """The same invariants on Solo (four spherical feet, floating) and on the double pendulum
    with point contacts at its joints (fixed base at z = 0, so its links reach below the ground)."""
    quadruped = solo(erd_dir)
    pendulum = double_pendulum(erd_dir, contact_frames=(("link1", 0.02), ("link2", 0.02)))
    _assert_ground_invariants(Simulator(quadruped), np.random.default_rng(9), 100,
                              lambda rng: _random_state(quadruped, rng, z=rng.uniform(0.15, 0.3)))
    # near horizontal, the point at the second joint is within a centimetre of the ground, above or below
    _assert_ground_invariants(Simulator(pendulum), np.random.default_rng(10), 100,
                              lambda rng: (np.array([rng.uniform(1.65, 1.85), rng.uniform(-0.2, 0.2)]),
                                           rng.normal(0, 0.5, 2)))
