"""The data check before a fit: per-run findings, identifiability from one Jacobian, `cobra check`."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from cobra_cli.cmd_fit import bound_warnings
from cobra_cli.main import main
from cobra_model import ModelParameters, SidewindingGait
from cobra_model.errors import InputError
from cobra_model.run import Run
from cobra_model.run_files import write_run
from integrators.simulate import simulate_gait
from integrators.simulator import SimulationDiverged
from sysid.identification.datacheck import (FLAT_LOADING, DataCheck, analyse_jacobian, apply, check_runs, inspect_run,
                             unit_jacobian)
from sysid.discrepancy.effects import EffectLibrary
from sysid.identification.lsq import FD_STEP, FitResult, FitStatus, ParameterReport, uncertainty
from sysid.identification.objective import Objective, Weights

#: The nominal model with a torque limit at the servo's stall torque (9.9 N m): the gait demands
#: about 4 N m, so the limit never acts and no run can see it (its Jacobian column is exactly 0).
WITH_IDLE_LIMIT = EffectLibrary().transform(ModelParameters.nominal(), {"torque_saturation": 9.9})


@pytest.fixture(scope="module")
def runs() -> list[Run]:
    """Two 2.5 s runs at 50 Hz (like the reference dataset's logs), two gaits and headings."""
    return [simulate_gait(SidewindingGait(f, ramp_s=0.5), 2.5, heading_rad=h, sample_rate_hz=50)
            for f, h in ((0.5, 0.0), (0.65, 1.0))]


@pytest.fixture(scope="module")
def run_files(runs, tmp_path_factory) -> list[Path]:
    d = tmp_path_factory.mktemp("check_runs")
    return [write_run(r, d / f"run{i}.csv") for i, r in enumerate(runs)]


def test_simulated_runs_are_clean(runs):
    """The base of the per-run cases: no finding on an undisturbed run (else the cases prove nothing)."""
    for r in runs:
        f = inspect_run(r)
        assert f.clean, f.problems()
        assert f.median_dt_s == pytest.approx(0.02, abs=1e-9)


def test_a_gap_is_reported_with_its_time(runs):
    """Rows strictly between 1.0 and 1.3 s removed: one gap after the sample at 1.0 s, 0.3 s long."""
    run = runs[0]
    gappy = run.select(~((run.t > 1.0 + 0.01) & (run.t < 1.3 - 0.01)))
    f = inspect_run(gappy, "gappy.csv")
    assert len(f.gaps) == 1
    assert f.gaps[0].t_s == pytest.approx(1.0, abs=1e-9)
    assert f.gaps[0].interval_s == pytest.approx(0.3, abs=1e-9)
    assert f.median_dt_s == pytest.approx(0.02, abs=1e-9)
    (line,) = f.problems()
    assert line.startswith("gappy.csv: 1 gap in the sample rate") and "at 1.00 s (0.300 s)" in line


def test_a_motion_capture_dropout_is_reported_with_its_length(runs):
    """head_x/y/z NaN from 1.0 s up to (not including) 1.3 s: 15 samples, 0.3 s without the head."""
    run = runs[0]
    head = run.head_pos.copy()
    lost = (run.t > 1.0 - 0.01) & (run.t < 1.3 - 0.01)
    head[lost] = np.nan
    f = inspect_run(dataclasses.replace(run, head_pos=head), "dropout.csv")
    assert lost.sum() == 15
    d = f.dropouts
    assert d.count == 1
    assert d.longest_s == pytest.approx(0.3, abs=1e-9)
    assert d.longest_at_s == pytest.approx(1.0, abs=1e-9)
    assert d.fraction == pytest.approx(15 / run.n_samples)
    assert not f.gaps                                  # a dropout is not a gap in the sample rate
    (line,) = f.problems()
    assert "1 motion-capture dropout" in line and "longest 0.30 s at 1.00 s" in line
    assert f.has_problems                               # 11.9 % of the samples: over the 10 % of a minor one


def test_clamped_joints_are_named(runs):
    """Joint 4 clamped to +-0.2 rad (commanded +-1.05): flat. Joint 6 driven past its +-90 deg URDF
    limit and clipped there: at the limit. No other joint is named."""
    run = runs[0]
    q = run.q.copy()
    q[:, 3] = np.clip(q[:, 3], -0.2, 0.2)
    q[:, 5] = np.clip(q[:, 5] * 2.0, -np.pi / 2, np.pi / 2)
    f = inspect_run(dataclasses.replace(run, q=q), "clamped.csv")
    assert f.saturated_joints == (4, 6)
    by = {(s.joint, s.kind): s for s in f.saturated}
    assert set(by) == {(4, "flat"), (6, "limit")}
    flat = by[(4, "flat")]
    assert flat.measured_swing_rad == pytest.approx(0.4, abs=1e-9)
    assert flat.commanded_swing_rad > 1.5                 # 60 deg yaw amplitude after a 0.5 s ramp
    limit = by[(6, "limit")]
    assert abs(limit.limit_rad) == pytest.approx(np.pi / 2)
    assert 0 < limit.at_limit_fraction < 0.5
    text = "\n".join(f.problems())
    assert "joint 4 keeps under half its commanded swing" in text and "joint 6 at its limit" in text


def test_a_recording_with_a_servo_motion_profile_is_named(runs):
    """The simulated servo steps to each goal; a recording whose servos ramped to it (a Profile
    Velocity or Acceleration set in the sidecar's bus.servo, as ``cobra record`` writes it) is
    named with both values, and one with both at 0 (the default) is not."""
    from hardware.config import BusConfig

    bus = BusConfig(port="/dev/null").to_json()
    assert inspect_run(runs[0].with_meta(bus=bus), "plain.csv").clean
    bus["servo"] = {**bus["servo"], "profile_velocity": 200, "profile_acceleration": 0}
    f = inspect_run(runs[0].with_meta(bus=bus), "ramped.csv")
    assert f.motion_profile == (200, 0) and f.has_problems
    assert "ramped.csv: recorded with a servo motion profile (Profile Velocity 200, Profile Acceleration 0)" \
        in "\n".join(f.problems())
    assert f.to_json_dict()["motion_profile"] == {"profile_velocity": 200, "profile_acceleration": 0}


def test_too_short_runs_are_fatal_before_any_simulation(runs):
    short = runs[0].slice_time(0.0, 1.0)
    check = check_runs([short], ModelParameters.nominal(), names=["short.csv"])
    assert not check.ok and check.identifiability is None
    assert "short.csv 1.00 s" in check.fatal[0] and "at least 1.5 s" in check.fatal[0]
    assert check.runs[0].too_short
    assert check.to_json_dict()["ok"] is False


def test_an_idle_effect_parameter_is_named_and_frozen_and_the_excited_ones_are_not(runs):
    """Identifiability on the robot's runs. The nominal 9 parameters are all excited by 2.5 s of
    sidewinding (smallest singular value 1e-2 of the largest, measured), so the unseen one is an
    effect at an inactive value: a torque limit above anything the gait demands."""
    params = WITH_IDLE_LIMIT.with_frozen(free=["joint_damping", "motor_km", "mu_c", "torque_limit"])
    check = check_runs(runs, params, horizon_s=3.0, threads=1)
    assert check.ok
    ident = check.identifiability
    assert ident.horizon_s == pytest.approx(2.5)            # the runs are shorter than the horizon
    assert ident.residual_count == sum(2 * 26 + 26 * 11 for _ in runs)   # 10 Hz samples of 2.5 s
    assert check.frozen_names == ("torque_limit",)
    limit = ident["torque_limit"]
    assert limit.sensitivity == 0.0 and limit.excitation == 0.0
    assert limit.reason.startswith("not excited by these runs: moving it across its whole range [0.5, 9.9] N m "
                                   "changes the residuals by 0 residual units")
    for name in ("joint_damping", "motor_km", "mu_c"):
        p = ident[name]
        assert not p.frozen and p.reason == "", p
        assert p.excitation > 1e-2, p                      # measured 0.23-1; the threshold is 1e-4
    assert ident.rank == 3 and ident.condition_number == float("inf")
    fitted_free = apply(check, params).free_names
    assert fitted_free == ("joint_damping", "motor_km", "mu_c")
    lines = check.messages()
    assert any(line.startswith("cannot be pinned down: torque_limit: not excited") for line in lines)
    doc = json.loads(json.dumps(check.to_json_dict()))    # valid JSON (no inf / NaN)
    assert doc["frozen"] == ["torque_limit"] and doc["identifiability"]["condition_number"] is None


def test_the_check_jacobian_is_the_least_squares_one(runs):
    """One column by hand: (r(z + h e_j) - r(z)) / h with h = FD_STEP in unit coordinates."""
    params = ModelParameters.nominal().with_frozen(free=["joint_damping", "mu_c"])
    objective = Objective(runs[:1], params, threads=1).truncated(1.0)
    J = unit_jacobian(objective)
    z = params.to_unit()
    zp = z + np.array([0.0, FD_STEP])
    R = objective.residuals(np.array([params.as_vector(), params.from_unit(zp).as_vector()]))
    assert np.allclose(J[:, 1], (R[1] - R[0]) / FD_STEP, rtol=0, atol=1e-9 * np.abs(J).max())


def test_nothing_left_to_fit_is_fatal_and_apply_refuses(runs):
    params = WITH_IDLE_LIMIT.with_frozen(free=["torque_limit"])
    check = check_runs(runs, params, horizon_s=1.5, threads=1)
    assert not check.ok and check.frozen_names == ("torque_limit",)
    assert "torque_limit: not excited" in check.fatal[0]
    assert "whole range [0.5, 9.9] N m changes the residuals by 0 residual units" in check.fatal[0]
    with pytest.raises(InputError, match="no free parameter can be pinned down.*torque_limit"):
        apply(check, params)


def test_two_parameters_that_act_as_a_product_share_a_flat_direction():
    """Synthetic Jacobian: k2's column is -0.7 x k1's (as for parameters entering as a product) to
    1e-9; one of them is frozen naming the other, mu_c is untouched; the fit's report agrees."""
    params = ModelParameters.nominal().with_frozen(free=["k1", "k2", "mu_c"])
    rng = np.random.default_rng(1)
    J = rng.normal(size=(200, 3))
    J[:, 1] = -0.7 * J[:, 0] + 1e-9 * rng.normal(size=200)
    ident = analyse_jacobian(J, params, horizon_s=3.0, run_count=1)
    assert ident.rank == 2 and ident.condition_number > 1e6
    assert len(ident.frozen_names) == 1 and ident.frozen_names[0] in ("k1", "k2")
    frozen = ident[ident.frozen_names[0]]
    partner = {"k1": "k2", "k2": "k1"}[frozen.name]
    assert f"in nearly the same way as {partner} (flat direction, singular value" in frozen.reason
    assert not ident["mu_c"].frozen
    assert ident["k1"].flat_loading > FLAT_LOADING and ident["k2"].flat_loading > FLAT_LOADING
    report = uncertainty(params, params, J, rng.normal(size=200), params.to_unit()).report
    assert {r.name for r in report if "flat direction" in r.reason} == {"k1", "k2"}


def test_a_barely_excited_parameter_is_named_with_its_relative_sensitivity():
    params = ModelParameters.nominal().with_frozen(free=["mu_c", "v_s"])
    rng = np.random.default_rng(2)
    J = rng.normal(size=(100, 2)) * 1e4          # mu_c's column norm 1e5: v_s's is 0.2, above the absolute floor
    J[:, 1] *= 2e-6 / np.linalg.norm(J[:, 1]) * np.linalg.norm(J[:, 0])
    ident = analyse_jacobian(J, params)
    assert ident.frozen_names == ("v_s",)
    assert ident["v_s"].reason == ("not excited by these runs: its residual sensitivity is 2e-06 of the "
                                   "largest parameter's (mu_c)")


def test_messages_name_each_problem_and_sum_up_minor_dropouts(runs):
    """A gap is a problem named with its run; a 0.1 s head dropout (2 % of the samples, like the
    reference dataset's) is routine: one summary line, not a line of its own."""
    run = runs[1]
    gappy = run.select(~((run.t > 0.5 + 0.01) & (run.t < 0.6 - 0.01)))
    head = run.head_pos.copy()
    head[(run.t > 2.0 - 0.01) & (run.t < 2.1 - 0.01)] = np.nan
    blinked = dataclasses.replace(run, head_pos=head)
    check = DataCheck((inspect_run(runs[0], "a.csv"), inspect_run(gappy, "b.csv"), inspect_run(blinked, "c.csv")))
    lines = check.messages()
    assert lines[0] == "data check: 3 runs, 1 with problems"
    assert any(line.startswith("b.csv: 1 gap") and "at 0.50 s" in line for line in lines)
    assert not any(line.startswith(("a.csv", "c.csv")) for line in lines)
    (summary,) = [line for line in lines if line.startswith("minor motion-capture dropouts")]
    assert "in 1 run " in summary and "longest 0.10 s in c.csv" in summary
    assert check.runs[2].dropouts.count == 1 and not check.runs[2].has_problems


def test_fit_warns_for_each_parameter_left_at_a_bound():
    fitted = ModelParameters.nominal().with_values(mu_c=0.02, k2=200.0)
    def rep(name: str, at_bound: bool) -> ParameterReport:
        v = fitted.value(name)
        return ParameterReport(name, fitted[name].unit, v, v, v, v, v, at_bound, not at_bound, "at a bound")
    result = FitResult(fitted, FitStatus.CONVERGED_COST, 0.0, 0.0, [],
                       [rep("k2", True), rep("mu_c", True), rep("motor_km", False)], np.ones(3), 1, 0.0)
    assert bound_warnings(result, fitted) == [
        "WARNING: k2 ended at its upper bound 200 N s/m: the data push it beyond its range",
        "WARNING: mu_c ended at its lower bound 0.02: the data push it beyond its range"]


# ----------------------------------------------------------------------------------------------
# The command line.


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_check_cli_names_a_missing_file(tmp_path, capsys):
    missing = tmp_path / "nope.csv"
    assert main(["check", str(missing)]) == 2
    line = _one_error_line(capsys)
    assert line.startswith("cobra check: error:") and str(missing) in line


def test_check_cli_names_a_malformed_csv(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,q_1\n0.0,abc\n")
    assert main(["check", str(bad)]) == 2
    line = _one_error_line(capsys)
    assert line.startswith("cobra check: error:") and str(bad) in line and "Traceback" not in line


def test_check_cli_refuses_runs_too_short(runs, tmp_path, capsys):
    path = write_run(runs[0].slice_time(0.0, 1.0), tmp_path / "short.csv")
    assert main(["check", str(path)]) == 2
    line = _one_error_line(capsys)
    assert "no run is long enough" in line and str(path) in line


def test_check_cli_reports_and_exits_0_or_2(run_files, tmp_path, capsys):
    ok = ["check", *map(str, run_files), "--free", "joint_damping,motor_km", "--horizon", "1.5"]
    assert main([*ok, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["ok"] is True and doc["frozen"] == [] and len(doc["runs"]) == 2
    assert set(doc["identifiability"]["parameters"]) == {"joint_damping", "motor_km"}
    # a parameter file whose only free parameter the runs cannot see: exit 2 naming it
    pfile = WITH_IDLE_LIMIT.save(tmp_path / "limit.json")
    assert main(["check", *map(str, run_files), "--params", str(pfile), "--free", "torque_limit",
                 "--horizon", "1.5"]) == 2
    captured = capsys.readouterr()
    assert "cannot be pinned down: torque_limit" in captured.out
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "torque_limit" in err[0]


@pytest.mark.parametrize("command,flag", [("check", "--horizon"), ("fit", "--no-check"),
                                          ("diagnose", "--no-check")])
def test_help_shows_the_options(command, flag, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0
    assert flag in capsys.readouterr().out


def test_fit_freezes_what_the_check_names_and_records_the_check(run_files, tmp_path, capsys):
    pfile = WITH_IDLE_LIMIT.save(tmp_path / "limit.json")
    out = tmp_path / "fit.json"
    args = ["fit", *map(str, run_files), "--params", str(pfile), "--free", "motor_km,torque_limit",
            "--max-iterations", "1", "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "freezing torque_limit: not excited by these runs" in printed
    assert "fitting motor_km on 2 runs" in printed
    doc = json.loads(out.read_text())
    assert doc["fit"]["data_check"]["frozen"] == ["torque_limit"]
    assert doc["parameters"]["torque_limit"]["frozen"] is True
    assert list(doc["fit"]["identifiable"]) == ["motor_km"]
    # --no-check fits both and records no check
    assert main([*args, "--no-check", "--force"]) == 0
    doc = json.loads(out.read_text())
    assert doc["fit"]["data_check"] is None and set(doc["fit"]["identifiable"]) == {"motor_km", "torque_limit"}


def test_the_check_weighs_the_motor_currents_when_the_fit_will(runs):
    """With ``use_current`` (``cobra check --current``, ``cobra fit --current``, ``cobra diagnose``
    when every run has currents) the check's Jacobian has the current rows too (11 per sample),
    and they separate the motor constant from the joint damping: the damping acts on the joint,
    the motor constant on the current as well (measured: the smaller singular value 60 -> 71,
    noise-free runs, so the margin below is deterministic)."""
    params = ModelParameters.nominal().with_frozen(free=["joint_damping", "motor_km"])
    plain = check_runs(runs, params, horizon_s=2.0).identifiability
    current = check_runs(runs, params, horizon_s=2.0, weights=Weights(use_current=True)).identifiability
    assert current.residual_count - plain.residual_count == 11 * sum(_samples(runs, 2.0))
    assert current.singular_values[-1] > 1.1 * plain.singular_values[-1]


def _samples(runs: list[Run], horizon_s: float) -> list[int]:
    """Residual samples per run on the check's horizon (the objective's 10 Hz)."""
    return [len(Objective([r], ModelParameters.nominal()).truncated(horizon_s).spec.targets[0].t_samples) for r in runs]


def test_a_probe_that_diverges_is_retaken_on_the_other_side_and_one_that_cannot_be_is_named():
    """The check's Jacobian takes a diverged probe the way the fit does (``lsq.retake_diverged``):
    on residuals linear in the unit coordinates the slope from the stable side is the slope. A
    parameter whose probes diverge on both sides, or a model that diverges where it stands, is a
    clear error instead of a zero column that would read as "not excited"."""
    from cliff import Cliff

    params = ModelParameters.nominal().with_frozen(free=["joint_damping", "motor_km", "mu_c"])
    z = params.to_unit()
    A = np.array([[1.0, 2.0, 0.0], [0.0, -3.0, 1.0], [0.5, 0.0, 4.0], [1.0, 1.0, 1.0]])
    wide = np.ones(3)
    below, above = z - FD_STEP / 2, z + FD_STEP / 2
    # motor_km's forward probe is over the cliff: measured backwards, the same slope
    cliff = Cliff(params, A, np.zeros(3), np.where([False, True, False], above, wide))
    J = unit_jacobian(cliff)
    assert np.allclose(J, A, rtol=0, atol=1e-9) and cliff.evaluations == 4 + 1   # the point, 3 probes, 1 retaken
    # motor_km stable only within half a step of its value: no side to measure from
    with pytest.raises(SimulationDiverged, match=rf"diverges when motor_km is stepped by {FD_STEP:g} of its range either way"):
        unit_jacobian(Cliff(params, A, np.where([False, True, False], below, 0.0), np.where([False, True, False], above, wide)))
    # the model diverges where it stands: the simulation's own error
    with pytest.raises(SimulationDiverged, match=r"rows \[0\] fell off the cliff"):
        unit_jacobian(Cliff(params, A, np.zeros(3), np.where([True, False, False], z - 0.1, wide)))
