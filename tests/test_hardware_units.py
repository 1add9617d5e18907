"""Raw Dynamixel units and the joint-angle convention (offsets, directions)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from hardware.units import (
    AMP_PER_CURRENT_UNIT,
    amp_to_current_units,
    current_units_to_amp,
    joint_to_servo_rad,
    pulses_to_rad,
    rad_s_to_velocity_units,
    rad_to_pulses,
    servo_to_joint_rad,
    to_signed,
    velocity_units_to_rad_s,
)


def test_position_is_0088_deg_per_pulse_around_2048() -> None:
    assert pulses_to_rad(2048) == 0.0
    assert np.degrees(pulses_to_rad(2049)) == pytest.approx(0.088, abs=2e-4)
    assert np.degrees(pulses_to_rad([1024, 3072, 0, 4096])) == pytest.approx([-90, 90, -180, 180])
    assert rad_to_pulses(np.radians([-90.0, 0.0, 90.0])).tolist() == [1024, 2048, 3072]
    # Rounding to the nearest pulse: the round trip is within half a pulse.
    q = np.linspace(-1.5, 1.5, 101)
    assert np.abs(pulses_to_rad(rad_to_pulses(q)) - q).max() <= math.pi / 4096 + 1e-12


def test_velocity_is_0229_rpm_per_unit() -> None:
    assert velocity_units_to_rad_s(1) == pytest.approx(0.229 * 2 * math.pi / 60)
    assert velocity_units_to_rad_s(-100) == pytest.approx(-22.9 * 2 * math.pi / 60)
    assert rad_s_to_velocity_units(velocity_units_to_rad_s(np.arange(-50, 50))).tolist() == list(range(-50, 50))


def test_current_is_269_ma_per_unit() -> None:
    assert AMP_PER_CURRENT_UNIT == 2.69e-3
    assert current_units_to_amp(1000) == pytest.approx(2.69)
    assert amp_to_current_units(-2.69).item() == -1000


def test_signed_registers() -> None:
    assert to_signed(0xFFFF, 2) == -1
    assert to_signed(0x7FFF, 2) == 32767
    assert to_signed(0x8000, 2) == -32768
    assert to_signed(0xFFFFFF9C, 4) == -100
    assert to_signed(4095, 4) == 4095


def test_offsets_and_directions_invert() -> None:
    offset = np.radians([10.0, -5.0, 0.0])
    direction = np.array([1.0, -1.0, -1.0])
    q = np.radians([30.0, 30.0, -45.0])
    theta = joint_to_servo_rad(q, offset, direction)
    assert np.degrees(theta) == pytest.approx([40.0, -35.0, 45.0])
    assert servo_to_joint_rad(theta, offset, direction) == pytest.approx(q)
