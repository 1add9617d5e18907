"""The COBRA URDF and the partitioned dynamics of paper Eq. 1, checked against MuJoCo."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from cobra_model import design, servo
from cobra_model.errors import InputError
from integrators import mujoco_twin


def random_state(model, rng, scale=1.0):
    q = pin.randomConfiguration(model.pin_model, -np.ones(model.nq) * 3, np.ones(model.nq) * 3)
    q[model.nq - model.n_joints:] = rng.uniform(-1.5, 1.5, model.n_joints)
    v = rng.normal(0, scale, model.nv)
    return q, v


def test_urdf_is_what_the_design_table_generates():
    assert design.DEFAULT_URDF_PATH.read_text() == design.render_urdf()


def test_structure(cobra):
    assert (cobra.nq, cobra.nv, cobra.n_joints) == (18, 17, 11)
    assert cobra.body_names[0] == "head" and cobra.body_names[-1] == "tail"
    for k, name in enumerate(cobra.joint_names, start=1):
        axis = cobra.chain.axes[k]
        assert np.allclose(axis, [0, 1, 0] if k % 2 else [0, 0, 1]), name
    pm = cobra.pin_model
    assert np.allclose(pm.upperPositionLimit[7:], np.pi / 2)
    assert np.allclose(pm.effortLimit[6:], servo.SERVO_STALL_TORQUE_NM)
    assert np.allclose(pm.velocityLimit[6:], 39 * 2 * np.pi / 60)
    # straight snake lies along the head's -x axis, 24 contact points (two per module)
    q = cobra.rest_configuration()
    X = cobra.contact_points(q)
    assert X.shape == (24, 3) and np.allclose(X[:, 1:], 0, atol=1e-12)
    assert np.all(np.diff(X[:, 0]) <= 1e-12)  # neighbouring modules touch end to end


def test_inertias_physically_consistent(cobra):
    for i in range(1, cobra.pin_model.njoints):
        inertia = cobra.pin_model.inertias[i]
        ev = np.linalg.eigvalsh(inertia.inertia)
        assert inertia.mass > 0 and np.all(ev > 0)
        a, b, c = np.sort(ev)
        assert a + b >= c


def test_mass_matrix_spd_and_aba_equals_crba_solve(cobra):
    rng = np.random.default_rng(0)
    model = cobra.with_armature(np.full(11, 0.03))
    for _ in range(10):
        q, v = random_state(model, rng)
        M = model.mass_matrix(q)
        assert np.allclose(M, M.T)
        assert np.linalg.eigvalsh(M).min() > 0
        tau = rng.normal(0, 1, model.nv)
        a_aba = model.forward_dynamics(q, v, tau)
        a_crba = np.linalg.solve(M, tau - model.bias(q, v))
        assert np.allclose(a_aba, a_crba, rtol=1e-9, atol=1e-9)


def test_partitions_assemble_eq1(cobra):
    rng = np.random.default_rng(1)
    q, v = random_state(cobra, rng)
    M = cobra.mass_matrix(q)
    assert np.array_equal(np.block([[cobra.D_H(q), cobra.D_Ha(q)], [cobra.D_Ha(q).T, cobra.D_a(q)]]), M)
    assert np.allclose(np.concatenate([cobra.H_H(q, v), cobra.H_a(q, v)]), cobra.bias(q, v))
    assert np.array_equal(cobra.B, np.vstack([np.zeros((6, 11)), np.eye(11)]))
    J = cobra.contact_jacobian(q)
    assert np.array_equal(np.hstack([cobra.J_H(q), cobra.J_a(q)]), J)


def test_mdot_minus_2c_is_skew(cobra):
    """Passivity: x^T (Mdot - 2C) x = 0, with Mdot by central differences along v."""
    rng = np.random.default_rng(2)
    pm = cobra.pin_model
    data = pm.createData()
    for _ in range(5):
        q, v = random_state(cobra, rng)
        h = 1e-6
        Mp = cobra.mass_matrix(pin.integrate(pm, q, h * v))
        Mm = cobra.mass_matrix(pin.integrate(pm, q, -h * v))
        Mdot = (Mp - Mm) / (2 * h)
        C = pin.computeCoriolisMatrix(pm, data, q, v)
        S = Mdot - 2 * C
        assert np.abs(S + S.T).max() < 1e-6 * max(1.0, np.abs(S).max())


def test_contact_jacobian_matches_finite_differences(cobra):
    rng = np.random.default_rng(3)
    q, v = random_state(cobra, rng)
    h = 1e-7
    fd = (cobra.contact_points(pin.integrate(cobra.pin_model, q, h * v))
          - cobra.contact_points(pin.integrate(cobra.pin_model, q, -h * v))) / (2 * h)
    # the contact point slides on the cylinder as it rolls; the material-point velocity and the
    # geometric point's velocity agree in the direction normal to the ground surface only
    assert np.allclose(cobra.contact_velocities(q, v)[:, 2], fd[:, 2], atol=1e-5)


@pytest.mark.parametrize("seed", range(5))
def test_mass_matrix_and_bias_match_mujoco(cobra, seed):
    """Pinocchio vs MuJoCo on the same URDF with a free joint: M and bias, relative error <= 1e-8."""
    mujoco = pytest.importorskip("mujoco")
    mj = mujoco_twin.build(cobra.urdf_path, mujoco_twin.TwinOptions(ground=False, actuators=False))
    mj.opt.gravity[:] = (0, 0, -9.81)
    d = mujoco.MjData(mj)
    rng = np.random.default_rng(100 + seed)
    q, v = random_state(cobra, rng)
    qpos, qvel = mujoco_twin.pin_to_mj(q, v)
    d.qpos[:], d.qvel[:] = qpos, qvel
    mujoco.mj_forward(mj, d)
    M_mj = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, d, M_mj)
    # v_pin = S v_mj with S = blkdiag(R^T, I): M_mj = S^T M S and
    # bias_mj = S^T (bias_pin + M [-omega x v_lin_local; 0])
    R = pin.Quaternion(q[6], q[3], q[4], q[5]).toRotationMatrix()
    S = np.eye(cobra.nv)
    S[:3, :3] = R.T
    M = cobra.mass_matrix(q)
    assert np.abs(S.T @ M @ S - M_mj).max() <= 1e-8 * np.abs(M_mj).max()
    sdot_v = np.zeros(cobra.nv)
    sdot_v[:3] = -np.cross(v[3:6], v[:3])
    b_pin = S.T @ (cobra.bias(q, v) + M @ sdot_v)
    assert np.abs(b_pin - d.qfrc_bias).max() <= 1e-8 * max(1.0, np.abs(d.qfrc_bias).max())


def test_body_tracks_are_body_centres_of_many_configurations(cobra) -> None:
    rng = np.random.default_rng(3)
    Q = np.array([cobra.configuration(rng.uniform(-1, 1, 11), rng.normal(size=3), rng.normal(size=4))
                  for _ in range(5)])
    tracks = cobra.body_tracks(Q, ("link_6", "tail"))
    for k, q in enumerate(Q):
        centres = cobra.body_centres(q)
        assert np.array_equal(tracks["link_6"][k], centres["link_6"])
        assert np.array_equal(tracks["tail"][k], centres["tail"])
    with pytest.raises(InputError, match=r"unknown link\(s\) \['link_12'\]"):
        cobra.body_tracks(Q, ("link_12",))
