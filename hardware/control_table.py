"""Control table of the ROBOTIS XH540-W270 (Protocol 2.0, X-series layout).

Addresses, sizes, access and defaults follow the XH540-W270 e-manual (the same table ships with
ROBOTIS's own SDK as ``dynamixel_easy_sdk/control_table/xh540_w270.model``). Fields below
address 64 live in EEPROM and can only be written while torque is off. The indirect-address
area (168 and up) and the external-port data are left out: nothing in this project uses them.

:class:`ControlTable` is the byte image of one servo's table, used by the bus emulator.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum, IntFlag

from cobra_model.servo import GAIN_REGISTER_MAX, PWM_FULL_SCALE
from hardware.units import to_signed

#: Model number the XH540-W270 answers a ping with. ROBOTIS's model list (the SDK's
#: ``dynamixel_easy_sdk/control_table/dynamixel.model``) gives 1100 for the XH540-W270;
#: 1120 is the XM540-W270.
XH540_W270_MODEL_NUMBER = 1100
#: Model numbers of the X-series servos whose control table is this one with Present Current
#: (126) read as the driver reads it (XM, XH and XW series; ROBOTIS's model numbers).
KNOWN_MODELS: dict[int, str] = {
    1000: "XH430-W350", 1010: "XH430-W210", 1020: "XM430-W350", 1030: "XM430-W210", 1040: "XH430-V350",
    1050: "XH430-V210", 1100: "XH540-W270", 1110: "XH540-W150", 1120: "XM540-W270", 1130: "XM540-W150",
    1140: "XH540-V270", 1150: "XH540-V150", 1170: "XW540-T260", 1180: "XW540-T140",
}
#: First RAM address; lower addresses are EEPROM.
EEPROM_END = 64
#: Bytes of the table image (addresses 0..146).
TABLE_SIZE = 147


class OperatingMode(IntEnum):
    """Values of Operating Mode (11)."""

    CURRENT = 0
    VELOCITY = 1
    POSITION = 3
    EXTENDED_POSITION = 4
    CURRENT_BASED_POSITION = 5
    PWM = 16


#: Operating modes in which the servo follows Goal Position (116).
POSITION_MODES = frozenset({OperatingMode.POSITION, OperatingMode.EXTENDED_POSITION,
                            OperatingMode.CURRENT_BASED_POSITION})


class HardwareError(IntFlag):
    """Bits of Hardware Error Status (70)."""

    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20


def describe_hardware_error(bits: int) -> str:
    """Readable list of the hardware error bits set in ``bits``, e.g. ``"overload, overheating"``."""
    names = [flag.name.lower().replace("_", " ") for flag in HardwareError if bits & flag]
    unknown = bits & ~sum(HardwareError)
    if unknown:
        names.append(f"unknown bits 0x{unknown:02X}")
    return ", ".join(names) if names else "none"


#: Baud Rate (8) register values of the supported port speeds [bit/s].
BAUD_RATE_CODES: dict[int, int] = {
    9600: 0, 57600: 1, 115200: 2, 1_000_000: 3, 2_000_000: 4, 3_000_000: 5, 4_000_000: 6,
}


@dataclass(frozen=True)
class Field:
    """One control-table entry.

    Attributes:
        name: the e-manual's name.
        address: first byte.
        size: bytes (1, 2 or 4), little endian.
        writable: RW (True) or read-only (False).
        default: value after power-on (raw units).
        signed: interpret as two's complement.
        valid: inclusive raw range a write must respect, or None for the full width.
    """

    name: str
    address: int
    size: int
    writable: bool
    default: int
    signed: bool = False
    valid: tuple[int, int] | None = None

    @property
    def eeprom(self) -> bool:
        """True for EEPROM fields (writable only with torque off)."""
        return self.address < EEPROM_END

    @property
    def end(self) -> int:
        """One past the last byte."""
        return self.address + self.size


MODEL_NUMBER = Field("Model Number", 0, 2, False, XH540_W270_MODEL_NUMBER)
MODEL_INFORMATION = Field("Model Information", 2, 4, False, 0)
FIRMWARE_VERSION = Field("Firmware Version", 6, 1, False, 46)
ID = Field("ID", 7, 1, True, 1, valid=(0, 252))
BAUD_RATE = Field("Baud Rate", 8, 1, True, 1, valid=(0, 7))
RETURN_DELAY_TIME = Field("Return Delay Time", 9, 1, True, 250)
DRIVE_MODE = Field("Drive Mode", 10, 1, True, 0)
OPERATING_MODE = Field("Operating Mode", 11, 1, True, OperatingMode.POSITION)
SECONDARY_ID = Field("Secondary(Shadow) ID", 12, 1, True, 255)
PROTOCOL_TYPE = Field("Protocol Type", 13, 1, True, 2, valid=(1, 2))
HOMING_OFFSET = Field("Homing Offset", 20, 4, True, 0, signed=True)
MOVING_THRESHOLD = Field("Moving Threshold", 24, 4, True, 10, valid=(0, 1023))
TEMPERATURE_LIMIT = Field("Temperature Limit", 31, 1, True, 80, valid=(0, 100))
MAX_VOLTAGE_LIMIT = Field("Max Voltage Limit", 32, 2, True, 160, valid=(95, 160))
MIN_VOLTAGE_LIMIT = Field("Min Voltage Limit", 34, 2, True, 95, valid=(95, 160))
PWM_LIMIT = Field("PWM Limit", 36, 2, True, PWM_FULL_SCALE, valid=(0, PWM_FULL_SCALE))
CURRENT_LIMIT = Field("Current Limit", 38, 2, True, 2047, valid=(0, 2047))
VELOCITY_LIMIT = Field("Velocity Limit", 44, 4, True, 128, valid=(0, 1023))
MAX_POSITION_LIMIT = Field("Max Position Limit", 48, 4, True, 4095, valid=(0, 4095))
MIN_POSITION_LIMIT = Field("Min Position Limit", 52, 4, True, 0, valid=(0, 4095))
SHUTDOWN = Field("Shutdown", 63, 1, True, 0x34)
TORQUE_ENABLE = Field("Torque Enable", 64, 1, True, 0, valid=(0, 1))
LED = Field("LED", 65, 1, True, 0, valid=(0, 1))
STATUS_RETURN_LEVEL = Field("Status Return Level", 68, 1, True, 2, valid=(0, 2))
REGISTERED_INSTRUCTION = Field("Registered Instruction", 69, 1, False, 0)
HARDWARE_ERROR_STATUS = Field("Hardware Error Status", 70, 1, False, 0)
VELOCITY_I_GAIN = Field("Velocity I Gain", 76, 2, True, 1920, valid=(0, GAIN_REGISTER_MAX))
VELOCITY_P_GAIN = Field("Velocity P Gain", 78, 2, True, 100, valid=(0, GAIN_REGISTER_MAX))
POSITION_D_GAIN = Field("Position D Gain", 80, 2, True, 0, valid=(0, GAIN_REGISTER_MAX))
POSITION_I_GAIN = Field("Position I Gain", 82, 2, True, 0, valid=(0, GAIN_REGISTER_MAX))
POSITION_P_GAIN = Field("Position P Gain", 84, 2, True, 800, valid=(0, GAIN_REGISTER_MAX))
FEEDFORWARD_2ND_GAIN = Field("Feedforward 2nd Gain", 88, 2, True, 0, valid=(0, GAIN_REGISTER_MAX))
FEEDFORWARD_1ST_GAIN = Field("Feedforward 1st Gain", 90, 2, True, 0, valid=(0, GAIN_REGISTER_MAX))
BUS_WATCHDOG = Field("Bus Watchdog", 98, 1, True, 0, signed=True, valid=(0, 127))
#: Bus Watchdog (98) unit [s]; the register reads -1 once the watchdog has stopped the servo.
BUS_WATCHDOG_UNIT_S = 0.020
BUS_WATCHDOG_TRIPPED = -1
GOAL_PWM = Field("Goal PWM", 100, 2, True, PWM_FULL_SCALE, signed=True, valid=(-PWM_FULL_SCALE, PWM_FULL_SCALE))
GOAL_CURRENT = Field("Goal Current", 102, 2, True, 2047, signed=True, valid=(-2047, 2047))
GOAL_VELOCITY = Field("Goal Velocity", 104, 4, True, 0, signed=True, valid=(-1023, 1023))
PROFILE_ACCELERATION = Field("Profile Acceleration", 108, 4, True, 0, valid=(0, 32767))
PROFILE_VELOCITY = Field("Profile Velocity", 112, 4, True, 0, valid=(0, 32767))
GOAL_POSITION = Field("Goal Position", 116, 4, True, 2048, signed=True)
REALTIME_TICK = Field("Realtime Tick", 120, 2, False, 0)
MOVING = Field("Moving", 122, 1, False, 0)
MOVING_STATUS = Field("Moving Status", 123, 1, False, 0)
PRESENT_PWM = Field("Present PWM", 124, 2, False, 0, signed=True)
PRESENT_CURRENT = Field("Present Current", 126, 2, False, 0, signed=True)
PRESENT_VELOCITY = Field("Present Velocity", 128, 4, False, 0, signed=True)
PRESENT_POSITION = Field("Present Position", 132, 4, False, 2048, signed=True)
VELOCITY_TRAJECTORY = Field("Velocity Trajectory", 136, 4, False, 0, signed=True)
POSITION_TRAJECTORY = Field("Position Trajectory", 140, 4, False, 2048, signed=True)
PRESENT_INPUT_VOLTAGE = Field("Present Input Voltage", 144, 2, False, 120)
PRESENT_TEMPERATURE = Field("Present Temperature", 146, 1, False, 30)

#: Goal registers, read-only while the Bus Watchdog has stopped the servo.
GOAL_FIELDS: tuple[Field, ...] = (GOAL_PWM, GOAL_CURRENT, GOAL_VELOCITY, GOAL_POSITION)

#: Every field above, in address order.
FIELDS: tuple[Field, ...] = tuple(sorted((v for v in list(globals().values()) if isinstance(v, Field)),
                                         key=lambda f: f.address))

#: The block the driver reads every cycle: Present Current (126) .. Present Position (132..135).
PRESENT_STATE_ADDRESS = PRESENT_CURRENT.address
PRESENT_STATE_LENGTH = PRESENT_POSITION.end - PRESENT_CURRENT.address


class ControlTable:
    """Byte image of one servo's control table with typed access.

    Args:
        servo_id: the servo's ID (stored in ID (7)).
        model_number: the value of Model Number (0).
    """

    def __init__(self, servo_id: int, model_number: int = XH540_W270_MODEL_NUMBER) -> None:
        self._bytes = bytearray(TABLE_SIZE)
        for field in FIELDS:
            self.set(field, field.default)
        self.set(ID, servo_id)
        self.set(MODEL_NUMBER, model_number)

    def get(self, field: Field) -> int:
        """Value of ``field`` (signed where the field is)."""
        raw = int.from_bytes(self._bytes[field.address:field.end], "little")
        return to_signed(raw, field.size) if field.signed else raw

    def set(self, field: Field, value: int) -> None:
        """Store ``value`` in ``field`` (no access or range check; wraps to the field width)."""
        self._bytes[field.address:field.end] = (int(value) & ((1 << (8 * field.size)) - 1)).to_bytes(
            field.size, "little")

    def read(self, address: int, length: int) -> bytes:
        """Raw bytes ``[address, address + length)``; the caller checks the range."""
        return bytes(self._bytes[address:address + length])

    def write(self, address: int, data: bytes) -> None:
        """Store raw bytes at ``address``; the caller checks access and values."""
        self._bytes[address:address + len(data)] = data

    @property
    def torque_enabled(self) -> bool:
        """Torque Enable (64) is 1."""
        return self.get(TORQUE_ENABLE) == 1

    @property
    def hardware_error(self) -> int:
        """Hardware Error Status (70) bits."""
        return self.get(HARDWARE_ERROR_STATUS)


def fields_in(address: int, length: int) -> list[Field]:
    """Every field overlapping the byte range ``[address, address + length)``."""
    end = address + length
    return [f for f in FIELDS if f.address < end and address < f.end]
