"""Driver and recorder against the emulated bus, with faults injected.

The real ``dynamixel_sdk`` client (inside :class:`~hardware.driver.DynamixelBus`) talks over a
pty to the emulator, which runs in a child process as ``cobra emulate`` would; the servos are
ideal (:class:`~hardware.plant.KinematicPlant`) so that each test takes about a second. Every fault starts ``at_s`` after the first torque on, i.e. after
the start of recording (``settle_s=0``). Each test checks what the driver did (retry or stop),
that torque went off, the message, and that the run on disk is valid and holds every sample the
driver received (:func:`assert_holds_every_sample`).
"""
from __future__ import annotations

import gc
import math
import os
import re
import signal
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pytest

from cobra_model.gait import SidewindingGait
from cobra_model.run_files import read_run
from hardware import control_table as ct
from hardware.config import BusConfig, JointConfig
from hardware.driver import ConnectError, DynamixelBus
from hardware.emulator import EmulatorProcess
from hardware.faults import Fault, FaultKind, parse_fault
from hardware.plant import KinematicPlant
from hardware.recorder import RecordResult, StopReason, record_gait
from hardware.runwriter import UNFINISHED_NOTE
from integrators.simulate import simulate_like
from sysid.gap.metrics import compare_runs

GAIT = SidewindingGait(freq_hz=0.5, ramp_s=0.5)


def start(faults: list[Fault] = (), **kw: Any) -> EmulatorProcess:
    emu = EmulatorProcess(KinematicPlant, faults=list(faults), **kw)
    emu.start()
    return emu


def record(emu: EmulatorProcess, out: Path, *, duration_s: float = 1.2, gait: Any = GAIT,
           config: BusConfig | None = None) -> RecordResult:
    config = (config or BusConfig(port=emu.port)).with_port(emu.port)
    return record_gait(config, gait, duration_s=duration_s, out=out, settle_s=0.0)


def assert_holds_every_sample(run, emu: EmulatorProcess, *, lost_in_flight: int = 0) -> None:
    """Every present-state read the driver received is a row, and the rows account for what the
    emulator sent: each intact reply set (less ``torque_on``'s read before recording) is a row
    unless the driver gave up waiting for it (a failed read, counted) or the stop came while it
    was in flight (``lost_in_flight``: a pulled cable, or a Ctrl-C that lands between receiving
    a sample and writing it)."""
    comm = run.meta["comm"]
    assert run.n_samples == comm["samples"], comm
    received = comm["reads_ok"] - 1
    assert received - lost_in_flight <= run.n_samples <= received, comm
    sent = emu.stats().intact_sync_reads.get(ct.PRESENT_STATE_ADDRESS, 0) - 1
    assert sent - comm["reads_failed"] - lost_in_flight <= run.n_samples <= sent, (
        f"{run.n_samples} rows, emulator sent {sent} intact state replies; driver {comm}; emulator {emu.stats()}")
    assert_comparable(run)


def assert_comparable(run) -> None:
    """`cobra compare` reproduces the (partial) run: a recording without motion capture gives
    the joint metrics only."""
    report = compare_runs(run, simulate_like(run))
    assert report.head_omitted and np.isfinite(report.joint_rmse).all()


def torque(emu: EmulatorProcess) -> list[int]:
    return [emu.register(i, ct.TORQUE_ENABLE) for i in range(1, 12)]


def assert_tracks(run) -> None:
    """The ideal servos lag the gait by their 30 ms time constant (~0.1 rad at the 3.3 rad/s
    peak speed of the yaw joints), more where a read was retried; a mix-up of joints, units or
    signs would be off by about the 1 rad amplitude."""
    error = np.abs(run.q - run.q_ref)
    worst = np.unravel_index(np.argmax(error), error.shape)
    assert np.percentile(error, 95) < 0.25, (f"95th percentile {np.percentile(error, 95):.3f} rad; worst "
                                             f"{error[worst]:.3f} rad at t = {run.t[worst[0]]:.3f} s, joint "
                                             f"{worst[1] + 1}; {run.meta['comm']}")
    assert np.sqrt(np.mean(error**2)) < 0.15


def test_clean_run_follows_the_gait(tmp_path: Path, emulators) -> None:
    emulators.append(emu := start())
    result = record(emu, tmp_path / "clean.csv")
    assert result.status is StopReason.COMPLETED
    assert result.message == "torque off on all 11 servos"
    assert torque(emu) == [0] * 11
    run = read_run(result.path)
    assert run.n_samples == result.samples
    assert_holds_every_sample(run, emu)
    assert "notes" not in run.meta
    assert run.meta["source"] == "emulator"
    assert run.meta["gait"] == GAIT.to_json()
    np.testing.assert_allclose(run.q_ref, GAIT.q_ref(run.t), atol=1e-12)
    assert_tracks(run)
    timing = result.timing
    # Every 20 ms slot of the 1.2 s either ran or was reported skipped, and the rate is what ran.
    assert 59 <= timing.cycles + timing.skipped_cycles <= 60
    assert timing.achieved_rate_hz == pytest.approx(1.0 / timing.period_mean_s)
    assert 40 < timing.achieved_rate_hz < 50.5
    assert run.meta["timing"] == timing.to_json()
    assert run.t[0] >= 0 and np.all(np.diff(run.t) > 0)
    # the Bus Watchdog was armed (100 ms = 5 units) and never had to act
    assert [emu.register(i, ct.BUS_WATCHDOG) for i in range(1, 12)] == [5] * 11
    assert emu.stats().watchdog_stops_s == {}


@pytest.mark.parametrize("spec", ["crc@0.4x4", "drop@0.4x4", "crc:7@0.4x2"])
def test_corrupted_and_dropped_replies_are_retried(tmp_path: Path, emulators, spec: str) -> None:
    emulators.append(emu := start([parse_fault(spec)]))
    result = record(emu, tmp_path / "retry.csv")
    stats = emu.stats()
    assert stats.corrupted + stats.dropped == parse_fault(spec).count, stats
    assert result.status is StopReason.COMPLETED, result.message
    run = read_run(result.path)
    assert_holds_every_sample(run, emu)
    assert run.meta["comm"]["reads_failed"] >= 1, run.meta["comm"]  # and then retried (a state read) or repeated
    assert_tracks(run)


def test_servo_that_stops_answering(tmp_path: Path, emulators) -> None:
    emulators.append(emu := start([Fault(FaultKind.SILENT, at_s=0.5, servo_id=5)]))
    # A 1 s watchdog: from the silence on, every read waits out the SDK's timeout (~36 ms) and
    # the packets go that far apart; a loaded test host once stalled the recorder the rest of
    # the 100 ms and the watchdog, rightly, stopped the run before the 5th failed read.
    result = record(emu, tmp_path / "silent.csv", duration_s=3.0,
                    config=BusConfig(port=emu.port, bus_watchdog_ms=1000))
    assert result.status is StopReason.COMM_FAILURE
    assert "5 consecutive failed reads" in result.message
    assert "not answering a ping: joint 5 (ID 5)" in result.message
    assert "confirmed by 10 servos, not by joint 5 (ID 5)" in result.message
    assert torque(emu) == [0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0]  # servo 5 never heard the torque off
    run = read_run(result.path)
    assert run.n_samples == result.samples
    assert_holds_every_sample(run, emu)
    assert 0.3 <= run.t[-1] <= 1.0  # the servo fell silent 0.5 s after the first torque on
    assert run.meta["notes"] == [f"partial run: {result.message.split('; torque off')[0]}"]
    assert run.meta["stop"]["status"] == "comm_failure"


def test_overload_error_bit_stops_with_torque_off(tmp_path: Path, emulators) -> None:
    emulators.append(emu := start([Fault(FaultKind.OVERLOAD, at_s=0.5, servo_id=3)]))
    result = record(emu, tmp_path / "overload.csv", duration_s=3.0)
    assert result.status is StopReason.HARDWARE_ERROR
    assert result.message == ("joint 3 (ID 3) reported a hardware error: overload (Hardware Error "
                              "Status 0x20); torque off on all 11 servos")
    assert torque(emu) == [0] * 11
    run = read_run(result.path)
    assert_holds_every_sample(run, emu)
    # Hardware Error Status is read every 5 cycles (100 ms at 50 Hz).
    assert 0.3 <= run.t[-1] < 1.0
    assert run.meta["notes"][0].startswith("partial run: joint 3 (ID 3) reported a hardware error: overload")


def test_pulled_cable(tmp_path: Path, emulators) -> None:
    # 1.5 s: a fresh clone's loaded test host once left the recorder no sample before 0.5 s
    # (first imports compiling while the other worker ran), and the run needs rows to check.
    emulators.append(emu := start([Fault(FaultKind.UNPLUG, at_s=1.5)]))
    result = record(emu, tmp_path / "unplugged.csv", duration_s=3.0)
    assert result.status is StopReason.DISCONNECTED, result.message
    assert result.message.startswith(f"port lost: serial port {emu.port} failed: ")
    assert result.message.endswith("torque off could NOT be sent: the servos hold their last goal, cut their power")
    assert result.torque.port_error is not None
    run = read_run(result.path)
    # The reply the emulator sent just before the cable went may not have been read.
    assert_holds_every_sample(run, emu, lost_in_flight=1)
    # The cable went 1.5 s of emulated time after the first torque on; a starved emulator gives
    # up lags beyond its max_lag_s, and emulated time then runs that much behind the wall clock.
    slipped_s = emu.stats().wall_time_s - emu.stats().emulated_time_s
    assert 0.3 <= run.t[-1] <= 2.0 + slipped_s, (run.t[-1], slipped_s, result.message)
    assert run.meta["notes"][0].startswith("partial run: port lost")


class _FailingGait:
    """The paper's gait until ``at_s``, then ``exc`` is raised (a bug)."""

    def __init__(self, exc: BaseException, at_s: float) -> None:
        self.exc, self.at_s = exc, at_s

    def q_ref(self, t: float) -> np.ndarray:
        if t > self.at_s:
            raise self.exc
        return GAIT.q_ref(t)

    def to_json(self) -> dict[str, Any]:
        return GAIT.to_json()


@pytest.fixture
def python_ctrl_c() -> Iterator[None]:
    """Python's own SIGINT handler, whatever this process inherited: a job started in the
    background by a non-interactive shell ignores SIGINT, and Python then keeps it ignored."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_stops_with_torque_off(tmp_path: Path, emulators, python_ctrl_c) -> None:
    emulators.append(emu := start())
    # A real SIGINT to this process half a second in, wherever the loop then is (sleeping,
    # or inside the SDK waiting for a reply).
    ctrl_c = threading.Timer(0.5, os.kill, (os.getpid(), signal.SIGINT))
    ctrl_c.start()
    try:
        result = record(emu, tmp_path / "ctrl_c.csv", duration_s=3.0)
    finally:
        ctrl_c.cancel()
    assert result.status is StopReason.INTERRUPTED
    assert result.message == "interrupted (Ctrl-C); torque off on all 11 servos"
    assert torque(emu) == [0] * 11
    run = read_run(result.path)
    # Ctrl-C may land while a reply is being received: that one is lost.
    assert_holds_every_sample(run, emu, lost_in_flight=1)
    assert 0.2 <= run.t[-1] <= 1.0  # Ctrl-C came 0.5 s after connecting began
    assert run.meta["notes"] == ["partial run: interrupted (Ctrl-C)"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored after cleanup


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_terminating_signal_stops_with_torque_off(tmp_path: Path, emulators, signum: int) -> None:
    # A process manager, `timeout` or a closed terminal: their signal kills a Python process at
    # once by default, which would leave the servos energised at their last goal.
    emulators.append(emu := start())
    previous = signal.getsignal(signum)
    kill = threading.Timer(0.5, os.kill, (os.getpid(), signum))
    kill.start()
    try:
        result = record(emu, tmp_path / "term.csv", duration_s=3.0)
    finally:
        kill.cancel()
    name = signal.Signals(signum).name
    assert result.status is StopReason.TERMINATED and result.signal_name == name
    assert result.message == f"terminated ({name}); torque off on all 11 servos"
    assert torque(emu) == [0] * 11
    run = read_run(result.path)
    assert_holds_every_sample(run, emu, lost_in_flight=1)
    assert 0.2 <= run.t[-1] <= 1.0
    assert run.meta["notes"] == [f"partial run: terminated ({name})"]
    assert signal.getsignal(signum) is previous  # restored after cleanup


def test_unexpected_exception_is_raised_after_torque_off(tmp_path: Path, emulators) -> None:
    emulators.append(emu := start())
    with pytest.raises(RuntimeError, match="boom"):
        record(emu, tmp_path / "bug.csv", gait=_FailingGait(RuntimeError("boom"), 0.4))
    assert torque(emu) == [0] * 11
    run = read_run(tmp_path / "bug.csv")
    assert_holds_every_sample(run, emu)
    assert run.meta["notes"] == ["partial run: unexpected error: RuntimeError: boom"]


class _ConstantGait:
    def __init__(self, q: np.ndarray) -> None:
        self.q = np.asarray(q, dtype=float)

    def q_ref(self, t: float) -> np.ndarray:
        return self.q

    def to_json(self) -> dict[str, Any]:
        return {"type": "constant", "q_rad": self.q.tolist()}


def test_commands_are_clamped_and_offsets_applied(tmp_path: Path, emulators) -> None:
    joints = tuple(JointConfig(k, k, zero_offset_rad=math.radians(5.0 * (k - 6)), direction=(-1) ** k)
                   for k in range(1, 12))
    config = BusConfig(port="", joints=joints, joint_limit_rad=math.radians(60.0))
    emulators.append(emu := start(joints=joints))
    q_cmd = np.linspace(-1.5, 1.5, 11)  # beyond +-60 deg at both ends
    result = record(emu, tmp_path / "clamp.csv", duration_s=0.6, gait=_ConstantGait(q_cmd), config=config)
    assert result.status is StopReason.COMPLETED
    run = read_run(result.path)
    expected = np.clip(q_cmd, -math.radians(60), math.radians(60))
    np.testing.assert_allclose(run.q_ref, np.broadcast_to(expected, run.q_ref.shape))
    np.testing.assert_allclose(run.q[-1], expected, atol=2 * math.pi / 4096)
    # Joint 11: +60 deg, direction -1, offset +25 deg -> servo angle -35 deg.
    pulses_per_deg = 4096 / 360
    assert emu.register(11, ct.GOAL_POSITION) == 2048 + round(-35.0 * pulses_per_deg)
    # The servos were given the joint limits too: joint 11 spans -35..85 deg of servo angle.
    assert emu.register(11, ct.MIN_POSITION_LIMIT) == 2048 + round(-35.0 * pulses_per_deg)
    assert emu.register(11, ct.MAX_POSITION_LIMIT) == 2048 + round(85.0 * pulses_per_deg)


def test_connect_names_every_missing_wrong_or_faulty_servo(emulators) -> None:
    emulators.append(emu := start(joints=[JointConfig(k, k) for k in range(1, 11)], model_number=1120))
    with pytest.raises(ConnectError) as info:
        DynamixelBus(BusConfig(port=emu.port), connect_retries=1).connect()
    text = str(info.value)
    assert "joint 1 (ID 1): model number 1120, expected 1100" in text
    assert "joint 11 (ID 11): no answer to ping" in text

    emulators.append(emu := start())
    bus = DynamixelBus(BusConfig(port=emu.port))
    bus.connect()
    bus.torque_on()
    emu.inject(Fault(FaultKind.OVERLOAD, servo_id=4))
    time.sleep(0.05)
    assert emu.register(4, ct.HARDWARE_ERROR_STATUS) == ct.HardwareError.OVERLOAD
    bus.torque_off()
    bus.close()
    with pytest.raises(ConnectError, match=r"joint 4 \(ID 4\): hardware error \(overload\); reboot"):
        DynamixelBus(BusConfig(port=emu.port)).connect()


def test_cut_bus_cable_stops_every_servo_by_its_watchdog(tmp_path: Path, emulators) -> None:
    # The cable between the adapter and the servos is cut: the port stays, no servo hears the
    # host, so the torque off cannot reach them; their watchdog is what stops them.
    emulators.append(emu := start([Fault(FaultKind.CUT, at_s=0.5)]))
    result = record(emu, tmp_path / "cut.csv", duration_s=3.0)
    assert result.status is StopReason.COMM_FAILURE
    assert "no servo answers a ping: bus cable or servo power lost?" in result.message
    assert result.torque.unconfirmed == tuple(range(1, 12))
    stats = emu.stats()
    stops, heard = stats.watchdog_stops_s, stats.watchdog_heard_s
    assert sorted(stops) == list(range(1, 12)) and heard.keys() == stops.keys()
    # Each servo stops 100 ms (its watchdog) after the last packet it heard, plus up to one 1 ms
    # physics step of the emulator, plus up to two 20 ms cycles late: an emulated servo also
    # counts the silence on the wall clock (``watchdog_due``), and when the emulator's thread was
    # starved its plant catches up faster than the wall, so the stop lands later in emulated time
    # by that starvation (0.1058 s after the cut once, in a loaded fresh-clone run). That packet
    # came before the cut, and the host sent until about it: within three of its 20 ms cycles, as
    # a starved host is late (a servo stopped 66 ms after the cut in a loaded fresh-clone run, so
    # it had heard nothing for 34 ms before it).
    for servo_id, at in stops.items():
        assert 0.5 - 0.060 <= heard[servo_id] <= 0.5, (servo_id, heard[servo_id])
        assert 0.1 < at - heard[servo_id] <= 0.1 + 0.001 + 0.040, (servo_id, at, heard[servo_id])
    assert [emu.register(i, ct.BUS_WATCHDOG) for i in range(1, 12)] == [-1] * 11
    time.sleep(0.3)  # the ideal servos settle on the pose they were stopped in (30 ms lag)
    assert all(abs(emu.register(i, ct.PRESENT_VELOCITY)) <= 1 for i in range(1, 12))
    run = read_run(result.path)
    assert_holds_every_sample(run, emu)
    assert 0.3 <= run.t[-1] <= 1.0


class _FreezingGait:
    """The paper's gait, but the host freezes for ``freeze_s`` once at ``at_s`` (swapping, a
    stalled disk, a debugger)."""

    def __init__(self, at_s: float, freeze_s: float) -> None:
        self.at_s, self.freeze_s, self.frozen = at_s, freeze_s, False

    def q_ref(self, t: float) -> np.ndarray:
        if t > self.at_s and not self.frozen:
            self.frozen = True
            time.sleep(self.freeze_s)
        return GAIT.q_ref(t)

    def to_json(self) -> dict[str, Any]:
        return GAIT.to_json()


def test_a_frozen_host_is_stopped_by_the_watchdog_and_told_so(tmp_path: Path, emulators) -> None:
    emulators.append(emu := start())
    result = record(emu, tmp_path / "frozen.csv", duration_s=2.0, gait=_FreezingGait(0.5, 0.3))
    assert result.status is StopReason.WATCHDOG
    assert result.message.startswith("the Bus Watchdog stopped joint 1 (ID 1), joint 2 (ID 2)")
    assert "no packet reached it for 100 ms (longest interval between cycles since torque on 3" in result.message
    assert result.message.endswith("torque off on all 11 servos")
    assert torque(emu) == [0] * 11
    assert sorted(emu.stats().watchdog_stops_s) == list(range(1, 12))
    run = read_run(result.path)
    assert_holds_every_sample(run, emu)
    assert run.meta["stop"]["status"] == "watchdog"


def test_a_freeze_before_the_first_cycle_is_in_the_watchdog_message(tmp_path: Path, emulators) -> None:
    """The host freezes between torque on and settling's first cycle (computing the gait's first
    pose): the message gives that interval, not only the intervals of the stream it stopped in."""
    emulators.append(emu := start())
    result = record_gait(BusConfig(port=emu.port), _FreezingGait(-1.0, 0.3), duration_s=1.0,
                         out=tmp_path / "frozen_at_start.csv", settle_s=0.5)
    assert result.status is StopReason.WATCHDOG
    match = re.search(r"longest interval between cycles since torque on (\d+) ms", result.message)
    assert match, result.message
    assert 300 <= int(match.group(1)) < 2000
    assert torque(emu) == [0] * 11
    assert result.path is None  # stopped while settling: nothing recorded, no file


class _CollectorWatch:
    """The paper's gait, noting at each command how many objects the garbage collector leaves
    out of its scans (``gc.get_freeze_count``)."""

    def __init__(self) -> None:
        self.frozen: list[int] = []

    def q_ref(self, t: float) -> np.ndarray:
        self.frozen.append(gc.get_freeze_count())
        return GAIT.q_ref(t)

    def to_json(self) -> dict[str, Any]:
        return GAIT.to_json()


#: How many 100 ms Bus Watchdogs a full collection over the project's loaded libraries lasted on
#: the machine the watchdog test was written on (143 ms).
GC_PER_WATCHDOG = 1.43


def test_no_garbage_collection_pause_can_starve_the_watchdog(tmp_path: Path, emulators) -> None:
    """A full collection over a test session's objects outlasts the Bus Watchdog; during a
    recording every object alive before it is frozen out of the scans, and handed back after.

    The watchdog is 100 ms where a full collection over the project's libraries takes 143 ms. On
    a slower host, or in a process holding more, everything the recording must do in time (the
    host's Python between two packets, the emulator's replies) is slower too, and a 100 ms
    watchdog there tests the host's speed, not the collector: it is set to the same fraction of a
    full collection measured in this process (never under 100 ms), so that an unfrozen
    collection still outlasts it (one full run of the suite on a host 2.3 times slower than the
    one the test was written on stopped at the first cycle with 100 ms)."""
    t = time.perf_counter()
    gc.collect()
    full_collection_ms = 1e3 * (time.perf_counter() - t)
    unit_ms = 1e3 * ct.BUS_WATCHDOG_UNIT_S
    watchdog_ms = max(100, int(unit_ms * math.floor(full_collection_ms / GC_PER_WATCHDOG / unit_ms)))
    emulators.append(emu := start())
    before = gc.get_freeze_count()
    watch = _CollectorWatch()
    result = record(emu, tmp_path / "gc.csv", duration_s=0.5, gait=watch,
                    config=BusConfig(port=emu.port, bus_watchdog_ms=watchdog_ms))
    assert result.status is StopReason.COMPLETED, result.message
    assert watch.frozen and min(watch.frozen) > 1000
    assert gc.get_freeze_count() == before


def test_brownout_stops_with_torque_off(tmp_path: Path, emulators) -> None:
    emulators.append(emu := start([parse_fault("voltage:2@0.5")]))
    result = record(emu, tmp_path / "brownout.csv", duration_s=3.0)
    assert result.status is StopReason.HARDWARE_ERROR
    assert result.message.startswith("joint 2 (ID 2) reported a hardware error: input voltage")
    assert result.message.endswith("torque off on all 11 servos")
    assert emu.register(2, ct.PRESENT_INPUT_VOLTAGE) == 85  # 8.5 V, below the 9.5 V minimum
    assert torque(emu) == [0] * 11
    run = read_run(result.path)
    assert_holds_every_sample(run, emu)
    assert 0.3 <= run.t[-1] < 1.0


def test_a_full_disk_stops_with_torque_off_and_keeps_what_was_written(tmp_path: Path, emulators,
                                                                      full_disk_after) -> None:
    emulators.append(emu := start())
    full_disk_after(20)  # the disk fills while the 21st sample is written
    result = record(emu, tmp_path / "full.csv", duration_s=3.0)
    assert result.status is StopReason.WRITE_FAILED
    assert result.message.startswith(f"cannot write sample 21 to {tmp_path / 'full.csv'}: the disk is full")
    assert "the file keeps the 20 samples before it; torque off on all 11 servos" in result.message
    assert result.message.endswith("could not be updated (No space left on device): it still says the "
                                   "recording did not finish")
    assert torque(emu) == [0] * 11
    run = read_run(result.path)
    assert run.n_samples == 20 == result.samples
    assert run.meta["notes"] == [UNFINISHED_NOTE]
    assert_comparable(run)
    # the 21st sample was received but could not be written; nothing after it was read. The
    # emulator may have sent more intact replies than that: those the driver gave up waiting for
    # (a loaded host), each a failed read.
    assert result.comm.reads_ok - 1 == 21, result.comm
    sent = emu.stats().intact_sync_reads[ct.PRESENT_STATE_ADDRESS] - 1
    assert sent - result.comm.reads_failed <= 21 <= sent, (sent, result.comm)
