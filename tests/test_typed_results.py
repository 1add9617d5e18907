"""Results travel as dataclasses: each survives a trip through JSON text unchanged."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cobra_model.errors import InputError
from cobra_model.model import CobraModel
from cobra_model.parameters import ModelParameters
from integrators import kernels as K
from integrators.simulator import STEP_EFFECT_PARAMETERS, Simulator, effect_parameter, effect_value, entry_of
from sysid.discrepancy.effects import EFFECTS, EffectLibrary
from sysid.discrepancy.diagnose import NamedEffect, StructuralDifference
from sysid.identification.intervals import Whiteness
from sysid.identification.lsq import FitResult, FitStatus, IterationLog, ParameterReport
from sysid.identification.objective import ObjectiveTerms, Weights
from sysid.gap.metrics import compare_runs
from sysid.gap.report import GapSummary
from test_metrics import AMPS, gait_run, with_head


def through_text(doc: dict) -> dict:
    """``doc`` written as JSON text and read back (what a file on disk holds)."""
    return json.loads(json.dumps(doc))


def test_named_effect_and_structural_difference_round_trip():
    effect = NamedEffect("joint_coulomb_friction", "joint_coulomb", 0.31, "N m", (0.27, 0.35), 0.62, 3, -41.5, 0.8,
                         "joint residuals on all joints")
    assert NamedEffect.from_json(through_text(effect.to_json())) == effect
    assert effect.to_json()["params"] == {"joint_coulomb": {"value": 0.31, "unit": "N m", "ci95": [0.27, 0.35]}}
    no_interval = NamedEffect("backlash", "backlash", 0.02, "rad", None, 0.3, 2, -5.0, 0.5, "lag")
    assert NamedEffect.from_json(through_text(no_interval.to_json())) == no_interval
    proxy = StructuralDifference("anisotropic_ground_friction", 0.3, "1", "outside [0.5, 3]", 0.4, 1)
    assert StructuralDifference.from_json(through_text(proxy.to_json())) == proxy


def test_gap_summary_averages_the_runs_and_round_trips():
    """``GapSummary.of`` averages each run's head errors over the runs that have a head pose
    (None when none has) and the per-run mean joint RMSE over all runs."""
    measured = gait_run(with_tail=False)
    shifted = compare_runs(measured, gait_run(with_tail=False, head_offset=(0.03, 0.04, 0.0)))  # head 5 cm off
    wider = compare_runs(measured, gait_run(with_tail=False, amp_scale=1.1))  # joints 10 % wider
    blind = compare_runs(with_head(measured, np.full_like(measured.head_pos, np.nan)),
                         gait_run(with_tail=False, head_offset=(0.3, 0.0, 0.0)))
    wider_rmse = float(np.mean(0.1 * AMPS / np.sqrt(2.0)))  # RMS of 0.1 A sin over whole periods
    summary = GapSummary.of({"shifted": shifted, "wider": wider, "blind": blind})
    assert summary.head_final_error_m == pytest.approx(0.05 / 2, rel=1e-9)  # 5 cm and 0 cm; blind left out
    assert summary.head_mean_error_m == pytest.approx(0.05 / 2, rel=1e-9)
    assert summary.joint_rmse_rad == pytest.approx(wider_rmse / 3, rel=1e-3)  # 0, 10 %, 0 over three runs
    assert set(summary.runs) == {"shifted", "wider", "blind"}
    assert summary.runs["shifted"]["head_final_error_m"] == pytest.approx(0.05)
    joint_only = GapSummary.of({"blind": blind})
    assert joint_only.head_final_error_m is None and joint_only.head_mean_error_m is None
    for s in (summary, joint_only):
        assert GapSummary.from_json(through_text(s.to_json())) == s


def test_objective_terms_sum_by_the_weights_and_round_trip():
    w = Weights()
    terms = ObjectiveTerms.weighted(0.05, 0.03, 0.004, 0.01, w)
    assert terms.external == pytest.approx(w.final_head * 0.05 + w.mean_head * 0.03)
    assert terms.total == pytest.approx(terms.external + terms.internal)
    assert np.array_equal(terms.observed(), [0.05, 0.03, 0.004, 0.01])
    assert ObjectiveTerms.from_json(through_text(terms.to_json())) == terms


def test_fit_result_round_trip():
    params = ModelParameters.nominal().with_values(mu_c=0.25)
    report = [ParameterReport("mu_c", "1", 0.3, 0.3, 0.25, 0.24, 0.26, False, True, "", 0.245, 0.255)]
    fit = FitResult(params, FitStatus.CONVERGED_COST, 1.5, 10.0,
                    [IterationLog(0, 10.0, 1.5, True, 1e-3, 0.2, 5, 0.4, 1.5)], report, np.array([3.0, 0.5]),
                    12, 2.5, residual_count=400,
                    residual_whiteness=Whiteness(50.0, 20, 0.001, 10, 0.6, 2, False, "not white"),
                    interval_method="HAC", report_without_current=report)
    back = FitResult.from_json(through_text(fit.to_json()), params)
    for name in ("status", "cost", "initial_cost", "log", "report", "evaluations", "seconds", "method",
                 "residual_count", "residual_whiteness", "interval_method", "report_without_current"):
        assert getattr(back, name) == getattr(fit, name), name
    assert np.array_equal(back.singular_values, fit.singular_values)
    assert fit.to_json()["intervals"] == {"mu_c": [0.24, 0.26]}


def test_an_effect_parameter_a_set_lacks_is_simulated_at_its_inactive_value():
    nominal = ModelParameters.nominal()
    for p in (*K.EFFECT_PARAMETERS, *STEP_EFFECT_PARAMETERS.values()):
        assert effect_value(nominal, p.name) == p.value
    sim = Simulator(CobraModel.load(), nominal)
    assert np.all(sim.act[:, K.A_TAU_MAX] == 9.9)        # the stall torque: no limit below it
    assert np.all(sim.act[:, K.A_BACKLASH] == 0.0) and sim.delay_s == 0.0
    assert sim.ground[K.G_LATERAL] == 1.0
    assert nominal.get("joint_coulomb", 0.2) == 0.2      # an explicit default still wins
    with pytest.raises(InputError, match="unknown parameter 'joint_coulomb'"):
        nominal.get("joint_coulomb")                     # the parameter table has no effect defaults
    assert effect_parameter("backlash").value == 0.0
    with pytest.raises(InputError, match="unknown effect parameter 'armature'; known: joint_coulomb"):
        effect_parameter("armature")


def test_each_effect_reads_the_parameter_its_physics_defines():
    """One home per effect parameter: the library's effect holds the object the simulator packs
    by, and every kernel effect parameter has a slot in the kernels' tables."""
    for e in EFFECTS:
        assert e.parameter is effect_parameter(e.parameter.name), e.name
    slots = set(K.GROUND_PARAMETERS) | set(K.ACTUATOR_PARAMETERS)
    for p in K.EFFECT_PARAMETERS:
        assert p.name in slots, p.name


def test_each_effect_enters_where_it_says():
    """An effect's ``enters`` is where the simulator puts its parameter: a simulator of a set with
    the effect at its realistic value holds that value there (every joint for an actuator entry),
    and one without it holds the inactive value."""
    model, nominal = CobraModel.load(), ModelParameters.nominal()
    library = EffectLibrary()
    for e in EFFECTS:
        entry = e.enters
        assert entry.parameter == e.parameter.name and entry.stage in ("ground", "actuator", "commands", "model")
        on = Simulator(model, library.transform(nominal, {e.name: e.realistic}, frozen=True))
        np.testing.assert_allclose(entry.read(on), e.realistic, rtol=1e-12, atol=1e-12, err_msg=e.name)
        off = entry.read(Simulator(model, nominal))
        np.testing.assert_allclose(off, e.parameter.value, atol=1e-12, err_msg=e.name)
    assert str(entry_of("mu_c")) == f"mu_c -> ground[{K.G_MU_C}] of the contact kernels"
    with pytest.raises(InputError, match="parameter 'armature' enters no kernel array or step stage"):
        entry_of("armature")
