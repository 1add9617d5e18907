"""End to end with the physics: a run recorded on the emulated robot is comparable with a simulated run.

``cobra emulate``'s plant is COBRA in the project's simulator; the recorder streams the paper's
gait through the real ``dynamixel_sdk`` client; the recorded joint angles are then compared
with an offline simulation of the same robot from the same pose driven by the run's own
``q_ref`` columns, put on the servo's ticks as the sidecar says the recorder applied them
(each goal held until the next cycle), as DATA_FORMAT.md says a run is reproduced.
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
    from integrators.simulate import command_ticks

    gait = SidewindingGait(freq_hz=0.5)
    with EmulatorProcess(SimulatorPlant.nominal) as emu:
        # The physics is under test here, not the watchdog (tests/test_emulator_faults.py): a
        # loaded test host can leave the recorder's process without the CPU for over 100 ms.
        result = record_gait(BusConfig(port=emu.port, bus_watchdog_ms=1000), gait, duration_s=3.0,
                             out=tmp_path / "emulated.csv", settle_s=0.2)
        stats = emu.stats()
    assert result.status is StopReason.COMPLETED, result.message
    assert stats.error is None
    assert stats.real_time_factor > 0.95  # the simulator keeps up with the wall clock
    run = read_run(result.path)
    assert run.meta["source"] == "emulator"
    assert run.n_samples > 0.9 * 3.0 * 50

    assert run.q_ref_held  # the recorder says how its goals were applied

    # Offline: the same robot at rest in the run's first pose, commanded with the run's q_ref on
    # the servo's 1 ms ticks as the project reproduces any run (each goal held until the next).
    sim = Simulator(CobraModel.load(), ModelParameters.nominal(),
                    SimSettings(dt=1e-3, control_dt=1e-3, gains=ServoGains()))
    commands = command_ticks(run, 1e-3)
    traj = sim.rollout(sim.rest_state(run.q[0]), commands, (len(commands) - 1) * 1e-3)
    # Each state was received read_latency_s after its goal was sent (about 1.5 ms): the
    # simulator is read at that time. A reading the host delayed is then still compared with
    # the simulator at the moment it was taken.
    latency = run.extra["read_latency_s"].astype(float)
    assert np.all((latency > 0) & (latency < 0.5))
    t_read = run.t - run.t[0] + latency
    q_sim = np.column_stack([np.interp(t_read, traj.t, traj.q_meas[:, j]) for j in range(11)])

    gap = run.q - q_sim
    # Observed alone: rms 1.1 mrad, max 5 mrad, at 1.5 mrad per encoder count (held goals read
    # at t + latency; 13 and 43 mrad with the goals interpolated, read at t). In the suite, with
    # the other worker loading the 2-core host, 12 mrad once: the emulator's plant then runs
    # up to 5 % behind the wall clock (real_time_factor > 0.95 above), which the read latency
    # does not see. The bound is the one this test had before.
    assert np.sqrt(np.mean(gap**2)) < 0.03
    # All but 1 % of the readings (the bound this test had before): a goal the emulator (a
    # process of its own on a loaded 2-core host) applies up to ~35 ms late at the yaw joints'
    # peak speed (3.3 rad/s) moves that joint by 0.12 rad. The plant's lag behind the wall
    # clock is not in the read latency, so a single reading is not bounded here.
    assert np.percentile(np.abs(gap), 99) < 0.12
    # Both lag the command alike: the emulated robot tracks as the simulator does.
    rms_emu = np.sqrt(np.mean((run.q - run.q_ref) ** 2))
    rms_sim = np.sqrt(np.mean((q_sim - run.q_ref) ** 2))
    assert rms_emu == pytest.approx(rms_sim, rel=0.1)
    assert rms_sim > 0.01  # the comparison is not trivial: the servos do lag the gait
