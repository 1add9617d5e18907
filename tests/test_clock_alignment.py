"""The take's clock offset is found from the data: a known shift, mocap noise and dropouts."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cobra_model import SidewindingGait
from cobra_model.errors import InputError
from cobra_model.resample import interpolate_rows
from integrators.simulate import simulate_gait
from cobra_model.clock_alignment import estimate_clock_offset
from cobra_model.servo import PULSES_PER_REV
from cobra_model.motive import MotiveTake, RigidBodyTrack

OFFSET_S = 0.137
FRAME_HZ = 120.0


@pytest.fixture(scope="module")
def recording(cobra):
    """An 8 s run seen twice: a 120 Hz take whose clock runs 0.137 s ahead of the joint log's
    (take time = joint-log time + 0.137 s; the robot rests before the gait starts at joint-log
    time 0), with 0.5 mm of marker noise and dropouts; and a 50 Hz joint log with quantised
    encoders."""
    run = simulate_gait(SidewindingGait(0.5, ramp_s=1.0), 8.0, sample_rate_hz=FRAME_HZ, model=cobra)
    rng = np.random.default_rng(7)
    n_rest = int(OFFSET_S * FRAME_HZ)  # frames before the gait starts, at rest
    times = np.concatenate([np.arange(n_rest) / FRAME_HZ, OFFSET_S + run.t])

    def track(pos: np.ndarray, quat: np.ndarray | None, name: str) -> RigidBodyTrack:
        p = np.vstack([np.repeat(pos[:1], n_rest, axis=0), pos]) + rng.normal(0, 5e-4, (len(times), 3))
        qt = np.full((len(times), 4), np.nan) if quat is None else np.vstack([np.repeat(quat[:1], n_rest, 0), quat])
        for start in rng.choice(len(times) - 30, 6, replace=False):  # dropouts of 5..25 frames
            p[start:start + rng.integers(5, 25)] = np.nan
        return RigidBodyTrack(name, p, qt)

    take = MotiveTake(times, np.arange(len(times)), {"head": track(run.head_pos, run.head_quat, "head"),
                                                     "link_6": track(run.bodies["link_6"], None, "link_6"),
                                                     "tail": track(run.bodies["tail"], None, "tail")},
                      FRAME_HZ, "Z", "Meters", {}, Path("take.csv"))
    t_log = np.arange(0.0, 8.0, 0.02)
    step = 2 * np.pi / PULSES_PER_REV
    q = interpolate_rows(t_log, run.t, run.q)
    return take, (t_log, np.round(q / step) * step, None)


def test_a_known_offset_is_recovered_within_one_mocap_frame(recording, cobra) -> None:
    take, joints = recording
    est = estimate_clock_offset(take, joints, model=cobra)
    assert abs(est.offset_s - OFFSET_S) < 1.0 / FRAME_HZ, est
    assert est.std_s < 1.0 / FRAME_HZ
    assert est.bodies == ("link_6", "tail")
    # the gait's start told the periods apart: a whole period away fits far worse
    assert est.runner_up_rms_m > 3 * est.rms_m
    assert "take time = joint-log time + 0.13" in est.describe()


def test_only_the_head_tracked_or_too_little_overlap_is_an_error(recording, cobra) -> None:
    take, joints = recording
    head_only = MotiveTake(take.times, take.frames, {"head": take.bodies["head"]}, take.frame_rate, "Z", "Meters",
                           {}, take.source)
    with pytest.raises(InputError, match="only the head is tracked.*give --time-offset"):
        estimate_clock_offset(head_only, joints, model=cobra)
    short = MotiveTake(take.times[:200], take.frames[:200], {k: RigidBodyTrack(v.name, v.positions[:200],
                                                                               v.quats[:200])
                                                             for k, v in take.bodies.items()},
                       take.frame_rate, "Z", "Meters", {}, take.source)
    with pytest.raises(InputError, match=r"take.csv spans \[0, 1.601\] s and the joint log spans \[0, 7.98\] s: "
                                         r"no shift leaves one gait cycle \(\d\.\d\d s\) of overlap"):
        estimate_clock_offset(short, joints, model=cobra)


def _cells(values: np.ndarray) -> str:
    return ",".join("" if not np.isfinite(v) else f"{v:.6f}" for v in values)


def test_import_optitrack_estimates_and_uses_the_offset(recording, tmp_path: Path, capsys) -> None:
    """End to end: the take as a Z-up Motive export, the joint log as a CSV, no --time-offset."""
    from cobra_cli.main import main
    from cobra_model.run_files import read_run

    take, (t_log, q, _) = recording
    head = take.bodies["head"]
    names = ["head"] * 7 + ["link_6"] * 3 + ["tail"] * 3
    lines = ["Format Version,1.23,Take Name,clock,Export Frame Rate,120.000000,Rotation Type,Quaternion,"
             "Length Units,Meters,Coordinate Space,Global,Up Axis,Z", "",
             ",Type," + ",".join(["Rigid Body"] * len(names)), ",Name," + ",".join(names),
             ",ID," + ",".join(["1"] * 7 + ["2"] * 3 + ["3"] * 3),
             ",," + ",".join(["Rotation"] * 4 + ["Position"] * 9),
             "Frame,Time (Seconds)," + ",".join(list("XYZW") + list("XYZ") * 3)]
    for k, t in enumerate(take.times):
        w, x, y, z = head.quats[k]
        lines.append(f"{k},{t:.6f}," + ",".join([_cells(np.array([x, y, z, w])), _cells(head.positions[k]),
                                                 _cells(take.bodies["link_6"].positions[k]),
                                                 _cells(take.bodies["tail"].positions[k])]))
    take_csv = tmp_path / "take.csv"
    take_csv.write_text("\n".join(lines) + "\n")
    joints_csv = tmp_path / "joints.csv"
    joints_csv.write_text("t," + ",".join(f"q_{j}" for j in range(1, 12)) + "\n"
                          + "\n".join(f"{t:.4f}," + ",".join(f"{v:.6f}" for v in row) for t, row in zip(t_log, q)) + "\n")
    out = tmp_path / "run.csv"
    assert main(["import-optitrack", str(take_csv), "--joints", str(joints_csv), "--out", str(out)]) == 0
    assert "clock offset estimated from the data: take time = joint-log time + 0.13" in capsys.readouterr().out
    run = read_run(out)
    assert abs(run.meta["optitrack"]["time_offset_s"] - OFFSET_S) < 1.0 / FRAME_HZ
    assert run.meta["optitrack"]["time_offset_estimate"]["bodies"] == ["link_6", "tail"]
