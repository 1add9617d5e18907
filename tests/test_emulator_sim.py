"""End to end with the physics: a run recorded on the emulated robot is comparable with a simulated run.

``cobra emulate``'s plant is COBRA in the project's simulator; the recorder streams the paper's
gait through the real ``dynamixel_sdk`` client; the recorded joint angles are then compared
with an offline simulation of the same robot from the same pose driven by the run's own
``q_ref`` columns (as DATA_FORMAT.md says a run is reproduced).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cobra_model.gait import SidewindingGait
from cobra_model.run_files import read_run
from hardware.config import BusConfig
from hardware.emulator import EmulatorProcess
from hardware.plant import SimulatorPlant
from hardware.recorder import StopReason, record_gait

pytestmark = pytest.mark.slow


def test_recorded_run_of_the_emulated_robot_matches_the_simulator(tmp_path: Path) -> None:
    from cobra_model import CobraModel, ModelParameters
    from integrators import ServoGains, SimSettings, Simulator

    gait = SidewindingGait(freq_hz=0.5)
    with EmulatorProcess(SimulatorPlant.nominal) as emu:
        result = record_gait(BusConfig(port=emu.port), gait, duration_s=3.0,
                             out=tmp_path / "emulated.csv", settle_s=0.2)
        stats = emu.stats()
    assert result.status is StopReason.COMPLETED, result.message
    assert stats.error is None
    assert stats.real_time_factor > 0.95  # the simulator keeps up with the wall clock
    run = read_run(result.path)
    assert run.meta["source"] == "emulator"
    assert run.n_samples > 0.9 * 3.0 * 50

    # Offline: the same robot at rest in the run's first pose, commanded with the run's q_ref
    # (interpolated onto the servo's 1 ms ticks), sampled at the run's times.
    sim = Simulator(CobraModel.load(), ModelParameters.nominal(),
                    SimSettings(dt=1e-3, control_dt=1e-3, gains=ServoGains()))
    ticks = np.arange(0.0, run.t[-1] + 1e-3, 1e-3)
    commands = np.column_stack([np.interp(ticks, run.t, run.q_ref[:, j]) for j in range(11)])
    traj = sim.rollout(sim.rest_state(run.q[0]), commands, float(ticks[-1]))
    q_sim = np.column_stack([np.interp(run.t, traj.t, traj.q_meas[:, j]) for j in range(11)])

    gap = run.q - q_sim
    # The emulated robot is read a few ms after each command is sent; at the gait's peak
    # joint speed (3.3 rad/s) that is the whole difference (observed: rms 0.013, max 0.06 rad).
    assert np.sqrt(np.mean(gap**2)) < 0.03
    # Emulator and recorder run against the wall clock; on a loaded 2-core machine (the suite's
    # other worker) one read can come tens of ms late (seen once: 0.22 rad at one sample), which
    # is the host's scheduling, not tracking: the bound holds for all but 1 % of the readings.
    assert np.percentile(np.abs(gap), 99) < 0.12
    # Both lag the command alike: the emulated robot tracks as the simulator does.
    rms_emu = np.sqrt(np.mean((run.q - run.q_ref) ** 2))
    rms_sim = np.sqrt(np.mean((q_sim - run.q_ref) ** 2))
    assert rms_emu == pytest.approx(rms_sim, rel=0.3)
    assert rms_sim > 0.01  # the comparison is not trivial: the servos do lag the gait
