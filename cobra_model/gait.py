"""The paper's sidewinding gait (Eq. 2): ``q_ref_i(t) = A_i sin(2 pi f t + phi_i)``.

Odd joints pitch with ``A = 14 deg``, even joints yaw with ``A = 60 deg``, and the phases are
``phi = pi/2 [0, 0, 1, 1, 2, 2, 3, 3, 0, 0, 1]``. A smooth start multiplies the amplitude by
``s(t) = sin^2(pi t / (2 T_ramp))`` for ``t < T_ramp`` (value and slope continuous at both
ends), so the robot is not kicked at ``t = 0``: at ``t = 0`` the command is the straight pose
with zero velocity.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from cobra_model.design import NUM_JOINTS
from cobra_model.errors import InputError

#: Paper's gait frequencies [Hz].
PAPER_FREQUENCIES_HZ: tuple[float, ...] = (0.35, 0.5, 0.65)
PAPER_PHASES_RAD: tuple[float, ...] = tuple(np.pi / 2 * np.array([0, 0, 1, 1, 2, 2, 3, 3, 0, 0, 1]))
AMP_PITCH_RAD = float(np.deg2rad(14.0))
AMP_YAW_RAD = float(np.deg2rad(60.0))


@dataclass(frozen=True)
class SidewindingGait:
    """Sinusoidal joint commands of the paper's sidewinding gait.

    Attributes:
        freq_hz: gait frequency f [Hz] (> 0).
        amp_pitch_rad: amplitude of the odd (pitch) joints [rad].
        amp_yaw_rad: amplitude of the even (yaw) joints [rad].
        phases_rad: the 11 joint phases phi_i [rad].
        ramp_s: smooth-start duration T_ramp [s] (0 for none).
    """

    freq_hz: float
    amp_pitch_rad: float = AMP_PITCH_RAD
    amp_yaw_rad: float = AMP_YAW_RAD
    phases_rad: tuple[float, ...] = field(default=PAPER_PHASES_RAD)
    ramp_s: float = 1.0

    def __post_init__(self) -> None:
        if not (self.freq_hz > 0 and np.isfinite(self.freq_hz)):
            raise InputError(f"gait frequency must be a positive number of Hz, got {self.freq_hz}")
        if len(self.phases_rad) != NUM_JOINTS:
            raise InputError(f"gait needs {NUM_JOINTS} phases, got {len(self.phases_rad)}")
        if self.ramp_s < 0:
            raise InputError(f"gait ramp must be >= 0 s, got {self.ramp_s}")

    @property
    def amplitudes(self) -> np.ndarray:
        """(11,) joint amplitudes [rad]: pitch on odd joints (index 0, 2, ...), yaw on even ones."""
        amp = np.full(NUM_JOINTS, self.amp_yaw_rad)
        amp[0::2] = self.amp_pitch_rad
        return amp

    def envelope(self, t: float | np.ndarray) -> np.ndarray:
        """Smooth-start factor in [0, 1] at time(s) ``t`` [s]."""
        t = np.asarray(t, dtype=float)
        if self.ramp_s == 0:
            return np.ones_like(t)
        x = np.clip(t / self.ramp_s, 0.0, 1.0)
        return np.sin(0.5 * np.pi * x) ** 2

    def q_ref(self, t: float | np.ndarray) -> np.ndarray:
        """Commanded joint angles [rad], shape ``t.shape + (11,)``."""
        t = np.asarray(t, dtype=float)
        arg = 2 * np.pi * self.freq_hz * t[..., None] + np.asarray(self.phases_rad)
        return self.envelope(t)[..., None] * self.amplitudes * np.sin(arg)

    def to_json(self) -> dict[str, Any]:
        """The sidecar's ``gait`` entry."""
        return {
            "type": "sidewinding",
            "frequency_hz": self.freq_hz,
            "amplitude_pitch_rad": self.amp_pitch_rad,
            "amplitude_yaw_rad": self.amp_yaw_rad,
            "phases_rad": list(self.phases_rad),
            "ramp_s": self.ramp_s,
        }


def dominant_frequency_hz(t: np.ndarray, angles: np.ndarray) -> float:
    """The gait frequency [Hz] of joint angles ``angles`` (N, J) sampled at times ``t`` (N,) [s]:
    the peak of their summed amplitude spectrum (for a recording whose sidecar names no gait)."""
    y = angles - angles.mean(axis=0)
    spec = np.abs(np.fft.rfft(y, axis=0)).sum(axis=1)
    freqs = np.fft.rfftfreq(len(y), float(np.median(np.diff(t))))
    return float(freqs[1 + np.argmax(spec[1:])])
