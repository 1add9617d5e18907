"""The offset between a motion-capture take's clock and a joint log's clock, from the data.

A Motive take and a joint log never start together, and 50 ms of error moves every joint's
phase by 12 degrees at 0.65 Hz. Both records see the same shape of the robot: where each tracked
body sits in the head's frame depends on the joint angles only (the robot is a kinematic chain
from the head). The take measures it as ``R_head(t)^T (p_body(t) - p_head(t))``; the joint log
predicts it through the model's kinematics, ``FK(q(t))``. The offset ``d`` (take time = joint-log
time + d) is the shift that best lines the two up: the least-squares misfit over the overlap,
each vector component centred on its mean (a rigid body's pivot need not sit exactly on the
model's tracked point), searched on a coarse grid over every shift that leaves at least one gait
cycle of overlap, then refined on a grid of a tenth of a take frame around the best, and
finally by a parabola through the misfits there. Take frames where tracking was lost are left
out (never interpolated across).

The gait is periodic, so shifts by whole periods fit almost as well: what tells them apart is
what is not periodic, above all the gait's smooth start, which the take should include (start
the capture before the gait). The reported uncertainty is the curvature of the misfit at its
minimum (``2 s^2 / SSE''``, ``s^2`` the residual variance): it treats the residuals as
independent and so understates the spread when they are correlated (pivot offsets, marker
noise filtered by Motive).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from cobra_model.errors import InputError
from cobra_model.gait import dominant_frequency_hz
from cobra_model.model import CobraModel
from cobra_model.resample import interpolate_rows
from cobra_model.motive import MotiveTake, resolve_mapping

#: Coarse search step [s].
COARSE_STEP_S = 0.005
#: Fine search: steps per take frame, and half-width in coarse steps.
FINE_STEPS_PER_FRAME = 10
FINE_HALF_WIDTH = 3


@dataclass(frozen=True)
class ClockOffset:
    """The estimated offset: take time = joint-log time + ``offset_s``.

    Attributes:
        offset_s: the offset [s]; std_s: its standard uncertainty [s] (see the module docstring).
        bodies: the run bodies whose head-frame positions were matched.
        overlap_s: joint-log span inside the take at that offset [s].
        samples: joint-log samples used (all tracked bodies seen).
        rms_m: root-mean-square misfit of the matched positions at the offset [m].
        runner_up_s: the best offset at least half a gait period away, and its rms_m (how
            clearly the gait's periodicity was resolved).
    """

    offset_s: float
    std_s: float
    bodies: tuple[str, ...]
    overlap_s: float
    samples: int
    rms_m: float
    runner_up_s: float
    runner_up_rms_m: float

    def describe(self) -> str:
        return (f"clock offset estimated from the data: take time = joint-log time + {self.offset_s:.4f} s "
                f"(+- {self.std_s * 1e3:.2f} ms), matching {', '.join(self.bodies)} in the head's frame over "
                f"{self.overlap_s:.1f} s ({self.samples} samples, misfit {self.rms_m * 1e3:.1f} mm rms; best "
                f"shift half a gait period or more away: {self.runner_up_s:+.3f} s, "
                f"{self.runner_up_rms_m * 1e3:.1f} mm)")

    def to_json(self) -> dict:
        return {"offset_s": self.offset_s, "std_s": self.std_s, "bodies": list(self.bodies),
                "overlap_s": self.overlap_s, "samples": self.samples, "rms_m": self.rms_m,
                "runner_up_s": self.runner_up_s, "runner_up_rms_m": self.runner_up_rms_m}


def head_frame_positions(take: MotiveTake, head: str, bodies: Mapping[str, str]) -> np.ndarray:
    """(N, k, 3) position of each of ``bodies`` (run name -> Motive name) in the head's frame [m]
    at every take frame; NaN where any was lost."""
    h = take.bodies[head]
    w, x, y, z = h.quats.T
    # rotation matrix, world from head (rows: x, y, z of the world)
    R = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=-2)
    rel = np.stack([take.bodies[name].positions - h.positions for name in bodies.values()], axis=1)
    return np.einsum("nji,nkj->nki", R, rel)  # R^T rel


def model_positions(model: CobraModel, q: np.ndarray, bodies: Sequence[str]) -> np.ndarray:
    """(N, k, 3) position of each body centre in the head's frame [m] from joint angles (N, 11)."""
    origin, level = np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0])
    tracks = model.body_tracks(np.array([model.configuration(qi, origin, level) for qi in q]), bodies)
    return np.stack([tracks[b] for b in bodies], axis=1)


def estimate_clock_offset(take: MotiveTake, joints: tuple[np.ndarray, np.ndarray, np.ndarray | None], *,
                          mapping: Mapping[str, str] | None = None, model: CobraModel | None = None,
                          joint_log: str = "the joint log") -> ClockOffset:
    """Estimate the take's clock offset from the joint log (see the module docstring).

    Args:
        take: the Motive take; joints: ``(t, q, q_ref)`` of :func:`cobra_model.motive.read_joint_log`.
        mapping: Motive rigid body -> run body (:func:`cobra_model.motive.resolve_mapping`).
        joint_log: the joint log's name for messages.

    Raises:
        InputError: the take tracks no body besides the head (nothing to match), or no shift
            leaves a gait cycle of overlap (naming both files and their spans).
    """
    model = model or CobraModel.load()
    t, q = np.asarray(joints[0], dtype=float), np.asarray(joints[1], dtype=float)
    resolved = resolve_mapping(take, mapping)
    head = next(name for name, target in resolved.items() if target == "head")
    others = {target: name for name, target in resolved.items() if target != "head"}
    if not others:
        raise InputError(f"{take.source}: only the head is tracked, so the take's clock cannot be matched to "
                         f"{joint_log}'s from the robot's shape; give --time-offset")
    period = 1.0 / dominant_frequency_hz(t, q)
    lo = take.times[0] - t[0] - (t[-1] - t[0]) + period
    hi = take.times[-1] - t[0] - period
    if min(take.times[-1] - take.times[0], t[-1] - t[0]) < period:
        raise InputError(f"{take.source} spans [{take.times[0]:g}, {take.times[-1]:g}] s and {joint_log} spans "
                         f"[{t[0]:g}, {t[-1]:g}] s: no shift leaves one gait cycle ({period:.2f} s) of overlap")
    seen = head_frame_positions(take, head, others)
    flat = seen.reshape(len(take.times), -1)
    predicted = model_positions(model, q, list(others)).reshape(len(t), -1)

    def misfit(d: float) -> tuple[float, int]:
        m = interpolate_rows(t + d, take.times, flat, max_gap_samples=0)
        ok = np.isfinite(m).all(axis=1)
        n = int(ok.sum())
        if n * float(np.median(np.diff(t))) < period:
            return np.inf, n
        r = (m[ok] - m[ok].mean(axis=0)) - (predicted[ok] - predicted[ok].mean(axis=0))
        return float(np.sum(r * r)), n

    coarse = np.arange(lo, hi + COARSE_STEP_S, COARSE_STEP_S)
    sse, used = np.array([misfit(d) for d in coarse]).T
    if not np.isfinite(sse).any():
        raise InputError(f"{take.source} and {joint_log}: no shift leaves one gait cycle ({period:.2f} s) of "
                         f"tracked samples to compare (tracking lost too often?)")
    k = int(np.argmin(sse))
    far = np.abs(coarse - coarse[k]) >= 0.5 * period
    j = int(np.argmin(np.where(far, sse, np.inf))) if far.any() else k
    frame = 1.0 / take.frame_rate if np.isfinite(take.frame_rate) else COARSE_STEP_S
    fine = coarse[k] + np.arange(-FINE_HALF_WIDTH * COARSE_STEP_S, (FINE_HALF_WIDTH + 0.01) * COARSE_STEP_S,
                                 frame / FINE_STEPS_PER_FRAME)
    fine_sse = np.array([misfit(d)[0] for d in fine])
    i = int(np.clip(np.argmin(fine_sse), 2, len(fine) - 3))
    a, b, _ = np.polyfit(fine[i - 2:i + 3] - fine[i], fine_sse[i - 2:i + 3], 2)
    best = float(fine[i] - b / (2 * a)) if a > 0 else float(fine[i])
    if not fine[i - 2] <= best <= fine[i + 2]:
        best = float(fine[i])
    sse_best, n = misfit(best)
    dof = max(n * flat.shape[1] - 1 - flat.shape[1], 1)
    std = float(np.sqrt(2.0 * (sse_best / dof) / (2 * a))) if a > 0 else float("nan")
    inside = (t + best >= take.times[0]) & (t + best <= take.times[-1])
    return ClockOffset(best, std, tuple(others), float(t[inside][-1] - t[inside][0]), n,
                       float(np.sqrt(sse_best / (n * len(others)))), float(coarse[j]),
                       float(np.sqrt(sse[j] / (used[j] * len(others)))))
