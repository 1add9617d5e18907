"""Raw Dynamixel X-series units and the joint-angle convention of the COBRA bus.

Raw units (XH540-W270 e-manual):

* position: 4096 pulses per revolution, 2048 at the centre of the range. The e-manual rounds
  the resolution to 0.088 deg/pulse; the exact value 360/4096 = 0.087890625 deg/pulse is used
  here so that 2048 +- 1024 pulses is exactly +-90 deg.
* velocity: 0.229 rev/min per unit (signed 32 bit).
* current: 2.69 mA per unit (signed 16 bit).
* profile acceleration: 214.577 rev/min^2 per unit.

Joint angles: a servo's angle ``theta = (raw - 2048) * RAD_PER_PULSE`` relates to the joint
angle ``q`` of ``urdf/cobra.urdf`` by ``theta = zero_offset + direction * q`` with the per-joint
zero offset [rad] and direction (+1 or -1) of the bus configuration.
"""
from __future__ import annotations

import math

import numpy as np

from cobra_model.servo import AMP_PER_CURRENT_UNIT, POSITION_CENTER_PULSE, RAD_PER_PULSE

#: Velocity resolution [rad/s per unit] (0.229 rpm/unit).
RAD_S_PER_VELOCITY_UNIT = 0.229 * 2.0 * math.pi / 60.0
#: Profile acceleration resolution [rad/s^2 per unit] (214.577 rev/min^2 per unit).
RAD_S2_PER_ACCELERATION_UNIT = 214.577 * 2.0 * math.pi / 3600.0


def to_signed(value: int, size: int) -> int:
    """Two's-complement interpretation of an unsigned ``size``-byte register value."""
    bits = 8 * size
    value &= (1 << bits) - 1
    return value - (1 << bits) if value >= 1 << (bits - 1) else value


def pulses_to_rad(raw: np.ndarray) -> np.ndarray:
    """Servo angle [rad] relative to the centre (2048) of raw positions [pulse]."""
    return (np.asarray(raw, dtype=float) - POSITION_CENTER_PULSE) * RAD_PER_PULSE


def rad_to_pulses(theta_rad: np.ndarray) -> np.ndarray:
    """Raw positions [pulse] (int64, rounded) of servo angles [rad] relative to the centre."""
    return np.rint(np.asarray(theta_rad, dtype=float) / RAD_PER_PULSE).astype(np.int64) + POSITION_CENTER_PULSE


def velocity_units_to_rad_s(raw: np.ndarray) -> np.ndarray:
    """Angular velocity [rad/s] of signed raw velocities [0.229 rpm]."""
    return np.asarray(raw, dtype=float) * RAD_S_PER_VELOCITY_UNIT


def rad_s_to_velocity_units(omega_rad_s: np.ndarray) -> np.ndarray:
    """Signed raw velocities [0.229 rpm] (int64, rounded) of angular velocities [rad/s]."""
    return np.rint(np.asarray(omega_rad_s, dtype=float) / RAD_S_PER_VELOCITY_UNIT).astype(np.int64)


def current_units_to_amp(raw: np.ndarray) -> np.ndarray:
    """Motor current [A] of signed raw currents [2.69 mA]."""
    return np.asarray(raw, dtype=float) * AMP_PER_CURRENT_UNIT


def amp_to_current_units(current_a: np.ndarray) -> np.ndarray:
    """Signed raw currents [2.69 mA] (int64, rounded) of motor currents [A]."""
    return np.rint(np.asarray(current_a, dtype=float) / AMP_PER_CURRENT_UNIT).astype(np.int64)


def joint_to_servo_rad(q_rad: np.ndarray, zero_offset_rad: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Servo angles [rad] from joint angles [rad]: ``offset + direction * q``."""
    return np.asarray(zero_offset_rad) + np.asarray(direction) * np.asarray(q_rad, dtype=float)


def servo_to_joint_rad(theta_rad: np.ndarray, zero_offset_rad: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """Joint angles [rad] from servo angles [rad]: ``direction * (theta - offset)``."""
    return np.asarray(direction) * (np.asarray(theta_rad, dtype=float) - np.asarray(zero_offset_rad))
