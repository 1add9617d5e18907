"""Bus configuration: a typed, validated description of COBRA's servo chain.

A configuration file (TOML, or YAML when PyYAML is installed) has three parts; see
``examples/bus.toml`` for a complete one (installed with the package: :data:`EXAMPLE_CONFIG`)::

    [bus]                       # the serial link and the control loop
    port = "/dev/ttyUSB0"       # required
    baud_rate = 1000000         # bit/s, one of BAUD_RATE_CODES
    control_rate_hz = 50.0      # goal/read cycles per second
    max_consecutive_failures = 5
    hardware_error_check_every = 5   # cycles between reads of Hardware Error Status
    bus_watchdog_ms = 100       # a servo that hears nothing this long stops (20..2540, x20)

    [servo]                     # written to every servo at connect (raw register values)
    model_number = 1100         # what every ping must answer (XH540-W270)
    operating_mode = "position" # position | extended_position | current_based_position
    position_p_gain = 800
    position_i_gain = 0
    position_d_gain = 0
    profile_velocity = 0        # 0.229 rpm units, 0 = no limit
    profile_acceleration = 0    # 214.577 rev/min^2 units, 0 = no limit
    pwm_limit = 885             # 0..885 (885 = 100 %)
    joint_limit_deg = 90.0      # commands are clamped to +-this

    [[joints]]                  # exactly one entry for each joint 1..11
    joint = 1
    id = 1
    zero_offset_deg = 0.0       # servo angle (from 2048) at which the joint is straight
    direction = 1               # +1: servo and joint angles agree, -1: opposite

Every problem is reported as :class:`cobra_model.errors.InputError` naming the file, the key
and what was expected. Unknown keys are errors too: a misspelt gain must not be ignored
silently on a real robot.
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Mapping

import numpy as np

from cobra_model.design import NUM_JOINTS
from cobra_model.errors import InputError
from cobra_model.servo import POSITION_CENTER_PULSE, PWM_FULL_SCALE, RAD_PER_PULSE
from cobra_model.shipped import shipped_path
from hardware import control_table as ct
from hardware.control_table import BAUD_RATE_CODES, OperatingMode
from hardware.units import joint_to_servo_rad, rad_to_pulses

#: ``examples/bus.toml``, as installed (package data ``hardware.examples``): a complete
#: configuration of COBRA's chain to copy and edit.
EXAMPLE_CONFIG = shipped_path("hardware.examples", "bus.toml")

#: Operating modes a configuration may ask for (goal positions are streamed).
OPERATING_MODE_NAMES: dict[str, OperatingMode] = {
    "position": OperatingMode.POSITION,
    "extended_position": OperatingMode.EXTENDED_POSITION,
    "current_based_position": OperatingMode.CURRENT_BASED_POSITION,
}
#: Mechanical joint range of COBRA [deg]; commands never go beyond it.
MAX_JOINT_LIMIT_DEG = 90.0


@dataclass(frozen=True)
class JointConfig:
    """How one joint is wired.

    Attributes:
        joint: joint number 1..11 (from the head).
        servo_id: Dynamixel ID of its servo (1..252).
        zero_offset_rad: servo angle [rad], relative to the 2048 centre, at joint angle 0.
        direction: +1 if the servo angle grows with the joint angle, -1 otherwise.
    """

    joint: int
    servo_id: int
    zero_offset_rad: float = 0.0
    direction: int = 1


@dataclass(frozen=True)
class ServoSettings:
    """Registers written to every servo at connect (raw register units)."""

    model_number: int = ct.XH540_W270_MODEL_NUMBER
    operating_mode: OperatingMode = OperatingMode.POSITION
    position_p_gain: int = 800
    position_i_gain: int = 0
    position_d_gain: int = 0
    profile_velocity: int = 0
    profile_acceleration: int = 0
    pwm_limit: int = PWM_FULL_SCALE


@dataclass(frozen=True)
class BusConfig:
    """The servo bus of COBRA.

    Attributes:
        port: serial device (or the emulator's pty link).
        joints: the 11 joints, ordered by joint number.
        baud_rate: port speed [bit/s].
        control_rate_hz: cycles per second of the streaming loop [Hz].
        joint_limit_rad: commands are clamped to +-this [rad].
        max_consecutive_failures: failed cycles in a row after which streaming stops.
        hardware_error_check_every: cycles between two reads of Hardware Error Status (and of
            Bus Watchdog).
        bus_watchdog_ms: each servo's Bus Watchdog (98) while torque is on [ms]: a servo that
            receives no instruction packet for this long stops where it is (a pulled bus cable,
            a frozen or killed host). A multiple of 20 ms in 20..2540.
        servo: registers written to every servo.
        source: where the configuration was read from (for messages), or None.
    """

    port: str
    joints: tuple[JointConfig, ...] = field(
        default_factory=lambda: tuple(JointConfig(k, k) for k in range(1, NUM_JOINTS + 1)))
    baud_rate: int = 1_000_000
    control_rate_hz: float = 50.0
    joint_limit_rad: float = math.radians(MAX_JOINT_LIMIT_DEG)
    max_consecutive_failures: int = 5
    hardware_error_check_every: int = 5
    bus_watchdog_ms: int = 100
    servo: ServoSettings = ServoSettings()
    source: str | None = None

    @property
    def servo_ids(self) -> tuple[int, ...]:
        """IDs in joint order (joint 1 first)."""
        return tuple(j.servo_id for j in self.joints)

    @property
    def zero_offsets_rad(self) -> np.ndarray:
        """(11,) zero offsets [rad] in joint order."""
        return np.array([j.zero_offset_rad for j in self.joints])

    @property
    def directions(self) -> np.ndarray:
        """(11,) directions (+1/-1) in joint order."""
        return np.array([j.direction for j in self.joints], dtype=float)

    @property
    def control_period_s(self) -> float:
        """Period of the streaming loop [s]."""
        return 1.0 / self.control_rate_hz

    def position_limits_pulses(self) -> list[tuple[int, int]]:
        """(Min, Max) Position Limit [pulse] of each servo in joint order: the servo angles of
        the joint limits, given each joint's zero offset and direction."""
        limit = self.joint_limit_rad
        ends = [rad_to_pulses(joint_to_servo_rad(np.array([-limit, limit]), j.zero_offset_rad, j.direction))
                for j in self.joints]
        return [(int(e.min()), int(e.max())) for e in ends]

    def with_port(self, port: str) -> BusConfig:
        """The same configuration on another serial port."""
        return replace(self, port=port)

    def to_json(self) -> dict[str, Any]:
        """Plain-JSON form, for a run's sidecar (angles in degrees as in the file)."""
        return {
            "port": self.port,
            "baud_rate": self.baud_rate,
            "control_rate_hz": self.control_rate_hz,
            "max_consecutive_failures": self.max_consecutive_failures,
            "hardware_error_check_every": self.hardware_error_check_every,
            "bus_watchdog_ms": self.bus_watchdog_ms,
            "servo": {
                "model_number": self.servo.model_number,
                "operating_mode": self.servo.operating_mode.name.lower(),
                "position_p_gain": self.servo.position_p_gain,
                "position_i_gain": self.servo.position_i_gain,
                "position_d_gain": self.servo.position_d_gain,
                "profile_velocity": self.servo.profile_velocity,
                "profile_acceleration": self.servo.profile_acceleration,
                "pwm_limit": self.servo.pwm_limit,
                "joint_limit_deg": math.degrees(self.joint_limit_rad),
            },
            "joints": [
                {"joint": j.joint, "id": j.servo_id, "zero_offset_deg": math.degrees(j.zero_offset_rad),
                 "direction": j.direction}
                for j in self.joints
            ],
        }


def estimated_bus_time_s(n_servos: int, baud_rate: int) -> float:
    """Lower bound [s] of one streaming cycle's time on the wire (10 bits per byte).

    A cycle is a Sync Write of goal positions (14 + 5 n bytes), a Sync Read request of the
    present-state block (14 + n bytes) and n status packets (11 + 10 bytes each); servo return
    delays come on top.
    """
    n_bytes = (14 + 5 * n_servos) + (14 + n_servos) + n_servos * (11 + ct.PRESENT_STATE_LENGTH)
    return 10.0 * n_bytes / baud_rate


class _Section:
    """Reads typed keys from one mapping and remembers which keys were used."""

    def __init__(self, data: Any, where: str) -> None:
        if not isinstance(data, Mapping):
            raise InputError(f"{where}: expected a table of keys, got {type(data).__name__}")
        self._data = data
        self.where = where
        self._used: set[str] = set()

    def _get(self, key: str, default: Any) -> Any:
        self._used.add(key)
        if key not in self._data:
            if default is _REQUIRED:
                raise InputError(f"{self.where}: missing required key '{key}'")
            return default
        return self._data[key]

    def get_int(self, key: str, default: Any, lo: int, hi: int) -> int:
        value = self._get(key, default)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise InputError(f"{self.where}: {key}: expected an integer in {lo}..{hi}, got {value!r}")
        return value

    def get_float(self, key: str, default: Any, lo: float, hi: float, *, lo_open: bool = False) -> float:
        value = self._get(key, default)
        ok = (isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
              and (lo < value if lo_open else lo <= value) and value <= hi)
        if not ok:
            bounds = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
            raise InputError(f"{self.where}: {key}: expected a number in {bounds}, got {value!r}")
        return float(value)

    def get_str(self, key: str, default: Any) -> str:
        value = self._get(key, default)
        if not isinstance(value, str) or not value:
            raise InputError(f"{self.where}: {key}: expected a non-empty string, got {value!r}")
        return value

    def get_choice(self, key: str, default: Any, choices: Iterable[Any]) -> Any:
        value = self._get(key, default)
        choices = list(choices)
        if type(value) not in {type(c) for c in choices} or value not in choices:
            raise InputError(f"{self.where}: {key}: expected one of "
                             f"{', '.join(map(repr, choices))}, got {value!r}")
        return value

    def check_no_unknown_keys(self) -> None:
        unknown = sorted(set(self._data) - self._used)
        if unknown:
            raise InputError(f"{self.where}: unknown key(s) {', '.join(map(repr, unknown))}; "
                             f"expected some of {', '.join(sorted(self._used))}")


_REQUIRED = object()


def _model_number(servo: _Section) -> int:
    """``[servo] model_number``: one of the X-series models this driver speaks to."""
    value = servo.get_int("model_number", ct.XH540_W270_MODEL_NUMBER, 0, 0xFFFF)
    if value not in ct.KNOWN_MODELS:
        known = ", ".join(f"{n} ({name})" for n, name in ct.KNOWN_MODELS.items())
        raise InputError(f"{servo.where}: model_number = {value} is no X-series servo with this control table; "
                         f"expected one of {known}")
    return value


def bus_config_from_dict(data: Any, *, source: str) -> BusConfig:
    """Validate a parsed configuration (the structure of the file) into a :class:`BusConfig`.

    Args:
        data: the parsed file: a mapping with ``bus``, optional ``servo`` and ``joints``.
        source: name used in error messages (usually the file path).

    Raises:
        InputError: on any missing, unknown or out-of-range key.
    """
    if not isinstance(data, Mapping):
        raise InputError(f"{source}: expected tables [bus], [servo] and [[joints]], got {type(data).__name__}")
    unknown = sorted(set(data) - {"bus", "servo", "joints"})
    if unknown:
        raise InputError(f"{source}: unknown table(s) {', '.join(map(repr, unknown))}; "
                         "expected [bus], [servo] and [[joints]]")
    if "bus" not in data:
        raise InputError(f"{source}: missing required table [bus]")
    if "joints" not in data:
        raise InputError(f"{source}: missing [[joints]]: one entry for each joint 1..{NUM_JOINTS}")

    bus = _Section(data["bus"], f"{source}: [bus]")
    port = bus.get_str("port", _REQUIRED)
    baud = bus.get_choice("baud_rate", 1_000_000, BAUD_RATE_CODES)
    rate = bus.get_float("control_rate_hz", 50.0, 0.0, 1000.0, lo_open=True)
    max_failures = bus.get_int("max_consecutive_failures", 5, 1, 1000)
    check_every = bus.get_int("hardware_error_check_every", 5, 1, 10_000)
    unit_ms = round(1e3 * ct.BUS_WATCHDOG_UNIT_S)
    watchdog_ms = bus.get_int("bus_watchdog_ms", 100, unit_ms, unit_ms * ct.BUS_WATCHDOG.valid[1])
    bus.check_no_unknown_keys()
    if watchdog_ms % unit_ms:
        raise InputError(f"{source}: [bus] bus_watchdog_ms = {watchdog_ms}: the servos count it in "
                         f"{unit_ms} ms units; expected a multiple of {unit_ms}")
    if watchdog_ms < 3e3 / rate:
        raise InputError(
            f"{source}: [bus] bus_watchdog_ms = {watchdog_ms}: shorter than 3 control periods "
            f"({3e3 / rate:.0f} ms at {rate:g} Hz), so one late or retried cycle would stop the servos; "
            f"expected at least {unit_ms * math.ceil(3e3 / rate / unit_ms)}")
    bus_time = estimated_bus_time_s(NUM_JOINTS, baud)
    if bus_time >= 1.0 / rate:
        raise InputError(
            f"{source}: [bus] control_rate_hz = {rate:g}: one cycle needs at least "
            f"{1e3 * bus_time:.1f} ms on the wire at {baud} baud, longer than the period "
            f"{1e3 / rate:.1f} ms; lower the rate or raise the baud rate")

    servo = _Section(data.get("servo", {}), f"{source}: [servo]")
    mode_name = servo.get_choice("operating_mode", "position", OPERATING_MODE_NAMES)
    settings = ServoSettings(
        model_number=_model_number(servo),
        operating_mode=OPERATING_MODE_NAMES[mode_name],
        position_p_gain=servo.get_int("position_p_gain", ct.POSITION_P_GAIN.default, *ct.POSITION_P_GAIN.valid),
        position_i_gain=servo.get_int("position_i_gain", ct.POSITION_I_GAIN.default, *ct.POSITION_I_GAIN.valid),
        position_d_gain=servo.get_int("position_d_gain", ct.POSITION_D_GAIN.default, *ct.POSITION_D_GAIN.valid),
        profile_velocity=servo.get_int("profile_velocity", 0, *ct.PROFILE_VELOCITY.valid),
        profile_acceleration=servo.get_int("profile_acceleration", 0, *ct.PROFILE_ACCELERATION.valid),
        pwm_limit=servo.get_int("pwm_limit", ct.PWM_LIMIT.default, *ct.PWM_LIMIT.valid),
    )
    limit_deg = servo.get_float("joint_limit_deg", MAX_JOINT_LIMIT_DEG, 0.0, MAX_JOINT_LIMIT_DEG, lo_open=True)
    servo.check_no_unknown_keys()

    entries = data["joints"]
    if not isinstance(entries, list) or len(entries) != NUM_JOINTS:
        count = len(entries) if isinstance(entries, list) else type(entries).__name__
        raise InputError(f"{source}: joints: expected a list of {NUM_JOINTS} entries "
                         f"([[joints]] tables), got {count}")
    joints: dict[int, JointConfig] = {}
    for i, entry in enumerate(entries):
        sec = _Section(entry, f"{source}: joints[{i}]")
        joint = sec.get_int("joint", _REQUIRED, 1, NUM_JOINTS)
        sec.where = f"{source}: joints[{i}] (joint {joint})"
        servo_id = sec.get_int("id", _REQUIRED, 1, 252)
        offset_deg = sec.get_float("zero_offset_deg", 0.0, -180.0, 180.0)
        direction = sec.get_choice("direction", 1, (1, -1))
        sec.check_no_unknown_keys()
        worst_pulse = POSITION_CENTER_PULSE + (abs(offset_deg) + limit_deg) / math.degrees(RAD_PER_PULSE)
        if worst_pulse > ct.MAX_POSITION_LIMIT.default:
            raise InputError(
                f"{source}: joints[{i}] (joint {joint}) zero_offset_deg = {offset_deg:g}: with the "
                f"joint limit of {limit_deg:g} deg the servo would leave its 0..4095 pulse range; "
                f"expected |zero_offset_deg| + joint_limit_deg < 180")
        if joint in joints:
            raise InputError(f"{source}: joints[{i}]: joint {joint} is listed twice")
        joints[joint] = JointConfig(joint, servo_id, math.radians(offset_deg), direction)
    ids = [j.servo_id for j in joints.values()]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise InputError(f"{source}: joints: servo id(s) {duplicates} used by more than one joint")

    return BusConfig(
        port=port,
        joints=tuple(joints[k] for k in range(1, NUM_JOINTS + 1)),
        baud_rate=baud,
        control_rate_hz=rate,
        joint_limit_rad=math.radians(limit_deg),
        max_consecutive_failures=max_failures,
        hardware_error_check_every=check_every,
        bus_watchdog_ms=watchdog_ms,
        servo=settings,
        source=source,
    )


def load_bus_config(path: str | Path) -> BusConfig:
    """Read and validate a bus configuration from a ``.toml``, ``.yaml`` or ``.yml`` file.

    Raises:
        InputError: unreadable or invalid file (the message names the file and the key).
        FileNotFoundError: no such file (naming it, as :meth:`cobra_model.parameters.ModelParameters.load` does).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if not path.is_file():
        raise FileNotFoundError(f"bus configuration {path} does not exist")
    if suffix == ".toml":
        try:
            with path.open("rb") as fh:
                data = tomllib.load(fh)
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"{path}: not valid TOML: {exc}") from exc
    elif suffix in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError as exc:
            raise InputError(f"{path}: reading YAML needs PyYAML (pip install pyyaml); "
                             "or write the configuration as TOML") from exc
        try:
            with path.open("r", encoding="utf-8") as fh:
                data = yaml.safe_load(fh)
        except yaml.YAMLError as exc:
            raise InputError(f"{path}: not valid YAML: {exc}") from exc
    else:
        raise InputError(f"{path}: expected a .toml, .yaml or .yml bus configuration")
    return bus_config_from_dict(data, source=str(path))
