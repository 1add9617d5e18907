"""The articulated-body algorithm behind the C interface the compiled loops call
(``integrators.native``), and the rollout that calls it from one compiled loop.

On a robot of another structure than COBRA's, the native ABA and inverse mass matrix are
``pin.aba`` in the WORLD convention and (after it) ``pin.computeMinverse`` bit for bit: the C++
model is a field-by-field copy and ABA is the same explicit instantiation in
``libpinocchio_default`` that the Python binding runs, so any difference is a defect (a field
not copied, an inertia summed instead of assigned, another code path). On COBRA's structure the
ABA is the generated one (``integrators/_aba_cobra.c``: Pinocchio's algorithm run on CasADi's
symbolic scalar and written out as straight-line C), whose arithmetic is the same operations in
another order: it agrees with ``pin.aba`` to roundoff, with every parameter a fit changes (the
armature, a body's mass, the gravity). The inverse mass matrix stays Pinocchio's bit for bit.
Either way the compiled rollout is the plain step-by-step rollout bit for bit.
"""
from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from cobra_model import ModelParameters, SidewindingGait
from cobra_model.model import RobotModel
from integrators import native
from integrators.simulator import SimSettings, Simulator
from invariants import double_pendulum, solo, undamped_params
from sysid.discrepancy.effects import EffectLibrary

#: Relative to the largest acceleration, how far the generated ABA may be from Pinocchio's: ten
#: times what Pinocchio's own two conventions (LOCAL, WORLD) differ by on COBRA at random states
#: (2000 of them: up to 9.7e-13; the generated code from WORLD up to 1.1e-12), the roundoff of
#: two orders of the same operations.
ROUNDOFF = 1e-11

#: A two-link arm whose second joint turns about an axis aligned with no coordinate axis
#: (Pinocchio's JointModelRevoluteUnaligned), on a free-flying base.
UNALIGNED_URDF = """<?xml version="1.0"?>
<robot name="tilted">
  <link name="base"><inertial><mass value="1.0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <link name="upper"><inertial><origin xyz="0 0 -0.1"/><mass value="0.4"/>
    <inertia ixx="0.002" ixy="0.0001" ixz="0" iyy="0.0015" iyz="0.0002" izz="0.001"/></inertial></link>
  <link name="lower"><inertial><origin xyz="0.02 0 -0.1"/><mass value="0.3"/>
    <inertia ixx="0.001" ixy="0" ixz="0.0001" iyy="0.001" iyz="0" izz="0.0005"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <axis xyz="1 0 0"/><limit lower="-3" upper="3" effort="5" velocity="10"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="lower"/>
    <origin xyz="0 0 -0.2" rpy="0.1 0.2 0.3"/><axis xyz="0 0.6 0.8"/>
    <limit lower="-3" upper="3" effort="5" velocity="10"/></joint>
</robot>
"""


def _robots(cobra, erd_dir: Path, tmp_path: Path) -> dict[str, RobotModel]:
    urdf = tmp_path / "tilted.urdf"
    urdf.write_text(UNALIGNED_URDF)
    with_effects = EffectLibrary().transform(ModelParameters.nominal(), {"link_mass_error": 0.3})
    return {
        "cobra": cobra.with_armature(np.linspace(0.005, 0.02, 11)),
        "cobra with a payload": Simulator(cobra, with_effects).model,
        "solo": solo(erd_dir).with_armature(np.full(8, 1e-3)),
        "double pendulum": double_pendulum(erd_dir),
        "unaligned axis": RobotModel.from_urdf(urdf, floating=True),
    }


def test_native_dynamics_are_pinocchios(cobra, erd_dir, tmp_path):
    rng = np.random.default_rng(7)
    for name, model in _robots(cobra, erd_dir, tmp_path).items():
        pm = model.pin_model
        nm = native.native_model(model)
        # COBRA's structure, whatever its parameters (if not: was the URDF changed without `make aba-codegen`?)
        assert nm.generated == name.startswith("cobra"), name
        data = native.NativeData(nm)
        reference = pm.createData()
        for _ in range(20):
            q = pin.randomConfiguration(pm, -np.ones(pm.nq), np.ones(pm.nq))
            v, tau = rng.normal(size=pm.nv), 10.0 * rng.normal(size=pm.nv)
            a = native.aba(data, q, v, tau)
            a_pin = pin.aba(pm, reference, q, v, tau, pin.Convention.WORLD)
            if nm.generated:  # the same dynamics, the operations in another order: roundoff
                assert np.allclose(a, a_pin, rtol=0, atol=ROUNDOFF * np.abs(a_pin).max()), name
            else:
                assert np.array_equal(a, a_pin), name
            a_world, minv = native.aba_minverse(data, q, v, tau)
            assert np.array_equal(a_world, a_pin), name  # always Pinocchio's pass
            assert np.array_equal(np.triu(minv), np.triu(pin.computeMinverse(pm, reference))), name
            # the WORLD pass is the same dynamics as the LOCAL one, to roundoff
            a_local = pin.aba(pm, reference, q, v, tau)
            assert np.allclose(a, a_local, rtol=1e-9, atol=1e-9 * np.abs(a_local).max()), name
        assert np.abs(a).max() > 0.1, name  # real values, not zeros on both sides
        D = np.triu(minv) + np.triu(minv, 1).T
        assert np.allclose(D @ model.mass_matrix(q), np.eye(pm.nv), atol=1e-8), name  # and it is D^-1
        assert np.allclose(D @ (tau - pin.nonLinearEffects(pm, reference, q, v)), a, rtol=1e-8,
                           atol=1e-8 * np.abs(a).max()), name  # and a = D (tau - nle)


def test_the_generated_aba_serves_cobras_structure_only(cobra, tmp_path):
    """Every parameter a fit changes keeps the generated ABA (they are its inputs: the gravity
    too); a link frame moved by a tenth of a millimetre is another structure, which gets
    Pinocchio's ABA, bit for bit."""
    moon = cobra.with_gravity(np.array([0.0, 0.0, -1.62]))
    assert native.native_model(moon).generated
    pm = moon.pin_model
    q = pin.randomConfiguration(pm, -np.ones(pm.nq), np.ones(pm.nq))
    v, tau = np.linspace(-1, 1, pm.nv), np.linspace(2, -2, pm.nv)
    a_pin = pin.aba(pm, pm.createData(), q, v, tau, pin.Convention.WORLD)
    a = native.aba(native.NativeData(native.native_model(moon)), q, v, tau)
    assert np.allclose(a, a_pin, rtol=0, atol=ROUNDOFF * np.abs(a_pin).max())
    assert not np.allclose(a, pin.aba(cobra.pin_model, cobra.pin_model.createData(), q, v, tau), rtol=1e-3)
    text = cobra.urdf_path.read_text()
    moved = text.replace('<origin xyz="-0.13 0 0"', '<origin xyz="-0.1301 0 0"', 1)  # joint_2's frame
    assert moved != text
    urdf = tmp_path / "cobra_moved.urdf"
    urdf.write_text(moved)
    other = RobotModel.from_urdf(urdf, floating=True)
    nm = native.native_model(other)
    assert not nm.generated
    pm = other.pin_model
    q = pin.randomConfiguration(pm, -np.ones(pm.nq), np.ones(pm.nq))
    v, tau = np.linspace(-1, 1, pm.nv), np.linspace(2, -2, pm.nv)
    assert np.array_equal(native.aba(native.NativeData(nm), q, v, tau),
                          pin.aba(pm, pm.createData(), q, v, tau, pin.Convention.WORLD))


def test_the_armature_is_each_calls_own(cobra, erd_dir, tmp_path):
    """A servo whose gear play is open carries no motor inertia (``integrators.kernels.gear_step``),
    so the armature is an argument of every call: with another armature than the model's, the
    native dynamics are those of the model with that armature (Pinocchio's pass bit for bit,
    the generated ABA to roundoff), and a workspace used with one armature and then another
    keeps nothing of the first."""
    rng = np.random.default_rng(11)
    for name, model in _robots(cobra, erd_dir, tmp_path).items():
        pm = model.pin_model
        other = model.with_armature(rng.uniform(0.0, 0.05, model.n_joints))
        data = native.NativeData(native.native_model(model))
        q = pin.randomConfiguration(pm, -np.ones(pm.nq), np.ones(pm.nq))
        v, tau = rng.normal(size=pm.nv), 10.0 * rng.normal(size=pm.nv)
        reference = other.pin_model.createData()
        a_pin = pin.aba(other.pin_model, reference, q, v, tau, pin.Convention.WORLD)
        assert not np.allclose(a_pin, pin.aba(pm, pm.createData(), q, v, tau, pin.Convention.WORLD)), name
        for _ in range(2):  # the model's armature, then the other's, twice over
            own = native.aba(data, q, v, tau)
            a = native.aba(data, q, v, tau, other.pin_model.armature)
            a_world, minv = native.aba_minverse(data, q, v, tau, other.pin_model.armature)
            assert np.array_equal(own, native.aba(native.NativeData(native.native_model(model)), q, v, tau)), name
            if native.native_model(model).generated:
                assert np.allclose(a, a_pin, rtol=0, atol=ROUNDOFF * np.abs(a_pin).max()), name
            else:
                assert np.array_equal(a, a_pin), name
            assert np.array_equal(a_world, a_pin), name
            assert np.array_equal(np.triu(minv), np.triu(pin.computeMinverse(other.pin_model, reference))), name
    with pytest.raises(ValueError, match=r"armature must be \(17,\)"):
        native.aba(native.NativeData(native.native_model(cobra)), cobra.configuration(), np.zeros(17), np.zeros(17),
                   np.zeros(11))


def test_the_native_model_is_built_once_per_model(cobra):
    assert native.native_model(cobra) is native.native_model(cobra)
    assert native.native_model(cobra.with_armature(np.full(11, 0.01))) is not native.native_model(cobra)


def test_native_aba_names_wrong_shapes(cobra):
    data = native.NativeData(native.native_model(cobra))
    with pytest.raises(ValueError, match=r"q, v, tau must be \(18,\), \(17,\), \(17,\)"):
        native.aba(data, np.zeros(17), np.zeros(17), np.zeros(17))


@pytest.mark.parametrize("robot, law", [("solo", "compliant"), ("solo", "soft_elliptic"),
                                        ("double pendulum", "compliant"), ("unaligned axis", "compliant")])
def test_the_compiled_rollout_is_the_single_step_repeated_on_other_robots(cobra, erd_dir, tmp_path, robot, law):
    """The compiled loop (Pinocchio called from numba) against ``Simulator.step`` (Pinocchio
    from Python), on Solo standing on its feet (under the compliant ground and MuJoCo's soft
    contact on the elliptic cone), the fixed-base double pendulum and the unaligned joint;
    COBRA's cases are ``test_integrator.test_rollout_is_the_single_step_repeated``."""
    model = _robots(cobra, erd_dir, tmp_path)[robot]
    params = undamped_params().with_values(armature=1e-3).with_contact_law(law)
    settings = SimSettings(dt=5e-4, control_dt=1e-3)
    sim, stepper = Simulator(model, params, settings), Simulator(model, params, settings)
    rng = np.random.default_rng(3)
    q0 = model.configuration(rng.uniform(-0.5, 0.5, model.n_joints))
    if robot == "solo":
        q0 = model.configuration(np.tile([0.8, -1.6], 4), np.array([0.0, 0.0, 0.3]))
    start = sim.state(q0, 0.5 * rng.normal(size=model.nv))
    table = rng.uniform(-0.3, 0.3, (101, model.n_joints))
    n = 200
    tr = sim.rollout(start, table, n * settings.dt, record_every=1)
    st = start
    for i in range(n):
        assert np.array_equal(tr.q[i], st.q) and np.array_equal(tr.v[i], st.v), f"{robot}, step {i}"
        st = stepper.step(st, table[i // 2])
    assert np.array_equal(tr.q[n], st.q) and np.array_equal(tr.v[n], st.v)
    assert np.abs(tr.q[n] - tr.q[0]).max() > 1e-3  # it moved


def test_progress_reports_rise_to_one_and_leave_the_rollout_unchanged(cobra):
    sim = Simulator(cobra)
    gait = SidewindingGait(0.5)
    start = sim.rest_state(gait.q_ref(0.0))
    seen: list[float] = []
    reported = sim.rollout(start, gait.q_ref, 1.0, record_every=10, progress=seen.append)
    silent = sim.rollout(start, gait.q_ref, 1.0, record_every=10)
    assert np.array_equal(reported.q, silent.q) and np.array_equal(reported.current, silent.current)
    assert 90 <= len(seen) <= 110 and seen[-1] == 1.0
    assert np.all(np.diff(seen) >= 0) and 0 < seen[0] <= 0.02
    seen.clear()
    assert len(sim.rollout(start, gait.q_ref, 0.0, progress=seen.append).t) == 1 and seen[-1] == 1.0  # no step


def test_a_pickled_simulator_rolls_out_alike_and_native_handles_do_not_pickle(cobra):
    """A simulator that has run (its compiled loop holds a Pinocchio workspace of this process)
    pickles without it and rolls out the same elsewhere; the handles themselves refuse to
    pickle instead of carrying a pointer into another process's memory."""
    sim = Simulator(cobra)
    gait = SidewindingGait(0.65)
    start = sim.rest_state(gait.q_ref(0.0))
    first = sim.rollout(start, gait.q_ref, 0.2)
    again = pickle.loads(pickle.dumps(sim)).rollout(start, gait.q_ref, 0.2)
    assert np.array_equal(first.q, again.q)
    with pytest.raises(TypeError, match="does not pickle"):
        pickle.dumps(sim._native)
    with pytest.raises(TypeError, match="does not pickle"):
        pickle.dumps(native.native_model(cobra))
