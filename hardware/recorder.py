"""Stream a gait to the robot and record the run, safely.

:func:`record_gait` connects (:class:`~hardware.driver.DynamixelBus`), brings the robot from
the pose it holds to the gait's first command in ``settle_s`` (not recorded), then runs the
control loop for ``duration_s``: every period it sends ``gait.q_ref(t)`` (clamped to the joint
limits) and reads the present state, and every ``hardware_error_check_every`` cycles it reads
Hardware Error Status and Bus Watchdog (a servo the watchdog stopped ends the recording). Each
sample is appended to the run file as it arrives (:class:`~hardware.runwriter.IncrementalRunWriter`).

Time: ``t`` of a sample is when its goal was sent, from the monotonic clock, relative to the
start of recording; the present state is read right after, and the column ``read_latency_s``
says how long after for each sample (``timing.read_latency_*`` in the sidecar sums it up).
Cycles follow a fixed schedule ``t_k = k / rate``; a cycle that starts more than a period late
skips the missed slots instead of bunching up, and the sidecar reports the achieved rate, the
jitter of the cycle starts and the skipped slots.

Safety: torque goes off (and the run is closed with a ``"partial run: <reason>"`` note) on
Ctrl-C, on SIGTERM and SIGHUP (a process manager, ``timeout``, a closed terminal), when a
sample cannot be written (a full disk: the file keeps every complete sample before it), on any
exception, on a hardware error bit of any servo, after ``max_consecutive_failures`` failed
reads in a row (the silent servos are then named), and when the port disappears; the cleanup
itself cannot be interrupted by a second signal. While torque is on, each servo's Bus Watchdog
(98) stops it when the host falls silent for ``bus_watchdog_ms`` (a cable pulled between the
adapter and the servos, a host that froze or was killed with SIGKILL).
"""
from __future__ import annotations

import contextlib
import dataclasses
import datetime as _dt
import gc
import math
import os
import signal
import stat
import threading
import time
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any, Callable, Iterator, Protocol

import numpy as np

from cobra_model.run import Q_REF_BETWEEN_SAMPLES
from hardware import control_table as ct
from hardware.config import BusConfig, estimated_bus_time_s
from hardware.control_table import OperatingMode, describe_hardware_error
from hardware.driver import (BusError, CommStats, ConnectError, Disconnected, DynamixelBus, JointState,
                             TorqueOffReport)
from hardware.runwriter import IncrementalRunWriter, RunWriteError, check_run_path
from hardware.units import joint_to_servo_rad, rad_to_pulses

#: Linux device majors of pseudo-terminal slaves (/dev/pts/N): the bus emulator's ports.
_PTY_SLAVE_MAJORS = range(136, 144)


class Gait(Protocol):
    """A commanded joint trajectory (e.g. :class:`cobra_model.gait.SidewindingGait`)."""

    def q_ref(self, t: float | np.ndarray) -> np.ndarray:
        """Joint angles [rad], shape ``t.shape + (11,)``."""

    def to_json(self) -> dict[str, Any]:
        """Description for the run's sidecar."""


class StopReason(Enum):
    """Why recording ended."""

    COMPLETED = "completed"
    INTERRUPTED = "interrupted"
    TERMINATED = "terminated"
    HARDWARE_ERROR = "hardware_error"
    COMM_FAILURE = "comm_failure"
    WATCHDOG = "watchdog"
    WRITE_FAILED = "write_failed"
    DISCONNECTED = "disconnected"
    ERROR = "error"


@dataclass(frozen=True)
class TimingReport:
    """How well the loop kept its schedule.

    Attributes:
        requested_rate_hz: configured control rate [Hz].
        achieved_rate_hz: cycles per second actually run [Hz].
        period_mean_s, period_std_s, period_max_s: statistics of the intervals between cycle
            starts [s] (``period_std_s`` is the jitter).
        lateness_max_s: latest cycle start after its scheduled time [s].
        skipped_cycles: scheduled slots skipped because the loop was more than a period late.
        read_latency_mean_s, read_latency_max_s: goal sent -> state received [s].
        cycles: cycles run.
    """

    requested_rate_hz: float
    achieved_rate_hz: float
    period_mean_s: float
    period_std_s: float
    period_max_s: float
    lateness_max_s: float
    skipped_cycles: int
    read_latency_mean_s: float
    read_latency_max_s: float
    cycles: int

    def to_json(self) -> dict[str, Any]:
        """Plain-JSON form (NaN for undefined statistics becomes null)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in dataclasses.asdict(self).items()}


@dataclass(frozen=True)
class RecordResult:
    """What :func:`record_gait` did.

    Attributes:
        status: why it stopped.
        message: one line for the operator: the reason and the torque-off outcome.
        path: the run file, or None when no sample was recorded (nothing written).
        samples: rows written.
        timing: loop timing of the recording phase (None if it never started).
        torque: outcome of the final torque off.
        comm: the driver's read counters at the stop (the same as the sidecar's ``comm``, which
            a full disk can leave unwritten).
        signal_name: the terminating signal (``"SIGTERM"``, ``"SIGHUP"``) when ``status`` is
            ``TERMINATED``.
    """

    status: StopReason
    message: str
    path: Path | None
    samples: int
    timing: TimingReport | None
    torque: TorqueOffReport
    comm: CommStats
    signal_name: str | None = None


class _Stop(Exception):
    """Internal: end the loop with a reason."""

    def __init__(self, status: StopReason, reason: str) -> None:
        super().__init__(reason)
        self.status = status
        self.reason = reason


class _Timing:
    """Accumulates cycle start times, lateness and read latencies."""

    def __init__(self) -> None:
        self.starts: list[float] = []
        self.lateness: list[float] = []
        self.latency: list[float] = []
        self.skipped = 0

    def report(self, rate_hz: float) -> TimingReport:
        starts = np.asarray(self.starts)
        periods = np.diff(starts)
        nan = float("nan")
        return TimingReport(
            requested_rate_hz=rate_hz,
            achieved_rate_hz=float(periods.size / (starts[-1] - starts[0])) if periods.size else nan,
            period_mean_s=float(periods.mean()) if periods.size else nan,
            period_std_s=float(periods.std()) if periods.size else nan,
            period_max_s=float(periods.max()) if periods.size else nan,
            lateness_max_s=float(max(self.lateness)) if self.lateness else nan,
            skipped_cycles=self.skipped,
            read_latency_mean_s=float(np.mean(self.latency)) if self.latency else nan,
            read_latency_max_s=float(np.max(self.latency)) if self.latency else nan,
            cycles=len(self.starts),
        )


def port_is_pseudo_terminal(port: str) -> bool:
    """True when ``port`` (or what it links to) is a pty slave, i.e. the bus emulator."""
    try:
        st = os.stat(port)
    except OSError:
        return False
    return stat.S_ISCHR(st.st_mode) and os.major(st.st_rdev) in _PTY_SLAVE_MAJORS


#: Signals that end a recording like Ctrl-C does: a process manager's or ``timeout``'s stop
#: request, and the hang-up of a closed terminal. Their default action kills the process at
#: once, which would leave the servos energised at their last goal.
TERMINATING_SIGNALS: tuple[signal.Signals, ...] = (signal.SIGTERM, signal.SIGHUP)


class Terminated(BaseException):
    """Raised in the main thread by a :data:`TERMINATING_SIGNALS` signal during
    :func:`record_gait` (a ``BaseException``, like ``KeyboardInterrupt``, so that no
    ``except Exception`` on the way swallows it)."""

    def __init__(self, signum: int) -> None:
        self.signal_name = signal.Signals(signum).name
        super().__init__(self.signal_name)


class _TerminationHandler:
    """Raises :class:`Terminated` while the robot is being driven; once the recording is
    stopping (``stopping``), a signal is only noted in ``received``: the cleanup must run."""

    def __init__(self) -> None:
        self.stopping = False
        self.received: list[str] = []

    def __call__(self, signum: int, _frame: object) -> None:
        self.received.append(signal.Signals(signum).name)
        if not self.stopping:
            raise Terminated(signum)


@contextlib.contextmanager
def _signals(handler: Any, signums: tuple[int, ...]) -> Iterator[Any]:
    """``handler`` for ``signums`` meanwhile (main thread only: elsewhere Python cannot set
    handlers, and signals are delivered to the main thread anyway); the previous ones after."""
    if threading.current_thread() is not threading.main_thread():
        yield handler
        return
    previous = {s: signal.signal(s, handler) for s in signums}
    try:
        yield handler
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


@contextlib.contextmanager
def _collector_frozen() -> Iterator[None]:
    """Every object alive now out of the garbage collector's scans meanwhile (``gc.freeze``).

    Why: a servo stops when it hears nothing for its Bus Watchdog time (100 ms in the example
    configuration), and a full collection scans every tracked object: with this project's
    libraries loaded (about 317 000 objects) one takes 143 ms on a 2-core machine, longer in a
    process that holds more (a test session). Frozen, a collection during the recording scans
    only what the recording itself allocated. Nothing is freed less: the frozen objects were
    alive anyway, and they are handed back (``gc.unfreeze``) when the recording ends.
    """
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _uninterruptible() -> contextlib.AbstractContextManager[None]:
    """Ignore Ctrl-C and the terminating signals meanwhile, so torque off is not cut short."""
    return _signals(signal.SIG_IGN, (signal.SIGINT, *TERMINATING_SIGNALS))


class _Session:
    """One connect-settle-record session; see :func:`record_gait`."""

    def __init__(self, bus: DynamixelBus, config: BusConfig) -> None:
        self.bus = bus
        self.config = config
        #: ``time.perf_counter()`` of the last packet cycle's start (torque on before the first)
        #: and the longest interval between two since torque on [s], over settling and recording:
        #: what a Bus Watchdog stop is compared with (a stream's own timing misses the others').
        self.last_cycle_start: float | None = None
        self.longest_interval_s = 0.0

    def torque_went_on(self) -> None:
        """Start counting the intervals the Bus Watchdog sees (it is armed with the torque)."""
        self.last_cycle_start = time.perf_counter()

    def stream(self, duration_s: float, command: Callable[[float], np.ndarray],
               on_sample: Callable[[float, np.ndarray, JointState, float], None], timing: _Timing) -> None:
        """Run the control loop for ``duration_s`` [s]; raises :class:`_Stop` on a fault."""
        period = self.config.control_period_s
        check_every = self.config.hardware_error_check_every
        n_slots = math.ceil(duration_s / period - 1e-9)
        t0 = time.perf_counter()
        slot = 0
        failures = 0
        error_check_due = True
        cycle = 0
        while True:
            deadline = t0 + slot * period
            wait = deadline - time.perf_counter()
            if wait > 0:
                time.sleep(wait)
            start = time.perf_counter()
            t = start - t0
            if t >= duration_s:
                return
            if self.last_cycle_start is not None:
                self.longest_interval_s = max(self.longest_interval_s, start - self.last_cycle_start)
            self.last_cycle_start = start
            q_cmd = self.bus.send_goal(command(t))
            state = self.bus.read_state()
            timing.starts.append(start)
            timing.lateness.append(start - deadline)
            if state is None:
                failures += 1
                if failures >= self.config.max_consecutive_failures:
                    raise _Stop(StopReason.COMM_FAILURE, self._silence_reason(failures))
            else:
                latency = time.perf_counter() - start
                timing.latency.append(latency)
                failures = 0
                on_sample(t, q_cmd, state, latency)
            cycle += 1
            if error_check_due or cycle % check_every == 0:
                errors = self.bus.read_hardware_errors()
                stopped = self.bus.read_watchdog_stops()
                error_check_due = errors is None or stopped is None  # a failed check is repeated next cycle
                if errors:
                    raise _Stop(StopReason.HARDWARE_ERROR, "; ".join(
                        f"{self.bus.name(i)} reported a hardware error: {describe_hardware_error(bits)} "
                        f"(Hardware Error Status 0x{bits:02X})" for i, bits in errors.items()))
                if stopped:
                    raise _Stop(StopReason.WATCHDOG, (
                        f"the Bus Watchdog stopped {', '.join(self.bus.name(i) for i in stopped)}: no packet "
                        f"reached it for {self.config.bus_watchdog_ms} ms (longest interval between cycles "
                        f"since torque on {1e3 * self.longest_interval_s:.0f} ms); raise [bus] "
                        f"bus_watchdog_ms if the host is that slow"))
            current_slot = int((time.perf_counter() - t0) / period)
            # Slots that passed while this cycle ran are skipped (those within the duration
            # are reported), not run in a burst.
            timing.skipped += max(0, min(current_slot, n_slots) - (slot + 1))
            slot = max(slot + 1, current_slot)

    def _silence_reason(self, failures: int) -> str:
        text = (f"{failures} consecutive failed reads of the present state "
                f"(last: {self.bus.stats.last_failure})")
        silent = self.bus.find_silent_servos()
        if len(silent) == len(self.config.joints):
            return text + "; no servo answers a ping: bus cable or servo power lost?"
        if silent:
            return text + "; not answering a ping: " + ", ".join(self.bus.name(i) for i in silent)
        return text + "; every servo answers a ping again (intermittent bus?)"


def record_gait(config: BusConfig, gait: Gait, *, duration_s: float, out: str | Path,
                force: bool = False, settle_s: float = 2.0,
                progress: Callable[[str], None] | None = None) -> RecordResult:
    """Connect, settle into the gait's first pose, stream the gait and record the run.

    Args:
        config: the bus.
        gait: commanded joint angles as a function of time [s] from the start of recording.
        duration_s: recording length [s].
        out: the run file ``NAME.csv`` (sidecar ``NAME.json``); created at the first sample.
        force: overwrite an existing run.
        settle_s: time to move from the held pose to ``gait.q_ref(0)`` before recording [s].
        progress: called with short status lines (connected, settling, recording).

    Returns:
        The outcome; every stop but an unexpected exception ends here, with torque off.

    Raises:
        InputError, FileExistsError: bad ``out`` (before anything is sent).
        ConnectError: the bus could not be brought up (torque off attempted, nothing written).
        BaseException: any unexpected error, re-raised after torque off and closing the
            partial run with its note.
    """
    out_path = check_run_path(out, force=force)
    with _signals(_TerminationHandler(), TERMINATING_SIGNALS) as handler, _collector_frozen():
        return _record(config, gait, duration_s, out_path, force, settle_s, progress or (lambda _msg: None), handler)


def _record(config: BusConfig, gait: Gait, duration_s: float, out_path: Path, force: bool, settle_s: float,
            say: Callable[[str], None], handler: _TerminationHandler) -> RecordResult:
    """:func:`record_gait` once its terminating-signal handler is in place."""
    bus = DynamixelBus(config)
    session = _Session(bus, config)
    timing = _Timing()
    writer: IncrementalRunWriter | None = None
    source = "emulator" if port_is_pseudo_terminal(config.port) else "hardware"
    meta = {
        "source": source,
        Q_REF_BETWEEN_SAMPLES: "held",  # each goal stays in the servos until the next cycle's
        "gait": gait.to_json(),
        "bus": config.to_json(),
        "recording": {
            "started_at": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "duration_s": duration_s,
            "settle_s": settle_s,
            "t_definition": "time the goal was sent, from the start of recording; the state is "
                            "received read_latency_s after it",
        },
    }

    def on_sample(t: float, q_cmd: np.ndarray, state: JointState, latency_s: float) -> None:
        nonlocal writer
        if writer is None:
            writer = IncrementalRunWriter(out_path, meta, force=force)
        writer.append(t, q_cmd, state.q_rad, state.dq_rad_s, state.current_a, latency_s)

    status, reason = StopReason.COMPLETED, ""
    unexpected: BaseException | None = None
    try:
        try:
            _run_session(bus, session, config, gait, duration_s, settle_s, out_path, timing, on_sample, say)
        finally:
            handler.stopping = True  # from here a terminating signal no longer interrupts
    except _Stop as stop:
        status, reason = stop.status, stop.reason
    except KeyboardInterrupt:
        status, reason = StopReason.INTERRUPTED, "interrupted (Ctrl-C)"
    except Terminated as exc:
        status, reason = StopReason.TERMINATED, f"terminated ({exc.signal_name})"
    except Disconnected as exc:
        status, reason = StopReason.DISCONNECTED, f"port lost: {exc}"
    except RunWriteError as exc:
        status, reason = StopReason.WRITE_FAILED, str(exc)
    except ConnectError:
        _shutdown(bus)
        raise
    except BusError as exc:
        status, reason = StopReason.COMM_FAILURE, str(exc)
    except BaseException as exc:
        status, reason = StopReason.ERROR, f"unexpected error: {type(exc).__name__}: {exc}"
        unexpected = exc
    torque = _shutdown(bus)
    comm = dataclasses.replace(bus.stats)  # the counters at the stop, for the sidecar and the result
    report = timing.report(config.control_rate_hz) if timing.starts else None
    if status is StopReason.DISCONNECTED and torque.port_error is not None:
        message = f"{reason}; torque off could NOT be sent: the servos hold their last goal, cut their power"
    else:
        message = f"{reason}; {torque.describe(bus.joint_of)}" if reason else torque.describe(bus.joint_of)
    if writer is not None:
        notes = [] if status is StopReason.COMPLETED else [f"partial run: {reason}"]
        writer.close(notes=notes, meta={
            "timing": report.to_json() if report else None,
            "comm": {**dataclasses.asdict(comm), "samples": writer.count_rows()},
            "stop": {"status": status.value, "message": message},
        })
        if writer.sidecar_error:
            message += f"; {writer.sidecar_error}: it still says the recording did not finish"
    if unexpected is not None:
        raise unexpected
    return RecordResult(status=status, message=message, path=writer.path if writer else None,
                        samples=writer.rows if writer else 0, timing=report, torque=torque,
                        comm=comm,
                        signal_name=handler.received[0] if status is StopReason.TERMINATED else None)


def _run_session(bus: DynamixelBus, session: _Session, config: BusConfig, gait: Gait, duration_s: float,
                 settle_s: float, out_path: Path, timing: _Timing,
                 on_sample: Callable[[float, np.ndarray, JointState, float], None], say: Callable[[str], None]) -> None:
    """Connect, torque on, settle and record (every stop is an exception; see :func:`record_gait`)."""
    bus.connect()
    held = bus.torque_on()
    session.torque_went_on()
    say(f"connected to {len(config.joints)} servos on {config.port}; torque on")
    if settle_s > 0:
        q_first = bus.clamp(gait.q_ref(0.0))
        say(f"settling into the gait's first pose for {settle_s:g} s")

        def settle_command(t: float) -> np.ndarray:
            s = 0.5 - 0.5 * math.cos(math.pi * min(t / settle_s, 1.0))
            return held.q_rad + s * (q_first - held.q_rad)

        session.stream(settle_s, settle_command, lambda *_: None, _Timing())
    say(f"recording {duration_s:g} s at {config.control_rate_hz:g} Hz to {out_path}")
    session.stream(duration_s, gait.q_ref, on_sample, timing)


def _shutdown(bus: DynamixelBus) -> TorqueOffReport:
    """Torque off and close the port, immune to Ctrl-C and the terminating signals."""
    with _uninterruptible():
        report = bus.torque_off()
        bus.close()
    return report


def describe_plan(config: BusConfig, gait: Gait, *, duration_s: float, settle_s: float,
                  show_cycles: int = 5) -> str:
    """What :func:`record_gait` would send, as text (``cobra record --dry-run``)."""
    servo = config.servo
    period = config.control_period_s
    n_cycles = int(math.ceil(duration_s / period))
    lines = [
        f"port {config.port} at {config.baud_rate} baud; Protocol 2.0",
        "connect: ping IDs " + ", ".join(map(str, config.servo_ids))
        + f" and expect model number {servo.model_number}; read Hardware Error Status",
        "configure every servo (write, with status reply):",
    ]
    for fld, value in ((ct.TORQUE_ENABLE, 0), (ct.BUS_WATCHDOG, "0 (off; clears an earlier watchdog stop)"),
                       (ct.OPERATING_MODE, f"{int(servo.operating_mode)} "
                                                                  f"({servo.operating_mode.name.lower()})"),
                       (ct.PWM_LIMIT, servo.pwm_limit), (ct.POSITION_P_GAIN, servo.position_p_gain),
                       (ct.POSITION_I_GAIN, servo.position_i_gain), (ct.POSITION_D_GAIN, servo.position_d_gain),
                       (ct.PROFILE_ACCELERATION, servo.profile_acceleration),
                       (ct.PROFILE_VELOCITY, servo.profile_velocity)):
        lines.append(f"  {fld.name} ({fld.address}) = {value}" + ("  [EEPROM: only if it differs]" if fld.eeprom else ""))
    if servo.operating_mode is OperatingMode.POSITION:
        lines.append("  Min/Max Position Limit (52/48) = the joint limit, per servo: "
                     + ", ".join(f"ID {i}: {lo}..{hi}" for i, (lo, hi) in
                                 zip(config.servo_ids, config.position_limits_pulses()))
                     + "  [EEPROM: only if they differ]")
    lines += [
        f"torque on: read the present pose, write it as Goal Position (116), Bus Watchdog (98) = "
        f"{round(config.bus_watchdog_ms * 1e-3 / ct.BUS_WATCHDOG_UNIT_S)} ({config.bus_watchdog_ms} ms: a servo that "
        f"hears nothing that long stops), Torque Enable (64) = 1",
        f"settle: {settle_s:g} s from the held pose to the gait's first command (not recorded)",
        f"record: {duration_s:g} s at {config.control_rate_hz:g} Hz = {n_cycles} cycles of "
        f"Sync Write Goal Position (116, 4 bytes) + Sync Read {ct.PRESENT_STATE_ADDRESS}.."
        f"{ct.PRESENT_STATE_ADDRESS + ct.PRESENT_STATE_LENGTH - 1} (current, velocity, position); "
        f"Hardware Error Status (70) and Bus Watchdog (98) every {config.hardware_error_check_every} cycles",
        f"  bus time per cycle >= {1e3 * estimated_bus_time_s(len(config.joints), config.baud_rate):.2f} ms "
        f"of the {1e3 * period:.1f} ms period (plus servo return delays)",
        f"  joint limit +-{math.degrees(config.joint_limit_rad):g} deg; stop after "
        f"{config.max_consecutive_failures} failed reads in a row",
    ]
    times = np.arange(n_cycles) * period
    q_all = gait.q_ref(times)
    limit = config.joint_limit_rad
    clamped = np.abs(q_all) > limit
    if clamped.any():
        joints = sorted({int(j) + 1 for j in np.nonzero(clamped)[1]})
        lines.append(f"  WARNING: commands beyond the joint limit are clamped on joints {joints}")
    header = "  cycle  t [s]   " + " ".join(f"{'j' + str(k):>6}" for k in range(1, len(config.joints) + 1))
    lines.append(f"goal positions, first {min(show_cycles, n_cycles)} cycles and the last "
                 "(deg, then raw pulses):")
    lines.append(header)
    shown = list(range(min(show_cycles, n_cycles))) + ([n_cycles - 1] if n_cycles > show_cycles else [])
    for k in shown:
        q = np.clip(q_all[k], -limit, limit)
        pulses = rad_to_pulses(joint_to_servo_rad(q, config.zero_offsets_rad, config.directions))
        lines.append(f"  {k:5d} {times[k]:7.3f}  " + " ".join(f"{np.degrees(v):6.1f}" for v in q))
        lines.append(f"  {'':5s} {'':7s}  " + " ".join(f"{int(p):6d}" for p in pulses))
    lines.append("stop: Torque Enable (64) = 0 by Sync Write, then confirmed servo by servo")
    return "\n".join(lines)
