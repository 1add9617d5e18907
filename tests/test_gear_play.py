"""The gear play (``backlash``): the motor and the joint's output are two bodies on one axis with
+-b of play between the teeth (``integrators.kernels.gear_step``).

What the model must do, and what these tests hold it to:

- the kernel's rules, case by case: an open play frees the output of the motor's torque and
  inertia while the motor turns alone; the teeth meet in a plastic impact, at the part of the
  step where the gap crossed the flank; a flank that would pull lets go;
- the impact, handed to the joined bodies at once, conserves their generalized momentum
  (``D v`` plus the motor's) and moves the positions by the late part of the step;
- a play far narrower than what the steps resolve is no play;
- MuJoCo's gear backlash (an independent engine's two hinges and a joint limit) and ours move the
  encoders' readings and the head alike, where the dead zone on the loop's error that this
  library had before moved the readings 2.6 times as much as MuJoCo's;
- a single step carries the play's state and steps it as the compiled rollout does;
- what cannot step it (the momentum scheme) refuses it by name.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cobra_model import ModelParameters, SidewindingGait
from cobra_model.errors import InputError
from integrators import kernels as K
from integrators import native
from integrators.kernels import EFFECT_PARAMETERS
from integrators.simulator import SimSettings, Simulator
from sysid.generators.dataset import RunPlan
from sysid.generators.mujoco_recording import true_trajectory, twin_options

PARAMS = ModelParameters.nominal().with_parameters(EFFECT_PARAMETERS)
DT = 1e-3


def _act(n: int, backlash: float, armature: float = 0.03) -> np.ndarray:
    act = np.zeros((n, K.N_ACT))
    act[:, K.A_BACKLASH], act[:, K.A_ARMATURE] = backlash, armature
    act[:, K.A_RKM], act[:, K.A_TAU_MAX], act[:, K.A_COULOMB_EPS] = 2.0, 9.9, 0.05
    return act


def test_the_kernel_frees_an_open_output_and_joins_the_bodies_when_the_teeth_meet():
    """Five joints on a fixed base (nv = 5), b = 0.01 rad, I = 0.03 kg m^2:
    0 open, turning alone under 0.6 N m; 1 open, the motor reaching the flank this step;
    2 in contact but the teeth would pull; 3 in contact and pushing; 4 without play."""
    b, inertia = 0.01, 0.03
    act = _act(5, b, inertia)
    act[4, K.A_BACKLASH] = 0.0
    gear = np.zeros((K.N_GEAR, 5))
    gear[K.GEAR_GAP] = [0.0, 0.0099, 0.01, 0.01, 0.0]
    gear[K.GEAR_RATE] = [0.2, 1.5, 0.3, 0.3, 0.0]
    gear[K.GEAR_ENGAGED] = [0.0, 0.0, 1.0, 1.0, 0.0]
    gear[K.GEAR_TORQUE] = [0.6, 0.0, -0.2, 0.5, 0.0]
    v = np.array([0.1, 0.5, 0.3, 0.3, 0.4])      # the outputs' new rates [rad/s]
    a = np.array([0.0, 0.0, 1.0, 1.0, 2.0])      # and their accelerations in the step [rad/s^2]
    arm = np.zeros(5)
    K.gear_armature(act, gear, 5, arm)
    assert arm.tolist() == [0.0, 0.0, inertia, inertia, inertia]   # an open play carries no motor
    K.gear_step(v, a, act, DT, gear, arm)
    w0 = 0.2 + DT * 0.6 / inertia                                   # I dw/dt = T
    assert gear[K.GEAR_RATE, 0] == pytest.approx(w0, rel=1e-12)
    assert gear[K.GEAR_GAP, 0] == pytest.approx(DT * (w0 - 0.1), rel=1e-12) and gear[K.GEAR_ENGAGED, 0] == 0
    # the flank reached: in contact, at the flank, the motor's relative momentum owed to the
    # joined bodies; the gap crossed the flank a tenth into the step (0.0099 + 0.1 DT (1.5 - 0.5) = b)
    assert gear[K.GEAR_ENGAGED, 1] == 1 and gear[K.GEAR_GAP, 1] == b and gear[K.GEAR_RATE, 1] == 0.5
    assert gear[K.GEAR_IMPULSE, 1] == pytest.approx(inertia * (1.5 - 0.5), rel=1e-12) and arm[1] == inertia
    assert gear[K.GEAR_LATE, 1] == pytest.approx(0.9, rel=1e-9)
    # T - I a = -0.2 - 0.03 < 0 on the + flank: it lets go, the motor at the output's rate
    assert gear[K.GEAR_ENGAGED, 2] == 0 and arm[2] == 0 and gear[K.GEAR_RATE, 2] == 0.3
    assert gear[K.GEAR_ENGAGED, 3] == 1 and arm[3] == inertia                 # 0.5 - 0.03 > 0: holds
    assert arm[4] == inertia and gear[K.GEAR_RATE, 4] == 0 and gear[K.GEAR_ENGAGED, 4] == 0   # no play: untouched

    # the motor's torque: on an open output none, on a joined one the motor's (the impact is not
    # a torque: gear_impacts hands it over); the back-EMF at the motor's own rate
    duty, tau, current = np.full(5, 0.5), np.zeros(5), np.zeros(5)
    gear[K.GEAR_RATE, 0] = 3.0
    K.actuator_torques(duty, v, np.ones(5, dtype=np.bool_), act, 12.0, 2.0, tau, current, gear)
    assert tau[0] == 0.0 and current[0] == pytest.approx((0.5 * 12.0 - 2.0 * 3.0) / 2.0)
    assert gear[K.GEAR_TORQUE, 0] == pytest.approx(2.0 * current[0])       # it turns the motor instead
    assert tau[1] == pytest.approx(2.0 * (6.0 - 2.0 * 0.5) / 2.0)
    assert tau[4] == pytest.approx(2.0 * (6.0 - 2.0 * 0.4) / 2.0)


def test_an_impact_conserves_the_momentum_of_the_joined_bodies(cobra):
    """``gear_impacts`` hands two joints' impacts (momenta ``P_j = I (w_j - v_j)``, late parts
    0.3 and 0.8 of the step) to the joined bodies: ``D_I v+ = D_0 v + I sum_j w_j e_j`` to
    roundoff (``D_I``: the inertia with the motors, ``D_0``: without those two, whose plays were
    open), on COBRA's free-floating chain (the generated ABA) at random states; the positions
    move on by ``dt D_I^-1 sum_j l_j P_j e_j`` (Pinocchio's ``integrate``); the momenta are
    consumed; with none owed nothing moves."""
    import pinocchio as pin

    rng = np.random.default_rng(3)
    pm = cobra.pin_model
    data = native.NativeData(native.native_model(cobra))
    inertia, joints, late = 0.03, (5, 8), (0.3, 0.8)
    scratch = np.empty(K.N_IMPACT_ROWS * pm.nv)
    for _ in range(5):
        q = cobra.configuration(rng.uniform(-0.5, 0.5, 11))
        v = rng.normal(scale=0.3, size=pm.nv)
        w = {j: v[6 + j] + rng.normal(scale=2.0) for j in joints}
        gear = np.zeros((K.N_GEAR, 11))
        for j, l in zip(joints, late):
            gear[K.GEAR_IMPULSE, j], gear[K.GEAR_LATE, j] = inertia * (w[j] - v[6 + j]), l
        arm = np.zeros(pm.nv)
        arm[6:] = inertia
        q1, v1 = q.copy(), v.copy()
        assert K.gear_impacts(q1, v1, gear, arm, DT, True, data.model.handle, data.handle, scratch)
        D_I = cobra.with_armature(np.full(11, inertia)).mass_matrix(q)
        D_0 = cobra.with_armature(np.where(np.isin(np.arange(11), joints), 0.0, inertia)).mass_matrix(q)
        motors = np.zeros(pm.nv)
        for j in joints:
            motors[6 + j] = inertia * w[j]
        assert np.allclose(D_I @ v1, D_0 @ v + motors, atol=1e-9)
        moved = np.zeros(pm.nv)
        for j, l in zip(joints, late):
            moved[6 + j] = l * inertia * (w[j] - v[6 + j])
        assert np.allclose(q1, pin.integrate(pm, q, DT * np.linalg.solve(D_I, moved)), atol=1e-12)
        assert not gear[K.GEAR_IMPULSE].any()                      # consumed
        q2, v2 = q.copy(), v.copy()
        assert not K.gear_impacts(q2, v2, gear, arm, DT, True, data.model.handle, data.handle, scratch)
        assert np.array_equal(q2, q) and np.array_equal(v2, v)


def test_a_play_far_narrower_than_the_steps_resolve_is_no_play(cobra):
    """b = 1 urad on the compliant ground: each reversal of a joint's load still opens the play
    for a step, which the impact then closes, so the model does not become the one without
    play bit for bit; it stays within 0.05 mm of its head and 0.005 mrad of its readings over a
    4 s gait (measured 0.0035 mm and 0.0004 mrad; 0.05 mm and 0.004 mrad while the impact was
    a torque over the next step; a play of 1 mrad moves them 0.97 mm and 0.41 mrad).
    (On the soft-constraint law the loads ring from step to step, on MuJoCo as on ours, and a 1
    urad play rattles on both: it moves the head by 12.6 mm in 4 s on ours, 5.5 mm on MuJoCo's
    own play, as a joint damping 0.1 % off moves it by 2.4 and 1.8 mm; docs/model.md.)"""
    gait = SidewindingGait(0.5)
    runs = {}
    for b in (0.0, 1e-6, 1e-3):
        sim = Simulator(cobra, PARAMS.with_values(backlash=b))
        runs[b] = sim.rollout(sim.rest_state(gait.q_ref(np.zeros(1))[0]), gait.q_ref, 4.0, record_every=10)

    def moved(b: float) -> tuple[float, float]:
        return (float(np.linalg.norm(runs[b].q[-1, :2] - runs[0.0].q[-1, :2])),
                float(np.sqrt(np.mean((runs[b].q_meas - runs[0.0].q_meas) ** 2))))

    head, readings = moved(1e-6)
    assert head < 5e-5 and readings < 5e-6
    head, readings = moved(1e-3)
    assert head > 5e-4 and readings > 2e-4       # and a real play is seen


def test_our_gear_play_moves_the_readings_and_the_head_as_mujocos_does(cobra):
    """The same 0.02 rad play on both engines, the same parameters and commands (a 6 s run at
    0.5 Hz; our soft-constraint law, MuJoCo's twin contact). The loop acts on the output's
    reading on both, so the readings follow their commands about as well as without play
    (RMS error moved by under b / 10: measured 0.0952 -> 0.0954 on MuJoCo, 0.0950 -> 0.0952 on
    ours), while the free output moves the head (8.7 cm on MuJoCo, 9.3 cm on ours; 10.6 while
    our impact was a torque over the next step).
    The play moves the readings by 7.0 mrad RMS on MuJoCo and 6.6 on ours; the two moves differ
    by 3.7 mrad RMS (bound: 0.7 of MuJoCo's move; the engines step the teeth's contact otherwise,
    a soft limit there, plastic impacts here). The dead zone this library had before moved the
    readings by 18.1 mrad and differed from MuJoCo's move by 19.1."""
    b = 0.02
    plan = RunPlan("gear", 0.5, 6.0, (0.3, -0.2), 0.7, "train")
    gait = SidewindingGait(plan.freq_hz)
    t = np.arange(0.0, plan.duration_s, 0.02)
    ref = gait.q_ref(t)
    late = t >= 2.0

    def readings_and_head(engine: str, backlash: float) -> tuple[np.ndarray, np.ndarray]:
        if engine == "mujoco":
            T, Q, J, _ = true_trajectory(plan, dataclasses.replace(twin_options(PARAMS), backlash=backlash),
                                         cobra, PARAMS)
        else:
            sim = Simulator(cobra, PARAMS.with_contact_law("soft_constraint").with_values(backlash=backlash))
            r = sim.rollout(sim.rest_state(gait.q_ref(np.zeros(1))[0], head_xy=plan.head_xy,
                                           heading_rad=plan.heading_rad), gait.q_ref, plan.duration_s)
            T, Q, J = r.t, r.q, r.q_meas
        return np.column_stack([np.interp(t, T, J[:, k]) for k in range(11)]), Q[-1, :2]

    moves = {}
    for engine in ("mujoco", "ours"):
        (J0, H0), (J, H) = readings_and_head(engine, 0.0), readings_and_head(engine, b)
        rms = [np.sqrt(np.mean((x - ref)[late] ** 2)) for x in (J0, J)]
        assert abs(rms[1] - rms[0]) < b / 10, engine
        assert np.linalg.norm(H - H0) > 0.03, engine
        moves[engine] = J - J0
    size = {e: np.sqrt(np.mean(m ** 2)) for e, m in moves.items()}
    assert 0.5 * size["mujoco"] < size["ours"] < 2.0 * size["mujoco"]
    assert np.sqrt(np.mean((moves["ours"] - moves["mujoco"]) ** 2)) < 0.7 * size["mujoco"]


def test_what_cannot_step_a_gear_play_refuses_it(cobra):
    params = PARAMS.with_values(backlash=0.01)
    with pytest.raises(InputError, match="backlash = 0.01 rad.*velocity scheme"):
        Simulator(cobra, params, SimSettings(scheme="momentum"))
    no_motor = PARAMS.with_parameters([dataclasses.replace(PARAMS["armature"], value=0.0, min=0.0, log_scale=False)])
    with pytest.raises(InputError, match=r"backlash = 0.01 rad needs the motors' inertia \(armature > 0"):
        Simulator(cobra, no_motor.with_values(backlash=0.01))


@pytest.mark.parametrize("law", ["compliant", "soft_constraint"])
def test_the_single_step_carries_the_play_as_the_rollout_steps_it(cobra, law):
    """``Simulator.step`` repeated gives exactly the compiled rollout's states and currents with a
    0.01 rad play, through the gait's first 0.3 s, in which teeth part and meet (the play's
    state in ``SimState.gear`` changes flank); a state without one starts open and centred."""
    params = PARAMS.with_values(backlash=0.01).with_contact_law(law)
    sim = Simulator(cobra, params)
    gait = SidewindingGait(0.65)
    start = sim.rest_state(gait.q_ref(0.0))
    n = 300
    table = gait.q_ref(np.arange(n + 1) * DT)
    tr = sim.rollout(start, table, n * DT)
    st, flanks = start, set()
    for i in range(n):
        assert np.array_equal(tr.q[i], st.q) and np.array_equal(tr.v[i], st.v), f"step {i}"
        assert np.array_equal(tr.current[i], st.current), f"step {i}"
        st = sim.step(st, table[i])
        flanks |= set(st.gear[K.GEAR_ENGAGED])
    assert np.array_equal(tr.q[n], st.q) and np.array_equal(tr.v[n], st.v)
    assert flanks == {-1.0, 0.0, 1.0}       # open, and on either flank, during the run
    assert np.all(np.abs(st.gear[K.GEAR_GAP]) <= 0.01)


@pytest.mark.slow
def test_the_realistic_play_at_one_millisecond_is_a_smooth_function_of_the_play(cobra):
    """``benchmarks/gear_play_step.py``'s dev case (the 0.02 rad play at 0.65 Hz, 6 s from rest,
    ``diagnose_accuracy.py``'s robot): at the 1 ms step a play 0.5 % wider or narrower moves the
    final head by under 5 mm (1.5 mm measured), and the run ends within 15 mm of the same run at
    0.125 ms (9.1 mm; the step's first-order error, 12 mm without a play on the worst gait).
    With the impact a step late (a torque over the next step) the play 0.5 % off moved it by
    24 mm and the run ended 33 mm from the fine one: which step an impact fell in decided the
    head's path."""
    from benchmarks._robot import with_error
    from sysid.discrepancy.effects import EffectLibrary

    truth, library, gait = with_error(), EffectLibrary(), SidewindingGait(0.65)

    def final_head(play: float, dt: float) -> np.ndarray:
        sim = Simulator(cobra, library.transform(truth, {"backlash": play}), SimSettings(dt=dt))
        run = sim.rollout(sim.rest_state(gait.q_ref(0.0)), gait.q_ref, 6.0, record_every=int(round(0.02 / dt)))
        return run.q[-1, :2]

    head = final_head(0.02, 1e-3)
    for play in (0.0199, 0.0201):
        assert np.linalg.norm(final_head(play, 1e-3) - head) < 5e-3, play
    assert np.linalg.norm(final_head(0.02, 1.25e-4) - head) < 15e-3
