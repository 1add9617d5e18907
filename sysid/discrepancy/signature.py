"""Localising a disagreement: where and how simulated runs differ from measured ones.

From pairs (measured run, simulated run on the measured times) the residuals are summarised in
numbers a person can read and the effect library can match:

- **channel**: head-path error [m] against joint-tracking error [rad], each over its noise scale
  (``head_share`` near 1: the head path carries the disagreement);
- **joints**: per-joint RMS of ``e = q_measured - q_simulated`` [rad];
- **gait phase**: RMS of ``e`` in eight bins of the gait cycle (peak bin);
- **dependence** of ``e`` on the commanded velocity's sign (``r_sign``), the commanded velocity
  (``r_vel``), the commanded position (``r_pos``), the commanded effort (``r_effort``: |e| against
  the loop error ``|q_ref - q_sim|``), and velocity reversals (``reversal_ratio``: RMS of ``e``
  within 10 % of a cycle of a reversal over RMS elsewhere);
- **offset**: mean of ``e`` over its spread per joint (``offset_score``);
- **amplitude**: measured over simulated joint amplitude (``amplitude_ratio``);
- **time shift**: the lag [s] maximising the cross-correlation of measured and simulated joints
  (``lag_s`` > 0: the measurement lags);
- **slip direction**: the head-velocity residual along the head's axis vs sideways
  (``sideways_share``).
Correlations are Pearson coefficients signed so that the effect's sign convention does not matter
(absolute values are reported with their signs kept in ``*_signed``).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Sequence

import numpy as np

from cobra_model.kinematics import yaw_of_quat_wxyz
from cobra_model.run import Run

HEAD_SCALE_M = 0.01
JOINT_SCALE_RAD = 0.01


@dataclass(frozen=True)
class Signature:
    """The localisation numbers (see the module docstring)."""

    head_final_m: float
    head_mean_m: float
    joint_rmse_rad: float
    head_share: float
    joint_rms_rad: list[float]
    worst_joint: int
    phase_rms_rad: list[float]
    peak_phase_bin: int
    r_sign: float
    r_vel: float
    r_pos: float
    r_effort: float
    r_sign_signed: float
    r_vel_signed: float
    reversal_ratio: float
    offset_score: float
    offset_rad: float
    amplitude_ratio: float
    lag_s: float
    sideways_share: float
    head_measured: bool = True

    def to_json(self) -> dict:
        return asdict(self)

    def summary(self) -> str:
        """One readable paragraph."""
        channel = "the head path" if self.head_share > 0.6 else "joint tracking" if self.head_share < 0.4 else \
            "both the head path and joint tracking"
        head = (f"head final {self.head_final_m * 100:.1f} cm, mean {self.head_mean_m * 100:.1f} cm"
                if self.head_measured else "head not measured: joint-only runs")
        return (f"disagreement mostly in {channel} ({head}; joint RMSE {self.joint_rmse_rad:.4f} rad, worst joint "
                f"{self.worst_joint}); joint residuals vs sign(qdot): r = {self.r_sign_signed:+.2f}, vs qdot: "
                f"r = {self.r_vel_signed:+.2f}, vs effort: r = {self.r_effort:+.2f}; reversal ratio "
                f"{self.reversal_ratio:.2f}; offset score {self.offset_score:.2f} ({self.offset_rad:+.4f} rad); "
                f"amplitude ratio {self.amplitude_ratio:.3f}; best lag {self.lag_s * 1000:+.0f} ms; "
                f"sideways share of head slip residual {self.sideways_share:.2f}")


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = np.sqrt((a * a).sum() * (b * b).sum())
    return float((a * b).sum() / den) if den > 0 else 0.0


def localise(pairs: Sequence[tuple[Run, Run]], *, freq_hz: Sequence[float] | None = None) -> Signature:
    """Signature of the residuals of (measured, simulated) run pairs sampled on the same times."""
    E, S, V, P, L, phase, rev = [], [], [], [], [], [], []
    finals, means, seen, joint_sq, amp_m, amp_s = [], [], [], [], [], []
    slip_along, slip_side, lags = [], [], []
    for k, (m, s) in enumerate(pairs):
        t = m.t
        e = m.q - s.q
        qd_ref = np.gradient(m.q_ref, t, axis=0)
        E.append(e)
        S.append(np.sign(qd_ref))
        V.append(qd_ref)
        P.append(m.q_ref)
        L.append(np.abs(m.q_ref - s.q))
        f = freq_hz[k] if freq_hz is not None else m.gait_frequency_hz
        phase.append(np.mod(f * (t - t[0]), 1.0))
        # time since the nearest reversal of the commanded velocity, per joint, in cycles
        near = np.zeros_like(e, dtype=bool)
        for j in range(e.shape[1]):
            flips = np.flatnonzero(np.diff(np.sign(qd_ref[:, j])) != 0)
            if flips.size:
                d = np.min(np.abs(t[:, None] - t[flips][None, :]), axis=1) * f
                near[:, j] = d < 0.1
        rev.append(near)
        err = np.linalg.norm(m.head_pos[:, :2] - s.head_pos[:, :2], axis=1)
        ok = np.flatnonzero(np.isfinite(err))
        seen.append(ok.size > 0)
        finals.append(float(err[ok[-1]]) if ok.size else 0.0)
        means.append(float(np.mean(err[ok])) if ok.size else 0.0)
        joint_sq.append(np.mean(e ** 2))
        amp_m.append(np.std(m.q, axis=0))
        amp_s.append(np.std(s.q, axis=0))
        # slip residual: head velocity difference in the head's (along, sideways) frame
        vm = np.gradient(m.head_pos[:, :2], t, axis=0)
        vs = np.gradient(s.head_pos[:, :2], t, axis=0)
        yaw = yaw_of_quat_wxyz(s.head_quat)
        dv = vm - vs
        good = np.all(np.isfinite(dv), axis=1) & np.isfinite(yaw)
        c, sn = np.cos(yaw[good]), np.sin(yaw[good])
        slip_along.append(np.sum((dv[good, 0] * c + dv[good, 1] * sn) ** 2))
        slip_side.append(np.sum((-dv[good, 0] * sn + dv[good, 1] * c) ** 2))
        # time shift: best lag of the measured joints against the simulated ones (+-0.2 s)
        dt = float(np.median(np.diff(t)))
        shifts = np.arange(-int(0.2 / dt), int(0.2 / dt) + 1)
        x = m.q - m.q.mean(axis=0)
        y = s.q - s.q.mean(axis=0)
        score = [np.sum(x[max(0, h):len(x) + min(0, h)] * y[max(0, -h):len(y) - max(0, h)]) for h in shifts]
        lags.append(shifts[int(np.argmax(score))] * dt)
    E_, S_, V_, P_, L_ = (np.concatenate(a) for a in (E, S, V, P, L))
    ph, near = np.concatenate(phase), np.concatenate(rev)
    bins = np.minimum((ph * 8).astype(int), 7)
    phase_rms = [float(np.sqrt(np.mean(E_[bins == b] ** 2))) if np.any(bins == b) else 0.0 for b in range(8)]
    rms_rev = np.sqrt(np.mean(E_[near] ** 2)) if near.any() else 0.0
    rms_else = np.sqrt(np.mean(E_[~near] ** 2)) if (~near).any() else 1.0
    per_joint_mean = E_.mean(axis=0)
    per_joint_std = E_.std(axis=0) + 1e-12
    joint_rmse = float(np.sqrt(np.mean(joint_sq)))
    head_n = float(np.mean(means)) / HEAD_SCALE_M
    joint_n = joint_rmse / JOINT_SCALE_RAD
    r_sign = _corr(E_.ravel(), S_.ravel())
    r_vel = _corr(E_.ravel(), V_.ravel())
    return Signature(
        head_final_m=float(np.mean(finals)), head_mean_m=float(np.mean(means)), joint_rmse_rad=joint_rmse,
        head_share=head_n / (head_n + joint_n) if head_n + joint_n > 0 else 0.5, head_measured=any(seen),
        joint_rms_rad=[float(v) for v in np.sqrt(np.mean(E_ ** 2, axis=0))],
        worst_joint=int(np.argmax(np.mean(E_ ** 2, axis=0))) + 1,
        phase_rms_rad=phase_rms, peak_phase_bin=int(np.argmax(phase_rms)),
        r_sign=abs(r_sign), r_vel=abs(r_vel), r_pos=abs(_corr(E_.ravel(), P_.ravel())),
        r_effort=_corr(np.abs(E_).ravel(), L_.ravel()), r_sign_signed=r_sign, r_vel_signed=r_vel,
        reversal_ratio=float(rms_rev / rms_else) if rms_else > 0 else 1.0,
        offset_score=float(np.mean(np.abs(per_joint_mean) / per_joint_std)),
        offset_rad=float(np.mean(per_joint_mean)),
        amplitude_ratio=float(np.mean(np.concatenate(amp_m)) / max(np.mean(np.concatenate(amp_s)), 1e-12)),
        lag_s=float(np.median(lags)),
        sideways_share=float(np.sum(slip_side) / max(np.sum(slip_side) + np.sum(slip_along), 1e-300)),
    )
