"""End to end: `cobra fit` and `cobra diagnose` on small data made with known parameters."""
from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from cobra_cli.main import main
from sysid.discrepancy.diagnose import NamedEffect
from cobra_model import ModelParameters, SidewindingGait
from cobra_model.errors import InputError
from cobra_model.run import Run
from cobra_model.run_files import read_run, write_run
from integrators.simulate import simulate_gait
from sysid.discrepancy.effects import EffectLibrary
from sysid.identification.lsq import FitStatus
from sysid.identification.objective import Weights
from sysid.identification.splits import expand

TRUTH = ModelParameters.nominal().with_values(mu_c=0.22)


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> tuple[list[Path], Path]:
    d = tmp_path_factory.mktemp("runs")
    truth = EffectLibrary().transform(TRUTH, {"joint_coulomb_friction": 0.4}, frozen=True)
    paths = []
    for i, (f, h) in enumerate(((0.5, 0.0), (0.65, 1.0), (0.5, 2.0))):
        run = simulate_gait(SidewindingGait(f, ramp_s=0.5), 3.0, params=truth, heading_rad=h, sample_rate_hz=50)
        paths.append(write_run(run, d / f"run{i}.csv"))
    return paths[:2], paths[2]


@pytest.mark.slow
def test_fit_writes_parameters_and_report(data, tmp_path, capsys):
    train, hold = data
    out, report = tmp_path / "fit.json", tmp_path / "report"
    args = ["fit", *map(str, train), "--holdout", str(hold), "--free", "mu_c", "--max-iterations", "4",
            "--out", str(out), "--report", str(report)]
    assert main(args) == 0
    doc = json.loads(out.read_text())
    assert doc["parameters"]["mu_c"]["frozen"] is False
    assert doc["fit"]["status"] in {status.value for status in FitStatus} and doc["fit"]["evaluations"] > 0
    assert doc["fit"]["cost"] < doc["fit"]["initial_cost"]   # the fit lowered the training cost
    # the truth has gearbox Coulomb friction the fitted model lacks: the residuals say so
    whiteness = doc["fit"]["residual_whiteness"]
    assert whiteness["white"] is False and "understate" in whiteness["verdict"]
    assert set(doc["fit"]["intervals_iid"]) == {"mu_c"} and "HAC" in doc["fit"]["interval_method"]
    printed = capsys.readouterr().out
    assert "WARNING: residuals: NOT white" in printed and "intervals: HAC" in printed
    html = (report / "report.html").read_text()
    assert "Residuals: NOT white" in html
    assert "held_out_head_error.png" in html and "replay.html" in html
    # the file's parameters are the fit's result, moved from the start
    fitted = ModelParameters.load(out).value("mu_c")
    assert doc["fit"]["report"][0]["name"] == "mu_c" and doc["fit"]["report"][0]["value"] == fitted
    assert fitted != ModelParameters.nominal().mu_c
    assert main(args) == 2                                  # no overwrite without --force
    assert "--force" in capsys.readouterr().err


@pytest.mark.slow
def test_diagnose_writes_report_json_and_a_usable_model(data, tmp_path, capsys):
    train, hold = data
    out = tmp_path / "diag"
    args = ["diagnose", *map(str, train), "--holdout", str(hold), "--out", str(out), "--free", "mu_c",
            "--max-effects", "1", "--json"]
    assert main(args) == 0
    doc = json.loads((out / "diagnosis.json").read_text())
    for key in ("effects", "gap_before", "gap_after", "signature"):
        assert key in doc
    assert set(doc["gap_before"]["mean"]) >= {"head_final_error_m", "head_mean_error_m", "joint_rmse_rad"}
    # the runs hide 0.4 N m of gearbox Coulomb friction: that is what is named, near its value
    assert [e["name"] for e in doc["effects"]] == ["joint_coulomb_friction"] and doc["structural"] == []
    effect = NamedEffect.from_json(doc["effects"][0])   # the file holds the typed result
    assert effect.parameter == "joint_coulomb" and abs(effect.value - 0.4) < 0.05
    assert effect.held_out_cost_reduction > 0.5
    # `cobra simulate`'s runs log the motor currents: every fit and judgement weighed them
    assert doc["channel_scales"]["current_scale_a"] == Weights().current_scale_a
    assert (out / "report.html").is_file() and (out / "signature.png").is_file()
    # the augmented model is a parameter file the other commands accept
    sim = tmp_path / "sim.csv"
    assert main(["simulate", "--from", str(hold), "--params", str(out / "augmented_params.json"),
                 "--out", str(sim)]) == 0
    assert np.isfinite(json.loads(sim.with_suffix(".json").read_text())["params"]["parameters"]["mu_c"]["value"])


@pytest.mark.slow
def test_diagnose_leaves_the_currents_out_when_asked(data, tmp_path):
    train, hold = data
    out = tmp_path / "diag"
    assert main(["diagnose", *map(str, train), "--holdout", str(hold), "--out", str(out), "--free", "mu_c",
                 "--max-effects", "0", "--no-current", "--no-check"]) == 0
    doc = json.loads((out / "diagnosis.json").read_text())
    assert doc["channel_scales"]["current_scale_a"] is None
    # the runs log currents (`cobra simulate`'s do), but the fit's residuals are the head's x, y
    # and the 11 joints of each training run only
    assert doc["residual_whiteness"]["series"] == 13 * len(train)
    # and the diagnosis is the one of the same runs recorded without currents, to the value
    stripped = []
    for path in [*train, hold]:
        run = read_run(path)
        assert run.current is not None
        stripped.append(write_run(dataclasses.replace(run, current=None), tmp_path / "bare" / path.name))
    bare = tmp_path / "diag_bare"
    assert main(["diagnose", *map(str, stripped[:-1]), "--holdout", str(stripped[-1]), "--out", str(bare),
                 "--free", "mu_c", "--max-effects", "0", "--no-check"]) == 0
    bare_doc = json.loads((bare / "diagnosis.json").read_text())
    assert bare_doc["channel_scales"]["current_scale_a"] is None
    for key in ("gap_before", "gap_after"):
        assert bare_doc[key] == doc[key], key
    fitted = [ModelParameters.load(d / "augmented_params.json").value("mu_c") for d in (out, bare)]
    assert fitted[0] == fitted[1] and fitted[0] != ModelParameters.nominal().mu_c


@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_a_missing_run_or_manifest_is_named(command, tmp_path, capsys):
    missing = tmp_path / "no_such_run.csv"
    args = [command, str(missing), "--out", str(tmp_path / "out")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"cobra {command}: error:"), err
    assert str(missing) in err[0] and "no such run CSV or dataset manifest.json" in err[0]
    assert not (tmp_path / "out").exists()                  # nothing written for bad input


def test_run_paths_resolve_as_read_run_resolves_them(tmp_path):
    """A bare NAME or a sidecar NAME.json whose CSV exists is a run, as for ``read_run``."""
    (tmp_path / "run.csv").write_text("t\n0\n")
    for name in ("run", "run.csv", "run.json"):
        assert expand([str(tmp_path / name)]) == ([tmp_path / name], [])
    with pytest.raises(InputError, match="other"):
        expand([str(tmp_path / "other")])


@pytest.fixture(scope="module")
def joint_only(tmp_path_factory) -> tuple[list[Path], Path]:
    """Runs recorded without motion capture (every head_* cell empty, no body tracks) of a
    robot whose motor constant is 10 % below the datasheet's."""
    d = tmp_path_factory.mktemp("joint_only")
    truth = ModelParameters.nominal().with_values(motor_km=0.9 * ModelParameters.nominal().motor_km)
    paths = []
    for i, f in enumerate((0.5, 0.65, 0.5)):
        run = simulate_gait(SidewindingGait(f, ramp_s=0.5), 3.0, params=truth, heading_rad=float(i), sample_rate_hz=50)
        blank = Run(t=run.t, q_ref=run.q_ref, q=run.q, head_pos=np.full_like(run.head_pos, np.nan),
                    head_quat=np.full_like(run.head_quat, np.nan), dq=run.dq, current=run.current, meta=run.meta)
        paths.append(write_run(blank, d / f"joints{i}.csv"))
    return paths[:2], paths[2]


@pytest.mark.slow
def test_fit_on_joint_only_runs_fits_the_joints_and_says_the_head_is_left_out(joint_only, tmp_path, capsys):
    train, hold = joint_only
    out = tmp_path / "fit.json"
    args = ["fit", *map(str, train), "--holdout", str(hold), "--free", "motor_km", "--max-iterations", "6",
            "--out", str(out)]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "joint-only runs (no head pose in any sample" in printed
    assert "head metrics omitted" in printed
    # the joints alone pin the motor constant: 10 % low, recovered to 1 %
    fitted = ModelParameters.load(out).value("motor_km")
    assert fitted == pytest.approx(0.9 * ModelParameters.nominal().motor_km, rel=0.01)


@pytest.mark.slow
def test_diagnose_on_joint_only_runs_judges_on_the_joints(joint_only, tmp_path, capsys):
    train, hold = joint_only
    out = tmp_path / "diag"
    assert main(["diagnose", *map(str, train), "--holdout", str(hold), "--out", str(out), "--free", "motor_km",
                 "--max-effects", "1"]) == 0
    printed = capsys.readouterr().out
    assert "held-out head final error omitted (joint-only runs: no head pose)" in printed
    doc = json.loads((out / "diagnosis.json").read_text())
    # nothing is missing from the model but the motor constant, which the base fit finds
    assert doc["effects"] == []
    assert "head not measured: joint-only runs" in doc["verdict"]
    assert doc["gap_after"]["mean"]["head_final_error_m"] is None
    assert doc["gap_after"]["mean"]["joint_rmse_rad"] < 1e-3


@pytest.fixture(scope="module")
def soft_data(tmp_path_factory) -> tuple[list[Path], Path]:
    """Runs of the soft-constraint contact law with a slower contact (30 ms) and mu_c = 0.22."""
    d = tmp_path_factory.mktemp("soft_runs")
    truth = TRUTH.with_values(contact_time_constant=0.03).with_contact_law("soft_constraint")
    paths = [write_run(simulate_gait(SidewindingGait(f, ramp_s=0.5), 3.0, params=truth, heading_rad=h,
                                     sample_rate_hz=50), d / f"soft{i}.csv")
             for i, (f, h) in enumerate(((0.5, 0.0), (0.65, 1.0), (0.35, 2.0)))]
    return paths[:2], paths[2]


@pytest.mark.slow
def test_fit_under_the_soft_law_records_it_and_compare_uses_it(soft_data, tmp_path, capsys):
    """``cobra fit --contact soft_constraint`` frees the law's own time constant, freezes what the
    law does not read, recovers the ground, and writes a file whose law ``cobra compare`` uses."""
    train, hold = soft_data
    out = tmp_path / "soft_fit.json"
    assert main(["fit", *map(str, train), "--contact", "soft_constraint", "--free", "k1", "--out", str(out)]) == 2
    assert "--free k1: the soft_constraint contact law does not read it" in capsys.readouterr().err
    assert main(["fit", *map(str, train), "--contact", "soft_constraint", "--frozen", "armature,joint_damping,motor_km",
                 "--max-iterations", "6", "--channel-weights", "residual", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "soft_constraint contact law: k1, k2, mu_s, mu_v, v_s do not enter it (frozen)" in printed
    # noise-free runs of the law itself: the joints' scale is the encoders' floor, the head's what the
    # first fit left (measured 1.04 mm), above motion capture's 0.5 mm floor
    scales = re.search(r"refitted with each channel weighted by its RMS residual: head ([0-9.]+) mm, "
                       r"joints ([0-9.]+) mrad", printed)
    assert scales is not None and 0.5 <= float(scales[1]) < 2.0 and float(scales[2]) == 0.443
    fitted = ModelParameters.load(out)
    assert fitted.contact_law == "soft_constraint" and fitted.free_names == ("mu_c", "contact_time_constant")
    assert abs(fitted.mu_c - 0.22) < 0.01 and abs(fitted.contact_time_constant - 0.03) < 0.0045  # 15 %
    assert main(["compare", str(hold), "--params", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["head_final_error_m"] < 0.01               # the law and values of the truth predict it


@pytest.mark.slow
def test_fit_with_the_ends_shape_free_starts_from_each_shape_and_keeps_the_cheapest(soft_data, tmp_path, capsys):
    """With ``contact_rounding`` and the soft law's time constant free, ``cobra fit`` starts from
    sharp, half- and fully rounded ends on a soft (20 ms) and the stiffest (2 ms) ground, screens
    the six starts on the runs' first 1.5 s, fits the three lowest on the whole runs and keeps
    the lowest training cost, printing each. The truth has sharp ends (0 m) on a 30 ms ground:
    the kept fit is not the capsule's and not the stiff ground's. Sharp and half-rounded ends are
    not told apart by these two 3 s runs: on sharp rims the cost is rough at the millimetre level
    (a contact switching on one step later moves the head; at the truth a change of 1e-4 of
    ``mu_c`` raises the cost from 0.003 to 2.8)."""
    train, _ = soft_data
    out = tmp_path / "shape_fit.json"
    assert main(["fit", *map(str, train), "--contact", "soft_constraint", "--free",
                 "mu_c,contact_time_constant,contact_rounding", "--max-iterations", "4", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    rows = re.findall(r"contact_time_constant ([0-9.e-]+) s, contact_rounding ([0-9.e-]+) m +screen ([0-9.e+-]+) +"
                      r"(?:whole runs ([0-9.e+-]+)|\(not kept\))", printed)
    starts = {(float(tc), float(r)): (float(screen), float(whole) if whole else None)
              for tc, r, screen, whole in rows}
    assert sorted(starts) == [(tc, r) for tc in (0.002, 0.02) for r in (0.0, 0.0225, 0.045)]
    kept = {k: whole for k, (_, whole) in starts.items() if whole is not None}
    screens = sorted(screen for screen, _ in starts.values())
    assert len(kept) == 3 and sorted(starts[k][0] for k in kept) == screens[:3]   # the three lowest screens
    fitted = ModelParameters.load(out)
    assert json.loads(out.read_text())["fit"]["cost"] == pytest.approx(min(kept.values()), rel=1e-3)
    assert fitted.contact_rounding < 0.03                                # not the capsule's ends
    assert fitted.contact_time_constant > 0.01                           # a soft ground (truth 30 ms)


@pytest.mark.slow
def test_fit_chooses_the_contact_law_that_predicts_the_held_out_run(soft_data, tmp_path, capsys):
    """``cobra fit --contact choose`` fits each law with the ground parameters it reads and keeps
    the one with the lower held-out cost: on runs of the soft-constraint law (on the pyramid),
    that law (no value of the compliant ground's spring, damper and Stribeck curve reproduces a
    soft constraint, ``benchmarks/results/contact_law.md``, and the elliptic cone's round
    friction limit is not the pyramid's diamond), recording every law's fit in the parameter file."""
    train, hold = soft_data
    out = tmp_path / "chosen.json"
    assert main(["fit", *map(str, train), "--holdout", str(hold), "--contact", "choose", "--frozen",
                 "armature,joint_damping,motor_km,contact_rounding", "--max-iterations", "4", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    fitted = ModelParameters.load(out)
    assert fitted.contact_law == "soft_constraint"
    assert abs(fitted.mu_c - 0.22) < 0.01 and abs(fitted.contact_time_constant - 0.03) < 0.0045  # 15 %
    choice = json.loads(out.read_text())["fit"]["contact_choice"]
    held = {f["law"]: f["held_out_cost"] for f in choice["fits"]}
    assert set(held) == {"compliant", "soft_constraint", "soft_elliptic"}
    assert choice["chosen"] == "soft_constraint" and held["soft_constraint"] < 0.5 * held["compliant"]
    assert held["soft_constraint"] < held["soft_elliptic"]
    assert "k1" in {n for f in choice["fits"] if f["law"] == "compliant" for n in f["params"]}
    assert "these runs also chose the contact law" in printed


@pytest.mark.slow
def test_diagnose_chooses_the_contact_law_by_the_held_out_cost_after_the_effects(soft_data, tmp_path, capsys):
    """``cobra diagnose --contact compliant,soft_constraint`` diagnoses under each listed law
    (``choose``: every law) and keeps the diagnosis with the lower held-out cost after its
    effects: the truth's soft constraint. The actuator, the truth's, is frozen in the starting
    file (the ground is what the laws differ in), and no effect is looked for (``--max-effects
    0``): this is the choice between laws; that nothing is named on runs hiding no effect is
    ``tests/test_diagnose_names.py``'s null case, and the screening under each law is the same
    code as under one (a round of screening per law cost 90-140 s here)."""
    train, hold = soft_data
    start = ModelParameters.nominal().with_frozen(frozen=["armature", "joint_damping", "motor_km"])
    start.save(tmp_path / "start.json")
    assert main(["diagnose", *map(str, train), "--holdout", str(hold), "--contact", "compliant,soft_constraint",
                 "--max-effects", "0", "--params", str(tmp_path / "start.json"), "--out", str(tmp_path / "d")]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((tmp_path / "d" / "diagnosis.json").read_text())
    choice = doc["contact_choice"]
    held = {f["law"]: f["held_out_cost"] for f in choice["laws"]}
    assert set(held) == {"compliant", "soft_constraint"}
    assert choice["chosen"] == "soft_constraint" and held["soft_constraint"] < 0.5 * held["compliant"]
    assert doc["effects"] == []
    assert ModelParameters.load(tmp_path / "d" / "augmented_params.json").contact_law == "soft_constraint"
    assert "contact law: soft_constraint" in doc["verdict"]
    # each law's base fit started from every ground its free set allows, as cobra fit's does: the
    # soft law's on a soft ground (20 ms) and on the stiffest (2 ms), and kept the soft one
    starts = {s["contact_time_constant"]: s["train_cost"] for s in doc["base_fit_starts"]}
    assert set(starts) == {0.02, 0.002} and starts[0.02] < starts[0.002], starts
    assert "the base fit's training cost from each start" in printed
    assert re.search(r"contact_time_constant 0\.002 s +whole runs [0-9.e+]+", printed), printed


@pytest.mark.parametrize("contact, extra, message", [
    ("choose", [], "--contact choose needs held-out runs to choose on"),
    ("choose", ["--holdout", "HOLD", "--free", "mu_c"], "--contact choose fits each law with the free set it reads"),
    ("compliant,soft_elliptic", ["--holdout", "HOLD", "--method", "ppo"],
     "--contact compliant,soft_elliptic: only least squares fits each contact law"),
])
def test_fit_refuses_to_choose_the_contact_law_without_what_it_needs(soft_data, tmp_path, capsys, contact, extra,
                                                                      message):
    train, hold = soft_data
    extra = [str(hold) if a == "HOLD" else a for a in extra]
    out = tmp_path / "never.json"
    assert main(["fit", *map(str, train), "--contact", contact, *extra, "--out", str(out)]) == 2
    assert message in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("command", ["fit", "diagnose"])
def test_an_unknown_law_in_a_list_to_choose_among_is_named(soft_data, tmp_path, capsys, command):
    train, hold = soft_data
    with pytest.raises(SystemExit) as exc:
        main([command, *map(str, train), "--holdout", str(hold), "--contact", "compliant,rigid",
              "--out", str(tmp_path / "never")])
    assert exc.value.code == 2 and not (tmp_path / "never").exists()
    assert ("argument --contact: 'compliant,rigid': expected one of compliant, soft_constraint, soft_elliptic, "
            "'choose'" in capsys.readouterr().err)


def test_check_and_diagnose_judge_the_parameters_of_the_law(soft_data, tmp_path, capsys):
    """``cobra check --contact soft_constraint`` judges the law's own parameters (the time constant,
    not the compliant ground's springs), and ``cobra diagnose`` refuses to fit what the law ignores."""
    train, hold = soft_data
    assert main(["check", *map(str, train), "--contact", "soft_constraint", "--json"]) == 0
    captured = capsys.readouterr()
    judged = json.loads(captured.out)["identifiability"]["parameters"]
    assert "contact_time_constant" in judged and not {"k1", "k2", "mu_s", "mu_v", "v_s"} & set(judged)
    assert judged["contact_time_constant"]["frozen"] is False            # the runs pin it down
    assert "do not enter it (frozen)" in captured.err                    # said off stdout with --json
    assert main(["diagnose", *map(str, train), "--holdout", str(hold), "--contact", "soft_constraint",
                 "--free", "mu_c,v_s", "--out", str(tmp_path / "d")]) == 2
    assert "--free v_s: the soft_constraint contact law does not read it" in capsys.readouterr().err


@pytest.mark.parametrize("option", [["--envs", "0"], ["--timesteps", "0"]])
def test_fit_ppo_refuses_no_environments_or_steps(tmp_path, capsys, option):
    out = tmp_path / "never.json"
    assert main(["fit", str(tmp_path / "run.csv"), "--method", "ppo", *option, "--out", str(out)]) == 2
    assert "--envs and --timesteps must be >= 1" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("option, message", [
    (["--budget-seconds", "-5"], "--budget-seconds must be > 0 s (the fit's wall-time budget), got -5"),
    (["--budget-seconds", "nan"], "--budget-seconds must be > 0 s (the fit's wall-time budget), got nan"),
    (["--max-iterations", "0"], "--max-iterations must be >= 1 (least squares' Jacobian evaluations), got 0"),
    (["--workers", "0"], "--workers must be >= 1 (local processes for evaluations), got 0"),
])
def test_fit_refuses_a_budget_iterations_or_workers_out_of_range(tmp_path, capsys, option, message):
    """Before this check a budget of no time returned the start (after the one Jacobian its
    intervals need), ``--max-iterations 0`` quietly ran one iteration and ``--workers 0`` ran
    in-process: each a fit the user did not ask for, said nowhere."""
    out = tmp_path / "never.json"
    assert main(["fit", str(tmp_path / "run.csv"), *option, "--out", str(out)]) == 2
    assert message in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("option, message", [
    (["--max-effects", "-1"], "--max-effects must be >= 0, got -1"),
    (["--fit-runs", "-3"], "--fit-runs must be >= 0 (0: every training run), got -3"),
])
def test_diagnose_refuses_negative_counts(tmp_path, capsys, option, message):
    """A negative ``--fit-runs`` used to fit on every run, as 0 asks, without a word."""
    out = tmp_path / "never"
    assert main(["diagnose", str(tmp_path / "run.csv"), "--holdout", str(tmp_path / "hold.csv"), *option,
                 "--out", str(out)]) == 2
    assert message in capsys.readouterr().err and not out.exists()


def test_fit_ppo_refuses_residual_channel_weights(tmp_path, capsys):
    out = tmp_path / "never.json"
    assert main(["fit", str(tmp_path / "run.csv"), "--method", "ppo", "--channel-weights", "residual",
                 "--out", str(out)]) == 2
    assert "--channel-weights residual: only least squares refits" in capsys.readouterr().err and not out.exists()
