"""The compliant ground's friction taken implicitly (``ModelParameters.with_friction_step("implicit")``):
the sign regularised at 1 mm/s, below the Stribeck velocity's lower bound, at the 1 ms step.

On a slope gentler than static friction a rigid robot creeps at the velocity ``u`` where the law's
friction balances gravity's pull, ``s(u) tanh(u / eps) M g cos(th) + n mu_v u = M g sin(th)``
(``n`` loaded contacts, all slipping at ``u``): the physics these tests hold the steps to."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import brentq

from cobra_model.gait import SidewindingGait
from cobra_model.errors import InputError
from cobra_model.parameters import FRICTION_STEPS, NOMINAL, ModelParameters
from integrators.batch import BatchSimulator
from integrators.simulator import FRICTION_EPS, SimSettings, Simulator

IMPLICIT = ModelParameters.nominal().with_friction_step("implicit")


def _creep(cobra, tan: float, params: ModelParameters, settings: SimSettings | None = None
           ) -> tuple[float, float, Simulator]:
    """The robot resting on a slope of gradient ``tan`` (gravity tilted along world x), servos
    holding its pose, for 3 s: its mean and spread of speed down the slope over the last second
    [m/s], and the simulator."""
    th = np.arctan(tan)
    model = cobra.with_gravity(np.array([9.81 * np.sin(th), 0.0, -9.81 * np.cos(th)]))
    sim = Simulator(model, params, settings)
    start = sim.rest_state()
    tr = sim.rollout(start, start.q[None, 7:], 3.0, record_every=10)
    speed = np.gradient(tr.q[:, 0], tr.t)[-100:]
    return float(speed.mean()), float(speed.std()), sim


def _law_creep(sim: Simulator, tan: float) -> float:
    """The creep speed [m/s] the ground law gives a rigid robot on a slope of gradient ``tan``."""
    p, th, eps = sim.params, np.arctan(tan), sim.friction_eps
    weight = sim.model.total_mass * 9.81
    n = int(np.sum(sim.model.contact_points(sim.rest_state().q)[:, 2] <= 1e-9))

    def balance(u: float) -> float:
        s = p.mu_c - (p.mu_c - p.mu_s) * np.exp(-(u / p.v_s) ** 2)
        return s * np.tanh(u / eps) * weight * np.cos(th) + n * p.mu_v * u - weight * np.sin(th)

    return brentq(balance, 0.0, 10 * eps)


@pytest.mark.parametrize("tan", [0.2, 0.44])
def test_a_slope_below_static_friction_holds_the_robot_at_the_laws_creep(cobra, tan):
    """The implicit step creeps at the law's speed within 0.5 % (steady: no chatter), at 0.2
    (far below ``mu_s`` = 0.45) and at 0.44 (just below it, above ``mu_c`` = 0.3)."""
    speed, spread, sim = _creep(cobra, tan, IMPLICIT)
    law = _law_creep(sim, tan)
    assert law < sim.faithful_slip  # creep: the regularised band, below the faithful speed
    assert speed == pytest.approx(law, rel=0.005)
    assert spread < 1e-3 * law


def test_the_explicit_step_chatters_at_the_implicit_steps_eps(cobra):
    """Why the implicit step: at 1 mm/s the explicit 1 ms step cannot resolve the sign's slope
    ``s F_z / eps``; a contact that should creep at 0.48 mm/s chatters and averages more than
    twice that (measured 1.09 mm/s)."""
    speed, spread, sim = _creep(cobra, 0.2, ModelParameters.nominal(), SimSettings(sgn_eps=FRICTION_EPS["implicit"]))
    law = _law_creep(sim, 0.2)
    assert speed > 1.5 * law
    assert spread > 0.05 * law


def test_the_explicit_steps_eps_lets_static_friction_slip(cobra):
    """Why a small eps: with the explicit step's 1 cm/s the creep speed on a 0.44 slope would
    be 2.2 cm/s, where the Stribeck curve (``v_s`` = 5 cm/s) has already let the friction fall
    below the pull, so the robot breaks away and slides (measured 68 cm/s after 3 s) where
    static friction (0.45) holds it; the implicit step's 1 mm/s holds it at 2.2 mm/s
    (``test_a_slope_below_static_friction_holds_the_robot_at_the_laws_creep``)."""
    speed, _, _ = _creep(cobra, 0.44, ModelParameters.nominal())
    assert speed > 0.1


def test_the_implicit_step_converges_to_a_fine_step(cobra):
    """3 s of the 0.5 Hz gait: the implicit step at 1, 0.5 and 0.25 ms against the explicit step
    at 0.05 ms (stable at eps = 1 mm/s), the same law. The error is first order: it halves with
    the step (final head measured 2.2, 1.1, 0.6 mm; joints at most 1.34, 0.62, 0.28 mrad), and at 1 ms
    it is of the explicit 1 cm/s step's own size (0.3-0.9 cm, 0.2-0.6 mrad over 6 s)."""
    gait = SidewindingGait(0.5)

    def run(params: ModelParameters, settings: SimSettings):
        sim = Simulator(cobra, params, settings)
        return sim.rollout(sim.rest_state(), gait.q_ref, 3.0, record_every=int(round(0.01 / settings.dt)))

    fine = run(ModelParameters.nominal(), SimSettings(dt=5e-5, control_dt=1e-3, sgn_eps=FRICTION_EPS["implicit"]))
    head, joints = [], []
    for dt in (1e-3, 5e-4, 2.5e-4):
        tr = run(IMPLICIT, SimSettings(dt=dt, control_dt=1e-3))
        head.append(np.linalg.norm(tr.q[-1, :2] - fine.q[-1, :2]))
        joints.append(np.abs(tr.q[:, 7:] - fine.q[:, 7:]).max())
    assert head[0] < 0.005 and joints[0] < 1.5e-3
    for error in (head, joints):
        for coarse, finer in zip(error, error[1:]):
            assert 0.3 * coarse < finer < 0.7 * coarse


def test_the_implicit_steps_faithful_slip_is_below_the_stribeck_velocitys_lower_bound(cobra):
    """The regularised sign is within 1 % of sign(u) above ``faithful_slip``: 2.65 mm/s for the
    implicit step, below ``v_s``'s lower bound (5 mm/s), so every ``v_s`` a fit may reach shapes
    a Stribeck curve; the explicit step's 2.65 cm/s is not."""
    v_s = next(p for p in NOMINAL if p.name == "v_s")
    implicit, explicit = Simulator(cobra, IMPLICIT), Simulator(cobra)
    assert np.tanh(implicit.faithful_slip / implicit.friction_eps) == pytest.approx(0.99)
    assert implicit.faithful_slip < v_s.min < explicit.faithful_slip


def test_the_friction_step_is_checked_and_kept(cobra, tmp_path):
    """An unknown step and the momentum scheme are refused; the step survives derived sets and
    the parameter file; a file without it (written before it existed) is explicit; a batch
    steps one friction step."""
    with pytest.raises(InputError, match="friction step must be one of explicit, implicit, got 'newton'"):
        ModelParameters.nominal().with_friction_step("newton")
    with pytest.raises(InputError, match="implicit friction step is a velocity-scheme step, got scheme 'momentum'"):
        Simulator(cobra, IMPLICIT, SimSettings(scheme="momentum"))
    with pytest.raises(ValueError, match="sgn_eps must be > 0 m/s"):
        SimSettings(sgn_eps=0.0)
    derived = IMPLICIT.with_values(mu_c=0.25).with_contact_law("soft_constraint").with_frozen(free=["mu_c"])
    assert derived.friction_step == "implicit" and derived != derived.with_friction_step("explicit")
    path = IMPLICIT.save(tmp_path / "p.json")
    assert ModelParameters.load(path) == IMPLICIT
    doc = IMPLICIT.to_json_dict()
    del doc["friction_step"]
    assert ModelParameters.from_json_dict(doc).friction_step == "explicit"
    with pytest.raises(InputError, match='p.json: "friction_step" is \'newton\', expected one of explicit, implicit'):
        ModelParameters.from_json_dict({**doc, "friction_step": "newton"}, source="p.json")
    with pytest.raises(InputError, match="a batch steps one friction step; the parameter sets have explicit, implicit"):
        BatchSimulator(cobra, [ModelParameters.nominal(), IMPLICIT])


def test_cobra_simulate_takes_the_friction_step(tmp_path, capsys):
    """``--friction-step`` overrides the parameter file's; the run records the step (in its
    parameters) and the sign's velocity. The two are one model apart by the sign's
    regularisation only (final heads within 2 cm over 3 s: at 6 s the explicit 1 cm/s step ends
    1.9 cm from a fine step of the implicit step's law, the implicit step 0.6 cm)."""
    from cobra_cli.main import main
    from cobra_model.run_files import read_run

    heads = {}
    for step in FRICTION_STEPS:
        out = tmp_path / f"{step}.csv"
        assert main(["simulate", "--duration", "3", "--friction-step", step, "--out", str(out)]) == 0
        run = read_run(out)
        assert run.meta["params"]["friction_step"] == step
        assert run.meta["sim_settings"]["sgn_eps"] == FRICTION_EPS[step]
        heads[step] = run.head_pos[-1, :2]
    assert 0 < np.linalg.norm(heads["implicit"] - heads["explicit"]) < 0.02
    capsys.readouterr()
    assert main(["simulate", "--friction-step", "implicit", "--scheme", "momentum", "--out",
                 str(tmp_path / "m.csv")]) == 2
    assert "implicit friction step is a velocity-scheme step, got scheme 'momentum'" in capsys.readouterr().err
