"""Physics of the semi-implicit step: energy, momentum, contact and actuator invariants.

Bounds. Semi-implicit Euler in velocity form (``v+ = v + dt a(q, v)``, ``q+ = q (+) dt v+``) is
symplectic for separable systems (constant inertia); a free-floating 12-link chain has
configuration-dependent inertia and Coriolis forces evaluated explicitly, and there the scheme's
energy error is first order: measured on COBRA in free flight (1 rad/s rms joint rates,
no gravity) it drifts by 0.29 % per second at dt = 1 ms, 0.14 % at 0.5 ms, 0.07 % at
0.25 ms. The tests assert the bound ``|E(t) - E(0)| <= 0.5 % of E(0) per second at dt = 1 ms``
and first-order convergence (halving dt halves the error), instead of the "no drift" a
separable system would give. Momenta drift the same way (measured 0.14 % per second of the
initial linear momentum): bound 0.3 % per second. The angular momentum about the world origin
(measured at most 0.47 % of its initial value per second plus one second's worth of
oscillation): bound 0.6 % per (t + 1 s). In free fall with gravity the energy error is
measured against the largest kinetic energy reached.
"""
from __future__ import annotations

import numpy as np
import pytest

from cobra_model import design, servo
from cobra_model.gait import SidewindingGait
from cobra_model.parameters import ModelParameters
from integrators.simulator import ServoGains, SimSettings, SimulationDiverged, Simulator, effect_parameter
from invariants import double_pendulum, energy, free_flight, solo, undamped_params


def test_free_flight_without_gravity_energy_bounded_and_momenta_conserved(cobra):
    sim, tr, E = free_flight(cobra, np.zeros(3))
    scale = E[0]
    assert np.all(np.abs(E - E[0]) <= 0.005 * scale * (tr.t - tr.t[0]) + 1e-9)
    _, _, E_half = free_flight(cobra, np.zeros(3), dt=5e-4)
    ratio = abs(E_half[-1] - E_half[0]) / abs(E[-1] - E[0])
    assert 0.4 <= ratio <= 0.6                                           # first order in dt
    P = np.array([sim.model.momentum(q, v) for q, v in zip(tr.q, tr.v)])
    lin, ang = P[:, 0], P[:, 1]
    elapsed = (tr.t - tr.t[0])[:, None]
    assert np.all(np.abs(lin - lin[0]) <= 0.003 * np.linalg.norm(lin[0]) * elapsed + 1e-9)
    assert np.all(np.abs(ang - ang[0]) <= 0.006 * np.linalg.norm(ang[0]) * (elapsed + 1.0))


def test_free_flight_with_gravity_energy_bounded(cobra):
    sim, tr, E = free_flight(cobra, np.array([0, 0, -9.81]), seconds=2.0)
    ke_max = max(sim.model.kinetic_energy(q, v) for q, v in zip(tr.q, tr.v))
    assert np.all(np.abs(E - E[0]) <= 0.005 * ke_max * (tr.t - tr.t[0]) + 1e-6)


def test_free_flight_centre_of_mass_falls_on_a_parabola(cobra):
    """Gravity is the only external force, so the centre of mass follows
    ``c0 + t p0 / m + g t^2 / 2`` (``p0`` the initial linear momentum) whatever the joints do.
    The step's error on it is first order: measured 1.5 cm per second of flight at dt = 1 ms
    (0.5 g dt t = 1 cm of it is the semi-implicit step's offset on any falling body), halved at
    0.5 ms; bound 2 cm per second, and the error at 0.5 ms between 0.4 and 0.6 of it."""
    g = np.array([0, 0, -9.81])

    def miss(dt: float) -> tuple[np.ndarray, np.ndarray]:
        sim, tr, _ = free_flight(cobra, g, seconds=2.0, dt=dt)
        c = np.array([sim.model.centre_of_mass(q) for q in tr.q])
        t = tr.t - tr.t[0]
        p0 = sim.model.momentum(tr.q[0], tr.v[0])[0]
        parabola = c[0] + np.outer(t, p0 / sim.model.total_mass) + 0.5 * np.outer(t**2, g)
        return t, np.linalg.norm(c - parabola, axis=1)

    t, err = miss(1e-3)
    assert np.all(err <= 0.02 * t + 1e-9)
    _, err_half = miss(5e-4)
    assert 0.4 <= err_half[-1] / err[-1] <= 0.6                          # first order in dt


@pytest.mark.parametrize("friction_step", ["explicit", "implicit"])
def test_dissipation_never_adds_energy(cobra, friction_step):
    """Ground + damping, no actuation: energy never rises above the integrator's bound."""
    sim = Simulator(cobra, ModelParameters.nominal().with_friction_step(friction_step))
    rng = np.random.default_rng(3)
    rest = sim.rest_state(rng.uniform(-0.5, 0.5, 11))
    st = sim.state(rest.q + np.r_[0, 0, 0.1, np.zeros(15)], rng.normal(0, 0.5, cobra.nv))
    off = np.zeros(11, dtype=bool)
    tr = sim.rollout(st, np.zeros((1, 11)), 3.0, record_every=5, torque_on=off)
    # the ground spring stores energy too: count 0.5 k1 depth^2 per contact point
    def total(q, v):
        depth = np.minimum(sim.model.contact_points(q)[:, 2], 0.0)
        return energy(sim.model, q, v) + 0.5 * sim.params.k1 * np.sum(depth**2)
    E = np.array([total(q, v) for q, v in zip(tr.q, tr.v)])
    rises = np.diff(np.maximum.accumulate(E))
    assert E[-1] < E[0]
    assert np.max(E - np.minimum.accumulate(E)) <= 0.01 * (E[0] - E[-1]) + 1e-3
    assert rises.sum() <= 1e-3


def test_dropped_snake_rests_at_expected_penetration(cobra):
    p = ModelParameters.nominal()
    sim = Simulator(cobra, p)
    st = sim.rest_state()
    st = sim.state(st.q + np.r_[0, 0, 0.02, np.zeros(15)])
    tr = sim.rollout(st, np.zeros((1, 11)), 3.0, record_every=100)
    depth = -sim.model.contact_points(tr.q[-1])[:, 2]
    expected = cobra.total_mass * 9.81 / (len(cobra.features) * p.k1)
    assert np.all(depth > 0)
    assert depth.mean() == pytest.approx(expected, rel=0.05)
    assert np.abs(tr.v[-1]).max() < 1e-3


@pytest.mark.parametrize("friction_step", ["explicit", "implicit"])
def test_resting_snake_does_not_creep(cobra, friction_step):
    sim = Simulator(cobra, ModelParameters.nominal().with_friction_step(friction_step))
    st = sim.rest_state()
    tr = sim.rollout(st, np.zeros((1, 11)), 10.0, record_every=1000)
    drift = np.linalg.norm(tr.q[-1, :2] - tr.q[0, :2])
    assert drift < 1e-3


def _head_displacement(cobra, f, seconds=10.0):
    sim = Simulator(cobra)
    gait = SidewindingGait(f)
    st = sim.rest_state()
    tr = sim.rollout(st, gait.q_ref, seconds, record_every=100)
    return tr.q[-1, :2] - tr.q[0, :2]


def test_sidewinding_moves_sideways_and_faster_with_frequency(cobra):
    """Sidewinding moves the body broadside (along the head's y axis at the start).

    A body length is 12 x 0.13 m = 1.56 m; snakes and snake robots sidewind at roughly 0.1 to 1
    body lengths per cycle. Faster cycles with the same shape cover more ground per second as
    long as the servos keep up (they do at these amplitudes below ~0.7 Hz), so the speed
    increases with frequency over the paper's three gaits.
    """
    body = design.NUM_MODULES * design.MODULE_PITCH_M
    speeds = []
    for f in (0.35, 0.5, 0.65):
        d = _head_displacement(cobra, f)
        per_cycle = np.linalg.norm(d) / (10.0 * f)
        assert 0.1 * body <= per_cycle <= 1.0 * body
        assert abs(d[1]) > 2 * abs(d[0])
        speeds.append(np.linalg.norm(d) / 10.0)
    assert speeds[0] < speeds[1] < speeds[2]


def test_actuator_step_respects_no_load_speed_and_saturates(cobra):
    sim = Simulator(cobra)
    st = sim.rest_state()
    goal = np.zeros(11)
    goal[5] = 1.0            # yaw joint 6: a 1 rad step
    st1 = sim.step(st, goal)
    assert st1.duty[5] == pytest.approx(1.0)        # PWM limit 885 = 100 %
    half = sim.with_gains(ServoGains(pwm_limit=442))
    assert half.step(st, goal).duty[5] == pytest.approx(442 / 885)
    tr = sim.rollout(st, goal[None, :], 2.0)
    qd = tr.v[:, 6 + 5]
    w0 = servo.SERVO_NO_LOAD_SPEED_RAD_S
    assert np.abs(qd).max() <= 1.02 * w0
    t90 = tr.t[np.argmax(tr.q_meas[:, 5] >= 0.9)]
    assert 0.9 / w0 <= t90 <= 1.0                   # cannot beat the no-load speed; no sluggishness
    assert abs(tr.q_meas[-1, 5] - 1.0) < 0.02


def test_settings_check_control_rate_divides_physics_rate():
    with pytest.raises(ValueError, match="integer multiple"):
        SimSettings(dt=1e-3, control_dt=1.5e-3)
    assert SimSettings(dt=5e-4, control_dt=2e-3).substeps == 4


def test_divergence_names_time_and_place(cobra):
    soft = ModelParameters.nominal().with_values(k1=1000.0, k2=1.0)
    sim = Simulator(cobra, soft, SimSettings(max_depth=0.001))
    st = sim.rest_state()
    with pytest.raises(SimulationDiverged, match=r"at t = .* contact point .* penetrated"):
        sim.rollout(st, np.zeros((1, 11)), 1.0)
    stiff = Simulator(cobra, ModelParameters.nominal(), SimSettings(dt=0.05, control_dt=0.05))
    with pytest.raises(SimulationDiverged, match="at t = "):
        stiff.rollout(stiff.rest_state(), SidewindingGait(0.5).q_ref, 5.0)


# --- robots this project did not write (example-robot-data) -------------------------------

def test_double_pendulum_conserves_energy(erd_dir):
    model = double_pendulum(erd_dir).without_contacts()
    sim = Simulator(model, undamped_params(), SimSettings(dt=5e-4, control_dt=5e-4))
    st = sim.state(model.configuration(np.array([1.2, -0.6])), np.zeros(2))
    tr = sim.rollout(st, np.zeros((1, 2)), 10.0, record_every=20, torque_on=np.zeros(2, bool))
    E = np.array([energy(sim.model, q, v) for q, v in zip(tr.q, tr.v)])
    swing = np.ptp([sim.model.potential_energy(q) for q in tr.q])
    assert swing > 0.1                                     # it really swings
    assert np.ptp(E) <= 0.01 * swing
    assert abs(E[-200:].mean() - E[:200].mean()) <= 0.002 * swing


@pytest.mark.parametrize("friction_step", ["explicit", "implicit"])
def test_solo_dropped_on_ground_settles_passively(erd_dir, friction_step):
    model = solo(erd_dir)
    assert len(model.features) >= 4
    params = ModelParameters.nominal().with_values(joint_damping=0.05, armature=1e-3).with_friction_step(friction_step)
    sim = Simulator(model, params, SimSettings(dt=5e-4, control_dt=5e-4))
    q = model.configuration(np.tile([0.8, -1.6], 4), np.array([0, 0, 0.35]))
    tr = sim.rollout(sim.state(q), np.zeros((1, 8)), 2.0, record_every=20, torque_on=np.zeros(8, bool))
    E = np.array([energy(sim.model, q_, v_) for q_, v_ in zip(tr.q, tr.v)])
    assert E[-1] < E[0]
    foot_z = sim.model.contact_points(tr.q[-1])[-4:, 2]
    assert np.all(foot_z < 0.0) and np.all(foot_z > -0.01)  # standing on the ground, shallow
    assert np.abs(tr.v[-1]).max() < 0.5


def test_solo_free_flight_energy_bounded_and_momenta_conserved(erd_dir):
    """COBRA's free-flight bounds of the velocity form hold on Solo (another floating robot)."""
    sim, tr, E = free_flight(solo(erd_dir, feet=False), np.zeros(3), seconds=5.0)
    elapsed = tr.t - tr.t[0]
    assert np.all(np.abs(E - E[0]) <= 0.005 * E[0] * elapsed + 1e-9)
    P = np.array([sim.model.momentum(q, v) for q, v in zip(tr.q, tr.v)])
    lin, ang = P[:, 0], P[:, 1]
    assert np.all(np.abs(lin - lin[0]) <= 0.003 * np.linalg.norm(lin[0]) * elapsed[:, None] + 1e-9)
    assert np.all(np.abs(ang - ang[0]) <= 0.006 * np.linalg.norm(ang[0]) * (elapsed[:, None] + 1.0))


@pytest.mark.parametrize("scheme", ["velocity", "momentum"])
def test_double_pendulum_with_damping_loses_what_the_damper_dissipates(erd_dir, scheme):
    """Joint damping, no actuation: the energy never rises, and what it loses is the damper's
    work ``int b qdot^2 dt`` (measured within 0.46 % of the initial energy for the velocity form
    over 20 s, 0.33 % for the momentum form; bound 1 %)."""
    model = double_pendulum(erd_dir).without_contacts()
    b, dt = 0.002, 1e-3
    sim = Simulator(model, ModelParameters.nominal().with_values(joint_damping=b),
                    SimSettings(dt=dt, control_dt=dt, scheme=scheme))
    st = sim.state(model.configuration(np.array([1.2, -0.6])), np.zeros(2))
    tr = sim.rollout(st, np.zeros((1, 2)), 20.0, record_every=1, torque_on=np.zeros(2, bool))
    E = np.array([energy(sim.model, q, v) for q, v in zip(tr.q, tr.v)])
    assert np.all(np.diff(E) <= 1e-9 * E[0])
    work = np.concatenate([[0.0], np.cumsum(b * np.sum(tr.v[:-1] ** 2, axis=1) * dt)])
    assert work[-1] > 0.5 * E[0]                                       # the damper took most of it
    assert np.abs((E[0] - E) - work).max() <= 0.01 * E[0]


@pytest.mark.parametrize("law, scheme, friction_step", [("compliant", "velocity", "explicit"),
                                                        ("compliant", "velocity", "implicit"),
                                                        ("soft_constraint", "velocity", "explicit"),
                                                        ("compliant", "momentum", "explicit")])
def test_rollout_is_the_single_step_repeated(cobra, law, scheme, friction_step):
    """``Simulator.rollout`` (one compiled call per step: the update in place, the sample, the
    next forces) gives exactly what ``Simulator.step`` gives step by step (separate force and
    update calls, out of place): the same states, and each sample's motor current is the one of
    the step before it. The servo ticks every 4th step, with a joint's motor off."""
    settings = SimSettings(dt=1e-3, control_dt=4e-3, scheme=scheme)
    params = ModelParameters.nominal().with_contact_law(law).with_friction_step(friction_step)
    sim = Simulator(cobra, params, settings)
    gait = SidewindingGait(0.65)
    start = sim.rest_state(gait.q_ref(0.0))
    on = np.ones(11, dtype=bool)
    on[4] = False
    n = 60
    table = gait.q_ref(np.arange(n // 4 + 1) * settings.control_dt)
    tr = sim.rollout(start, table, n * settings.dt, record_every=1, torque_on=on)
    stepper = Simulator(cobra, params, settings)  # its own solver warm start (soft law)
    st = start
    for i in range(n):
        assert np.array_equal(tr.q[i], st.q) and np.array_equal(tr.v[i], st.v), f"step {i}"
        assert np.array_equal(tr.current[i], st.current), f"step {i}"
        st = stepper.step(st, table[i // 4], torque_on=on)
    assert np.array_equal(tr.q[n], st.q) and np.array_equal(tr.v[n], st.v)
    assert np.array_equal(tr.current[n], st.current)


def test_a_torque_limit_clips_the_motor_current_with_the_torque(cobra):
    """A 1 rad step demands the stall current; a 2 N m torque limit holds the motor current at
    2 N m / (r Km) while it acts, as the servo's current limit does (the reported current never
    runs past the torque)."""
    params = ModelParameters.nominal().with_parameters([effect_parameter("torque_limit")]).with_values(torque_limit=2.0)
    sim = Simulator(cobra, params)
    goal = np.zeros(11)
    goal[5] = 1.0
    tr = sim.rollout(sim.rest_state(), goal[None, :], 0.3)
    limit = 2.0 / (params.motor_km * servo.SERVO_GEAR_RATIO)
    assert np.abs(tr.current).max() == pytest.approx(limit, rel=1e-12)
    assert (np.abs(tr.current[:, 5]) > limit * (1 - 1e-12)).mean() > 0.5   # held at the limit most of the step
    free = Simulator(cobra).rollout(Simulator(cobra).rest_state(), goal[None, :], 0.3)
    assert np.abs(free.current[:, 5]).max() > 2 * limit
