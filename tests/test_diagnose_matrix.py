"""The confusion-matrix benchmark's bookkeeping: jobs, rates and the heatmap (no diagnosis run)."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks._robot import PARAMETER_ERROR, with_error
from benchmarks.diagnose_matrix import (DEV_SEEDS, EVAL_SEEDS, MUJOCO_CONTACTS, Job,
                                        finished_rows, gap_at_truth, interval_coverage, job_key, jobs_for, make_runs,
                                        near_limit, summary, truth_params)
from benchmarks.effect_signal import ENCODER_FLOOR_RAD, HEAD_FLOOR_M, signal
from cobra_model import CobraModel
from cobra_model.errors import InputError
from cobra_model.parameters import CONTACT_LAWS
from sysid.discrepancy.diagnose import torque_demand
from sysid.discrepancy.effects import EffectLibrary
from sysid.gap.plots import plot_confusion
from sysid.generators.mujoco_recording import EFFECT_OPTIONS


def _row(engine: str, effect: str | None, named: str | None, shrink: float = 0.9, wall: float = 40.0,
         head_before: float = 0.02, joints_before: float = 0.004) -> dict:
    """A results row; the held-out head and joint gaps shrink by ``shrink`` when an effect is named."""
    kept = 1.0 - shrink if named else 1.0
    return {"engine": engine, "effect": effect, "named": named, "gap_shrink": shrink, "wall_s": wall,
            "level": "realistic" if effect else "null", "held_out_cost_reduction": 0.5 + shrink / 2 if named else 0.0,
            "head_final_before_m": head_before, "head_final_after_m": head_before * kept,
            "joint_rmse_before_rad": joints_before, "joint_rmse_after_rad": joints_before * kept}


def test_jobs_cover_each_effect_level_and_seed_on_both_engines() -> None:
    jobs = jobs_for(["sim", "mujoco"], ["backlash", "actuator_delay"], ["realistic", "near_limit"], [31, 32], 3, 3.0)
    sim = [j for j in jobs if j.engine == "sim"]
    mujoco = [j for j in jobs if j.engine == "mujoco"]
    assert len(sim) == len(mujoco) == 2 * 2 * 2 + 3
    # every library effect is expressed on MuJoCo's side, by an option of the twin
    assert set(EFFECT_OPTIONS) == set(EffectLibrary().names)
    assert all(hasattr(MUJOCO_CONTACTS["twin"], option) for option in EFFECT_OPTIONS.values())
    nulls = [j for j in sim if j.effect is None]
    assert [j.seed for j in nulls] == [31, 32, 1031]  # distinct data for every null
    assert {j.magnitude for j in sim if j.effect == "actuator_delay"} == {0.04, 0.01}


def test_the_reported_seeds_are_none_the_workflow_was_developed_on() -> None:
    """Every dataset of a default run (effects, nulls, pairs) is drawn from a seed that no
    development looked at: the evaluation seeds, and the nulls' seeds beyond them."""
    jobs = jobs_for(["sim", "mujoco"], ["backlash", "actuator_delay", "encoder_offset"], ["realistic"],
                    list(EVAL_SEEDS), 6, 3.0, pairs=True)
    assert {j.seed for j in jobs}.isdisjoint(DEV_SEEDS)
    assert {31, 32, 33, 34, 35, 36} <= set(DEV_SEEDS)  # evaluation seeds until mechanisms were found on their misses


def test_near_limit_magnitudes_are_a_quarter_of_the_way_from_where_each_effect_starts_to_act() -> None:
    library = EffectLibrary()
    for effect in ("joint_coulomb_friction", "anisotropic_ground_friction", "link_mass_error"):
        spec = library[effect]  # these act as soon as they leave their inactive value
        assert near_limit(effect, 3.0) == pytest.approx(spec.parameter.value + 0.25 * (spec.realistic - spec.parameter.value))
    # a torque limit acts only below the torque the gait demands: its way starts there, on the
    # development seed's runs without any effect (each of this design's runs demands 3.9-4.2 N m)
    model = CobraModel.load()
    runs = make_runs(Job("sim", None, None, "null", DEV_SEEDS[0], 3.0), model)
    demand = torque_demand(with_error(), runs)
    assert 3.9 < demand < 4.2
    limit = near_limit("torque_saturation", 3.0)
    assert library["torque_saturation"].realistic < limit < demand
    assert demand - limit == pytest.approx(0.25 * (demand - library["torque_saturation"].realistic), abs=0.005)
    # near the detection limit, not past it: the limit moves the data above their noise floors
    # (measured 1.9 x the encoders' quantisation and 7.2 x the motion capture's noise)
    clipped = make_runs(Job("sim", "torque_saturation", limit, "near_limit", DEV_SEEDS[0], 3.0), model)
    joints, head = signal(clipped, runs)
    assert joints > ENCODER_FLOOR_RAD and head > 3 * HEAD_FLOOR_M


def test_pairs_hide_every_two_effects_at_their_realistic_magnitudes_on_both_engines() -> None:
    effects = ["backlash", "actuator_delay", "encoder_offset"]
    jobs = [j for j in jobs_for(["sim", "mujoco"], effects, ["realistic"], [31, 32], 0, 3.0, pairs=True)
            if j.level == "pair"]
    assert sorted(j.effect for j in jobs if j.engine == "sim") == [
        "actuator_delay+encoder_offset", "backlash+actuator_delay", "backlash+encoder_offset"]
    assert [j.effect for j in jobs if j.engine == "mujoco"] == [j.effect for j in jobs if j.engine == "sim"]
    assert [j.seed for j in jobs if j.engine == "sim"] == [31, 32, 31]
    assert jobs[0].hidden == {"backlash": 0.02, "actuator_delay": 0.04}
    assert Job("sim", "backlash", 0.005, "near_limit", 31, 3.0).hidden == {"backlash": 0.005}
    assert Job("sim", None, None, "null", 31, 3.0).hidden == {}
    assert not any(j.level == "pair" for j in jobs_for(["sim"], effects, ["realistic"], [31], 0, 3.0))


def test_mujocos_runs_take_the_contact_law_asked_for_and_resume_tells_laws_apart(tmp_path: Path) -> None:
    jobs = jobs_for(["sim", "mujoco"], ["actuator_delay"], ["realistic"], [31], 1, 3.0, mujoco_law="soft_constraint")
    assert {(j.engine, j.contact_law) for j in jobs} == {("sim", "compliant"), ("mujoco", "soft_constraint")}
    old = {**_row("mujoco", "actuator_delay", "actuator_delay"), "magnitude": 0.04, "seed": 31}  # no law: compliant
    path = tmp_path / "diagnose_matrix.json"
    path.write_text(json.dumps({"meta": {"duration_s": 3.0}, "rows": [old]}))
    done = finished_rows(path, 3.0)
    mujoco = next(j for j in jobs if j.engine == "mujoco" and j.effect == "actuator_delay")
    assert job_key(mujoco) not in done  # a compliant row is no soft-constraint job
    assert job_key(jobs_for(["mujoco"], ["actuator_delay"], ["realistic"], [31], 0, 3.0)[0]) in done


def test_a_choice_of_laws_is_among_the_laws_asked_for_and_resume_tells_choices_apart(tmp_path: Path) -> None:
    two = ("compliant", "soft_constraint")
    jobs = jobs_for(["sim", "mujoco"], ["actuator_delay"], ["realistic"], [31], 0, 3.0, mujoco_law="choose", laws=two)
    assert {(j.engine, j.contact_law, j.laws) for j in jobs} == {("sim", "compliant", ()), ("mujoco", "choose", two)}
    every = jobs_for(["mujoco"], ["actuator_delay"], ["realistic"], [31], 0, 3.0, mujoco_law="choose")[0]
    assert every.laws == CONTACT_LAWS and job_key(every) != job_key(jobs[-1])
    # a row written before the laws were recorded chose between the first two
    old = {**_row("mujoco", "actuator_delay", "actuator_delay"), "magnitude": 0.04, "seed": 31, "contact_law": "choose"}
    path = tmp_path / "diagnose_matrix_choose.json"
    path.write_text(json.dumps({"meta": {"duration_s": 3.0}, "rows": [old]}))
    done = finished_rows(path, 3.0)
    assert job_key(jobs[-1]) in done and job_key(every) not in done


def test_mujocos_runs_take_the_contact_configuration_asked_for_and_resume_tells_them_apart(tmp_path: Path) -> None:
    jobs = jobs_for(["sim", "mujoco"], ["actuator_delay"], ["realistic"], [31], 0, 3.0, mujoco_contact="stiff")
    assert {(j.engine, j.mujoco_contact) for j in jobs} == {("sim", None), ("mujoco", "stiff")}
    assert MUJOCO_CONTACTS["stiff"].solref[0] == 0.002 and MUJOCO_CONTACTS["twin"].solref[0] == 0.02
    old = {**_row("mujoco", "actuator_delay", "actuator_delay"), "magnitude": 0.04, "seed": 31}  # no configuration: twin
    path = tmp_path / "diagnose_matrix.json"
    path.write_text(json.dumps({"meta": {"duration_s": 3.0}, "rows": [old]}))
    done = finished_rows(path, 3.0)
    stiff = next(j for j in jobs if j.engine == "mujoco")
    assert job_key(stiff) not in done  # a twin row is no stiff-contact job
    assert job_key(jobs_for(["mujoco"], ["actuator_delay"], ["realistic"], [31], 0, 3.0)[0]) in done
    sim = next(j for j in jobs if j.engine == "sim")  # this simulator's runs have no MuJoCo configuration
    assert job_key(sim) == job_key(jobs_for(["sim"], ["actuator_delay"], ["realistic"], [31], 0, 3.0)[0])


def test_pairs_are_counted_apart_from_the_confusion_matrix() -> None:
    pair = {**_row("sim", "backlash+actuator_delay", "backlash"), "level": "pair",
            "named_all": ["backlash", "actuator_delay"], "all_named": True}
    half = {**pair, "named_all": ["backlash"], "all_named": False}
    s = summary([_row("sim", "backlash", "backlash"), pair, half], "sim")
    assert s["diagnoses"] == 1 and s["pairs"] == 2
    assert s["pairs_both_named_rate"] == pytest.approx(0.5)
    assert s["confusion"] == {"backlash -> backlash": 1}


def test_summary_counts_right_names_false_positives_and_medians() -> None:
    rows = [_row("sim", "backlash", "backlash", 0.9, 30), _row("sim", "backlash", "actuator_delay", 0.1, 50),
            _row("sim", "actuator_delay", "actuator_delay", 0.7, 40), _row("sim", None, None, wall=20),
            _row("sim", None, "backlash", wall=60), _row("mujoco", "encoder_offset", None)]
    s = summary(rows, "sim")
    assert s["diagnoses"] == 5
    assert s["named_first_rate"] == pytest.approx(2 / 3)
    assert s["false_positive_rate"] == pytest.approx(0.5)
    assert s["median_gap_shrink_when_right"] == pytest.approx(0.8)
    assert s["median_cost_reduction_when_right"] == pytest.approx(0.9)
    assert s["median_wall_s"] == pytest.approx(40)
    assert s["confusion"] == {"actuator_delay -> actuator_delay": 1, "backlash -> actuator_delay": 1,
                              "backlash -> backlash": 1, "none -> backlash": 1, "none -> none": 1}


def test_interval_coverage_counts_the_right_names_intervals_against_the_values_hidden() -> None:
    delay, friction = EffectLibrary()["actuator_delay"].realistic, EffectLibrary()["joint_coulomb_friction"].realistic

    def named(effect: str | None, level: str, magnitude: float | None, intervals: dict, white: bool | None) -> dict:
        return {**_row("mujoco", effect, next(iter(intervals), None)), "level": level, "magnitude": magnitude,
                "named_all": list(intervals), "named_ci95": intervals, "final_residuals_white": white,
                "all_named": effect is not None and set(effect.split("+")) <= set(intervals)}

    rows = [named("backlash", "realistic", 0.02, {"backlash": [0.019, 0.021]}, True),          # holds
            named("backlash", "near_limit", 0.005, {"backlash": [0.006, 0.007]}, False),      # misses, flagged
            named("backlash", "realistic", 0.02, {"actuator_delay": [0.0, 1.0]}, False),      # not hidden: not counted
            named("actuator_delay+joint_coulomb_friction", "pair", None,  # each at its realistic value
                  {"actuator_delay": [delay - 1e-3, delay + 1e-3],
                   "joint_coulomb_friction": [0.5 * friction, 0.9 * friction]}, False),
            named(None, "null", None, {}, None),
            {**_row("mujoco", "backlash", "backlash"), "level": "realistic", "magnitude": 0.02}]  # kept no intervals
    assert interval_coverage(rows) == dict(named=4, holding=2, checked=4, flagged=3, flagged_holding=1)
    assert summary(rows, "mujoco")["intervals"]["holding"] == 2
    # a run's own rows carry numpy floats (a reloaded file's are Python's): still counts, not floats in the JSON
    in_process = [{**r, "named_ci95": {k: list(np.asarray(v)) for k, v in r["named_ci95"].items()}}
                  if r.get("named_ci95") else r for r in rows]
    assert {k: type(v) for k, v in interval_coverage(in_process).items()} == dict.fromkeys(interval_coverage(rows), int)


def test_the_gaps_shrink_is_taken_over_the_cases_above_the_floor_the_nulls_leave() -> None:
    # nulls leave the head 3 mm and the joints 0.5 mrad off: a right name whose gap was at that
    # floor (2 mm, 0.4 mrad) cannot shrink and is left out of the shrink above the floor
    rows = [_row("sim", None, None, head_before=0.003, joints_before=0.0005),
            _row("sim", None, None, head_before=0.001, joints_before=0.0002),
            _row("sim", "backlash", "backlash", 0.9, head_before=0.05, joints_before=0.01),
            _row("sim", "backlash", "backlash", 0.8, head_before=0.04, joints_before=0.008),
            {**_row("sim", "actuator_delay", "actuator_delay", -2.0, head_before=0.002, joints_before=0.0004),
             "joint_rmse_after_rad": 0.0004}]  # its head grew from 2 to 6 mm
    s = summary(rows, "sim")
    assert s["head_floor_m"] == pytest.approx(0.003) and s["joint_floor_rad"] == pytest.approx(0.0005)
    assert s["right_head_above_floor"] == 2 and s["right_joints_above_floor"] == 2
    assert s["median_head_shrink_above_floor"] == pytest.approx(0.85)
    assert s["median_joint_shrink_above_floor"] == pytest.approx(0.85)
    assert s["median_gap_shrink_when_right"] == pytest.approx(0.8)  # all right names, the floor's too


def test_the_share_closed_is_of_the_gap_above_our_model_at_the_truth() -> None:
    # a 50 mm gap whose own floor is 5 mm, closed to 10 mm: 40 of its 45 mm; a gap already below
    # its floor is not the effect's; closing below the floor counts as closing all of it
    truth = {"head_final_truth_m": 0.005, "joint_rmse_truth_rad": 0.0005}
    rows = [{**_row("sim", "backlash", "backlash", 0.8, head_before=0.05, joints_before=0.0105), **truth},
            {**_row("sim", "backlash", "backlash", 0.5, head_before=0.004, joints_before=0.0004), **truth},
            {**_row("sim", "actuator_delay", "actuator_delay", 0.9, head_before=0.02, joints_before=0.003), **truth},
            {**_row("sim", "actuator_delay", "backlash", 0.9, head_before=0.02, joints_before=0.003), **truth}]
    s = summary(rows, "sim")
    assert s["right_head_above_truth"] == 2 and s["right_joints_above_truth"] == 2
    weak = summary(rows + [{**_row("sim", "backlash", "backlash", 0.2, head_before=0.01, joints_before=0.001),
                            **truth}], "sim")   # 2 of its 5 mm above the floor closed, 0.2 of 0.5 mrad
    assert weak["right_head_above_truth"] == 3 and weak["right_head_closed_70_above_truth"] == 2
    assert weak["right_joints_closed_70_above_truth"] == 2
    # head: 40/45 and (20 - 2)/(20 - 5) capped at 1; joints: (10.5 - 2.1)/10 and (3 - 0.3)/2.5 capped
    assert s["median_head_closed_above_truth"] == pytest.approx((40 / 45 + 1) / 2)
    assert s["median_joint_closed_above_truth"] == pytest.approx((0.84 + 1) / 2)
    assert s["right_head_closed_70_above_truth"] == 2 and s["right_joints_closed_70_above_truth"] == 2
    # rows written before the gap at the truth was kept: no figure rather than one from some rows
    old = summary(rows[:1] + [_row("sim", "backlash", "backlash")], "sim")
    assert old["right_head_above_truth"] is None and np.isnan(old["median_head_closed_above_truth"])


def test_our_model_at_the_truth_reproduces_a_case_to_its_sensors_noise() -> None:
    """On this simulator's runs the truth is the model that made them: the held-out gap it leaves
    is the sensors' (encoders' 0.44 mrad, one mocap sample's millimetre); without the hidden
    backlash the same model misses the head by centimetres and the joints by over ten times
    that noise (measured 3.9 cm and 6.6 mrad: 44 and 15 times)."""
    model = CobraModel.load()
    job = Job("sim", "backlash", 0.02, "realistic", 31, 3.0)
    runs = make_runs(job, model)
    head, joints = gap_at_truth(job, runs, "compliant", model)
    assert head < 0.002 and joints < 0.0006
    head_without, joints_without = gap_at_truth(Job("sim", None, None, "null", 31, 3.0), runs, "compliant", model)
    assert head_without > 20 * head and joints_without > 10 * joints


def test_mujocos_truth_is_its_own_values_under_the_law_fitted_with_the_effect_at_its_options_value() -> None:
    job = Job("mujoco", "encoder_offset", 0.03, "realistic", 31, 3.0, contact_law="soft_constraint",
              mujoco_contact="stiff")
    p = truth_params(job, "soft_constraint")
    assert p.contact_law == "soft_constraint" and p.contact_time_constant == MUJOCO_CONTACTS["stiff"].solref[0]
    assert p.encoder_offset == 0.03
    assert p.mu_c == PARAMETER_ERROR["mu_c"] and p.joint_damping == PARAMETER_ERROR["joint_damping"]
    # MuJoCo's capsule pairs: the modules' ends rounded to the module radius
    assert p.contact_rounding == pytest.approx(0.045)
    model = CobraModel.load()
    runs = make_runs(job, model)
    head, joints = gap_at_truth(job, runs, "soft_constraint", model)
    # another engine's runs: the joints at the encoders' floor, the head within a centimetre
    assert joints < 0.0006 and head < 0.01
    _, joints_without = gap_at_truth(dataclasses.replace(job, effect=None, magnitude=None, level="null"), runs,
                                     "soft_constraint", model)
    assert joints_without > 10 * joints


def test_summary_only_recomputes_from_the_files_rows_keeping_their_date_and_diagnoses_nothing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import benchmarks._results as results
    import benchmarks.diagnose_matrix as matrix
    monkeypatch.setattr(results, "RESULTS_DIR", tmp_path)
    monkeypatch.setattr(matrix, "RESULTS_DIR", tmp_path)
    monkeypatch.setattr(matrix, "run_job", lambda job: pytest.fail("--summary-only diagnosed a job"))
    argv = ["--engines", "sim", "--effects", "backlash", "--magnitudes", "realistic", "--seeds", "31",
            "--nulls", "1", "--no-pairs", "--summary-only"]
    jobs = jobs_for(["sim"], ["backlash"], ["realistic"], [31], 1, 3.0)
    extra = {"named_all": [], "structural": [], "contact_law": "compliant", "law_fitted": "compliant", "laws": [],
             "mujoco_contact": None, "current": False, "named_values": {}, "all_named": False}
    rows = [{**_row("sim", j.effect, j.effect, head_before=0.05 if j.effect else 0.001), **extra,
             "level": j.level, "magnitude": j.magnitude, "seed": j.seed} for j in jobs]
    env = {"date_utc": "2026-01-02T03:04:05+00:00", "machine": {"platform": "p", "processor": "x", "cpu_count": 2,
                                                                  "python": "3"}, "versions": {"numpy": "1"}}
    path = tmp_path / "diagnose_matrix.json"
    path.write_text(json.dumps({"meta": {"duration_s": 3.0}, "environment": env, "rows": rows[:1]}))
    with pytest.raises(SystemExit, match="1 of this run's 2 jobs have no row"):
        matrix.main(argv)
    path.write_text(json.dumps({"meta": {"duration_s": 3.0}, "environment": env, "rows": rows}))
    assert matrix.main(argv) == 0
    doc = json.loads(path.read_text())
    assert doc["environment"] == env and "summarised_utc" in doc["meta"]
    # the rows are the file's, each given the gap our model at the truth leaves (written before
    # it was kept): on this simulator's runs, the sensors' noise
    truth_keys = {"head_final_truth_m", "joint_rmse_truth_rad"}
    assert [{k: v for k, v in r.items() if k not in truth_keys} for r in doc["rows"]] == rows
    assert all(0 < r["head_final_truth_m"] < 0.003 and 0 < r["joint_rmse_truth_rad"] < 0.0006 for r in doc["rows"])
    s = doc["meta"]["summary"][0]
    assert s["head_floor_m"] == pytest.approx(0.001) and s["median_head_shrink_above_floor"] == pytest.approx(0.9)
    text = (tmp_path / "diagnose_matrix.md").read_text()
    assert "Measured 2026-01-02T03:04:05+00:00" in text and "held-out runs of the 2 rows written before" in text
    # a second pass has nothing to add
    assert matrix.main(argv) == 0 and json.loads(path.read_text())["rows"] == doc["rows"]


def test_the_heatmap_is_written_and_checks_its_shape(tmp_path: Path) -> None:
    out = plot_confusion(np.array([[2, 1], [0, 3]]), ["a", "none"], ["a", "none"], tmp_path / "m.png")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(InputError, match="does not match 2 x 3 labels"):
        plot_confusion(np.zeros((2, 2)), ["a", "b"], ["a", "b", "c"], tmp_path / "bad.png")


def test_resume_keeps_the_rows_of_this_runs_jobs_and_refuses_other_durations(tmp_path: Path) -> None:
    jobs = jobs_for(["sim"], ["backlash"], ["realistic"], [31, 32], 0, 3.0)
    row = {**_row("sim", "backlash", "backlash"), "level": "realistic", "magnitude": jobs[0].magnitude, "seed": 31}
    path = tmp_path / "diagnose_matrix.json"
    path.write_text(json.dumps({"meta": {"duration_s": 3.0}, "rows": [row]}))
    done = finished_rows(path, 3.0)
    assert [j.seed for j in jobs if job_key(j) not in done] == [32]  # only seed 32 is left to diagnose
    with pytest.raises(SystemExit, match="lasted 3.0 s, this run's 6.0 s"):
        finished_rows(path, 6.0)
    assert finished_rows(tmp_path / "missing.json", 3.0) == {}
    path.write_text('{"meta": {"duration_s": 3.0}, "rows": [')
    with pytest.raises(SystemExit, match="diagnose_matrix.json: not a diagnose_matrix results file"):
        finished_rows(path, 3.0)


def test_write_runs_writes_one_jobs_runs_and_the_cli_command_that_diagnoses_them_so(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    import shlex

    import benchmarks.diagnose_matrix as matrix
    from cobra_cli.main import build_parser
    from cobra_model.run_files import read_run
    from sysid.identification.contact_choice import nominal_start
    monkeypatch.setattr(matrix, "RESULTS_DIR", tmp_path / "results")
    monkeypatch.setattr(matrix, "run_job", lambda job: pytest.fail("--write-runs diagnosed a job"))
    argv = ["--engines", "mujoco", "--effects", "encoder_offset", "--magnitudes", "realistic", "--seeds", "31",
            "--nulls", "0", "--mujoco-contact-law", "soft_constraint", "--duration", "0.5",
            "--write-runs", str(tmp_path / "runs"), "--job", "encoder_offset:realistic:31"]
    assert matrix.main(argv) == 0
    command = capsys.readouterr().out.strip().splitlines()
    assert len(command) == 1 and command[0].startswith("cobra diagnose ")
    args = build_parser().parse_args(shlex.split(command[0])[1:])
    job = Job("mujoco", "encoder_offset", EffectLibrary()["encoder_offset"].realistic, "realistic", 31, 0.5,
              contact_law="soft_constraint", mujoco_contact="twin")
    assert args.contact == "soft_constraint" and args.max_effects == 1 and args.no_check
    assert args.free.split(",") == list(nominal_start("soft_constraint", matrix.FREE_MUJOCO).free_names)
    folder = tmp_path / "runs" / "mujoco_encoder_offset_realistic_31"
    written = [read_run(p) for p in (*args.runs, *args.holdout)]
    assert [Path(p).parent for p in (*args.runs, *args.holdout)] == [folder] * 3
    made_runs = make_runs(job, CobraModel.load())
    assert len(made_runs) == len(written) == 3
    for run, made in zip(written, made_runs):  # the job's own runs, seed for seed
        np.testing.assert_array_equal(run.q, made.q)
        np.testing.assert_array_equal(run.t, made.t)
    assert not (tmp_path / "results").exists()
    before = (folder / "train_0.csv").read_bytes()
    with pytest.raises(SystemExit, match="exists"):
        matrix.main(argv)
    assert (folder / "train_0.csv").read_bytes() == before
    with pytest.raises(SystemExit):
        matrix.main(argv[:-1] + ["encoder_offset:near_limit:31"])
    assert "not a job of this run" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        matrix.main(argv + ["--resume"])
    assert "--write-runs diagnoses nothing and writes no results" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    with pytest.raises(SystemExit, match=r"--write-runs .*file: cannot write .*file/mujoco_encoder_offset_realistic_31 "
                                         r"\(Not a directory\)"):
        matrix.main(argv[:-3] + [str(tmp_path / "file"), "--job", "encoder_offset:realistic:31"])
