"""A Protocol 2.0 servo-bus emulator on a pseudo-terminal: COBRA's 11 XH540-W270 on a wire.

:class:`BusEmulator` opens a pty, answers on its master side as the daisy chain of servos
would, and moves the servos with a :class:`~hardware.plant.Plant` (the simulator of COBRA by
default in ``cobra emulate``). Any Protocol 2.0 client, ``dynamixel_sdk`` included, opens the
pty's slave path (or a symlink to it) as a serial port.

What is emulated:

* each servo's control table (:mod:`hardware.control_table`): EEPROM writable only with torque
  off, read-only fields, value ranges (Data Range error), goal positions outside the position
  limits (Data Limit error), Status Return Level, Hardware Error Status with the alert bit in
  every status packet and torque off as the Shutdown register says;
* the Bus Watchdog (98): a servo with torque on that receives no instruction packet (addressed
  to it or broadcast) for longer than its setting stops where it is; the register then reads
  -1 and goal writes are refused (Access error) until 0 is written;
* encoder offsets (``encoder_offsets_rad``): each encoder reads the joint angle plus a constant
  that the driver's configuration does not know (a mis-set zero), and the servo's position loop
  acts on that reading, as a real one would;
* instructions ping, read, write, sync read, sync write and bulk read, unicast or broadcast
  (broadcasts of write and sync write get no reply; sync and bulk reads are answered servo by
  servo in the requested order); other instructions get an Instruction error;
* instruction packets are parsed with header search, byte stuffing and CRC-16 checks; a packet
  with a wrong CRC is answered with a CRC error by the addressed servo;
* the velocity-based profile (Profile Velocity/Acceleration) that turns Goal Position into
  Position Trajectory, which the plant then tracks;
* faults (:mod:`hardware.faults`): corrupted CRCs, dropped replies, a servo falling silent,
  hardware error bits (with the input voltage sagging in a brownout), a cut bus cable, a
  pulled USB cable.

Timing: one thread serves the bus and steps the plant, so packets are answered between plant
steps, never during one. The plant follows the wall clock: whenever it is at least
``physics_period_s`` behind, it is advanced by what it lags, in steps of at most
``max_advance_s`` with the bus served in between. A lag longer than ``max_lag_s`` (the plant is
slower than real time, or the process was starved) is given up: the emulator then runs on
"emulated time", which falls behind the wall clock, and :meth:`BusEmulator.stats` reports the
real-time factor (emulated / wall time). Replies are sent as soon as a packet is parsed (no
return delay).

:class:`EmulatorProcess` runs a :class:`BusEmulator` in a child process, controlled through a
pipe, for a client in the same program (tests, scripts) that must not share an interpreter
with the emulated servos.
"""
from __future__ import annotations

import dataclasses
import errno
import multiprocessing
import os
import select
import threading
import time
import tty
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from cobra_model.design import NUM_JOINTS
from cobra_model.errors import InputError
from hardware import control_table as ct
from hardware.config import JointConfig
from hardware.control_table import POSITION_MODES, ControlTable, HardwareError, OperatingMode
from hardware.faults import BROWNOUT_VOLTAGE_V, HARDWARE_FAULT_BITS, Fault, FaultKind
from hardware.plant import Plant
from hardware.protocol import (
    ALERT_BIT,
    BROADCAST_ID,
    Instruction,
    Packet,
    PacketParser,
    StatusError,
    encode_status,
)
from hardware.units import (
    RAD_S2_PER_ACCELERATION_UNIT,
    RAD_S_PER_VELOCITY_UNIT,
    amp_to_current_units,
    joint_to_servo_rad,
    pulses_to_rad,
    rad_s_to_velocity_units,
    rad_to_pulses,
    servo_to_joint_rad,
)

#: Status Return Level (68) values: which instructions get a status packet.
_REPLY_PING_ONLY, _REPLY_READS, _REPLY_ALL = 0, 1, 2
_READ_INSTRUCTIONS = {Instruction.PING, Instruction.READ, Instruction.SYNC_READ, Instruction.BULK_READ}
_INT16 = (-(1 << 15), (1 << 15) - 1)
_OPERATING_MODES = frozenset(int(m) for m in OperatingMode)


def default_joints() -> tuple[JointConfig, ...]:
    """IDs 1..11 on joints 1..11, no zero offsets, all directions +1."""
    return tuple(JointConfig(k, k) for k in range(1, NUM_JOINTS + 1))


@dataclass
class EmulatorStats:
    """Counters and clocks of a running emulator (a snapshot).

    Attributes:
        wall_time_s: wall time since start [s].
        emulated_time_s: time the plant has advanced [s].
        real_time_factor: emulated / wall time (1 when the plant keeps up).
        packets: instruction packets parsed (any CRC).
        crc_errors: of those, with a wrong CRC.
        replies: status packets sent.
        dropped: status packets withheld by a ``drop`` fault.
        corrupted: status packets sent with a wrong CRC by a ``crc`` fault.
        intact_sync_reads: sync reads every addressed servo answered intact, by start address.
        watchdog_stops_s: servo ID -> when its Bus Watchdog stopped it [s of emulated time after
            the first torque on, like fault times].
        watchdog_heard_s: servo ID -> when it last heard the host before its watchdog stopped
            it [same clock]: the silence the watchdog timed began there.
        torque_off_s: servo ID -> when its torque last went off (a write or its Shutdown) [same
            clock].
        closed: the pty is closed (stopped, unplugged or failed).
        error: why the emulator failed (e.g. the simulation diverged), or None.
        notes: remarks for the operator (e.g. about gains the plant cannot take).
    """

    wall_time_s: float = 0.0
    emulated_time_s: float = 0.0
    real_time_factor: float = 1.0
    packets: int = 0
    crc_errors: int = 0
    replies: int = 0
    dropped: int = 0
    corrupted: int = 0
    intact_sync_reads: dict[int, int] = field(default_factory=dict)
    watchdog_stops_s: dict[int, float] = field(default_factory=dict)
    watchdog_heard_s: dict[int, float] = field(default_factory=dict)
    torque_off_s: dict[int, float] = field(default_factory=dict)
    closed: bool = False
    error: str | None = None
    notes: list[str] = field(default_factory=list)


@dataclass
class _Countdown:
    """An active ``crc`` or ``drop`` fault and the status packets it still spoils."""

    fault: Fault
    left: int


class _Servo:
    """One emulated servo: its control table and its profile generator's state."""

    def __init__(self, joint: JointConfig, model_number: int) -> None:
        self.joint = joint
        self.table = ControlTable(joint.servo_id, model_number)
        self.silent = False
        #: Emulated time [s] of the last instruction packet this servo received.
        self.last_heard_s = 0.0
        #: Wall-clock time [s] (``time.perf_counter``) of that packet; None: nothing heard yet.
        self.last_heard_wall_s: float | None = None
        #: Profile generator state in servo angle [rad] and [rad/s].
        self.traj_rad = 0.0
        self.traj_vel = 0.0

    def error_byte(self, error: StatusError) -> int:
        return int(error) | (ALERT_BIT if self.table.hardware_error else 0)

    def read(self, address: int, length: int) -> tuple[StatusError, bytes]:
        if length < 1 or address + length > ct.TABLE_SIZE:
            return StatusError.ACCESS, b""
        return StatusError.NONE, self.table.read(address, length)

    def check_write(self, address: int, data: bytes) -> StatusError:
        """Why writing ``data`` at ``address`` is refused, or NONE."""
        end = address + len(data)
        fields = ct.fields_in(address, len(data))
        covered = sum(f.size for f in fields)
        if not data or end > ct.TABLE_SIZE or covered != len(data) or any(
                f.address < address or f.end > end for f in fields):
            return StatusError.ACCESS
        for f in fields:
            if not f.writable or (f.eeprom and self.table.torque_enabled):
                return StatusError.ACCESS
        for f in fields:
            raw = int.from_bytes(data[f.address - address:f.end - address], "little")
            value = ct.to_signed(raw, f.size) if f.signed else raw
            if f.valid is not None and not f.valid[0] <= value <= f.valid[1]:
                return StatusError.DATA_RANGE
            if f is ct.OPERATING_MODE and value not in _OPERATING_MODES:
                return StatusError.DATA_RANGE
            if f is ct.GOAL_POSITION and self.table.get(ct.OPERATING_MODE) == OperatingMode.POSITION and not (
                    self.table.get(ct.MIN_POSITION_LIMIT) <= value <= self.table.get(ct.MAX_POSITION_LIMIT)):
                return StatusError.DATA_LIMIT
            if f is ct.TORQUE_ENABLE and value == 1 and self.table.hardware_error:
                return StatusError.RESULT_FAIL
            if self.watchdog_stopped and (f in ct.GOAL_FIELDS or (f is ct.BUS_WATCHDOG and value != 0)):
                return StatusError.ACCESS
        return StatusError.NONE

    @property
    def watchdog_stopped(self) -> bool:
        """The Bus Watchdog has stopped this servo (register -1)."""
        return self.table.get(ct.BUS_WATCHDOG) == ct.BUS_WATCHDOG_TRIPPED

    def watchdog_due(self, now_s: float, now_wall_s: float) -> bool:
        """Torque on, the watchdog armed, and nothing heard for longer than it allows, both in
        emulated time (``now_s``) and on the wall clock (``now_wall_s``, ``time.perf_counter``).

        Why both: after the emulator's own process was starved, it catches the plant up in fast
        steps with the packets that queued meanwhile all read at once before them, so emulated
        time runs ahead of every packet still to come; a real servo counts the host's silence in
        real time, and a host that kept sending is not silent (seen under a loaded test run: a
        trip with every cycle of the host on time)."""
        setting = self.table.get(ct.BUS_WATCHDOG)
        allowed = setting * ct.BUS_WATCHDOG_UNIT_S
        wall_silent = self.last_heard_wall_s is None or now_wall_s - self.last_heard_wall_s > allowed
        return (self.table.torque_enabled and setting > 0
                and now_s - self.last_heard_s > allowed and wall_silent)

    def stop_by_watchdog(self) -> None:
        """Hold where it is and refuse goals (Bus Watchdog Error)."""
        self.table.set(ct.BUS_WATCHDOG, ct.BUS_WATCHDOG_TRIPPED)
        self.table.set(ct.GOAL_POSITION, self.table.get(ct.PRESENT_POSITION))
        self.traj_rad, self.traj_vel = float(pulses_to_rad(self.table.get(ct.PRESENT_POSITION))), 0.0


class BusEmulator:
    """Emulated servo bus on a pty.

    Args:
        plant: what the servos move (joint order).
        joints: how servos are wired to joints (IDs, zero offsets, directions); a recording
            driver must use the same, as it would on the robot it describes. A joint left out
            has no servo on the bus (it stays limp).
        model_number: what pings answer.
        faults: scheduled faults; more can be added with :meth:`inject`.
        encoder_offsets_rad: (11,) what each joint's encoder reads at joint angle 0 [rad, joint
            frame], unknown to the driver (default none).
        physics_period_s: smallest lag behind the wall clock worth a plant step [s].
        max_advance_s: longest single plant step [s] (bounds how long a packet may wait).
        max_lag_s: largest lag that is caught up; beyond it emulated time slips [s].
    """

    def __init__(self, plant: Plant, *, joints: Sequence[JointConfig] | None = None,
                 model_number: int = ct.XH540_W270_MODEL_NUMBER, faults: Sequence[Fault] = (),
                 encoder_offsets_rad: Sequence[float] | None = None, physics_period_s: float = 1e-3,
                 max_advance_s: float = 5e-3, max_lag_s: float = 0.1) -> None:
        self._plant = plant
        self._lock = threading.RLock()
        self._servos = [_Servo(j, model_number) for j in (joints or default_joints())]
        self._by_id = {s.joint.servo_id: s for s in self._servos}
        #: Plant joint index of each servo; joints without a servo on the bus stay limp.
        self._index = np.array([s.joint.joint - 1 for s in self._servos])
        self._q = np.zeros(NUM_JOINTS)
        self._offsets = np.array([s.joint.zero_offset_rad for s in self._servos])
        self._directions = np.array([s.joint.direction for s in self._servos], dtype=float)
        encoder = np.zeros(NUM_JOINTS) if encoder_offsets_rad is None else np.asarray(encoder_offsets_rad, float)
        if encoder.shape != (NUM_JOINTS,) or not np.all(np.isfinite(encoder)):
            raise InputError(f"encoder_offsets_rad: expected {NUM_JOINTS} finite angles [rad] in joint order, "
                             f"got {encoder_offsets_rad!r}")
        #: Encoder offset of each servo's joint [rad].
        self._encoder = encoder[self._index]
        self._faults: list[Fault] = []
        for fault in faults:
            self.inject(fault)
        self._active: list[_Countdown] = []  # active crc/drop faults
        self.physics_period_s = physics_period_s
        self.max_advance_s = max_advance_s
        self.max_lag_s = max_lag_s
        self._slipped_s = 0.0
        self._stop = threading.Event()
        self._closed = threading.Event()
        self._thread: threading.Thread | None = None
        self._parser = PacketParser()
        self._master = self._slave = -1
        self._port = ""
        self._links: list[Path] = []
        self._stats = EmulatorStats()
        self._emulated_s = 0.0
        self._motion_start_s: float | None = None
        self._gains_dirty = True
        self._wall_start = 0.0
        self._wall_end: float | None = None
        self._update_present(*plant.advance(0.0, np.zeros(NUM_JOINTS), np.zeros(NUM_JOINTS, dtype=bool)))
        for s in self._servos:
            s.table.set(ct.GOAL_POSITION, s.table.get(ct.PRESENT_POSITION))
            s.traj_rad = float(pulses_to_rad(s.table.get(ct.PRESENT_POSITION)))
            s.table.set(ct.POSITION_TRAJECTORY, s.table.get(ct.PRESENT_POSITION))

    # -- lifecycle ------------------------------------------------------------------------------
    @property
    def port(self) -> str:
        """The pty slave's path (what a client opens); empty before :meth:`start`."""
        return self._port

    def start(self) -> str:
        """Open the pty and serve it in a background thread; returns the slave's path."""
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self._port = os.ttyname(self._slave)
        self._wall_start = time.perf_counter()
        self._thread = threading.Thread(target=self._serve, name="bus-emulator", daemon=True)
        self._thread.start()
        return self._port

    def stop(self) -> None:
        """Stop serving, close the pty and remove the links made by :meth:`link`."""
        self._stop.set()
        if self._thread is not None:
            self._closed.wait(timeout=5.0)  # the serving thread closes the pty on its way out
        else:
            self._close_pty()
        for path in self._links:
            if path.is_symlink() and os.readlink(path) == self._port:
                path.unlink()
        self._links.clear()

    def __enter__(self) -> BusEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def link(self, path: str | Path) -> Path:
        """Make ``path`` a symlink to the pty slave (replacing an older symlink only).

        Raises:
            FileExistsError: ``path`` exists and is not a symlink.
        """
        if not self._port:
            raise RuntimeError("start the emulator before linking its port")
        path = Path(path)
        if path.exists() and not path.is_symlink():
            raise FileExistsError(f"{path} exists and is not a symlink; refusing to replace it")
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        os.symlink(self._port, tmp)
        os.replace(tmp, path)
        self._links.append(path)
        return path

    def wait_closed(self, timeout_s: float | None = None) -> bool:
        """Block until the emulator stops serving (unplugged, failed or stopped); True if it has."""
        return self._thread is None or self._closed.wait(timeout_s)

    # -- inspection and faults -----------------------------------------------------------------
    def inject(self, fault: Fault) -> None:
        """Schedule ``fault`` (``at_s`` counts from the first torque on, as always).

        Raises:
            InputError: the fault names a servo ID that is not on the bus.
        """
        if fault.servo_id is not None and fault.servo_id not in self._by_id:
            raise InputError(f"fault {fault.kind.value}:{fault.servo_id}: no servo with ID {fault.servo_id} "
                             f"on the emulated bus (IDs {', '.join(map(str, sorted(self._by_id)))})")
        with self._lock:
            self._faults.append(fault)

    def stats(self) -> EmulatorStats:
        """A snapshot of the counters and clocks."""
        with self._lock:
            end = self._wall_end if self._wall_end is not None else time.perf_counter()
            wall = end - self._wall_start if self._wall_start else 0.0
            return dataclasses.replace(
                self._stats, wall_time_s=wall, emulated_time_s=self._emulated_s,
                real_time_factor=self._emulated_s / wall if wall > 0 else 1.0,
                intact_sync_reads=dict(self._stats.intact_sync_reads),
                watchdog_stops_s=dict(self._stats.watchdog_stops_s),
                watchdog_heard_s=dict(self._stats.watchdog_heard_s), torque_off_s=dict(self._stats.torque_off_s),
                notes=[self._plant.note] if self._plant.note else [])

    def register(self, servo_id: int, fld: ct.Field) -> int:
        """Current value of one register of one servo (for tests and diagnostics)."""
        with self._lock:
            return self._by_id[servo_id].table.get(fld)

    # -- the serving thread --------------------------------------------------------------------
    def _serve(self) -> None:
        try:
            while not self._stop.is_set():
                lag = self._lag_s()
                timeout = max(0.0, self.physics_period_s - lag)
                readable, _, _ = select.select([self._master], [], [], timeout)
                if readable:
                    try:
                        data = os.read(self._master, 4096)
                    except BlockingIOError:
                        data = b""
                    if data:
                        with self._lock:
                            self._on_bytes(data, time.perf_counter())
                lag = self._lag_s()
                if lag >= self.physics_period_s:
                    with self._lock:
                        self._advance(min(lag, self.max_advance_s))
        except Exception as exc:  # noqa: BLE001 - reported through stats(), the pty closes
            with self._lock:
                self._stats.error = f"{type(exc).__name__}: {exc}"
        finally:
            self._close_pty()

    def _lag_s(self) -> float:
        """How far [s] the plant is behind the wall clock, after giving up lags beyond max_lag_s."""
        lag = time.perf_counter() - self._wall_start - self._slipped_s - self._emulated_s
        if lag > self.max_lag_s:
            self._slipped_s += lag - self.max_lag_s
            lag = self.max_lag_s
        return lag

    def _close_pty(self) -> None:
        with self._lock:
            for fd in (self._master, self._slave):
                if fd >= 0:
                    try:
                        os.close(fd)
                    except OSError:
                        pass
            self._master = self._slave = -1
            self._stats.closed = True
            if self._wall_end is None and self._wall_start:
                self._wall_end = time.perf_counter()
        self._closed.set()

    def _send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                view = view[os.write(self._master, view):]
            except BlockingIOError:
                return  # nobody reads the port: the bytes are lost, as on a real bus
            except OSError as exc:
                if exc.errno == errno.EIO:
                    return
                raise

    # -- physics -------------------------------------------------------------------------------
    def _advance(self, dt: float) -> None:
        """Profile, plant step of ``dt`` [s], present registers, then due faults."""
        if self._gains_dirty:
            self._plant.set_gains(*(self._per_joint(f) for f in (
                ct.POSITION_P_GAIN, ct.POSITION_I_GAIN, ct.POSITION_D_GAIN, ct.PWM_LIMIT)))
            self._gains_dirty = False
        for s in self._servos:
            if s.watchdog_due(self._emulated_s, time.perf_counter()):
                s.stop_by_watchdog()
                self._stats.watchdog_stops_s[s.joint.servo_id] = self._since_motion_s()
                self._stats.watchdog_heard_s[s.joint.servo_id] = self._since_motion_s(s.last_heard_s)
        enabled = np.array([s.table.torque_enabled for s in self._servos])
        for s, on in zip(self._servos, enabled):
            self._profile_step(s, dt, on)
        traj = np.array([s.traj_rad for s in self._servos])
        goal, torque = self._q.copy(), np.zeros(NUM_JOINTS, dtype=bool)
        goal[self._index] = servo_to_joint_rad(traj, self._offsets, self._directions) - self._encoder
        torque[self._index] = enabled
        self._update_present(*self._plant.advance(dt, goal, torque))
        self._emulated_s += dt
        self._apply_due_faults()

    def _per_joint(self, fld: ct.Field) -> np.ndarray:
        """(11,) values of a register in joint order (the default where a joint has no servo)."""
        values = np.full(NUM_JOINTS, fld.default)
        values[self._index] = [s.table.get(fld) for s in self._servos]
        return values

    def _profile_step(self, s: _Servo, dt: float, torque_on: bool) -> None:
        """Move the servo's Position Trajectory toward Goal Position (velocity-based profile)."""
        table = s.table
        if not torque_on or table.get(ct.OPERATING_MODE) not in POSITION_MODES:
            s.traj_rad = float(pulses_to_rad(table.get(ct.PRESENT_POSITION)))
            s.traj_vel = 0.0
        else:
            goal = float(pulses_to_rad(table.get(ct.GOAL_POSITION)))
            v_raw, a_raw = table.get(ct.PROFILE_VELOCITY), table.get(ct.PROFILE_ACCELERATION)
            v_max = v_raw * RAD_S_PER_VELOCITY_UNIT if v_raw else np.inf
            a_max = a_raw * RAD_S2_PER_ACCELERATION_UNIT if a_raw else np.inf
            error = goal - s.traj_rad
            if v_raw == 0 and a_raw == 0 or error == 0.0:
                s.traj_rad, s.traj_vel = goal, 0.0
            else:
                # Fastest speed from which the goal can still be reached with a_max, capped by v_max.
                v_want = np.sign(error) * min(v_max, np.sqrt(2.0 * a_max * abs(error)))
                vel = float(np.clip(v_want, s.traj_vel - a_max * dt, s.traj_vel + a_max * dt))
                if abs(vel * dt) >= abs(error):
                    s.traj_rad, s.traj_vel = goal, 0.0
                else:
                    s.traj_rad, s.traj_vel = s.traj_rad + vel * dt, vel
        table.set(ct.POSITION_TRAJECTORY, int(rad_to_pulses(s.traj_rad)))
        table.set(ct.VELOCITY_TRAJECTORY, int(rad_s_to_velocity_units(s.traj_vel)))

    def _update_present(self, q: np.ndarray, dq: np.ndarray, current: np.ndarray) -> None:
        """Present registers from the plant's joint angles, velocities and currents, (11,) each."""
        self._q = np.asarray(q, dtype=float)
        idx = self._index
        pos = rad_to_pulses(joint_to_servo_rad(self._q[idx] + self._encoder, self._offsets, self._directions))
        vel = rad_s_to_velocity_units(self._directions * np.asarray(dq)[idx])
        cur = np.clip(amp_to_current_units(self._directions * np.asarray(current)[idx]), *_INT16)
        tick = int(self._emulated_s * 1000.0) % 32768
        for k, s in enumerate(self._servos):
            t = s.table
            t.set(ct.PRESENT_POSITION, int(pos[k]))
            t.set(ct.PRESENT_VELOCITY, int(vel[k]))
            t.set(ct.PRESENT_CURRENT, int(cur[k]))
            t.set(ct.REALTIME_TICK, tick)
            moving = abs(int(vel[k])) > t.get(ct.MOVING_THRESHOLD) or s.traj_vel != 0.0
            t.set(ct.MOVING, int(moving))

    def _apply_due_faults(self) -> None:
        if self._motion_start_s is None:
            return
        elapsed = self._emulated_s - self._motion_start_s
        due = [f for f in self._faults if f.at_s <= elapsed]
        if not due:
            return
        self._faults = [f for f in self._faults if f.at_s > elapsed]
        for fault in due:
            if fault.kind in (FaultKind.CRC, FaultKind.DROP):
                self._active.append(_Countdown(fault, fault.count))
            elif fault.kind is FaultKind.SILENT:
                self._by_id[fault.servo_id].silent = True
            elif fault.kind is FaultKind.UNPLUG:
                self._stop.set()
            elif fault.kind is FaultKind.CUT:
                for s in self._servos:
                    s.silent = True
            else:
                servo = self._by_id[fault.servo_id]
                if fault.kind is FaultKind.VOLTAGE:
                    servo.table.set(ct.PRESENT_INPUT_VOLTAGE, round(10 * BROWNOUT_VOLTAGE_V))
                self._set_hardware_error(servo, HARDWARE_FAULT_BITS[fault.kind])

    def _since_motion_s(self, emulated_s: float | None = None) -> float:
        """Emulated time ``emulated_s`` (default: now) since the first torque on [s] (the clock
        of faults and stats)."""
        return (self._emulated_s if emulated_s is None else emulated_s) - (self._motion_start_s or 0.0)

    def _set_hardware_error(self, s: _Servo, bit: HardwareError) -> None:
        """Raise a hardware error bit; torque goes off if Shutdown (63) has that bit."""
        table = s.table
        table.set(ct.HARDWARE_ERROR_STATUS, table.hardware_error | bit)
        if table.get(ct.SHUTDOWN) & bit and table.torque_enabled:
            table.set(ct.TORQUE_ENABLE, 0)
            self._stats.torque_off_s[s.joint.servo_id] = self._since_motion_s()

    # -- packets -------------------------------------------------------------------------------
    def _on_bytes(self, data: bytes, now_s: float) -> None:
        for packet in self._parser.feed(data, now_s):
            self._stats.packets += 1
            reply = self._dispatch(packet)
            if reply:
                self._send(reply)

    def _dispatch(self, packet: Packet) -> bytes:
        """Everything the bus answers to ``packet`` (possibly nothing)."""
        if packet.crc_ok:
            addressed = self._servos if packet.servo_id == BROADCAST_ID else [self._by_id.get(packet.servo_id)]
            for s in addressed:
                if s is not None and not s.silent:
                    s.last_heard_s, s.last_heard_wall_s = self._emulated_s, time.perf_counter()
        if packet.servo_id == BROADCAST_ID:
            if not packet.crc_ok:
                self._stats.crc_errors += 1
                return b""
            return self._broadcast(packet)
        servo = self._by_id.get(packet.servo_id)
        if servo is None or servo.silent:
            return b""
        if not packet.crc_ok:
            self._stats.crc_errors += 1
            return self._status(servo, packet.instruction, StatusError.CRC)
        inst, params = packet.instruction, packet.params
        if inst == Instruction.PING:
            return self._ping_reply(servo)
        if inst == Instruction.READ:
            if len(params) != 4:
                return self._status(servo, inst, StatusError.DATA_LENGTH)
            error, data = servo.read(_u16(params, 0), _u16(params, 2))
            return self._status(servo, inst, error, data)
        if inst == Instruction.WRITE:
            if len(params) < 3:
                return self._status(servo, inst, StatusError.DATA_LENGTH)
            return self._status(servo, inst, self._write(servo, _u16(params, 0), params[2:]))
        return self._status(servo, inst, StatusError.INSTRUCTION)

    def _broadcast(self, packet: Packet) -> bytes:
        inst, params = packet.instruction, packet.params
        listening = [s for s in self._servos if not s.silent]
        if inst == Instruction.PING:
            return b"".join(self._ping_reply(s) for s in listening)
        if inst == Instruction.WRITE and len(params) >= 3:
            for s in listening:
                self._write(s, _u16(params, 0), params[2:])
        elif inst == Instruction.SYNC_WRITE and len(params) >= 4:
            address, length = _u16(params, 0), _u16(params, 2)
            body = params[4:]
            if length and len(body) % (1 + length) == 0:
                for k in range(0, len(body), 1 + length):
                    s = self._by_id.get(body[k])
                    if s is not None and not s.silent:
                        self._write(s, address, body[k + 1:k + 1 + length])
        elif inst == Instruction.SYNC_READ and len(params) >= 5:
            address, length = _u16(params, 0), _u16(params, 2)
            requests = [(servo_id, address, length) for servo_id in params[4:]]
            return self._multi_read(inst, requests, count_as=address)
        elif inst == Instruction.BULK_READ and params and len(params) % 5 == 0:
            requests = [(params[k], _u16(params, k + 1), _u16(params, k + 3)) for k in range(0, len(params), 5)]
            return self._multi_read(inst, requests, count_as=None)
        return b""

    def _multi_read(self, inst: int, requests: list[tuple[int, int, int]], count_as: int | None) -> bytes:
        """Replies of a sync or bulk read, in the requested order; counts intact sync reads."""
        replies = []
        intact = True
        for servo_id, address, length in requests:
            s = self._by_id.get(servo_id)
            if s is None or s.silent:
                intact = False
                continue
            error, data = s.read(address, length)
            before = (self._stats.dropped, self._stats.corrupted)
            replies.append(self._status(s, inst, error, data))
            intact &= before == (self._stats.dropped, self._stats.corrupted) and error == StatusError.NONE
        if count_as is not None and intact:
            self._stats.intact_sync_reads[count_as] = self._stats.intact_sync_reads.get(count_as, 0) + 1
        return b"".join(replies)

    def _ping_reply(self, s: _Servo) -> bytes:
        model = s.table.get(ct.MODEL_NUMBER)
        params = bytes((model & 0xFF, model >> 8, s.table.get(ct.FIRMWARE_VERSION)))
        return self._status(s, Instruction.PING, StatusError.NONE, params)

    def _status(self, s: _Servo, inst: int, error: StatusError, params: bytes = b"") -> bytes:
        """Status packet of ``s`` after Status Return Level and the active crc/drop faults."""
        level = s.table.get(ct.STATUS_RETURN_LEVEL)
        if level == _REPLY_PING_ONLY and inst != Instruction.PING:
            return b""
        if level == _REPLY_READS and inst not in _READ_INSTRUCTIONS:
            return b""
        packet = encode_status(s.joint.servo_id, s.error_byte(error), params)
        for active in self._active:
            if active.left > 0 and active.fault.servo_id in (None, s.joint.servo_id):
                active.left -= 1
                if active.fault.kind is FaultKind.DROP:
                    self._stats.dropped += 1
                    return b""
                self._stats.corrupted += 1
                packet = packet[:-1] + bytes((packet[-1] ^ 0xFF,))
                break
        self._active = [a for a in self._active if a.left > 0]
        self._stats.replies += 1
        return packet

    def _write(self, s: _Servo, address: int, data: bytes) -> StatusError:
        error = s.check_write(address, data)
        if error != StatusError.NONE:
            return error
        torque_was_on = s.table.torque_enabled
        s.table.write(address, data)
        touched = ct.fields_in(address, len(data))
        if any(f in (ct.POSITION_P_GAIN, ct.POSITION_I_GAIN, ct.POSITION_D_GAIN, ct.PWM_LIMIT) for f in touched):
            self._gains_dirty = True
        if torque_was_on and not s.table.torque_enabled:
            self._stats.torque_off_s[s.joint.servo_id] = self._since_motion_s()
        if s.table.torque_enabled and not torque_was_on:
            s.traj_rad = float(pulses_to_rad(s.table.get(ct.PRESENT_POSITION)))
            s.traj_vel = 0.0
            if self._motion_start_s is None:
                self._motion_start_s = self._emulated_s
        return StatusError.NONE


def _u16(data: bytes, offset: int) -> int:
    return data[offset] | (data[offset + 1] << 8)


class EmulatorProcess:
    """A :class:`BusEmulator` in a child process, controlled through a pipe.

    A client in this process (the driver, the SDK) then shares neither the interpreter lock nor
    a thread scheduler with the emulated servos: as with ``cobra emulate`` in another terminal,
    but scriptable. The ``dynamixel_sdk`` client busy-waits for replies, which starves an
    emulator thread in the same process when the machine is loaded.

    Args:
        plant_factory: builds the plant in the child (picklable: a class, a classmethod such
            as :meth:`SimulatorPlant.nominal <hardware.plant.SimulatorPlant.nominal>`, or a
            ``functools.partial`` of one).
        **emulator_kwargs: passed to :class:`BusEmulator` in the child (joints, faults, ...).
    """

    def __init__(self, plant_factory: Callable[[], Plant], **emulator_kwargs: Any) -> None:
        self._factory = plant_factory
        self._kwargs = emulator_kwargs
        self._conn: Connection | None = None
        self._process: multiprocessing.process.BaseProcess | None = None
        self._port = ""
        self._final: EmulatorStats | None = None

    @property
    def port(self) -> str:
        """The pty slave's path; empty before :meth:`start`."""
        return self._port

    def start(self, timeout_s: float = 60.0) -> str:
        """Spawn the child, wait until it serves, and return the pty slave's path.

        Raises:
            RuntimeError: the child did not start in time; or the child's own error (e.g. an
                :class:`InputError` for a fault on a missing servo), raised here.
        """
        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(target=_serve_in_child, args=(child, self._factory, self._kwargs),
                                    name="bus-emulator", daemon=True)
        self._process.start()
        child.close()
        if not self._conn.poll(timeout_s):
            self._process.kill()
            raise RuntimeError(f"the emulator process did not start within {timeout_s:g} s")
        self._port = self._unwrap(self._conn.recv())
        return self._port

    def _call(self, *request: Any) -> Any:
        if self._conn is None:
            raise RuntimeError("the emulator process is not running")
        self._conn.send(request)
        return self._unwrap(self._conn.recv())

    @staticmethod
    def _unwrap(reply: tuple[str, Any]) -> Any:
        status, value = reply
        if status == "error":
            raise value
        return value

    def stats(self) -> EmulatorStats:
        """:meth:`BusEmulator.stats` of the child (the last ones once stopped)."""
        return self._final if self._final is not None else self._call("stats")

    def register(self, servo_id: int, fld: ct.Field) -> int:
        """:meth:`BusEmulator.register` in the child."""
        return self._call("register", servo_id, fld)

    def inject(self, fault: Fault) -> None:
        """:meth:`BusEmulator.inject` in the child."""
        self._call("inject", fault)

    def link(self, path: str | Path) -> Path:
        """:meth:`BusEmulator.link` in the child."""
        return self._call("link", Path(path))

    def stop(self) -> None:
        """Stop the child's emulator (its links are removed) and wait for the child to exit."""
        if self._conn is None:
            return
        try:
            self._final = self._call("stop")
        except (EOFError, OSError, RuntimeError):
            self._final = None
        self._conn.close()
        self._conn = None
        if self._process is not None:
            self._process.join(10.0)
            if self._process.is_alive():
                self._process.kill()

    def __enter__(self) -> EmulatorProcess:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _serve_in_child(conn: Connection, plant_factory: Callable[[], Plant], kwargs: dict[str, Any]) -> None:
    """Child side of :class:`EmulatorProcess`: answer requests until "stop" or a closed pipe."""
    try:
        emulator = BusEmulator(plant_factory(), **kwargs)
        conn.send(("ok", emulator.start()))
    except Exception as exc:  # noqa: BLE001 - sent to the parent, which raises it
        _send_error(conn, exc)
        return
    handlers: dict[str, Callable[..., Any]] = {
        "stats": emulator.stats, "register": emulator.register, "inject": emulator.inject,
        "link": emulator.link,
    }
    try:
        while True:
            try:
                name, *args = conn.recv()
            except EOFError:
                return
            if name == "stop":
                emulator.stop()
                conn.send(("ok", emulator.stats()))
                return
            try:
                conn.send(("ok", handlers[name](*args)))
            except Exception as exc:  # noqa: BLE001 - sent to the parent, which raises it
                _send_error(conn, exc)
    finally:
        emulator.stop()


def _send_error(conn: Connection, exc: Exception) -> None:
    """Send ``exc`` to the parent (as a RuntimeError with its text if it does not pickle)."""
    try:
        conn.send(("error", exc))
    except Exception:  # noqa: BLE001 - unpicklable exception
        conn.send(("error", RuntimeError(f"emulator process: {type(exc).__name__}: {exc}")))
