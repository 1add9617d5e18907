"""Tests of the sim-to-real gap metrics on analytic runs."""
from __future__ import annotations

import json

import numpy as np
import pytest

from cobra_model.errors import InputError
from cobra_model.run import NUM_JOINTS, Run
from sysid.gap.metrics import (
    DEFAULT_WINDOW_S,
    compare_runs,
    correlation_summary,
    cpg_error,
    fit_sine,
    head_error,
    joint_l2,
    joint_rmse,
    resample_to,
    window_correlation,
    wrap_angle,
)

FREQ = 0.5
PHASES = np.pi / 2 * np.array([0, 0, 1, 1, 2, 2, 3, 3, 0, 0, 1])
AMPS = np.where(np.arange(1, NUM_JOINTS + 1) % 2 == 1, np.deg2rad(14), np.deg2rad(60))


def gait_run(
    *,
    rate: float = 100.0,
    duration: float = 8.0,
    start: float = 0.0,
    amp_scale: float = 1.0,
    phase_shift: float = 0.0,
    head_offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    with_tail: bool = True,
) -> Run:
    """A sidewinding-like run: q = q_ref = A sin(2 pi f t + phi) and a smooth head path."""
    t = start + np.arange(int(round(duration * rate)) + 1) / rate
    q = amp_scale * AMPS * np.sin(2 * np.pi * FREQ * t[:, None] + PHASES + phase_shift)
    q_ref = AMPS * np.sin(2 * np.pi * FREQ * t[:, None] + PHASES)
    head = np.column_stack([0.05 * t, 0.1 * np.sin(0.3 * t), np.full(t.size, 0.045)])
    head = head + np.asarray(head_offset)
    yaw = 0.1 * t
    quat = np.column_stack([np.cos(yaw / 2), 0 * t, 0 * t, np.sin(yaw / 2)])
    bodies = {"tail": head - [0.8, 0.0, 0.0]} if with_tail else {}
    return Run(t=t, q_ref=q_ref, q=q, head_pos=head, head_quat=quat, bodies=bodies)


def with_head(run: Run, head_pos: np.ndarray) -> Run:
    quat = run.head_quat.copy()
    quat[np.isnan(head_pos).any(axis=1)] = np.nan
    return Run(t=run.t, q_ref=run.q_ref, q=run.q, head_pos=head_pos, head_quat=quat, bodies=run.bodies)


# ---------------------------------------------------------------------------------------------
# Sine fit.


@pytest.mark.parametrize(
    ("amp", "freq", "phase", "offset"),
    [(0.24, 0.5, 0.0, 0.0), (1.05, 0.35, 2.9, 0.1), (0.5, 0.65, -3.1, -0.2), (0.3, 0.5, np.pi, 0.0)],
)
def test_fit_sine_recovers_parameters(amp: float, freq: float, phase: float, offset: float) -> None:
    t = np.arange(0, 3.2 / freq, 0.01)  # a little over 3 cycles
    y = amp * np.sin(2 * np.pi * freq * t + phase) + offset
    fit = fit_sine(t, y)
    assert fit.amplitude == pytest.approx(amp, abs=1e-6)
    assert fit.frequency == pytest.approx(freq, abs=1e-6)
    assert wrap_angle(fit.phase - phase) == pytest.approx(0.0, abs=1e-6)
    assert -np.pi < fit.phase <= np.pi
    assert fit.offset == pytest.approx(offset, abs=1e-6)
    assert fit.rmse < 1e-6


def test_fit_sine_with_noise_nan_gaps_and_uneven_sampling() -> None:
    rng = np.random.default_rng(7)
    t = np.sort(rng.uniform(0, 10, 800))
    y = 0.8 * np.sin(2 * np.pi * 0.4 * t + 1.0) + 0.01 * rng.normal(size=t.size)
    y[100:160] = np.nan
    fit = fit_sine(t, y)
    assert fit.amplitude == pytest.approx(0.8, abs=3e-3)
    assert fit.frequency == pytest.approx(0.4, abs=1e-3)
    assert fit.phase == pytest.approx(1.0, abs=1e-2)
    assert fit.rmse == pytest.approx(0.01, rel=0.2)
    guessed = fit_sine(t, y, freq_guess=0.41)
    assert guessed.frequency == pytest.approx(fit.frequency, abs=1e-9)


def test_fit_sine_constant_and_bad_input() -> None:
    flat = fit_sine(np.arange(50.0), np.full(50, 0.3))
    assert flat.amplitude == 0.0 and np.isnan(flat.frequency) and np.isnan(flat.phase)
    assert flat.offset == pytest.approx(0.3)
    with pytest.raises(InputError, match="at least 5"):
        fit_sine(np.arange(4.0), np.arange(4.0))
    with pytest.raises(InputError, match="equal length"):
        fit_sine(np.arange(10.0), np.arange(9.0))
    with pytest.raises(InputError, match="freq_guess"):
        fit_sine(np.arange(10.0), np.arange(10.0), freq_guess=0.0)


# ---------------------------------------------------------------------------------------------
# Identical runs, known shifts.


def test_identical_runs_have_no_gap() -> None:
    run = gait_run()
    report = compare_runs(run, run)
    assert report.head.final == 0.0 and report.head.mean == 0.0
    assert report.head.body_errors["tail"].final == 0.0
    np.testing.assert_array_equal(report.joint_rmse, np.zeros(NUM_JOINTS))
    assert [entry["joint"] for entry in report.cpg] == list(range(1, NUM_JOINTS + 1))
    for entry in report.cpg:
        assert entry["amplitude"] == pytest.approx(0.0, abs=1e-9)
        assert entry["frequency"] == pytest.approx(0.0, abs=1e-9)
        assert entry["phase"] == pytest.approx(0.0, abs=1e-9)
        assert entry["measured"]["amplitude"] == pytest.approx(AMPS[entry["joint"] - 1], abs=1e-6)
        assert entry["measured"]["frequency"] == pytest.approx(FREQ, abs=1e-6)
    for summary in report.correlation.values():
        assert summary["mean"] == pytest.approx(1.0, abs=1e-9)
        assert summary["min"] == pytest.approx(1.0, abs=1e-9)
        assert summary["max"] == pytest.approx(1.0, abs=1e-9)
    assert "no resampling" in report.resampled


@pytest.mark.parametrize("shift", [0.3, -1.2, 3.0])
def test_known_phase_shift_is_recovered(shift: float) -> None:
    measured = gait_run()
    simulated = gait_run(phase_shift=shift)
    errors = cpg_error(measured, simulated)
    assert len(errors) == NUM_JOINTS
    for entry in errors:
        assert entry["phase"] == pytest.approx(shift, abs=1e-3)
        assert entry["amplitude"] == pytest.approx(0.0, abs=1e-6)
        assert entry["frequency"] == pytest.approx(0.0, abs=1e-6)
    rmse = joint_rmse(measured, simulated)
    # RMS of A sin(x) - A sin(x + s) over whole cycles is A * sqrt(2) * |sin(s / 2)|.
    np.testing.assert_allclose(rmse, AMPS * np.sqrt(2) * abs(np.sin(shift / 2)), rtol=1e-3)


def test_phase_difference_wraps() -> None:
    measured = gait_run(phase_shift=3.0)
    simulated = gait_run(phase_shift=-3.0)
    errors = cpg_error(measured, simulated, labels=("m", "s"))
    assert len(errors) == NUM_JOINTS
    for entry in errors:
        assert entry["phase"] == pytest.approx(2 * np.pi - 6.0, abs=1e-3)
        assert set(entry) == {"joint", "amplitude", "frequency", "phase", "m", "s"}


def test_known_amplitude_change() -> None:
    measured = gait_run()
    simulated = gait_run(amp_scale=1.2)
    errors = cpg_error(measured, simulated)
    np.testing.assert_allclose([e["amplitude"] for e in errors], 0.2 * AMPS, atol=1e-6)
    np.testing.assert_allclose([e["phase"] for e in errors], 0.0, atol=1e-6)
    np.testing.assert_allclose(joint_rmse(measured, simulated), 0.2 * AMPS / np.sqrt(2), rtol=1e-3)


def test_constant_head_offset_gives_that_distance() -> None:
    measured = gait_run()
    simulated = gait_run(head_offset=(0.03, -0.04, 0.5))  # z does not count (ground plane)
    err = head_error(measured, simulated)
    np.testing.assert_allclose(err.distance, 0.05, atol=1e-12)
    assert err.final == pytest.approx(0.05) and err.mean == pytest.approx(0.05)
    assert err.final_t == measured.t[-1]
    assert err.body_errors["tail"].final == pytest.approx(0.05)


def test_joint_l2_of_constant_offset() -> None:
    measured = gait_run(duration=4.0)
    q = measured.q + 0.1
    simulated = Run(t=measured.t, q_ref=measured.q_ref, q=q, head_pos=measured.head_pos,
                    head_quat=measured.head_quat)
    np.testing.assert_allclose(joint_l2(measured, simulated), 0.1 * np.sqrt(4.0), rtol=1e-9)
    np.testing.assert_allclose(joint_rmse(measured, simulated), 0.1, rtol=1e-9)


# ---------------------------------------------------------------------------------------------
# Different rates, spans and gaps.


def test_runs_at_different_rates_and_spans() -> None:
    measured = gait_run(rate=100.0, duration=8.0)
    simulated = gait_run(rate=250.0, duration=9.0, start=0.5, head_offset=(0.03, 0.04, 0.0))
    a, b, note = resample_to(measured, simulated, labels=("measured", "simulated"))
    np.testing.assert_array_equal(a.t, b.t)
    assert a.t[0] == pytest.approx(0.5) and a.t[-1] == pytest.approx(8.0)
    assert a.n_samples == 751
    assert "measured" in note and "simulated interpolated" in note

    report = compare_runs(measured, simulated)
    assert report.head.final == pytest.approx(0.05, abs=1e-6)
    assert report.head.mean == pytest.approx(0.05, abs=1e-6)
    assert np.all(report.joint_rmse < 2e-4)  # linear interpolation error of the 250 Hz run
    assert len(report.cpg) == NUM_JOINTS
    for entry in report.cpg:
        assert abs(entry["phase"]) < 1e-3 and abs(entry["amplitude"]) < 1e-3
    assert report.correlation["measured_vs_simulated"]["min"] > 0.9999
    assert report.window_samples == round(DEFAULT_WINDOW_S * 100)

    # Swapping the arguments picks the same (coarser) time base.
    b2, a2, _ = resample_to(simulated, measured)
    np.testing.assert_array_equal(a2.t, a.t)
    np.testing.assert_allclose(b2.q, b.q)


def test_mocap_gaps_are_ignored() -> None:
    measured = gait_run()
    head = measured.head_pos.copy()
    head[700:] = np.nan  # tracking lost for the last 0.01 * 101 s
    head[100:150] = np.nan
    lossy = with_head(measured, head)
    simulated = gait_run(head_offset=(0.03, 0.04, 0.0))
    err = head_error(lossy, simulated)
    assert np.isnan(err.distance[700:]).all() and np.isnan(err.distance[100:150]).all()
    assert err.final == pytest.approx(0.05) and err.final_t == pytest.approx(lossy.t[699])
    assert err.mean == pytest.approx(0.05)
    report = compare_runs(lossy, simulated).to_json_dict()
    assert report["head_final_error_m"] == pytest.approx(0.05)


def test_short_gaps_bridged_long_gaps_kept_when_resampling() -> None:
    coarse = gait_run(rate=50.0, with_tail=False)
    fine = gait_run(rate=200.0, with_tail=False, head_offset=(0.03, 0.04, 0.0))
    head = fine.head_pos.copy()
    # Every 4th fine sample is a coarse sample time (t = 0.005 i).
    head[403:405] = np.nan  # 2 samples, covering the coarse time 2.02 s: bridged
    head[1206:1209] = np.nan  # 3 samples, covering the coarse time 6.04 s: left NaN
    fine = with_head(fine, head)
    _, b, _ = resample_to(coarse, fine)
    bridged, kept = np.searchsorted(b.t, [2.02, 6.04])
    assert np.isfinite(b.head_pos[bridged]).all() and np.isfinite(b.head_quat[bridged]).all()
    assert np.isnan(b.head_pos[kept]).all() and np.isnan(b.head_quat[kept]).all()
    err = head_error(coarse, fine)
    finite = np.isfinite(err.distance)
    np.testing.assert_allclose(err.distance[finite], 0.05, atol=1e-6)
    assert finite.sum() == coarse.n_samples - 1


def test_no_mocap_at_all_gives_null_in_json() -> None:
    run = gait_run(with_tail=False)
    blind = with_head(run, np.full_like(run.head_pos, np.nan))
    report = compare_runs(blind, run)
    assert np.isnan(report.head.final)
    out = report.to_json_dict()
    assert out["head_final_error_m"] is None and out["head_mean_error_m"] is None
    json.dumps(out, allow_nan=False)


def test_runs_that_do_not_overlap() -> None:
    with pytest.raises(InputError, match="overlap"):
        resample_to(gait_run(duration=2.0), gait_run(duration=2.0, start=3.0))


# ---------------------------------------------------------------------------------------------
# Sliding-window correlation.


def _window_corr_reference(x: np.ndarray, y: np.ndarray, window: int) -> np.ndarray:
    """Plain-loop reference of :func:`window_correlation`."""
    out = np.full((x.shape[0] - window + 1, x.shape[1]), np.nan)
    for i in range(out.shape[0]):
        for j in range(x.shape[1]):
            xs, ys = x[i : i + window, j], y[i : i + window, j]
            if np.isfinite(xs).all() and np.isfinite(ys).all() and xs.std() > 0 and ys.std() > 0:
                out[i, j] = np.corrcoef(xs, ys)[0, 1]
    return out


def test_window_correlation_matches_reference() -> None:
    rng = np.random.default_rng(11)
    x = np.cumsum(rng.normal(size=(300, 4)), axis=0) + 50.0
    y = 0.7 * x + rng.normal(size=(300, 4)) * 3.0
    x[40, 1] = np.nan
    y[200:230, 2] = 3.0
    x[200:230, 2] = 1.0  # zero variance in both
    got = window_correlation(x, y, 25)
    want = _window_corr_reference(x, y, 25)
    assert got.shape == (276, 4)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(want))
    np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)], atol=1e-9)


def test_window_correlation_of_shifted_sines() -> None:
    t = np.arange(0, 10, 0.01)[:, None]
    x = np.sin(2 * np.pi * 0.5 * t)
    corr = window_correlation(np.hstack([x, x]), np.hstack([x, -x]), 200)
    np.testing.assert_allclose(corr[:, 0], 1.0, atol=1e-9)
    np.testing.assert_allclose(corr[:, 1], -1.0, atol=1e-9)
    summary = correlation_summary(corr)
    np.testing.assert_allclose(summary["mean_curve"], 0.0, atol=1e-9)
    assert summary["min"] == pytest.approx(-1.0) and summary["max"] == pytest.approx(1.0)
    assert summary["mean"] == pytest.approx(0.0, abs=1e-9)


def test_window_correlation_bad_input_and_all_nan_summary() -> None:
    x = np.zeros((10, 2))
    with pytest.raises(InputError, match="window"):
        window_correlation(x, x, 11)
    with pytest.raises(InputError, match="one shape"):
        window_correlation(x, x[:, :1], 3)
    summary = correlation_summary(window_correlation(x, x, 3))
    assert np.isnan(summary["mean"]) and np.isnan(summary["min"]) and np.isnan(summary["max"])


# ---------------------------------------------------------------------------------------------
# Report.


def test_report_json_keys_and_table() -> None:
    measured = gait_run()
    simulated = gait_run(amp_scale=0.9, phase_shift=0.2, head_offset=(0.1, 0.0, 0.0))
    report = compare_runs(measured, simulated, window_s=1.0)
    out = report.to_json_dict()
    assert list(out) == [
        "head_omitted", "head_final_error_m", "head_mean_error_m", "joint_rmse_rad", "cpg_error",
        "window_correlation", "body_final_error_m", "resampled",
    ]
    assert out["head_omitted"] is None
    assert out["head_final_error_m"] == pytest.approx(0.1)
    assert len(out["joint_rmse_rad"]["per_joint"]) == NUM_JOINTS
    assert out["joint_rmse_rad"]["mean"] == pytest.approx(np.mean(report.joint_rmse))
    assert len(out["cpg_error"]) == NUM_JOINTS
    first = out["cpg_error"][0]
    assert first["joint"] == 1 and first["phase"] == pytest.approx(0.2, abs=1e-3)
    assert set(first["measured"]) >= {"amplitude", "frequency", "phase"}
    window = out["window_correlation"]
    assert {"mean", "min", "max", "measured_vs_command", "simulated_vs_command"} <= set(window)
    assert window["window_samples"] == 100 and window["window_s"] == 1.0
    assert window["measured_vs_command"]["mean"] == pytest.approx(1.0)
    assert out["body_final_error_m"] == {"tail": pytest.approx(0.1)}
    assert isinstance(out["resampled"], str)
    json.dumps(out, allow_nan=False)

    table = report.format_table()
    assert "head final error" in table and "tail final error" in table
    assert len([line for line in table.splitlines() if line.strip()[:2].strip().isdigit()]) >= NUM_JOINTS
    with pytest.raises(InputError, match="window_s"):
        compare_runs(measured, simulated, window_s=0.0)
