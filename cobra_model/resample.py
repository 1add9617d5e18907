"""Moving a run onto another time base: linear interpolation of samples, slerp of orientations.

Motion-capture gaps (NaN) longer than a few samples stay gaps; nothing is extrapolated.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from cobra_model.errors import InputError
from cobra_model.run import Run

# Interpolation onto another time base.


def _brackets(
    t_new: np.ndarray, t: np.ndarray, valid: np.ndarray, max_gap_samples: int | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Bracketing valid samples of ``t`` for each time of ``t_new``.

    Returns ``(lo, hi, w, ok)``: indices into ``t`` of the valid samples on either side, the
    weight of ``hi`` in ``[0, 1]`` and whether a value exists (inside the valid span, and the two
    valid samples are separated by at most ``max_gap_samples`` invalid ones, or the time hits a
    valid sample exactly). ``max_gap_samples=None`` bridges any gap.
    """
    idx = np.flatnonzero(valid)
    m = t_new.size
    if idx.size == 0:
        zeros = np.zeros(m, dtype=int)
        return zeros, zeros, np.zeros(m), np.zeros(m, dtype=bool)
    tv = t[idx]
    if idx.size == 1:
        ok = t_new == tv[0]
        zeros = np.zeros(m, dtype=int)
        return idx[zeros], idx[zeros], np.zeros(m), ok
    k = np.clip(np.searchsorted(tv, t_new, side="right") - 1, 0, idx.size - 2)
    t_lo, t_hi = tv[k], tv[k + 1]
    w = np.clip((t_new - t_lo) / (t_hi - t_lo), 0.0, 1.0)
    inside = (t_new >= tv[0]) & (t_new <= tv[-1])
    exact = (t_new == t_lo) | (t_new == t_hi)
    if max_gap_samples is None:
        close = np.ones(m, dtype=bool)
    else:
        close = (idx[k + 1] - idx[k] - 1) <= max_gap_samples
    return idx[k], idx[k + 1], w, inside & (close | exact)


def interpolate_rows(
    t_new: np.ndarray, t: np.ndarray, y: np.ndarray, *, max_gap_samples: int | None = None
) -> np.ndarray:
    """Linear interpolation of the rows of ``y`` (N, K) sampled at ``t`` (N,) onto ``t_new`` (M,).

    A row of ``y`` containing a NaN is a missing sample. The result is NaN outside the span of the
    valid samples and between two valid samples separated by more than ``max_gap_samples``
    missing ones (``None``: always bridge). Units are those of ``y``.
    """
    valid = np.isfinite(y).all(axis=1)
    lo, hi, w, ok = _brackets(t_new, t, valid, max_gap_samples)
    out = (1.0 - w)[:, None] * y[lo] + w[:, None] * y[hi]
    out[~ok] = np.nan
    return out


def interpolate_quaternions(
    t_new: np.ndarray, t: np.ndarray, quat: np.ndarray, *, max_gap_samples: int | None = None
) -> np.ndarray:
    """Normalised linear interpolation (nlerp) of unit quaternions ``quat`` (N, 4), any order.

    The later quaternion of each pair is sign-aligned with the earlier one (``q`` and ``-q`` are the
    same rotation) before blending, and the result is renormalised. Gaps are handled as in
    :func:`interpolate_rows`.
    """
    valid = np.isfinite(quat).all(axis=1)
    lo, hi, w, ok = _brackets(t_new, t, valid, max_gap_samples)
    q0, q1 = quat[lo], quat[hi]
    q1 = np.where((np.einsum("ij,ij->i", q0, q1) < 0)[:, None], -q1, q1)
    out = (1.0 - w)[:, None] * q0 + w[:, None] * q1
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    out = out / np.where(norm > 0, norm, 1.0)
    out[~ok] = np.nan
    return out


def resample_run(run: Run, t_new: np.ndarray, *, max_gap_samples: int = 2) -> Run:
    """``run`` linearly interpolated onto the times ``t_new`` (M,) [s].

    Joint signals are interpolated across their (rare) NaN samples; motion capture is left NaN
    across dropouts longer than ``max_gap_samples`` samples, quaternions use nlerp. Extra columns
    are kept when every time of ``t_new`` is a sample time of ``run`` and dropped otherwise (their
    values are strings and cannot be interpolated).

    Raises:
        InputError: if ``t_new`` reaches outside ``[run.t[0], run.t[-1]]``.
    """
    t_new = np.asarray(t_new, dtype=float)
    if t_new.size and (t_new[0] < run.t[0] or t_new[-1] > run.t[-1]):
        raise InputError(
            f"{run._name()}: cannot resample onto [{t_new[0]:g}, {t_new[-1]:g}] s; "
            f"the run spans [{run.t[0]:g}, {run.t[-1]:g}] s (no extrapolation)"
        )

    def joints(arr: np.ndarray | None) -> np.ndarray | None:
        return None if arr is None else interpolate_rows(t_new, run.t, arr)

    def mocap(arr: np.ndarray) -> np.ndarray:
        return interpolate_rows(t_new, run.t, arr, max_gap_samples=max_gap_samples)

    pos = np.searchsorted(run.t, t_new)
    pos_c = np.minimum(pos, run.t.size - 1)
    on_samples = bool(np.all(run.t[pos_c] == t_new))
    return dataclasses.replace(
        run,
        t=t_new,
        q_ref=joints(run.q_ref),
        q=joints(run.q),
        dq=joints(run.dq),
        current=joints(run.current),
        head_pos=mocap(run.head_pos),
        head_quat=interpolate_quaternions(
            t_new, run.t, run.head_quat, max_gap_samples=max_gap_samples
        ),
        bodies={name: mocap(p) for name, p in run.bodies.items()},
        extra={name: v[pos_c] for name, v in run.extra.items()} if on_samples else {},
    )

