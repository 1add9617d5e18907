"""Bring-up check: does the bus hold the servos the configuration describes?

:func:`survey_bus` opens the port, pings every ID on the bus (one broadcast ping, then each
configured ID that did not answer, again), reads each configured servo's identity, mode,
limits, input voltage and temperature, and compares them with the configuration. It writes
nothing and never turns torque on (``cobra check-bus``, before the first ``cobra record``).

A mismatch is one line naming the servo and what was expected: a missing servo, another model,
a hardware error, an input voltage outside the servo's own limits, a temperature within
:data:`TEMPERATURE_MARGIN_C` of its limit, an ID on the bus that the configuration does not
list, and registers that ``cobra record`` would rewrite at connect (operating mode, position
limits), which are named so that a surprise (another robot's servos, a factory reset) shows.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from hardware import control_table as ct
from hardware.config import BusConfig
from hardware.control_table import OperatingMode, describe_hardware_error
from hardware.driver import DynamixelBus

#: A temperature this close to the servo's Temperature Limit (31) [deg C] is a mismatch.
TEMPERATURE_MARGIN_C = 10
#: Registers read from every configured servo that answers, in table order.
SURVEYED: tuple[ct.Field, ...] = (
    ct.FIRMWARE_VERSION, ct.OPERATING_MODE, ct.TEMPERATURE_LIMIT, ct.MAX_VOLTAGE_LIMIT, ct.MIN_VOLTAGE_LIMIT,
    ct.MAX_POSITION_LIMIT, ct.MIN_POSITION_LIMIT, ct.TORQUE_ENABLE, ct.HARDWARE_ERROR_STATUS,
    ct.PRESENT_INPUT_VOLTAGE, ct.PRESENT_TEMPERATURE,
)


@dataclass(frozen=True)
class ServoSurvey:
    """What one configured servo reported.

    Attributes:
        joint: its joint number; servo_id: its ID.
        model_number: what it answered to ping (None: no answer).
        registers: the :data:`SURVEYED` values read (a register that could not be read is absent).
        mismatches: one sentence per difference from the configuration.
    """

    joint: int
    servo_id: int
    model_number: int | None
    registers: dict[str, int] = field(default_factory=dict)
    mismatches: tuple[str, ...] = ()

    def get(self, fld: ct.Field) -> int | None:
        """A surveyed register's value, or None."""
        return self.registers.get(fld.name)


@dataclass(frozen=True)
class BusSurvey:
    """The whole bus: every configured servo, and IDs that answer but are not configured."""

    port: str
    servos: tuple[ServoSurvey, ...]
    unexpected: dict[int, int]  # ID -> model number

    @property
    def mismatches(self) -> list[str]:
        """Every mismatch line, servo by servo, then the unexpected IDs."""
        lines = [m for s in self.servos for m in s.mismatches]
        lines += [f"ID {i} (model number {model}) answers but is not in the configuration"
                  for i, model in sorted(self.unexpected.items())]
        return lines

    def table(self) -> str:
        """One line per configured servo (voltage [V], temperature [deg C], limits in pulses)."""
        head = (f"{'joint':>5} {'ID':>3} {'model':>6} {'fw':>3} {'mode':<24} {'position limits':>15} "
                f"{'input V':>7} {'temp C':>6} {'torque':>6}")
        lines = [head]
        for s in self.servos:
            if s.model_number is None:
                lines.append(f"{s.joint:>5} {s.servo_id:>3} {'-':>6}  no answer")
                continue
            mode = s.get(ct.OPERATING_MODE)
            mode_text = _mode_name(mode) if mode is not None else "?"
            lo, hi = s.get(ct.MIN_POSITION_LIMIT), s.get(ct.MAX_POSITION_LIMIT)
            volts, temp = s.get(ct.PRESENT_INPUT_VOLTAGE), s.get(ct.PRESENT_TEMPERATURE)
            torque = s.get(ct.TORQUE_ENABLE)
            lines.append(f"{s.joint:>5} {s.servo_id:>3} {s.model_number:>6} {_text(s.get(ct.FIRMWARE_VERSION)):>3} "
                         f"{mode_text:<24} {f'{_text(lo)}..{_text(hi)}':>15} "
                         f"{(f'{volts / 10:.1f}' if volts is not None else '?'):>7} {_text(temp):>6} "
                         f"{('on' if torque else 'off') if torque is not None else '?':>6}")
        return "\n".join(lines)

    def to_json(self) -> dict[str, Any]:
        return {"port": self.port, "ok": not self.mismatches, "mismatches": self.mismatches,
                "servos": [{"joint": s.joint, "id": s.servo_id, "model_number": s.model_number,
                            "registers": s.registers, "mismatches": list(s.mismatches)} for s in self.servos],
                "unexpected_ids": {str(i): m for i, m in sorted(self.unexpected.items())}}


def _text(value: int | None) -> str:
    return "?" if value is None else str(value)


def _mode_name(value: int) -> str:
    try:
        return f"{value} ({OperatingMode(value).name.lower()})"
    except ValueError:
        return f"{value} (unknown)"


def survey_bus(config: BusConfig, *, attempts: int = 3) -> BusSurvey:
    """Survey the bus against ``config`` (see the module docstring); writes nothing.

    Raises:
        ConnectError: the port cannot be opened. Disconnected: it failed meanwhile.
    """
    bus = DynamixelBus(config, connect_retries=attempts)
    bus.open()
    try:
        answered = bus.broadcast_ping()
        servos = []
        for joint in config.joints:
            model = answered.get(joint.servo_id)
            if model is None:
                model = bus.ping_model(joint.servo_id)
            registers = {} if model is None else {
                f.name: v for f in SURVEYED if (v := bus.read_register(joint.servo_id, f)) is not None}
            survey = ServoSurvey(joint.joint, joint.servo_id, model, registers)
            servos.append(replace(survey, mismatches=tuple(_mismatches(survey, config, bus.name(joint.servo_id)))))
    finally:
        bus.close()
    configured = set(config.servo_ids)
    return BusSurvey(config.port, tuple(servos), {i: m for i, m in answered.items() if i not in configured})


def _mismatches(s: ServoSurvey, config: BusConfig, name: str) -> list[str]:
    """Each difference of one servo from the configuration, as a sentence naming it."""
    if s.model_number is None:
        return [f"{name}: no answer to ping (wired? powered? another ID or baud rate?)"]
    out = []
    servo = config.servo
    if s.model_number != servo.model_number:
        out.append(f"{name}: model number {s.model_number}, the configuration expects {servo.model_number} "
                   f"([servo] model_number)")
    missing = [f.name for f in SURVEYED if f.name not in s.registers]
    if missing:
        out.append(f"{name}: could not read {', '.join(missing)}")
    bits = s.get(ct.HARDWARE_ERROR_STATUS)
    if bits:
        out.append(f"{name}: hardware error ({describe_hardware_error(bits)}); reboot or power-cycle the servo")
    volts, v_lo, v_hi = (s.get(ct.PRESENT_INPUT_VOLTAGE), s.get(ct.MIN_VOLTAGE_LIMIT), s.get(ct.MAX_VOLTAGE_LIMIT))
    if None not in (volts, v_lo, v_hi) and not v_lo <= volts <= v_hi:
        out.append(f"{name}: input voltage {volts / 10:.1f} V outside its limits {v_lo / 10:.1f}..{v_hi / 10:.1f} V "
                   f"(supply or wiring)")
    temp, t_max = s.get(ct.PRESENT_TEMPERATURE), s.get(ct.TEMPERATURE_LIMIT)
    if None not in (temp, t_max) and temp >= t_max - TEMPERATURE_MARGIN_C:
        out.append(f"{name}: temperature {temp} C, within {TEMPERATURE_MARGIN_C} C of its limit {t_max} C; "
                   f"let it cool")
    mode = s.get(ct.OPERATING_MODE)
    if mode is not None and mode != int(servo.operating_mode):
        asked = _mode_name(int(servo.operating_mode))
        out.append(f"{name}: Operating Mode {_mode_name(mode)}, the configuration asks {asked} "
                   f"(cobra record writes it at connect)")
    if servo.operating_mode is OperatingMode.POSITION:
        limits = dict(zip(config.servo_ids, config.position_limits_pulses()))[s.servo_id]
        found = (s.get(ct.MIN_POSITION_LIMIT), s.get(ct.MAX_POSITION_LIMIT))
        if None not in found and found != limits:
            out.append(f"{name}: position limits {found[0]}..{found[1]} pulses, the configuration's joint limit "
                       f"gives {limits[0]}..{limits[1]} (cobra record writes them at connect)")
    return out
