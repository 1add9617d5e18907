"""The bus emulator answers ROBOTIS's real ``dynamixel_sdk`` client over a pty as servos would.

The servos here move with :class:`~hardware.plant.KinematicPlant` (ideal servos): these tests
are about the wire protocol and the control table, not the physics. The emulator runs in a child
process (:class:`~hardware.emulator.EmulatorProcess`), as ``cobra emulate`` would, except where
a test looks at the in-process :class:`~hardware.emulator.BusEmulator` itself.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Iterator

import numpy as np
import pytest
import serial
from dynamixel_sdk import (
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from hardware import control_table as ct
from hardware.config import JointConfig
from hardware.emulator import BusEmulator, EmulatorProcess
from hardware.faults import Fault, FaultKind
from hardware.plant import KinematicPlant
from hardware.protocol import ALERT_BIT, Instruction, PacketParser, StatusError, encode_instruction
from hardware.units import to_signed

IDS = range(1, 12)


@pytest.fixture
def emulator() -> Iterator[EmulatorProcess]:
    with EmulatorProcess(KinematicPlant) as emu:
        yield emu


@pytest.fixture
def sdk(emulator: EmulatorProcess) -> Iterator[tuple[PortHandler, PacketHandler]]:
    port = PortHandler(emulator.port)
    assert port.openPort() and port.setBaudRate(1_000_000)
    yield port, PacketHandler(2.0)
    port.closePort()


def wait_until(predicate, timeout_s: float = 2.0) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


def test_ping_every_servo_and_broadcast_ping(sdk) -> None:
    port, packet = sdk
    for servo_id in IDS:
        assert packet.ping(port, servo_id) == (ct.XH540_W270_MODEL_NUMBER, COMM_SUCCESS, 0)
    assert packet.ping(port, 12)[1] == COMM_RX_TIMEOUT  # nobody home
    found, result = packet.broadcastPing(port)
    assert result == COMM_SUCCESS
    assert sorted(found) == list(IDS)
    assert all(model == ct.XH540_W270_MODEL_NUMBER for model, _fw in found.values())


def test_read_write_and_access_rules(sdk, emulator: EmulatorProcess) -> None:
    port, packet = sdk
    assert packet.read1ByteTxRx(port, 4, ct.OPERATING_MODE.address) == (ct.OperatingMode.POSITION, COMM_SUCCESS, 0)
    assert packet.write2ByteTxRx(port, 4, ct.POSITION_P_GAIN.address, 640) == (COMM_SUCCESS, 0)
    assert packet.read2ByteTxRx(port, 4, ct.POSITION_P_GAIN.address) == (640, COMM_SUCCESS, 0)
    # Read-only field, out-of-range value, EEPROM with torque on, goal beyond the position limits.
    assert packet.write2ByteTxRx(port, 4, ct.MODEL_NUMBER.address, 1) == (COMM_SUCCESS, StatusError.ACCESS)
    assert packet.write2ByteTxRx(port, 4, ct.PWM_LIMIT.address, 900) == (COMM_SUCCESS, StatusError.DATA_RANGE)
    assert packet.write1ByteTxRx(port, 4, ct.OPERATING_MODE.address, 2) == (COMM_SUCCESS, StatusError.DATA_RANGE)
    assert packet.write1ByteTxRx(port, 4, ct.TORQUE_ENABLE.address, 1) == (COMM_SUCCESS, 0)
    assert packet.write1ByteTxRx(port, 4, ct.OPERATING_MODE.address, 4) == (COMM_SUCCESS, StatusError.ACCESS)
    assert packet.write4ByteTxRx(port, 4, ct.GOAL_POSITION.address, 5000) == (COMM_SUCCESS, StatusError.DATA_LIMIT)
    assert packet.write4ByteTxRx(port, 4, ct.GOAL_POSITION.address, 2560) == (COMM_SUCCESS, 0)
    assert wait_until(lambda: abs(emulator.register(4, ct.PRESENT_POSITION) - 2560) <= 2)
    assert packet.readTxRx(port, 4, 140, 10)[2] == StatusError.ACCESS  # beyond the table
    assert packet.reboot(port, 4) == (COMM_SUCCESS, StatusError.INSTRUCTION)  # not emulated


def test_broadcast_write_gets_no_reply_but_is_applied(sdk, emulator: EmulatorProcess) -> None:
    port, packet = sdk
    replies_before = emulator.stats().replies
    assert packet.write1ByteTxOnly(port, 0xFE, ct.LED.address, 1) == COMM_SUCCESS
    assert wait_until(lambda: all(emulator.register(i, ct.LED) == 1 for i in IDS))
    time.sleep(0.05)
    assert port.getBytesAvailable() == 0
    assert emulator.stats().replies == replies_before


def test_sync_write_sync_read_and_bulk_read(sdk, emulator: EmulatorProcess) -> None:
    port, packet = sdk
    for servo_id in IDS:
        assert packet.write1ByteTxRx(port, servo_id, ct.TORQUE_ENABLE.address, 1) == (COMM_SUCCESS, 0)
    writer = GroupSyncWrite(port, packet, ct.GOAL_POSITION.address, 4)
    goals = {i: 2048 + 40 * i for i in IDS}
    for i, goal in goals.items():
        writer.addParam(i, list(goal.to_bytes(4, "little")))
    assert writer.txPacket() == COMM_SUCCESS
    reader = GroupSyncRead(port, packet, ct.PRESENT_STATE_ADDRESS, ct.PRESENT_STATE_LENGTH)
    for i in IDS:
        reader.addParam(i)

    def settled() -> bool:
        assert reader.txRxPacket() == COMM_SUCCESS
        return all(abs(reader.getData(i, ct.PRESENT_POSITION.address, 4) - goals[i]) <= 2 for i in IDS)

    assert wait_until(settled)
    bulk = GroupBulkRead(port, packet)
    assert bulk.addParam(2, ct.GOAL_POSITION.address, 4)
    assert bulk.addParam(9, ct.HARDWARE_ERROR_STATUS.address, 1)
    assert bulk.txRxPacket() == COMM_SUCCESS
    assert bulk.getData(2, ct.GOAL_POSITION.address, 4) == goals[2]
    assert bulk.getData(9, ct.HARDWARE_ERROR_STATUS.address, 1) == 0
    # Velocity and current are signed: moving back gives negative values.
    writer.changeParam(3, list((2048 - 400).to_bytes(4, "little")))
    assert writer.txPacket() == COMM_SUCCESS
    time.sleep(0.02)
    assert reader.txRxPacket() == COMM_SUCCESS
    assert to_signed(reader.getData(3, ct.PRESENT_VELOCITY.address, 4), 4) < 0
    assert to_signed(reader.getData(3, ct.PRESENT_CURRENT.address, 2), 2) < 0


def test_instruction_with_bad_crc_gets_a_crc_error(emulator: EmulatorProcess) -> None:
    with serial.Serial(emulator.port, 1_000_000, timeout=0.5) as raw:
        good = encode_instruction(6, Instruction.PING)
        raw.write(good[:-2] + bytes((good[-2] ^ 0x55, good[-1])))
        reply = raw.read(11)
    (status,) = list(PacketParser().feed(reply, now_s=0.0))
    assert (status.servo_id, status.params[0]) == (6, StatusError.CRC)
    assert emulator.stats().crc_errors == 1


def test_status_return_level_and_profile(sdk, emulator: EmulatorProcess) -> None:
    port, packet = sdk
    assert packet.write1ByteTxOnly(port, 8, ct.STATUS_RETURN_LEVEL.address, 1) == COMM_SUCCESS
    # Level 1: reads are answered, writes are not.
    assert packet.write4ByteTxRx(port, 8, ct.PROFILE_VELOCITY.address, 20)[0] == COMM_RX_TIMEOUT
    assert packet.read4ByteTxRx(port, 8, ct.PROFILE_VELOCITY.address) == (20, COMM_SUCCESS, 0)
    packet.write1ByteTxOnly(port, 8, ct.TORQUE_ENABLE.address, 1)
    packet.write4ByteTxOnly(port, 8, ct.GOAL_POSITION.address, 3072)
    # 20 units = 4.58 rpm = 0.48 rad/s: a quarter turn takes about 3.3 s, so after 0.3 s the
    # trajectory has covered about 0.14 rad = 94 pulses.
    time.sleep(0.3)
    traj, result, _ = packet.read4ByteTxRx(port, 8, ct.POSITION_TRAJECTORY.address)
    assert result == COMM_SUCCESS and 2048 + 50 < traj < 2048 + 150
    velocity, _, _ = packet.read4ByteTxRx(port, 8, ct.VELOCITY_TRAJECTORY.address)
    assert velocity == 20


def test_hardware_error_sets_the_alert_bit_and_torque_off(sdk, emulator: EmulatorProcess) -> None:
    port, packet = sdk
    emulator.inject(Fault(FaultKind.OVERHEATING, servo_id=2))
    assert packet.write1ByteTxRx(port, 2, ct.TORQUE_ENABLE.address, 1) == (COMM_SUCCESS, 0)
    assert wait_until(lambda: emulator.register(2, ct.HARDWARE_ERROR_STATUS) != 0)
    model, result, error = packet.ping(port, 2)
    assert result == COMM_SUCCESS and error & ALERT_BIT
    assert packet.read1ByteTxRx(port, 2, ct.HARDWARE_ERROR_STATUS.address)[0] == ct.HardwareError.OVERHEATING
    assert packet.read1ByteTxRx(port, 2, ct.TORQUE_ENABLE.address)[0] == 0
    # Torque cannot come back until the servo is rebooted.
    assert packet.write1ByteTxRx(port, 2, ct.TORQUE_ENABLE.address, 1) == (
        COMM_SUCCESS, ALERT_BIT | StatusError.RESULT_FAIL)
    assert packet.ping(port, 3) == (ct.XH540_W270_MODEL_NUMBER, COMM_SUCCESS, 0)


def test_offsets_and_directions_are_emulated() -> None:
    joints = [JointConfig(k, 20 + k, zero_offset_rad=0.0, direction=1) for k in range(1, 12)]
    joints[1] = JointConfig(2, 22, zero_offset_rad=0.1, direction=-1)
    with BusEmulator(KinematicPlant(q0=[0.0, 0.3] + [0.0] * 9), joints=joints) as emu:
        # joint 2 at 0.3 rad: servo angle 0.1 - 0.3 = -0.2 rad = 2048 - 130.4 pulses.
        assert emu.register(22, ct.PRESENT_POSITION) == 2048 - 130
        assert emu.register(21, ct.PRESENT_POSITION) == 2048


def test_encoder_offsets_shift_the_reading_and_the_loop_acts_on_it() -> None:
    # A mis-set encoder zero: the servo reads joint angle + offset and holds its goal in those
    # readings, so the joint really stands at goal - offset.
    offsets = np.zeros(11)
    offsets[4] = 0.05
    with BusEmulator(KinematicPlant(), encoder_offsets_rad=offsets) as emu:
        assert emu.register(5, ct.PRESENT_POSITION) == 2048 + round(0.05 * 4096 / (2 * np.pi))
        port = PortHandler(emu.port)
        assert port.openPort()
        packet = PacketHandler(2.0)
        goal = 2048 + 200  # 0.307 rad read on every servo
        for i in IDS:
            assert packet.write4ByteTxRx(port, i, ct.GOAL_POSITION.address, goal)[0] == COMM_SUCCESS
            assert packet.write1ByteTxRx(port, i, ct.TORQUE_ENABLE.address, 1)[0] == COMM_SUCCESS
        assert wait_until(lambda: emu.register(5, ct.PRESENT_POSITION) == goal)
        port.closePort()
        q = emu._q  # the plant's joint angles
    assert q[4] == pytest.approx(200 * 2 * np.pi / 4096 - 0.05, abs=2 * np.pi / 4096)
    assert q[3] == pytest.approx(200 * 2 * np.pi / 4096, abs=2 * np.pi / 4096)


def test_the_bus_watchdog_stops_a_servo_that_hears_nothing(sdk, emulator: EmulatorProcess) -> None:
    port, packet = sdk
    assert packet.write1ByteTxRx(port, 3, ct.BUS_WATCHDOG.address, 5)[0] == COMM_SUCCESS  # 100 ms
    assert packet.write1ByteTxRx(port, 3, ct.TORQUE_ENABLE.address, 1)[0] == COMM_SUCCESS
    assert packet.write4ByteTxRx(port, 3, ct.GOAL_POSITION.address, 2100)[0] == COMM_SUCCESS
    time.sleep(0.3)  # silence
    assert emulator.stats().watchdog_stops_s.keys() == {3}
    assert to_signed(packet.read1ByteTxRx(port, 3, ct.BUS_WATCHDOG.address)[0], 1) == -1
    # goals are refused until the watchdog is cleared with 0; a new setting is refused too
    assert packet.write4ByteTxRx(port, 3, ct.GOAL_POSITION.address, 2200) == (COMM_SUCCESS, StatusError.ACCESS)
    assert packet.write1ByteTxRx(port, 3, ct.BUS_WATCHDOG.address, 5) == (COMM_SUCCESS, StatusError.ACCESS)
    assert packet.write1ByteTxRx(port, 3, ct.BUS_WATCHDOG.address, 0) == (COMM_SUCCESS, 0)
    assert packet.write4ByteTxRx(port, 3, ct.GOAL_POSITION.address, 2200) == (COMM_SUCCESS, 0)
    # torque off: an armed watchdog does not act
    assert packet.write1ByteTxRx(port, 4, ct.BUS_WATCHDOG.address, 5)[0] == COMM_SUCCESS
    time.sleep(0.3)
    assert emulator.stats().watchdog_stops_s.keys() == {3}


def test_a_stall_of_the_emulator_itself_is_not_the_hosts_silence() -> None:
    # The emulator's thread stalls 250 ms (its lock held) while the host keeps sending a goal
    # every 40 ms (within the 100 ms watchdog): the queued packets are read at once, then the
    # plant catches up in fast steps of emulated time. A servo counts the host's silence in
    # real time, so nothing trips; when the host then falls silent, it does.
    import threading

    with BusEmulator(KinematicPlant()) as emu:
        port = PortHandler(emu.port)
        assert port.openPort()
        packet = PacketHandler(2.0)
        assert packet.write1ByteTxRx(port, 3, ct.BUS_WATCHDOG.address, 5)[0] == COMM_SUCCESS  # 100 ms
        assert packet.write1ByteTxRx(port, 3, ct.TORQUE_ENABLE.address, 1)[0] == COMM_SUCCESS

        def stall() -> None:
            with emu._lock:
                time.sleep(0.25)

        staller = threading.Thread(target=stall)
        staller.start()
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            packet.write4ByteTxOnly(port, 3, ct.GOAL_POSITION.address, 2100)
            time.sleep(0.04)
        staller.join()
        stats = emu.stats()
        assert stats.wall_time_s - stats.emulated_time_s > 0.1  # the stall happened: emulated time slipped
        assert stats.watchdog_stops_s == {}
        time.sleep(0.3)  # now the host is silent
        assert emu.stats().watchdog_stops_s.keys() == {3}
        port.closePort()


def test_port_link_is_a_symlink_and_never_replaces_a_file(tmp_path: Path, emulator: EmulatorProcess) -> None:
    link = tmp_path / "cobra-bus"
    link.symlink_to("/nonexistent/old-pty")
    emulator.link(link)
    assert link.resolve() == Path(emulator.port).resolve()
    plain = tmp_path / "plain"
    plain.write_text("keep me")
    with pytest.raises(FileExistsError, match="plain exists and is not a symlink"):
        emulator.link(plain)
    assert plain.read_text() == "keep me"
    emulator.stop()
    assert not link.exists() and not link.is_symlink()


class _SlowPlant(KinematicPlant):
    """Ideal servos that need 2 s of computation per second of motion."""

    def advance(self, dt_total: float, goal_rad: np.ndarray, torque_on: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        time.sleep(2.0 * dt_total)
        return super().advance(dt_total, goal_rad, torque_on)


def test_a_plant_slower_than_real_time_runs_on_emulated_time() -> None:
    with EmulatorProcess(_SlowPlant) as emu:
        port = PortHandler(emu.port)
        assert port.openPort()
        packet = PacketHandler(2.0)
        time.sleep(0.6)
        for servo_id in IDS:  # the bus is still served between plant steps
            assert packet.ping(port, servo_id)[1] == COMM_SUCCESS
        stats = emu.stats()
        port.closePort()
    assert 0.3 < stats.real_time_factor < 0.6
    assert stats.emulated_time_s < 0.6 * stats.wall_time_s
