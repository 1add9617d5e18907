"""The soft-constraint contact laws (``params.with_contact_law("soft_constraint")`` on the friction
pyramid, ``"soft_elliptic"`` on the elliptic cone): MuJoCo's contact.

Their pieces are checked against independent references (the edge rows against Pinocchio's frame
Jacobians, the pyramid's force solver against brute-force enumeration, the elliptic one against
the optimality conditions of its dual problem, the impedance against MuJoCo's formula), their
physics by invariants (a module at rest sinks to where the constraint's spring holds its weight;
forces push, never pull, and stay in their cone), and each law against MuJoCo with the same
cone: on MuJoCo's default contact (time constant 20 ms) our compliant ground at MuJoCo's values
ends a 3 s, 0.5 Hz run several centimetres from MuJoCo's head, the soft-constraint law about
one; on MuJoCo's elliptic cone the pyramid's joints miss MuJoCo's by millimetres, the elliptic
law's by a fraction of one.
"""
from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from cobra_model import ModelParameters
from cobra_model.errors import InputError
from cobra_model.gait import SidewindingGait
from integrators import kernels as K
from integrators import mujoco_twin
from integrators.batch import BatchSimulator
from integrators.simulator import SimSettings, Simulator, contact_resolved
from sysid.generators.mujoco_recording import rollout, rollout_with_torques, twin_counterpart, twin_options
from sysid.identification.objective import SENSOR_NOISE
from benchmarks._robot import with_error


def soft(params: ModelParameters) -> ModelParameters:
    """``params`` under the soft-constraint law."""
    return params.with_contact_law("soft_constraint")


def test_impedance_is_mujocos_default_solimp():
    assert K.soft_impedance(0.0) == pytest.approx(0.9)
    assert K.soft_impedance(-0.0005) == pytest.approx(0.925)       # the midpoint
    assert K.soft_impedance(-0.002) == pytest.approx(0.95)          # beyond the width


def test_nonnegative_qp_solves_the_lcp_exactly():
    """Against enumerating every active set of small random positive definite problems."""
    rng = np.random.default_rng(3)
    for trial in range(40):
        m = int(rng.integers(1, 7))
        B = rng.normal(size=(m, m))
        M = B @ B.T + 0.05 * np.eye(m)
        r = rng.normal(size=m)
        best, best_cost = None, np.inf
        for free in itertools.product((False, True), repeat=m):
            idx = np.flatnonzero(free)
            f = np.zeros(m)
            if len(idx):
                f[idx] = np.linalg.solve(M[np.ix_(idx, idx)], r[idx])
            if np.all(f >= -1e-12):
                cost = 0.5 * f @ M @ f - r @ f
                if cost < best_cost:
                    best, best_cost = f, cost
        start = np.abs(rng.normal(size=m)) * (trial % 2)      # cold and warm starts
        K.nonnegative_qp(M, r, start)
        np.testing.assert_allclose(start, best, atol=1e-9)
        w = M @ start - r
        assert np.all(start >= 0) and np.all(w >= -1e-9) and abs(start @ w) < 1e-9


def test_the_solvers_scratch_carries_nothing_from_one_step_to_the_next(cobra):
    """Both soft laws' solvers and rows on a rollout's scratch arrays (made once, larger than a
    step needs, left with the last step's numbers) answer bit for bit what they answer on arrays
    of their own: no entry is read before it is written."""
    rng = np.random.default_rng(5)
    for trial in range(20):
        m = int(rng.integers(1, 12))
        B = rng.normal(size=(m, m))
        M, r = B @ B.T + 0.05 * np.eye(m), rng.normal(size=m)
        start = np.abs(rng.normal(size=m)) * (trial % 2)
        own, on_scratch = start.copy(), start.copy()
        it_own = K.nonnegative_qp(M, r, own)
        big = m + 5
        it_scratch = K.nonnegative_qp_into(M, r, on_scratch, rng.integers(0, 2, big).astype(bool),
                                           rng.integers(-9, 9, big), np.full((big, big), np.nan),
                                           np.full((big, big), np.nan), np.full(big, np.nan), np.full(big, np.nan),
                                           np.full(big, np.nan))
        assert it_scratch == it_own and np.all(np.isfinite(on_scratch))
        np.testing.assert_array_equal(on_scratch, own)
    nv, newton_steps = 9, 0
    for trial in range(10):                       # the elliptic cone's Newton solve
        nc = int(rng.integers(1, 5))
        B = rng.normal(size=(nv, nv))
        D = np.linalg.inv(B @ B.T + nv * np.eye(nv))
        rows, v, a0 = rng.normal(size=(3 * nc, nv)), rng.normal(size=nv), 5 * rng.normal(size=nv)
        depth, drift = np.repeat(-rng.uniform(1e-5, 2e-3, nc), 3), rng.normal(size=3 * nc)
        weight, start = rng.uniform(0.2, 1.0, nc), np.abs(rng.normal(size=3 * nc)) * (trial % 2)
        f_own, a_own = start.copy(), np.empty(nv)
        it_own = K.elliptic_contact_acceleration(D, a0, v, rows, depth, drift, weight, 0.3, 0.5, 0.02, f_own, a_own)
        scratch = K.elliptic_scratch(nc + 3, nv)
        for s in scratch:
            s.fill(np.nan)
        f, a = start.copy(), a0.copy()            # the loop's call: the acceleration in place
        it = K.elliptic_contact_acceleration_into(D, a, v, rows, depth, drift, weight, 0.3, 0.5, 0.02, f, a,
                                                  np.full(4 * (nc + 3) * nv, np.nan), scratch)
        assert it == it_own and np.all(np.isfinite(a)) and np.all(np.isfinite(f))
        np.testing.assert_array_equal(a, a_own)
        np.testing.assert_array_equal(f, f_own)
        newton_steps += it
    assert newton_steps >= 10                     # the solves iterated (not all separating at the start)
    sim = Simulator(cobra, soft(ModelParameters.nominal()))
    q = sim.rest_state(rng.uniform(-0.5, 0.5, cobra.n_joints), heading_rad=0.3).q
    q[2] -= 0.004
    v = rng.normal(scale=0.3, size=cobra.nv)
    n = cobra.n_joints
    K.pre_step(True, q, v, np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.ones(n, dtype=np.bool_),
               sim.act, sim.scal, sim.ground, True, sim._chain_i, sim._chain_R, sim._chain_f, sim._feat_i,
               sim._feat_f, np.empty(cobra.nv), np.zeros(n), sim._X, sim._F, sim._kin_R, sim._kin_v,
               np.zeros((K.N_GEAR, n)))
    args = (cobra.nv, True, sim._chain_i[:, 0], sim._chain_i[:, 2], sim._feat_i[:, 0], sim._X, sim._kin_R,
            sim._kin_v, v, 0.3, 0.6)
    for elliptic in (False, True):
        own = K.soft_contact_rows(*args, elliptic)
        nf = len(sim._feat_i)
        on_scratch = K.soft_contact_rows_into(*args, elliptic, np.full(4 * nf * cobra.nv, np.nan),
                                              np.full(4 * nf, np.nan), np.full(4 * nf, np.nan),
                                              np.full((3, cobra.nv), np.nan))
        assert own[0].shape[0] > 0
        for a, b in zip(own, on_scratch):
            assert np.all(np.isfinite(b))                      # no NaN of the scratch was read
            np.testing.assert_array_equal(a, b)


def test_cholesky_solves_the_contact_solvers_systems():
    """The contact solvers' own Cholesky against LAPACK on positive definite systems of their
    sizes (a few rows to a 17-coordinate mass matrix and beyond), conditioned as the pyramid's
    ``A + R`` is (condition numbers up to about 1e8), and the inverse made from the factor (the
    mass matrix from its inverse); only the lower triangle is read, and a matrix that is not
    positive definite gives NaN, which a rollout reports as a divergence."""
    rng = np.random.default_rng(5)
    for m in (1, 2, 4, 7, 12, 17, 28, 50):
        B = rng.normal(size=(m, m))
        M = B @ B.T + 1e-8 * m * np.eye(m)
        b = rng.normal(size=m)
        A = np.tril(M) + np.triu(np.full((m, m), 1e9), 1)      # garbage above the diagonal
        L, x = np.empty((m, m)), np.empty(m)
        K.spd_factor(A, m, L)
        K.spd_substitute(L, b, m, x)
        expected = np.linalg.solve(M, b)
        cond = np.linalg.cond(M)
        assert np.linalg.norm(x - expected) <= 1e-15 * cond * np.linalg.norm(expected) * 10 * m
        np.testing.assert_allclose(np.tril(L) @ np.tril(L).T, M, atol=1e-12 * np.abs(M).max())
        inverse, X = np.full((m, m), np.nan), np.full((m, m), np.nan)   # the inverse, from the lower triangle
        K.spd_inverse_into(A, L, X, inverse)
        expected = np.linalg.inv(M)
        assert np.abs(inverse - expected).max() <= 1e-15 * cond * np.abs(expected).max() * 10 * m
        np.testing.assert_allclose(inverse, inverse.T, rtol=0, atol=1e-14 * np.abs(inverse).max())
    L, x = np.empty((2, 2)), np.empty(2)
    K.spd_factor(np.array([[1.0, 2.0], [2.0, 1.0]]), 2, L)             # eigenvalues 3 and -1
    K.spd_substitute(L, np.ones(2), 2, x)
    assert np.isnan(x).all()


def test_the_solve_through_the_velocities_is_the_row_systems():
    """The pyramid's active-set method with each free set solved through the velocities
    (Woodbury's identity) against the same method on the formed row system, on random problems
    of 1-100 rows and 3-17 velocities: the same forces to roundoff, the same iterations, and
    the complementarity conditions hold (the velocities' system updated row by row as the free
    set changes, over as many as a hundred rows joining and leaving)."""
    rng = np.random.default_rng(11)
    for trial in range(30):
        nv, m = int(rng.integers(3, 18)), int(rng.integers(1, 100))
        B = rng.normal(size=(nv, nv))
        Minv = np.linalg.inv(B @ B.T + nv * np.eye(nv))
        Minv = (Minv + Minv.T) / 2
        rows, reg, r = rng.normal(size=(m, nv)), rng.uniform(0.01, 1.0, m), 3.0 * rng.normal(size=m)
        W = rows @ Minv
        A = W @ rows.T + np.diag(reg)
        start = np.abs(rng.normal(size=m)) * (trial % 2)
        direct, through = start.copy(), start.copy()
        iterations = K.nonnegative_qp(A, r, direct)
        assert K.nonnegative_qp_through_velocities_into(rows, reg, Minv, r, through, np.empty(m, dtype=np.bool_),
                                                        np.empty(m), K.soft_scratch(m, nv)[-1]) == iterations
        np.testing.assert_allclose(through, direct, rtol=0, atol=1e-12 * np.abs(direct).max())
        w = A @ through - r
        assert through.min() >= 0 and w.min() > -1e-9 * np.abs(r).max()
        assert abs(through @ w) < 1e-9 * np.abs(r).max() * max(np.abs(through).max(), 1.0)


def test_on_all_its_ends_cobras_pyramid_is_solved_through_the_velocities(cobra):
    """Every end touching (96 rows for 17 velocities, as at rest): the contact acceleration the
    compiled law returns, by the solve through the velocities, is the docstring's system solved
    on the formed rows, to roundoff."""
    sim = Simulator(cobra, soft(ModelParameters.nominal()))
    rng = np.random.default_rng(2)
    q = sim.rest_state(np.zeros(cobra.n_joints), heading_rad=0.2).q
    q[2] -= 0.004                                             # lying straight: every end touches
    v = rng.normal(scale=0.1, size=cobra.nv)
    tau, n = np.empty(cobra.nv), cobra.n_joints
    K.pre_step(True, q, v, np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.ones(n, dtype=np.bool_),
               sim.act, sim.scal, sim.ground, True, sim._chain_i, sim._chain_R, sim._chain_f, sim._feat_i,
               sim._feat_f, tau, np.zeros(n), sim._X, sim._F, sim._kin_R, sim._kin_v,
               np.zeros((K.N_GEAR, n)))
    pm, data = cobra.pin_model, cobra.pin_model.createData()
    a0 = pin.aba(pm, data, q, v, tau, pin.Convention.WORLD).copy()
    Minv = pin.computeMinverse(pm, data)
    Minv = np.triu(Minv) + np.triu(Minv, 1).T
    g = sim.ground
    mu1, tc = g[K.G_MU_C], g[K.G_TC]
    rows, depth, drift = K.soft_contact_rows(cobra.nv, True, sim._chain_i[:, 0], sim._chain_i[:, 2],
                                             sim._feat_i[:, 0], sim._X, sim._kin_R, sim._kin_v, v, mu1,
                                             mu1 * g[K.G_LATERAL])
    m = rows.shape[0]
    assert m > K.THROUGH_VELOCITIES_ROWS_PER_VELOCITY * cobra.nv
    touching = np.flatnonzero(sim._X[:, 2] < 0)
    d = np.array([K.soft_impedance(x) for x in depth])
    weight = np.repeat(cobra.reference_weights[sim._feat_i[touching, 0]], 4)
    reg = 2 * mu1 ** 2 * (1 - d) / d * (1 + mu1 ** 2) * weight
    d_max = K.SOFT_SOLIMP[1]
    rhs = (-2 / (d_max * tc) * rows @ v - d * depth / (d_max * tc * K.SOFT_DAMPRATIO) ** 2 - drift - rows @ a0)
    f = np.zeros(m)
    K.nonnegative_qp(rows @ Minv @ rows.T + np.diag(reg), rhs, f)
    expected = a0 + Minv @ rows.T @ f
    a = a0.copy()
    warm = np.zeros((len(sim._feat_i), 4))
    K.soft_contact_acceleration(v, Minv.copy(), True, sim._chain_i[:, 0],
                                sim._chain_i[:, 2], sim._feat_i[:, 0], sim._X, sim._kin_R, sim._kin_v, g,
                                cobra.reference_weights, warm, a, K.soft_scratch(len(sim._feat_i), cobra.nv))
    np.testing.assert_allclose(a, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    assert np.abs(expected - a0).max() > 1.0                 # the contact forces matter
    np.testing.assert_allclose(warm[touching].ravel(), f, rtol=0, atol=1e-9 * f.max())


def test_edge_rows_are_pinocchios_contact_jacobian(cobra):
    sim = Simulator(cobra, soft(ModelParameters.nominal()))
    rng = np.random.default_rng(0)
    q = sim.rest_state(rng.uniform(-0.5, 0.5, cobra.n_joints), heading_rad=0.7).q
    q[2] -= 0.004                                             # every lowest point touches
    v = rng.normal(scale=0.3, size=cobra.nv)
    tau = np.empty(cobra.nv)
    n = cobra.n_joints
    K.pre_step(True, q, v, np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n), np.ones(n, dtype=np.bool_),
               sim.act, sim.scal, sim.ground, True, sim._chain_i, sim._chain_R, sim._chain_f, sim._feat_i,
               sim._feat_f, tau, np.zeros(n), sim._X, sim._F, sim._kin_R, sim._kin_v,
               np.zeros((K.N_GEAR, n)))
    mu1, mu2 = 0.3, 0.6
    rows, depth, drift = K.soft_contact_rows(cobra.nv, True, sim._chain_i[:, 0], sim._chain_i[:, 2],
                                             sim._feat_i[:, 0], sim._X, sim._kin_R, sim._kin_v, v, mu1, mu2)
    touching = np.flatnonzero(sim._X[:, 2] < 0)
    assert len(touching) >= 2 and rows.shape == (4 * len(touching), cobra.nv)
    J = cobra.contact_jacobian(q, sim.ground[K.G_ROUND])
    data = cobra.pin_model.createData()
    pin.forwardKinematics(cobra.pin_model, data, q)
    for i, k in enumerate(touching):
        Jk = J[3 * k:3 * k + 3]
        x_axis = data.oMi[int(cobra.features.body[k]) + 1].rotation[:, 0]
        t1 = np.array([x_axis[0], x_axis[1], 0.0]) / np.hypot(x_axis[0], x_axis[1])
        t2 = np.cross([0.0, 0.0, 1.0], t1)
        expected = [Jk[2] + mu1 * t1 @ Jk, Jk[2] - mu1 * t1 @ Jk, Jk[2] + mu2 * t2 @ Jk, Jk[2] - mu2 * t2 @ Jk]
        np.testing.assert_allclose(rows[4 * i:4 * i + 4], expected, atol=1e-12)
        assert np.all(depth[4 * i:4 * i + 4] == sim._X[k, 2])


def test_at_rest_the_constraint_holds_the_weight_pushing_only(cobra):
    """Lying still under gravity, the robot settles where the constraint's regulariser and its
    spring balance (``R f = -k d r``): at 20 ms a sustained load sinks by micrometres, as in
    MuJoCo (its twin lying straight: 4.5 um after 2 s; this law 9.2 um with the sharp ends'
    rims as contact points), far less than the constraint's 1 mm impedance width; no velocity
    is left and every edge force is >= 0. (With the per-edge regulariser of before, 2 mu^2
    times too soft, it sank by tens of micrometres.)"""
    params = twin_counterpart(ModelParameters.nominal())
    sim = Simulator(cobra, soft(params))
    q_joints = np.zeros(cobra.n_joints)
    traj = sim.rollout(sim.rest_state(q_joints), np.tile(q_joints, (10, 1)), 2.0, record_every=100)
    assert np.abs(traj.v[-1]).max() < 1e-3
    lowest = cobra.contact_points(traj.q[-1], sim.ground[K.G_ROUND])[:, 2].min()
    assert -20e-6 < lowest < -1e-6
    assert np.all(sim._soft_warm >= 0) and sim._soft_warm.sum() > 0


def test_cone_projection_is_the_nearest_point_of_the_cone():
    """Moreau's decomposition: ``p = g + (p - g)`` with ``g`` in the cone, ``p - g`` in its polar
    cone and the two orthogonal; the Jacobian, ``G^T G`` from the factor ``G`` the solvers use,
    agrees with central differences inside the cone, in its polar cone and on its surface."""
    rng = np.random.default_rng(3)
    G, Gd = np.empty((3, 3)), np.empty((3, 3))
    zones = set()
    for _ in range(300):
        p, slope = 2 * rng.normal(size=3), rng.uniform(0.1, 2.0)
        g = np.array(K.cone_projection(*p, slope, G))
        rest = p - g
        assert np.hypot(g[1], g[2]) <= slope * g[0] + 1e-12                # in the cone
        assert slope * np.hypot(rest[1], rest[2]) <= -rest[0] + 1e-12      # in the polar cone
        assert abs(g @ rest) < 1e-12
        h = 1e-6
        num = np.column_stack([(np.array(K.cone_projection(*(p + h * e), slope, Gd))
                                - np.array(K.cone_projection(*(p - h * e), slope, Gd))) / (2 * h) for e in np.eye(3)])
        np.testing.assert_allclose(G.T @ G, num, atol=1e-6)
        zones.add(int(np.linalg.matrix_rank(G.T @ G)))
    assert zones == {0, 2, 3}                          # every zone was met


def elliptic_problem(rng: np.random.Generator, nv: int, nc: int, warm: bool):
    """A random contact problem of ``nc`` points on ``nv`` velocities, set up as
    ``elliptic_contact_acceleration_into`` sets it up for its Newton solves."""
    B = rng.normal(size=(nv, nv))
    D = np.linalg.inv(B @ B.T + nv * np.eye(nv))
    rows, v, a0 = rng.normal(size=(3 * nc, nv)), rng.normal(size=nv), 5 * rng.normal(size=nv)
    depth, drift = -rng.uniform(1e-5, 2e-3, nc), rng.normal(size=3 * nc)
    weight, mu1, mu2, tc = rng.uniform(0.2, 1.0, nc), 0.3, 0.5, 0.02
    d_max = K.SOFT_SOLIMP[1]
    sR, aref = np.empty(3 * nc), np.empty(3 * nc)
    for c in range(nc):
        d = K.soft_impedance(depth[c])
        sn = np.sqrt((1 - d) / d * weight[c])
        sR[3 * c:3 * c + 3] = sn, sn, sn * mu1 / mu2
        aref[3 * c:3 * c + 3] = -2 / (d_max * tc) * (rows[3 * c:3 * c + 3] @ v) - drift[3 * c:3 * c + 3]
        aref[3 * c] -= d / (d_max * tc * K.SOFT_DAMPRATIO) ** 2 * depth[c]
    start = np.abs(rng.normal(size=3 * nc)) * warm
    return D, np.ascontiguousarray(rows @ D), rows, a0, aref, sR, mu1, start


def test_the_elliptic_newton_steps_in_the_rows_are_those_in_the_velocities():
    """The elliptic cone's two Newton solves (in the contact rows, used up to
    ``ELLIPTIC_ROWS_PER_VELOCITY`` rows per velocity, and in the velocities) take the same steps:
    the same iterations on most problems and as many in all (near the end, roundoff can lead one
    through a few more halvings of its line search at a kink of the cost), the same accelerations
    and forces to well within the solve's tolerance; each reads no scratch entry it has not written (scratch full of NaN,
    and left by a larger problem, gives the answer of fresh scratch bit for bit)."""
    rng = np.random.default_rng(13)
    same_iterations, worst, totals = 0, 0.0, np.zeros(2)
    for trial in range(100):
        nv, nc = int(rng.integers(6, 18)), int(rng.integers(1, 7))
        D, W, rows, a0, aref, sR, mu1, start = elliptic_problem(rng, nv, nc, trial % 2 == 1)
        answers = []
        for solve in (K._elliptic_newton_in_rows, K._elliptic_newton_in_velocities):
            per_path = []
            for scratch in (K.elliptic_scratch(nc, nv), K.elliptic_scratch(nc + 3, nv)):
                for s in scratch:
                    s.fill(np.nan)
                for _ in range(2):                     # the second call on the first call's leftovers
                    f, a = start.copy(), a0.copy()     # in place, as the loop calls it
                    args = (W, rows, a, aref, sR, mu1, f, a, scratch)
                    it = solve(*args) if solve is K._elliptic_newton_in_rows else solve(D, *args)
                    per_path.append((a, f, it))
            for a, f, it in per_path[1:]:
                assert np.all(np.isfinite(a)) and it == per_path[0][2]
                np.testing.assert_array_equal(a, per_path[0][0])
                np.testing.assert_array_equal(f, per_path[0][1])
            answers.append(per_path[0])
        (a_rows, f_rows, it_rows), (a_vel, f_vel, it_vel) = answers
        same_iterations += it_rows == it_vel
        totals += np.array([it_rows, it_vel])
        worst = max(worst, np.abs(a_rows - a_vel).max() / np.abs(a_vel).max(),
                    np.abs(f_rows - f_vel).max() / (np.abs(f_vel).max() + 1e-300))
    assert same_iterations >= 70 and abs(totals[0] - totals[1]) <= 0.05 * totals[1], (same_iterations, totals)
    assert worst < 1e-7


def test_elliptic_forces_solve_the_dual_problem():
    """On random contact problems the elliptic solve's forces satisfy the optimality conditions
    of the problem its docstring states: ``f`` in the cone, ``y = (A + R) f - (a_ref - J a0)``
    in the dual cone ``|mu * y_t| <= y_n``, ``f . y = 0``, and ``a = a0 + D^-1 J^T f``."""
    rng = np.random.default_rng(7)
    nv, nc = 9, 4
    d_max, tc = K.SOFT_SOLIMP[1], 0.02
    for trial in range(20):
        L = rng.normal(size=(nv, nv))
        D = np.linalg.inv(L @ L.T + nv * np.eye(nv))
        rows = rng.normal(size=(3 * nc, nv))
        depth = np.repeat(-rng.uniform(1e-5, 2e-3, nc), 3)
        v, a0 = rng.normal(size=nv), rng.normal(size=nv) * 5
        mu1, mu2 = 0.3, 0.3 * rng.uniform(0.5, 2.0)
        weight = rng.uniform(0.2, 1.0, nc)
        f, a = np.zeros(3 * nc), np.empty(nv)
        drift = rng.normal(size=3 * nc)
        K.elliptic_contact_acceleration(D, a0, v, rows, depth, drift, weight, mu1, mu2, tc, f, a)
        A = rows @ D @ rows.T
        R, aref = np.empty(3 * nc), np.empty(3 * nc)
        for c in range(nc):
            d = K.soft_impedance(depth[3 * c])
            Rn = (1 - d) / d * weight[c]
            R[3 * c:3 * c + 3] = Rn, Rn, Rn * mu1 ** 2 / mu2 ** 2
            aref[3 * c:3 * c + 3] = -2 / (d_max * tc) * (rows[3 * c:3 * c + 3] @ v) - drift[3 * c:3 * c + 3]
            aref[3 * c] -= d / (d_max * tc) ** 2 * depth[3 * c]
        y = (A + np.diag(R)) @ f - (aref - rows @ a0)
        scale = np.abs(y).max() * np.abs(f).max() + 1e-12
        for c in range(nc):
            fn, f1, f2 = f[3 * c:3 * c + 3]
            yn, y1, y2 = y[3 * c:3 * c + 3]
            assert np.hypot(f1 / mu1, f2 / mu2) <= fn * (1 + 1e-9) + 1e-12
            assert np.hypot(mu1 * y1, mu2 * y2) <= yn + 1e-7 * np.abs(y).max()
        assert abs(f @ y) < 1e-7 * scale
        np.testing.assert_allclose(a, a0 + D @ rows.T @ f, atol=1e-8 * np.abs(a).max())


def test_bad_soft_settings_are_refused(cobra):
    with pytest.raises(InputError, match="contact_time_constant = 0.003 s: the soft-constraint contact needs at least"):
        Simulator(cobra, soft(ModelParameters.nominal().with_values(contact_time_constant=0.003)),
                  SimSettings(dt=0.002, control_dt=0.002))
    with pytest.raises(InputError, match="soft_constraint contact law runs with the velocity scheme, got 'momentum'"):
        Simulator(cobra, soft(ModelParameters.nominal()), SimSettings(scheme="momentum"))
    with pytest.raises(InputError, match="contact law must be one of compliant, soft_constraint, soft_elliptic, got 'rigid'"):
        ModelParameters.nominal().with_contact_law("rigid")
    with pytest.raises(InputError, match="a batch steps one contact law; the parameter sets have compliant, soft_constraint"):
        BatchSimulator(cobra, [ModelParameters.nominal(), soft(ModelParameters.nominal())])


@pytest.mark.slow
def test_reference_weights_are_mujocos_body_weights(cobra):
    """Each body's weight at the reference pose, which scales the soft laws' compliance, is the
    value MuJoCo computes for the same URDF (``body_invweight0``), transmission inertia included
    (it halves a middle module's weight here: 0.59 -> 0.32 1/kg)."""
    truth = with_error()
    options = twin_options(truth)
    assert options.armature > 0
    mj = mujoco_twin.build(cobra.urdf_path, options, truth)
    ours = cobra.with_armature(np.full(cobra.n_joints, options.armature)).reference_weights
    np.testing.assert_allclose(ours, mj.body_invweight0[1:, 0], rtol=1e-9)
    assert np.all(cobra.reference_weights > ours)                      # armature only adds inertia


@pytest.mark.parametrize("cone, law", [("pyramidal", "soft_constraint"), ("elliptic", "soft_elliptic")])
def test_at_mujocos_states_the_contact_accelerations_are_mujocos(cobra, cone, law):
    """States of MuJoCo's twin mid-gait (0.65 Hz, the robot sliding and turning), given to our law
    with MuJoCo's actuator and passive forces: the joints' accelerations equal MuJoCo's to 1 % of
    the contact's share of them (measured: at most 0.2 %, from where the contact point sits, at
    the sphere's lowest point here, at the middle of the penetration in MuJoCo, micrometres
    apart). This checks the whole constraint problem at once: rows, regulariser, reference
    acceleration and solver. Without the root frame's turning (``drift`` of
    :func:`integrators.kernels.soft_contact_rows`) the difference reached 10 %."""
    import mujoco

    truth = with_error()
    options = dataclasses.replace(twin_options(truth), cone=cone)
    mj = mujoco_twin.build(cobra.urdf_path, options, truth)
    sim = Simulator(cobra, twin_counterpart(truth).with_contact_law(law))
    gait = SidewindingGait(0.65)
    q0 = sim.rest_state(gait.q_ref(np.zeros(1))[0], heading_rad=0.3).q
    data = mujoco.MjData(mj)
    data.qpos[:], data.qvel[:] = mujoco_twin.pin_to_mj(q0, np.zeros(cobra.nv))
    n, dt, checked = cobra.n_joints, mj.opt.timestep, 0
    for i in range(int(round(2.5 / dt))):
        data.ctrl[:] = gait.q_ref(np.array([i * dt]))[0]
        mujoco.mj_step(mj, data)
        if i < int(round(0.5 / dt)) or i % int(round(0.1 / dt)):
            continue
        mujoco.mj_forward(mj, data)
        q, v = mujoco_twin.mj_to_pin(data.qpos.copy(), data.qvel.copy())
        tau = np.empty(cobra.nv)
        K.pre_step(True, q, v, data.ctrl.copy(), np.zeros(n), np.zeros(n), np.zeros(n), np.ones(n, dtype=np.bool_),
                   sim.act, sim.scal, sim.ground, True, sim._chain_i, sim._chain_R, sim._chain_f, sim._feat_i,
                   sim._feat_f, tau, np.zeros(n), sim._X, sim._F, sim._kin_R, sim._kin_v,
                   np.zeros((K.N_GEAR, n)))
        assert np.count_nonzero(sim._X[:, 2] < 0) == data.ncon
        tau[:] = 0.0
        tau[6:] = data.qfrc_actuator[6:] + data.qfrc_passive[6:]
        a = sim._acceleration(sim._pin, sim._data, q, v, tau)
        contact_share = np.abs(data.qacc[6:] - data.qacc_smooth[6:]).max()
        if data.ncon == 0 or contact_share < 1.0:
            continue
        checked += 1
        assert np.abs(a[6:] - data.qacc[6:]).max() < 0.01 * contact_share
    assert checked >= 15


def test_the_soft_law_follows_mujocos_default_contact(cobra):
    truth = with_error()
    ours = twin_counterpart(truth)
    gait, duration = SidewindingGait(0.5), 3.0
    q0 = Simulator(cobra).rest_state(gait.q_ref(np.zeros(1))[0], heading_rad=0.3).q
    options = dataclasses.replace(twin_options(truth), solref=(0.02, 1.0), timestep=0.00025)
    mj = mujoco_twin.build(cobra.urdf_path, options, truth)
    _, qm, _ = rollout(mj, q0, gait.q_ref, duration, record_every=int(round(duration / 0.00025)),
                       error_limit_rad=mujoco_twin.servo_error_limit(options))
    mujoco = qm[-1, :2]
    finals = {}
    for contact in ("compliant", "soft_constraint"):
        sim = Simulator(cobra, ours.with_contact_law(contact))
        finals[contact] = sim.rollout(sim.state(q0), gait.q_ref, duration, record_every=3000).q[-1, :2]
    gap = {c: np.linalg.norm(h - mujoco) for c, h in finals.items()}
    assert np.linalg.norm(mujoco - q0[:2]) > 0.3                       # it sidewinds
    assert gap["compliant"] > 0.04                                     # the structural gap (5.7 cm)
    assert gap["soft_constraint"] < 0.4 * gap["compliant"]             # closed by the law
    # MuJoCo's pyramidal regulariser: measured 0.82 cm (0.78 cm with the current pose's weights of
    # before, 1.12 cm with the per-edge regulariser before that)
    assert gap["soft_constraint"] < 0.01


def test_the_soft_laws_accelerations_ring_from_step_to_step_as_mujocos_do(cobra):
    """Under the soft-constraint law the joints' accelerations alternate from one 1 ms step to the
    next with the contact forces (on ours a touching end's force goes to zero and back every 5-13
    steps). It is the law's, not our solve's: MuJoCo's accelerations on its default contact ring
    as much (the RMS second difference of each joint's acceleration against its RMS, t >= 0.5 s
    of a 2 s run at 0.5 Hz: 0.52-1.76 on MuJoCo, ours 0.97-1.15 times MuJoCo's per joint when
    written; the elliptic cone's as much as the pyramid's), where our compliant ground at the
    same values rings a third as much (median 0.34 of the soft law's). A gear play rattles
    under such loads on both engines (docs/model.md), so this test keeps the law's step-level
    behaviour MuJoCo's."""
    import mujoco

    truth = with_error()
    gait, duration, settle = SidewindingGait(0.5), 2.0, 0.5
    q0 = Simulator(cobra).rest_state(gait.q_ref(np.zeros(1))[0], heading_rad=0.3).q
    options = twin_options(truth)
    mj = mujoco_twin.build(cobra.urdf_path, options, truth)
    servo, _ = mujoco_twin.joint_addresses(mj)
    dofs = np.array([mj.jnt_dofadr[j] for j in range(mj.njnt) if mj.jnt_qposadr[j] in servo])
    steps: list[np.ndarray] = []
    rollout_with_torques(mj, q0, gait.q_ref, duration, error_limit_rad=mujoco_twin.servo_error_limit(options),
                         after_step=lambda data: steps.append(data.qacc[dofs].copy()))
    assert mj.opt.timestep == pytest.approx(1e-3) and mj.opt.cone == mujoco.mjtCone.mjCONE_PYRAMIDAL

    def ring(acc: np.ndarray, dt: float) -> np.ndarray:
        acc = acc[int(round(settle / dt)):]
        return np.sqrt(np.mean(np.diff(acc, 2, axis=0) ** 2, axis=0) / np.mean(acc ** 2, axis=0))

    rings = {"mujoco": ring(np.array(steps), mj.opt.timestep)}
    for law in ("soft_constraint", "compliant"):
        sim = Simulator(cobra, twin_counterpart(truth).with_contact_law(law))
        assert sim.settings.dt == pytest.approx(1e-3)
        v = sim.rollout(sim.state(q0), gait.q_ref, duration, record_every=1).v[:, 6:]
        rings[law] = ring(np.diff(v, axis=0) / sim.settings.dt, sim.settings.dt)
    assert np.all(rings["mujoco"] > 0.4)                                  # MuJoCo's ring
    ratio = rings["soft_constraint"] / rings["mujoco"]
    assert np.all((ratio > 2 / 3) & (ratio < 1.5)), ratio                 # ours as much, joint by joint
    assert 0.8 < np.median(ratio) < 1.25, ratio
    assert np.median(rings["compliant"] / rings["soft_constraint"]) < 0.5  # the law's more than the step's


def test_a_soft_contact_gets_at_least_eight_steps_per_time_constant(cobra):
    """``contact_resolved``: the default step is refined to an integer fraction of the servo
    period with ``dt <= tc / 8``, never coarsened, the compliant ground left alone; explicit
    settings are the user's."""
    base = SimSettings()
    for tc, dt in ((0.002, 0.00025), (0.003, 0.001 / 3), (0.004, 0.0005), (0.0079, 0.0005), (0.008, 0.001),
                   (0.02, 0.001)):
        resolved = contact_resolved(base, soft(ModelParameters.nominal().with_values(contact_time_constant=tc)))
        assert resolved.dt == pytest.approx(dt) and resolved.control_dt == base.control_dt, (tc, resolved)
        assert resolved.substeps * resolved.dt == pytest.approx(resolved.control_dt)
    fine = SimSettings(dt=0.0002, control_dt=0.001)
    assert contact_resolved(fine, soft(ModelParameters.nominal().with_values(contact_time_constant=0.002))) == fine
    stiff = ModelParameters.nominal().with_values(contact_time_constant=0.002)
    assert contact_resolved(base, stiff) == base                        # the compliant ground: no time constant
    assert Simulator(cobra, soft(stiff)).settings.dt == pytest.approx(0.00025)
    assert Simulator(cobra, soft(stiff), base).settings.dt == base.dt   # given settings are kept


@pytest.mark.slow
def test_on_mujocos_stiff_contact_the_resolved_step_follows_mujocos_joints(cobra):
    """Why a soft contact gets finer steps: against MuJoCo's 2 ms contact (its 0.25 ms steps) at
    MuJoCo's values, the 0.65 Hz gait's joints with our 1 ms step are 1.6 mrad off, 3.6 times the
    encoders' rounding floor (0.44 mrad); at the resolved step (0.25 ms, eight per time constant)
    0.40 mrad (measured; 0.54 mrad at four), inside issue 16's 1.5 x floor."""
    truth = with_error()
    ours = twin_counterpart(truth).with_values(contact_time_constant=0.002).with_contact_law("soft_constraint")
    gait, duration, every = SidewindingGait(0.65), 6.0, 0.02
    q0 = Simulator(cobra).rest_state(gait.q_ref(np.zeros(1))[0], heading_rad=0.3).q
    options = dataclasses.replace(twin_options(truth), solref=(0.002, 1.0), timestep=0.00025)
    mj = mujoco_twin.build(cobra.urdf_path, options, truth)
    _, qm, _ = rollout(mj, q0, gait.q_ref, duration, record_every=int(round(every / 0.00025)),
                       error_limit_rad=mujoco_twin.servo_error_limit(options))
    rms = {}
    for name, settings in (("1 ms", SimSettings()), ("resolved", None)):
        sim = Simulator(cobra, ours, settings)
        q = sim.rollout(sim.state(q0), gait.q_ref, duration, record_every=int(round(every / sim.settings.dt))).q
        n, start = min(len(q), len(qm)), int(round(1.0 / every))            # after the gait's smooth start
        rms[name] = float(np.sqrt(np.mean((q[start:n, 7:] - qm[start:n, 7:]) ** 2)))
    floor = SENSOR_NOISE["joints"]
    assert rms["1 ms"] > 2.5 * floor, rms
    assert rms["resolved"] <= 1.5 * floor, rms


@pytest.mark.slow
def test_the_elliptic_law_follows_mujocos_elliptic_cone(cobra):
    """On MuJoCo's elliptic cone (``cone="elliptic"``, 40 ms contact: the ``elliptic_soft``
    configuration of ``benchmarks/mujoco_fit.py``) the pyramid's joints miss MuJoCo's by
    millimetres (measured 2.9 mrad RMS over 3 s at 0.5 Hz, the head by 6.2 cm), the elliptic
    law's by 0.29 mrad (1.4 cm; 0.47 mrad with the current pose's weights of before), under the
    0.44 mrad noise floor of that benchmark's measured joints; every force stays in its cone."""
    truth = with_error()
    ours = twin_counterpart(truth).with_values(contact_time_constant=0.04)
    gait, duration = SidewindingGait(0.5), 3.0
    q0 = Simulator(cobra).rest_state(gait.q_ref(np.zeros(1))[0], heading_rad=0.3).q
    options = dataclasses.replace(twin_options(truth), solref=(0.04, 1.0), cone="elliptic")
    mj = mujoco_twin.build(cobra.urdf_path, options, truth)
    _, qm, qj = rollout(mj, q0, gait.q_ref, duration, record_every=20,
                        error_limit_rad=mujoco_twin.servo_error_limit(options))
    rms, head = {}, {}
    for law in ("soft_constraint", "soft_elliptic"):
        sim = Simulator(cobra, ours.with_contact_law(law))
        q = sim.rollout(sim.state(q0), gait.q_ref, duration, record_every=20).q
        n = min(len(q), len(qj))
        rms[law] = float(np.sqrt(np.mean((q[n // 6:n, 7:] - qj[n // 6:n]) ** 2)))
        head[law] = float(np.linalg.norm(q[n - 1, :2] - qm[n - 1, :2]))
        if law == "soft_elliptic":
            w = sim._soft_warm
            assert np.all(w[:, 0] >= 0) and np.all(np.hypot(w[:, 1], w[:, 2]) <= 0.24 * w[:, 0] * (1 + 1e-9) + 1e-12)
    assert np.linalg.norm(qm[-1, :2] - q0[:2]) > 0.3                   # it sidewinds
    assert rms["soft_constraint"] > 2e-3                               # the cone's structural gap
    assert rms["soft_elliptic"] < 0.25 * rms["soft_constraint"] and rms["soft_elliptic"] < 0.44e-3
    assert head["soft_elliptic"] < 0.03


@pytest.mark.parametrize("law", ["soft_constraint", "soft_elliptic"])
def test_batched_soft_rollouts_are_the_single_ones(cobra, law):
    """Environments with different friction, time constants and armature (two rigid-body
    models) step as single rollouts do, bit for bit, at the step the fastest contact needs
    (5 ms: 0.5 ms steps; the batch's default)."""
    gait = SidewindingGait(0.5)
    nominal = twin_counterpart(ModelParameters.nominal()).with_contact_law(law)
    params = [nominal, nominal.with_values(mu_c=0.4, mu_s=0.4, contact_time_constant=0.005),
              nominal.with_values(armature=0.05, contact_time_constant=0.04)]
    batch = BatchSimulator(cobra, params, threads=2)  # the threaded path, whatever $COBRA_THREADS says
    assert batch.settings == Simulator(cobra, params[1]).settings and batch.settings.dt == pytest.approx(0.0005)
    sims = [Simulator(cobra, p, batch.settings) for p in params]
    states = [sim.rest_state(gait.q_ref(np.zeros(1))[0], heading_rad=0.3 * k) for k, sim in enumerate(sims)]
    duration = 1.5
    goals = sims[0].commands(gait.q_ref, 0.0, int(round(duration / batch.settings.control_dt)) + 1)
    Q, _, _, _, _ = batch.rollout(states, np.repeat(goals[:, None], 3, axis=1), duration)
    for k, sim in enumerate(sims):
        single = sim.rollout(states[k], goals, duration, record_every=3000).q[-1]
        np.testing.assert_array_equal(Q[k], single)
    assert np.linalg.norm(Q[0, :2] - Q[1, :2]) > 0.01                # the parameters matter


def test_cobra_simulate_takes_the_contact_law(tmp_path):
    from cobra_cli.main import main
    from cobra_model.run_files import read_run

    heads = {}
    for law in ("compliant", "soft_constraint"):
        assert main(["simulate", "--duration", "2", "--contact", law, "--out", str(tmp_path / f"{law}.csv")]) == 0
        run = read_run(tmp_path / f"{law}.csv")
        assert run.meta["params"]["contact_law"] == law
        heads[law] = run.head_pos[-1, :2]
    # two contact laws of one robot: both sidewind, not along the same path
    assert np.linalg.norm(heads["soft_constraint"]) > 0.1
    assert np.linalg.norm(heads["soft_constraint"] - heads["compliant"]) > 1e-3


def test_the_contact_law_travels_with_the_parameter_file(tmp_path):
    """A parameter file records its law: a fit under the soft law and every command that simulates
    with that file use it; ``--contact`` overrides it; a file of before the law was recorded is
    compliant; an unknown law names the file and the key."""
    import json
    import pickle

    from cobra_cli.main import main
    from cobra_model.run_files import read_run

    params = soft(ModelParameters.nominal())
    derived = params.with_values(mu_c=0.3).with_frozen(free=["mu_c"]).update_from_vector(np.array([0.25]))
    assert derived.contact_law == "soft_constraint" and pickle.loads(pickle.dumps(derived)) == derived
    assert derived != derived.with_contact_law("compliant")
    path = params.save(tmp_path / "soft.json")
    assert ModelParameters.load(path).contact_law == "soft_constraint"
    runs = {}
    for name, extra in (("file", ["--params", str(path)]), ("option", ["--contact", "soft_constraint"]),
                        ("override", ["--params", str(path), "--contact", "compliant"])):
        out = tmp_path / f"{name}.csv"
        assert main(["simulate", "--duration", "1", "--out", str(out), *extra]) == 0
        runs[name] = read_run(out)
    np.testing.assert_array_equal(runs["file"].head_pos, runs["option"].head_pos)
    assert runs["override"].meta["params"]["contact_law"] == "compliant"
    assert np.abs(runs["override"].head_pos[-1] - runs["file"].head_pos[-1]).max() > 1e-4
    doc = json.loads(path.read_text())
    del doc["contact_law"]
    (tmp_path / "old.json").write_text(json.dumps(doc))
    assert ModelParameters.load(tmp_path / "old.json").contact_law == "compliant"
    doc["contact_law"] = "rigid"
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    with pytest.raises(InputError, match=r"bad.json: \"contact_law\" is 'rigid', expected one of compliant, soft_constraint"):
        ModelParameters.load(tmp_path / "bad.json")


def test_choosing_a_contact_law_needs_held_out_runs_and_known_laws():
    from sysid.identification.contact_choice import choose_contact_law

    with pytest.raises(InputError, match="needs held-out runs that no fit sees"):
        choose_contact_law([object()], [])
    with pytest.raises(InputError, match=r"unknown contact law\(s\) \['rigid'\]; known: compliant, soft_constraint"):
        choose_contact_law([object()], [object()], laws=["rigid"])


def test_a_contact_choice_gives_each_laws_fit_and_names_the_fitted_ones_for_another():
    from sysid.identification.contact_choice import ContactChoice, LawFit

    fits = tuple(LawFit(law, fit=None, held_out_cost=c, starts=(), seconds=1.0)
                 for law, c in (("compliant", 2.0), ("soft_constraint", 1.0)))
    choice = ContactChoice(fits, chosen="soft_constraint")
    assert choice.fit_of("compliant") is fits[0] and choice.best is fits[1]
    with pytest.raises(InputError, match="no fit of the 'soft_elliptic' contact law here; fitted: compliant, "
                                         "soft_constraint"):
        choice.fit_of("soft_elliptic")


def test_a_fit_from_shapes_starts_at_each_rounding_when_it_is_free_and_keeps_the_lowest_cost():
    """The mechanism of the multi-start (no real fit: the fit is a stand-in that records where it
    starts and whose cost has its minimum between the second and third shape)."""
    from types import SimpleNamespace

    from cobra_model.run_files import read_run
    from sysid.identification.contact_choice import ROUNDING_STARTS_M, fit_from_shapes
    from sysid.identification.objective import Objective, Weights

    runs = [read_run(Path(__file__).resolve().parent.parent / "data" / "reference" / "run_02_0p50hz.csv")]
    started = []

    def fake_fit(objective):
        r0 = objective.params.contact_rounding
        started.append(r0)
        return SimpleNamespace(cost=(r0 - 0.04) ** 2, seconds=1.0, params=objective.params)

    free = ModelParameters.nominal().with_frozen(free=["mu_c", "contact_rounding"])
    shapes = fit_from_shapes(Objective(runs, free, Weights()), fake_fit)
    assert started == list(ROUNDING_STARTS_M)                           # three starts: no screen
    assert shapes.best.params.contact_rounding == ROUNDING_STARTS_M[-1]  # 0.045 m is nearest 0.04 m
    assert 0.0 < shapes.seconds < 60.0  # the wall time of its fits, measured
    assert [s.values["contact_rounding"] for s in shapes.starts] == list(ROUNDING_STARTS_M)
    assert all(s.screen_cost is None for s in shapes.starts)
    started.clear()
    fixed = ModelParameters.nominal().with_frozen(free=["mu_c"]).with_values(contact_rounding=0.01)
    (only,) = fit_from_shapes(Objective(runs, fixed, Weights()), fake_fit).starts
    assert only.values == {} and only.cost == (0.01 - 0.04) ** 2
    assert started == [0.01]  # a frozen shape is kept: one fit from it


def test_a_fit_from_shapes_leaves_out_a_start_whose_simulation_diverges():
    """A start no simulation follows (the stand-in fit raises the simulator's divergence from the
    middle shape) is left out, recorded and reported; the others' best is kept. Only when every
    start diverges is that an error, naming the starts."""
    from types import SimpleNamespace

    from cobra_model.run_files import read_run
    from integrators.simulator import SimulationDiverged
    from sysid.identification.contact_choice import ROUNDING_STARTS_M, fit_from_shapes
    from sysid.identification.objective import Objective, Weights

    runs = [read_run(Path(__file__).resolve().parent.parent / "data" / "reference" / "run_02_0p50hz.csv")]

    def fit_diverging_at(bad):
        def fake_fit(objective):
            r0 = objective.params.contact_rounding
            if r0 in bad:
                raise SimulationDiverged(f"t = 0.2 s: the head sank 3 cm (rounding {r0})")
            return SimpleNamespace(cost=(r0 - 0.02) ** 2, seconds=1.0, params=objective.params)
        return fake_fit

    free = ModelParameters.nominal().with_frozen(free=["mu_c", "contact_rounding"])
    said = []
    shapes = fit_from_shapes(Objective(runs, free, Weights()), fit_diverging_at({ROUNDING_STARTS_M[1]}),
                             progress=said.append)
    assert shapes.best.params.contact_rounding in (ROUNDING_STARTS_M[0], ROUNDING_STARTS_M[2])
    assert [s.diverged for s in shapes.starts] == [False, True, False]
    assert shapes.starts[1].cost is None and shapes.starts[1].to_json()["diverged"] is True
    assert any("diverged from contact_rounding 0.0225 m" in line for line in said)
    with pytest.raises(SimulationDiverged, match="diverged from every start.*contact_rounding 0.045 m"):
        fit_from_shapes(Objective(runs, free, Weights()), fit_diverging_at(set(ROUNDING_STARTS_M)))


def test_a_soft_law_fit_starts_on_a_soft_and_the_stiffest_ground_and_screens_the_starts_on_the_first_seconds():
    """Under a soft law with the time constant free, the starts are every shape on the nominal
    (20 ms) and the stiffest (2 ms, the bound) ground; all six are fitted on the first 1.5 s and
    the three lowest go on to the whole runs, each from where its screen ended. The stand-in fit's
    cost has its minimum at a stiff ground with rounded ends (on the screen's horizon too)."""
    from types import SimpleNamespace

    from cobra_model.run_files import read_run
    from sysid.identification.contact_choice import SCREEN_HORIZON_S, fit_count, fit_from_shapes, fit_starts
    from sysid.identification.objective import Objective, Weights

    runs = [read_run(Path(__file__).resolve().parent.parent / "data" / "reference" / "run_02_0p50hz.csv")]
    calls = []

    def fake_fit(objective):
        p = objective.params
        calls.append((round(objective.longest_run_s, 2), p.contact_time_constant, p.contact_rounding, p.mu_c))
        cost = (p.contact_rounding - 0.04) ** 2 + (np.log(p.contact_time_constant / 0.003)) ** 2
        return SimpleNamespace(cost=cost, seconds=1.0, params=p.with_values(mu_c=p.mu_c + 0.01))  # where it ends

    free = ModelParameters.nominal().with_contact_law("soft_constraint").with_frozen(
        free=["mu_c", "contact_time_constant", "contact_rounding"])
    assert len(fit_starts(free)) == 6 and fit_count(free) == 9
    shapes = fit_from_shapes(Objective(runs, free, Weights()), fake_fit)
    mu0 = free.mu_c
    screens, wholes = calls[:6], calls[6:]
    assert all(h == pytest.approx(SCREEN_HORIZON_S, abs=0.03) and mu == mu0 for h, _, _, mu in screens)
    assert sorted((tc, r) for _, tc, r, _ in screens) == [(tc, r) for tc in (0.002, 0.02) for r in (0.0, 0.0225, 0.045)]
    # the three lowest screens are the stiff ground's; each goes on from where its screen ended
    assert sorted((tc, r) for _, tc, r, _ in wholes) == [(0.002, r) for r in (0.0, 0.0225, 0.045)]
    assert all(h > 2 * SCREEN_HORIZON_S and mu == pytest.approx(mu0 + 0.01) for h, _, _, mu in wholes)
    assert shapes.best.params.contact_rounding == 0.045 and shapes.best.params.mu_c == pytest.approx(mu0 + 0.02)
    assert [s.cost is not None for s in shapes.starts] == [False] * 3 + [True] * 3
    assert all(s.screen_cost is not None for s in shapes.starts)