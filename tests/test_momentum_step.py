"""The momentum-form step (``SimSettings(scheme="momentum")``, :mod:`integrators.momentum_step`):
bounded energy error where the velocity form drifts, on COBRA and on example-robot-data's Solo
and double pendulum, with the same contact and passivity invariants as the velocity form.

Bounds. Symplectic Euler keeps the energy within an O(dt) band around a conserved "modified"
energy instead of drifting. COBRA in free flight without gravity (1 rad/s rms joint rates,
dt = 1 ms, 60 s) is chaotic, so the excursions depend on the rounding and differ between
machines: measured linear trend +1e-4 to +3.4e-4 % per second (the velocity form: +0.39 % per
second), 10 s window means 0.013-0.044 % of E(0) (their change over the flight 0.025 %),
largest excursion 0.10 % on one machine and 0.49 % on another. The band is O(dt) times the
fastest joint rate: from other initial speeds, where the energy gathers in a distal joint
whipping at 25-40 rad/s, it reaches 6 % at 1 ms and 1.5 % at 0.5 ms, and comes back. The tests
assert the issue's 0.02 % per second on the trend, that the level of the last 10 s is within
0.1 % of the first 10 s on COBRA and 0.02 % on the double pendulum and Solo (no systematic
growth: a drift at the issue's bar would move it by 1 % between the windows, the velocity form
moves it by ~20 %) and a 1 % band on COBRA.
The step is first order in the trajectory, which a refinement study asserts.
"""
from __future__ import annotations

import numpy as np
import pytest

from cobra_model.errors import InputError
from cobra_model.model import RobotModel
from cobra_model.parameters import ModelParameters
from integrators.batch import BatchSimulator
from integrators.simulator import SimSettings, Simulator
from invariants import double_pendulum, energy, free_flight, solo, undamped_params


def flight(model: RobotModel, seconds: float, *, scheme: str = "momentum", dt: float = 1e-3,
           record_s: float = 0.01):
    """:func:`invariants.free_flight` without gravity, the energy relative to its initial value."""
    sim, tr, E = free_flight(model, np.zeros(3), seconds, scheme=scheme, dt=dt, record_s=record_s)
    return sim, tr, (E - E[0]) / E[0]


def assert_bounded(t: np.ndarray, rel: np.ndarray, band: float, level: float = 2e-4) -> None:
    """No drift (trend at most 0.02 % per second), no growth of the level between the first and
    the last 10 s (within ``level``), and every excursion within ``band`` (fractions of E(0))."""
    trend = np.polyfit(t - t[0], rel, 1)[0]
    assert abs(trend) <= 2e-4, f"energy trend {100 * trend:+.4f} % per second"
    first, last = rel[t - t[0] < 10.0], rel[t - t[0] >= t[-1] - t[0] - 10.0]
    assert abs(last.mean() - first.mean()) <= level, f"energy level moved {100 * (last.mean() - first.mean()):+.4f} %"
    assert np.abs(rel).max() <= band


def test_lagrangian_gradient_matches_finite_differences_in_the_chart(cobra):
    """``dL/d delta`` of the chart ``q (+) delta`` (body velocity ``J(delta) delta_dot``, J the
    derivative of ``pin.integrate``), by central differences, on a turned, moving COBRA with
    gravity: the root's chart term and Pinocchio's ``C^T v`` together make the exact gradient."""
    import pinocchio as pin

    from integrators.momentum_step import MomentumStep

    model = cobra.without_contacts().with_armature(np.full(cobra.n_joints, 0.03))
    pm, data = model.pin_model, model.pin_model.createData()
    rng = np.random.default_rng(5)
    q = model.configuration(rng.uniform(-0.8, 0.8, model.n_joints), np.array([0.1, -0.2, 0.3]),
                            np.array([0.9, 0.2, -0.3, 0.25]) / np.linalg.norm([0.9, 0.2, -0.3, 0.25]))
    v = rng.normal(0, 1.0, model.nv)

    def lagrangian(delta: np.ndarray) -> float:
        q_d = pin.integrate(pm, q, delta)
        body_v = pin.dIntegrate(pm, q, delta, pin.ArgumentPosition.ARG1) @ v
        return model.kinetic_energy(q_d, body_v) - pin.computePotentialEnergy(pm, data, q_d)

    h = 1e-6
    fd = np.array([(lagrangian(h * e) - lagrangian(-h * e)) / (2 * h) for e in np.eye(model.nv)])
    analytic = MomentumStep(model, 1e-3).lagrangian_gradient(q, v)
    assert np.abs(analytic - fd).max() <= 1e-6 * np.abs(fd).max()
    # without the root's chart term it is off by a share of the gradient itself
    C = pin.computeCoriolisMatrix(pm, data, q, v)
    assert np.abs(C.T @ v - pin.computeGeneralizedGravity(pm, data, q) - fd).max() > 0.05 * np.abs(fd).max()


@pytest.mark.slow
def test_cobra_free_flight_energy_bounded_over_60_s(cobra):
    sim, tr, rel = flight(cobra, 60.0)
    assert_bounded(tr.t, rel, 1e-2, level=1e-3)
    # the same flight in the velocity form drifts: the test can tell the two apart
    _, tr_v, rel_v = flight(cobra, 10.0, scheme="velocity")
    assert np.polyfit(tr_v.t, rel_v, 1)[0] > 1e-3


def test_cobra_free_flight_momenta_conserved(cobra):
    """Without gravity nothing external acts: linear and angular momentum keep their values to
    first order (the step is symplectic, not a momentum-preserving variational integrator).
    Measured over 5 s: 0.15 % (linear) and 0.12 % (angular) of their initial size; the velocity
    form: 0.7 % and 2.7 %."""
    sim, tr, _ = flight(cobra, 5.0, record_s=0.05)
    P = np.array([sim.model.momentum(q, v) for q, v in zip(tr.q, tr.v)])
    lin, ang = P[:, 0], P[:, 1]
    assert np.abs(lin - lin[0]).max() <= 3e-3 * np.linalg.norm(lin[0])
    assert np.abs(ang - ang[0]).max() <= 3e-3 * np.linalg.norm(ang[0])


def test_first_order_convergence(cobra):
    """Trajectory error after 0.3 s against a dt = 0.05 ms reference halves with dt (first order)."""
    finals = {dt: flight(cobra, 0.3, dt=dt, record_s=0.3)[1].q[-1, 7:] for dt in (2e-3, 1e-3, 5e-4, 5e-5)}
    errors = [np.abs(finals[dt] - finals[5e-5]).max() for dt in (2e-3, 1e-3, 5e-4)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all((orders > 0.8) & (orders < 1.3)), orders


def test_double_pendulum_with_gravity_energy_bounded(erd_dir):
    model = double_pendulum(erd_dir).without_contacts()
    dt = 1e-3
    sim = Simulator(model, undamped_params(), SimSettings(dt=dt, control_dt=dt, scheme="momentum"))
    st = sim.state(model.configuration(np.array([1.2, -0.6])), np.zeros(2))
    tr = sim.rollout(st, np.zeros((1, 2)), 60.0, record_every=10, torque_on=np.zeros(2, bool))
    E = np.array([energy(sim.model, q, v) for q, v in zip(tr.q, tr.v)])
    swing = np.ptp([sim.model.potential_energy(q) for q in tr.q])
    assert swing > 0.1                                                   # it really swings
    assert_bounded(tr.t, (E - E[0]) / swing, 0.01)


def test_solo_free_flight_energy_bounded(erd_dir):
    _, tr, rel = flight(solo(erd_dir, feet=False), 20.0)
    assert_bounded(tr.t, rel, 5e-4)  # measured: largest excursion 3.4e-5 (velocity form: trend 0.16 % per second)


def test_solo_dropped_on_ground_settles_passively(erd_dir):
    """Contacts and joint damping with the momentum step: the energy (ground springs included)
    only falls and Solo comes to rest standing on its feet."""
    model = solo(erd_dir)
    params = ModelParameters.nominal().with_values(joint_damping=0.05, armature=1e-3)
    sim = Simulator(model, params, SimSettings(dt=5e-4, control_dt=5e-4, scheme="momentum"))
    q = model.configuration(np.tile([0.8, -1.6], 4), np.array([0, 0, 0.35]))
    tr = sim.rollout(sim.state(q), np.zeros((1, 8)), 2.0, record_every=20, torque_on=np.zeros(8, bool))

    def total(q_, v_):  # the ground spring stores energy too
        depth = np.minimum(sim.model.contact_points(q_)[:, 2], 0.0)
        return energy(sim.model, q_, v_) + 0.5 * params.k1 * np.sum(depth**2)
    E = np.array([total(q_, v_) for q_, v_ in zip(tr.q, tr.v)])
    assert np.all(np.diff(E) <= 1e-3 * E[0])
    assert E[-1] < 0.5 * E[0]
    foot_z = sim.model.contact_points(tr.q[-1])[-4:, 2]
    assert np.all(foot_z < 0.0) and np.all(foot_z > -0.01)  # standing on the ground, shallow
    assert np.abs(tr.v[-1]).max() < 0.5


def test_cobra_on_ground_gait_converges_to_the_velocity_form(cobra):
    """Both steps are first-order discretisations of one model: on a 3 s gait with ground
    contact and servos their head paths differ by O(dt) (measured 4.7 mm of 0.38 m at 1 ms,
    2.4 mm at 0.5 ms, 1.2 mm at 0.25 ms)."""
    from cobra_model.gait import SidewindingGait

    def head_end(scheme: str, dt: float) -> np.ndarray:
        sim = Simulator(cobra, settings=SimSettings(dt=dt, control_dt=1e-3, scheme=scheme))
        tr = sim.rollout(sim.rest_state(), SidewindingGait(0.5, ramp_s=0.5).q_ref, 3.0,
                         record_every=int(round(3.0 / dt)))
        return tr.q[-1, :2] - tr.q[0, :2]
    gap = {dt: np.linalg.norm(head_end("momentum", dt) - head_end("velocity", dt)) for dt in (1e-3, 5e-4)}
    assert np.linalg.norm(head_end("velocity", 1e-3)) > 0.3                 # it sidewinds
    assert gap[1e-3] < 0.02
    assert 1.6 < gap[1e-3] / gap[5e-4] < 2.5                                 # the gap halves with dt


def test_unknown_scheme_and_batched_momentum_are_refused(cobra):
    with pytest.raises(ValueError, match="scheme must be one of velocity, momentum, got 'rk4'"):
        SimSettings(scheme="rk4")
    with pytest.raises(InputError, match="batched rollouts use the velocity-form step"):
        BatchSimulator(cobra, [ModelParameters.nominal()], SimSettings(scheme="momentum"))


def test_cobra_simulate_takes_the_scheme(tmp_path, capsys):
    from cobra_cli.main import main
    from cobra_model.run_files import read_run

    heads = {}
    for scheme in ("velocity", "momentum"):
        assert main(["simulate", "--duration", "2", "--scheme", scheme, "--out", str(tmp_path / f"{scheme}.csv")]) == 0
        run = read_run(tmp_path / f"{scheme}.csv")
        assert run.meta["sim_settings"]["scheme"] == scheme
        heads[scheme] = run.head_pos[-1, :2]
    assert 0 < np.linalg.norm(heads["momentum"] - heads["velocity"]) < 0.01   # two steps, one model


def test_a_rollout_does_not_depend_on_the_previous_one(cobra):
    """The fixed point starts from the last step's correction only when it continues from that
    step's result: the same rollout twice on one simulator gives the same numbers."""
    from cobra_model.gait import SidewindingGait

    sim = Simulator(cobra, settings=SimSettings(scheme="momentum"))
    first, second = (sim.rollout(sim.rest_state(), SidewindingGait(0.5).q_ref, 0.5, record_every=100).q
                     for _ in range(2))
    assert np.array_equal(first, second)
