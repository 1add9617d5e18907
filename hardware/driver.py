"""Driver of COBRA's servo bus through ROBOTIS's ``dynamixel_sdk`` (Protocol 2.0).

:class:`DynamixelBus` owns the serial port and speaks to the 11 servos in joint units:

* :meth:`DynamixelBus.connect` opens the port, pings every ID and checks its model number and
  hardware error status, turns torque off, writes the operating mode, PWM limit and position
  limits (EEPROM: only when they differ), the position gains and the profile, and leaves
  torque off;
  :meth:`DynamixelBus.torque_on` then holds the present pose and arms each servo's Bus
  Watchdog (98) before enabling torque, so nothing jumps, and a servo that stops hearing the
  host (pulled cable, frozen or killed host) stops by itself after ``bus_watchdog_ms``.
* :meth:`DynamixelBus.send_goal` clamps joint angles to the configured limit and sends them
  with one GroupSyncWrite (broadcast, no reply).
* :meth:`DynamixelBus.read_state` reads Present Current, Velocity and Position of every servo
  with one GroupSyncRead and converts them to A, rad/s and rad; a failed read is retried.
* :meth:`DynamixelBus.torque_off` broadcasts Torque Enable = 0 and then asks each servo to
  confirm, so the caller can say exactly which servos are known to be off.

Errors that end a session are :class:`BusError` subclasses whose message says what failed,
on which joint and servo ID. A vanished port (USB cable pulled, pty closed) raises
:class:`Disconnected` from whichever call notices it.
"""
from __future__ import annotations

import termios
import time
from dataclasses import dataclass
from typing import Callable, TypeVar

import numpy as np
from dynamixel_sdk import COMM_SUCCESS, GroupSyncRead, GroupSyncWrite, PacketHandler, PortHandler

from hardware import control_table as ct
from hardware.config import BusConfig
from hardware.control_table import HardwareError, OperatingMode, describe_hardware_error
from hardware.protocol import ALERT_BIT
from hardware.units import (
    current_units_to_amp,
    joint_to_servo_rad,
    pulses_to_rad,
    rad_to_pulses,
    servo_to_joint_rad,
    to_signed,
    velocity_units_to_rad_s,
)

T = TypeVar("T")

#: Longest wait [s] of one read of the serial port (see :meth:`DynamixelBus.open`).
READ_POLL_S = 0.001
#: Wait [s] after a failed read before the port is flushed of late replies.
LATE_REPLY_WAIT_S = 0.002
#: Every bit Hardware Error Status (70) defines.
KNOWN_ERROR_BITS = int(sum(HardwareError))


def _os_error_text(exc: BaseException) -> str:
    """Readable text of an OS-level error (``termios.error`` only carries ``(errno, text)``)."""
    if isinstance(exc, termios.error) and len(exc.args) == 2:
        return f"{exc.args[1]} (errno {exc.args[0]})"
    return str(exc)


class BusError(Exception):
    """The bus cannot be used (or no longer): the message says what failed and where."""


class ConnectError(BusError):
    """Connecting failed: a servo is missing, of the wrong model, in error, or refused a write."""


class Disconnected(BusError):
    """The serial port itself failed (cable or adapter unplugged, pty closed)."""


@dataclass(frozen=True)
class JointState:
    """One reading of every joint, in joint order.

    Attributes:
        q_rad: (11,) joint angles [rad].
        dq_rad_s: (11,) joint velocities [rad/s].
        current_a: (11,) motor currents [A] (sign of the joint direction).
    """

    q_rad: np.ndarray
    dq_rad_s: np.ndarray
    current_a: np.ndarray


@dataclass(frozen=True)
class TorqueOffReport:
    """What :meth:`DynamixelBus.torque_off` achieved.

    Attributes:
        confirmed: IDs that acknowledged Torque Enable = 0.
        unconfirmed: IDs that did not answer (the broadcast may still have reached them).
        port_error: why nothing could be sent (port gone), or None.
    """

    confirmed: tuple[int, ...]
    unconfirmed: tuple[int, ...]
    port_error: str | None = None

    def describe(self, joint_of: dict[int, int]) -> str:
        """One sentence for the operator."""
        if self.port_error is not None:
            return (f"torque off could NOT be sent ({self.port_error}); "
                    "the servos hold their last goal: cut their power")
        if not self.unconfirmed:
            return f"torque off on all {len(self.confirmed)} servos"
        missing = ", ".join(f"joint {joint_of[i]} (ID {i})" for i in self.unconfirmed)
        return (f"torque off broadcast; confirmed by {len(self.confirmed)} servos, "
                f"not by {missing}")


@dataclass
class CommStats:
    """Counters of the streaming transactions since connect.

    Attributes:
        reads_ok: state reads that succeeded (retries included).
        reads_failed: read attempts (state or Hardware Error Status) that failed.
        retries: state reads repeated after a failure within the same cycle.
        last_failure: the SDK's text of the last failure, or "".
    """

    reads_ok: int = 0
    reads_failed: int = 0
    retries: int = 0
    last_failure: str = ""


class DynamixelBus:
    """The 11 servos of COBRA on one serial port.

    Args:
        config: the validated bus configuration.
        read_retries: extra attempts of a failed state read within one call of
            :meth:`read_state` (a corrupted or lost reply is usually a one-off).
        connect_retries: attempts of each ping and configuration write at connect.
    """

    def __init__(self, config: BusConfig, *, read_retries: int = 1, connect_retries: int = 5) -> None:
        self.config = config
        self.read_retries = read_retries
        self.connect_retries = connect_retries
        self.stats = CommStats()
        self._ids = config.servo_ids
        self._joint_of = {j.servo_id: j.joint for j in config.joints}
        self._offsets = config.zero_offsets_rad
        self._directions = config.directions
        self._port = PortHandler(config.port)
        self._packet = PacketHandler(2.0)
        self._goal_writer = GroupSyncWrite(self._port, self._packet, ct.GOAL_POSITION.address,
                                           ct.GOAL_POSITION.size)
        self._torque_writer = GroupSyncWrite(self._port, self._packet, ct.TORQUE_ENABLE.address,
                                             ct.TORQUE_ENABLE.size)
        self._state_reader = GroupSyncRead(self._port, self._packet, ct.PRESENT_STATE_ADDRESS,
                                           ct.PRESENT_STATE_LENGTH)
        self._error_reader = GroupSyncRead(self._port, self._packet, ct.HARDWARE_ERROR_STATUS.address,
                                           ct.HARDWARE_ERROR_STATUS.size)
        self._watchdog_reader = GroupSyncRead(self._port, self._packet, ct.BUS_WATCHDOG.address,
                                              ct.BUS_WATCHDOG.size)
        for servo_id in self._ids:
            self._goal_writer.addParam(servo_id, [0] * ct.GOAL_POSITION.size)
            self._torque_writer.addParam(servo_id, [0])
            self._state_reader.addParam(servo_id)
            self._error_reader.addParam(servo_id)
            self._watchdog_reader.addParam(servo_id)

    # -- naming -------------------------------------------------------------------------------
    def name(self, servo_id: int) -> str:
        """``"joint 3 (ID 3)"`` for messages."""
        return f"joint {self._joint_of[servo_id]} (ID {servo_id})"

    @property
    def joint_of(self) -> dict[int, int]:
        """Joint number of each servo ID."""
        return dict(self._joint_of)

    # -- port ---------------------------------------------------------------------------------
    def _guard(self, call: Callable[..., T], *args: object) -> T:
        """Run one SDK call, turning a failed port into :class:`Disconnected`."""
        try:
            return call(*args)
        except (OSError, termios.error) as exc:
            # The SDK leaves its "port in use" flag set when a call dies half-way.
            self._port.is_using = False
            raise Disconnected(f"serial port {self.config.port} failed: {_os_error_text(exc)}") from exc

    def open(self) -> None:
        """Open the port at the configured baud rate.

        Raises:
            ConnectError: the port cannot be opened.
        """
        try:
            opened = self._port.openPort() and self._port.setBaudRate(self.config.baud_rate)
            if opened:
                # The SDK opens the port with a zero read timeout and polls it in a busy loop
                # while it waits for a reply, burning a whole core. With a short timeout each
                # poll sleeps in select() until bytes arrive: same latency, the CPU left to
                # the rest of the machine (on the robot's computer, or an emulator).
                self._port.ser.timeout = READ_POLL_S
        except (OSError, termios.error) as exc:
            raise ConnectError(f"cannot open serial port {self.config.port}: {_os_error_text(exc)}") from exc
        if not opened:
            raise ConnectError(f"cannot open serial port {self.config.port} at {self.config.baud_rate} baud")

    def close(self) -> None:
        """Close the port (torque is not touched: call :meth:`torque_off` first)."""
        if self._port.is_open:
            try:
                self._port.closePort()
            except (OSError, termios.error):
                self._port.is_open = False

    # -- connect ------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the port, check every servo and write the configuration (torque stays off).

        Raises:
            ConnectError: a servo is missing, of another model, reports a hardware error, or
                refused a configuration write; the message lists every problem found.
            Disconnected: the port failed.
        """
        self.open()
        problems = []
        alerts = []
        for servo_id in self._ids:
            model, result, error = self._ping(servo_id, self.connect_retries)
            if result != COMM_SUCCESS:
                problems.append(f"{self.name(servo_id)}: no answer to ping "
                                f"({self._packet.getTxRxResult(result)})")
            elif model != self.config.servo.model_number:
                problems.append(f"{self.name(servo_id)}: model number {model}, expected "
                                f"{self.config.servo.model_number}")
            elif error & ALERT_BIT:
                alerts.append(servo_id)
        for servo_id in alerts:
            bits, result, _ = self._guard(self._packet.read1ByteTxRx, self._port, servo_id,
                                          ct.HARDWARE_ERROR_STATUS.address)
            what = describe_hardware_error(bits) if result == COMM_SUCCESS else "unreadable status"
            problems.append(f"{self.name(servo_id)}: hardware error ({what}); "
                            "reboot or power-cycle the servo")
        if problems:
            raise ConnectError(f"bus on {self.config.port}: " + "; ".join(problems))
        servo = self.config.servo
        writes = (
            (ct.TORQUE_ENABLE, 0),
            (ct.BUS_WATCHDOG, 0),  # off, which also clears a watchdog stop of an earlier session
            (ct.OPERATING_MODE, int(servo.operating_mode)),
            (ct.PWM_LIMIT, servo.pwm_limit),
            (ct.POSITION_P_GAIN, servo.position_p_gain),
            (ct.POSITION_I_GAIN, servo.position_i_gain),
            (ct.POSITION_D_GAIN, servo.position_d_gain),
            (ct.PROFILE_ACCELERATION, servo.profile_acceleration),
            (ct.PROFILE_VELOCITY, servo.profile_velocity),
        )
        for field, value in writes:
            for servo_id in self._ids:
                self._write(servo_id, field, value)
        if servo.operating_mode is OperatingMode.POSITION:  # the other modes ignore these limits
            # The servo itself then refuses a goal beyond the joint limit (Data Limit error).
            for servo_id, (low, high) in zip(self._ids, self.config.position_limits_pulses()):
                self._write(servo_id, ct.MIN_POSITION_LIMIT, low)
                self._write(servo_id, ct.MAX_POSITION_LIMIT, high)

    def broadcast_ping(self) -> dict[int, int]:
        """Every ID that answers a broadcast ping -> its model number (a servo whose reply
        collided or was lost is missing: ping it on its own)."""
        data, result = self._guard(self._packet.broadcastPing, self._port)
        if result != COMM_SUCCESS:
            return {}
        return {int(i): int(info[0]) for i, info in data.items()}

    def ping_model(self, servo_id: int) -> int | None:
        """The model number ``servo_id`` answers (``connect_retries`` attempts), or None."""
        model, result, _ = self._ping(servo_id, self.connect_retries)
        return int(model) if result == COMM_SUCCESS else None

    def read_register(self, servo_id: int, field: ct.Field) -> int | None:
        """One register of one servo (signed where the field is; ``connect_retries`` attempts),
        or None when it does not answer."""
        reader = {1: self._packet.read1ByteTxRx, 2: self._packet.read2ByteTxRx,
                  4: self._packet.read4ByteTxRx}[field.size]
        for _ in range(self.connect_retries):
            value, result, _ = self._guard(reader, self._port, servo_id, field.address)
            if result == COMM_SUCCESS:
                return to_signed(value, field.size) if field.signed else int(value)
        return None

    def _ping(self, servo_id: int, attempts: int) -> tuple[int, int, int]:
        for _ in range(attempts):
            model, result, error = self._guard(self._packet.ping, self._port, servo_id)
            if result == COMM_SUCCESS:
                break
        return model, result, error

    def _write(self, servo_id: int, field: ct.Field, value: int) -> None:
        """Write one register with confirmation, retrying; raise :class:`ConnectError` if refused.

        EEPROM fields are read first and written only when they differ (EEPROM wears out).
        """
        raw = value & ((1 << (8 * field.size)) - 1)
        if field.eeprom and self.read_register(servo_id, field) == value:
            return
        writer = {1: self._packet.write1ByteTxRx, 2: self._packet.write2ByteTxRx,
                  4: self._packet.write4ByteTxRx}[field.size]
        for _ in range(self.connect_retries):
            result, error = self._guard(writer, self._port, servo_id, field.address, raw)
            if result == COMM_SUCCESS and not error & ~ALERT_BIT:
                return
        if result != COMM_SUCCESS:
            reason = self._packet.getTxRxResult(result)
        else:
            reason = self._packet.getRxPacketError(error & ~ALERT_BIT)
            if error & ALERT_BIT:
                reason += " (the servo reports a hardware error)"
        raise ConnectError(f"{self.name(servo_id)} refused {field.name} ({field.address}) = {value}: {reason}")

    def torque_on(self) -> JointState:
        """Hold the present pose (goal = present position, clamped to the joint limits), arm
        the Bus Watchdog (``config.bus_watchdog_ms``), then enable torque on every servo.

        Returns:
            The measured pose.

        Raises:
            ConnectError: the present pose cannot be read or a servo refuses torque.
        """
        state = None
        for _ in range(self.connect_retries):
            state = self.read_state()
            if state is not None:
                break
        if state is None:
            raise ConnectError(f"cannot read the present pose before torque on: {self.stats.last_failure}")
        self.send_goal(state.q_rad)
        units = round(self.config.bus_watchdog_ms * 1e-3 / ct.BUS_WATCHDOG_UNIT_S)
        for servo_id in self._ids:
            self._write(servo_id, ct.BUS_WATCHDOG, units)
        for servo_id in self._ids:
            self._write(servo_id, ct.TORQUE_ENABLE, 1)
        return state

    # -- streaming ----------------------------------------------------------------------------
    def clamp(self, q_rad: np.ndarray) -> np.ndarray:
        """Joint angles [rad] limited to +- the configured joint limit."""
        limit = self.config.joint_limit_rad
        return np.clip(np.asarray(q_rad, dtype=float), -limit, limit)

    def send_goal(self, q_rad: np.ndarray) -> np.ndarray:
        """Send goal joint angles (11,) [rad] to every servo in one Sync Write.

        Args:
            q_rad: goal joint angles in joint order [rad].

        Returns:
            (11,) the joint angles actually sent [rad] (clamped, before pulse rounding).

        Raises:
            BusError: the packet could not be sent.
        """
        q_cmd = self.clamp(q_rad)
        pulses = rad_to_pulses(joint_to_servo_rad(q_cmd, self._offsets, self._directions))
        for servo_id, value in zip(self._ids, pulses):
            self._goal_writer.changeParam(servo_id, list((int(value) & 0xFFFFFFFF).to_bytes(4, "little")))
        result = self._guard(self._goal_writer.txPacket)
        if result != COMM_SUCCESS:
            raise BusError(f"cannot send goal positions on {self.config.port}: "
                           f"{self._packet.getTxRxResult(result)}")
        return q_cmd

    def read_state(self) -> JointState | None:
        """Present current, velocity and position of every servo, or None when the read failed.

        A failed read (no reply, corrupted or malformed reply) is retried ``read_retries``
        times; failures are counted in :attr:`stats`.
        """
        for attempt in range(1 + self.read_retries):
            if attempt:
                self.stats.retries += 1
            result = self._guard(self._state_reader.txRxPacket)
            if result == COMM_SUCCESS:
                try:
                    state = self._decode_state()
                except IndexError:  # a status packet shorter than asked for
                    self._failed("malformed reply (too short)")
                    continue
                self.stats.reads_ok += 1
                return state
            self._failed(self._packet.getTxRxResult(result))
        return None

    def _failed(self, why: str) -> None:
        """Count a failed read and drain the port.

        A reply that comes after the SDK stopped waiting would otherwise be taken for the
        answer to the next request: the SDK matches replies by servo ID only.
        """
        self.stats.reads_failed += 1
        self.stats.last_failure = why
        time.sleep(LATE_REPLY_WAIT_S)
        self._guard(self._port.clearPort)

    def _decode_state(self) -> JointState:
        reader = self._state_reader
        cur = np.array([to_signed(reader.getData(i, ct.PRESENT_CURRENT.address, 2), 2) for i in self._ids])
        vel = np.array([to_signed(reader.getData(i, ct.PRESENT_VELOCITY.address, 4), 4) for i in self._ids])
        pos = np.array([to_signed(reader.getData(i, ct.PRESENT_POSITION.address, 4), 4) for i in self._ids])
        return JointState(
            q_rad=servo_to_joint_rad(pulses_to_rad(pos), self._offsets, self._directions),
            dq_rad_s=self._directions * velocity_units_to_rad_s(vel),
            current_a=self._directions * current_units_to_amp(cur),
        )

    def read_hardware_errors(self) -> dict[int, int] | None:
        """Hardware Error Status of every servo: ``{id: bits}`` of those with bits set.

        Bits set are confirmed by a second read before they are reported (a corrupted or
        misattributed reply must not stop the robot), and a value with bits the XH540 does not
        define counts as a failed read.

        Returns:
            The servos in error (empty when none), or None when the read failed.
        """
        first = self._read_error_bits()
        if not first:
            return first
        second = self._read_error_bits()
        if second is None:
            return None
        return {i: bits for i, bits in second.items() if first.get(i)}

    def _read_error_bits(self) -> dict[int, int] | None:
        result = self._guard(self._error_reader.txRxPacket)
        if result != COMM_SUCCESS:
            self._failed(self._packet.getTxRxResult(result))
            return None
        errors = {i: self._error_reader.getData(i, ct.HARDWARE_ERROR_STATUS.address, 1) for i in self._ids}
        if any(bits & ~KNOWN_ERROR_BITS for bits in errors.values()):
            self._failed("Hardware Error Status with undefined bits (corrupted reply)")
            return None
        return {i: bits for i, bits in errors.items() if bits}

    def read_watchdog_stops(self) -> list[int] | None:
        """IDs whose Bus Watchdog has stopped them (register -1: they heard nothing for
        ``bus_watchdog_ms`` and now refuse goals), or None when the read failed."""
        result = self._guard(self._watchdog_reader.txRxPacket)
        if result != COMM_SUCCESS:
            self._failed(self._packet.getTxRxResult(result))
            return None
        return [i for i in self._ids if to_signed(self._watchdog_reader.getData(i, ct.BUS_WATCHDOG.address, 1), 1)
                == ct.BUS_WATCHDOG_TRIPPED]

    def find_silent_servos(self) -> list[int]:
        """IDs that do not answer a ping (two attempts each; ~70 ms per silent servo)."""
        return [i for i in self._ids if self._ping(i, 2)[1] != COMM_SUCCESS]

    def torque_off(self) -> TorqueOffReport:
        """Broadcast Torque Enable = 0 twice, then write it to each servo with confirmation
        (two attempts each).

        Never raises: a failed port is reported in :attr:`TorqueOffReport.port_error`.
        """
        if not self._port.is_open:
            return TorqueOffReport((), self._ids, port_error=f"serial port {self.config.port} is not open")
        self._port.is_using = False  # an interrupted SDK call may have left it set
        try:
            for _ in range(2):
                self._guard(self._torque_writer.txPacket)
            confirmed, unconfirmed = [], []
            for servo_id in self._ids:
                for _ in range(2):  # one lost reply must not leave a servo "unconfirmed"
                    result, _ = self._guard(self._packet.write1ByteTxRx, self._port, servo_id,
                                            ct.TORQUE_ENABLE.address, 0)
                    if result == COMM_SUCCESS:
                        break
                (confirmed if result == COMM_SUCCESS else unconfirmed).append(servo_id)
        except Disconnected as exc:
            return TorqueOffReport((), self._ids, port_error=str(exc))
        return TorqueOffReport(tuple(confirmed), tuple(unconfirmed))
