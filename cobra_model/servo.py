"""The servo: ROBOTIS XH540-W270 datasheet values and the Dynamixel X conventions, in one place.

Datasheet values are at the 12 V operating point. The conventions are the e-manual's: a position
is counted in pulses, 4096 per turn and 2048 at the centre; the position loop's gains are raw
register values scaled by ``P/128``, ``I/65536`` and ``D/16`` onto an error in pulses, and its
output is a PWM command in which 885 is 100 % duty. The simulator's servo model
(:mod:`integrators.kernels`), the MuJoCo twin's linearised servo, the bus driver's registers and
units (:mod:`hardware`) and the measured runs' encoder quantisation all read them from here.
"""
from __future__ import annotations

import math

# --- Datasheet (XH540-W270 at 12 V) ----------------------------------------------------------
SERVO_MASS_KG = 0.165
SERVO_GEAR_RATIO = 272.5
SERVO_STALL_TORQUE_NM = 9.9
SERVO_NO_LOAD_RPM = 39.0
SUPPLY_VOLTAGE_V = 12.0
SERVO_NO_LOAD_SPEED_RAD_S = SERVO_NO_LOAD_RPM * 2.0 * math.pi / 60.0

# --- Dynamixel X conventions (e-manual) ------------------------------------------------------
#: Encoder pulses per revolution of the output shaft.
PULSES_PER_REV = 4096
#: Raw position at the centre of the range.
POSITION_CENTER_PULSE = 2048
#: Position resolution [rad/pulse] (0.088 deg/pulse).
RAD_PER_PULSE = 2.0 * math.pi / PULSES_PER_REV
#: PWM command of 100 % duty (also the largest PWM Limit).
PWM_FULL_SCALE = 885
#: Position-loop gain registers -> gains on the error in pulses: ``P/128``, ``I/65536``, ``D/16``.
P_GAIN_DIVISOR = 128.0
I_GAIN_DIVISOR = 65536.0
D_GAIN_DIVISOR = 16.0
#: Largest value of a position-loop gain register.
GAIN_REGISTER_MAX = 16383
#: Present Current resolution [A per unit] (2.69 mA/unit).
AMP_PER_CURRENT_UNIT = 2.69e-3
#: A Present Current reading's noise [A RMS] (about 20 mA; what a measured run's currents are
#: given in :mod:`sysid.generators.dataset` and the floor of the current channel's weight).
CURRENT_NOISE_A = 0.02
