"""What a replay shows of each run, without any viewer: names, colours, frames, gap-free poses.

Times: every run is aligned on its own first sample, so frame time ``tau`` [s] shows sample
``t ~= t[0] + tau`` of each run (a simulated reproduction starts where the measured run starts).
A run shorter than the measured one holds its last sample.

Motion capture: the head pose and tracked bodies may have NaN gaps (DATA_FORMAT.md); a replay
holds the last valid value through a gap, and shows the first valid value before it.
"""
from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cobra_model.errors import InputError
from cobra_model.run import Run

#: RGB in [0, 1] of the measured run's trail, markers, final-position ball and legend entry
#: (red, as the paper's ball where the real robot ended).
MEASURED_COLOUR: tuple[float, float, float] = (0.84, 0.15, 0.16)
#: RGB in [0, 1] of the simulated runs, in order; reused cyclically past the last one.
GHOST_COLOURS: tuple[tuple[float, float, float], ...] = (
    (0.12, 0.47, 0.71),  # blue
    (0.17, 0.63, 0.17),  # green
    (0.58, 0.40, 0.74),  # purple
    (0.09, 0.75, 0.81),  # cyan
    (0.55, 0.34, 0.29),  # brown
    (0.89, 0.47, 0.76),  # pink
    (0.74, 0.74, 0.13),  # olive
)


@dataclass(frozen=True)
class Track:
    """One run as the replay draws it.

    Attributes:
        name: legend text.
        node: meshcat path segment of the run, unique in the scene (``[A-Za-z0-9_-]+``).
        colour: RGB in [0, 1].
        ghost: drawn translucent in ``colour`` (a simulated run) rather than in the URDF colours.
        run: the run.
        head_pos: (N, 3) head position, world frame [m], gaps filled (see module docstring).
        head_quat: (N, 4) head orientation ``(w, x, y, z)``, world from head, gaps filled.
        bodies: tracked body -> (N, 3) world position [m], gaps filled; bodies never seen
            are left out.
    """

    name: str
    node: str
    colour: tuple[float, float, float]
    ghost: bool
    run: Run
    head_pos: np.ndarray
    head_quat: np.ndarray
    bodies: dict[str, np.ndarray]

    @property
    def t_rel(self) -> np.ndarray:
        """(N,) sample times since the run's first sample [s]."""
        return self.run.t - self.run.t[0]

    @property
    def final_head_pos(self) -> np.ndarray:
        """(3,) last valid head position, world frame [m]."""
        return self.head_pos[-1]

    def samples_at(self, times: np.ndarray) -> np.ndarray:
        """(F,) indices of the samples nearest to ``times`` [s since the first sample], clamped."""
        return nearest_samples(self.t_rel, times)


def hold_last_valid(values: np.ndarray) -> np.ndarray | None:
    """Fill rows of ``values`` (N, K) that contain a NaN with the last row before them without.

    Rows before the first valid one take the first valid row. Returns ``None`` when no row is
    valid.
    """
    valid = np.isfinite(values).all(axis=1)
    if not valid.any():
        return None
    source = np.where(valid, np.arange(valid.size), -1)
    source = np.maximum.accumulate(source)
    source[source < 0] = int(np.flatnonzero(valid)[0])
    return values[source]


def nearest_samples(t: np.ndarray, times: np.ndarray) -> np.ndarray:
    """(F,) index into increasing ``t`` (N,) of the sample nearest to each of ``times`` (F,)."""
    if t.size == 1:
        return np.zeros(np.shape(times), dtype=int)
    hi = np.clip(np.searchsorted(t, times), 1, t.size - 1)
    lo = hi - 1
    return np.where(np.abs(times - t[lo]) <= np.abs(t[hi] - times), lo, hi)


def frame_samples(t: np.ndarray, fps: float) -> np.ndarray:
    """Indices of the samples of ``t`` (N,) [s] that become animation frames at ``fps`` [1/s].

    The sample nearest to each multiple of ``1/fps`` after ``t[0]``, without repeats, always
    including the first and the last sample (so the animation lasts exactly ``t[-1] - t[0]``).
    A run sampled more slowly than ``fps`` keeps every sample.

    Raises:
        InputError: if ``fps`` is not a positive finite number.
    """
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"frame rate must be a positive number of frames per second, got {fps}")
    t_rel = t - t[0]
    grid = np.arange(int(np.floor(t_rel[-1] * fps + 1e-9)) + 1) / fps
    return np.union1d(nearest_samples(t_rel, grid), [0, t.size - 1])


def _node_name(name: str, taken: set[str]) -> str:
    base = re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_") or "run"
    node, k = base, 2
    while node in taken:
        node, k = f"{base}_{k}", k + 1
    taken.add(node)
    return node


def make_tracks(measured: Run, others: Sequence[tuple[str, Run]], *,
                measured_name: str | None = None) -> tuple[Track, ...]:
    """The measured run (solid, :data:`MEASURED_COLOUR`) then the others as ghosts.

    Args:
        measured: the reference run, drawn solid from its joint angles and mocap head pose; a
            joint-only run (no head pose in any sample, recorded without motion capture) is
            drawn on the first other run's head pose, so that its joints can be compared.
        others: ``(name, run)`` of the runs to compare, e.g. simulated reproductions; each gets
            the next colour of :data:`GHOST_COLOURS`.
        measured_name: legend text of the measured run (default ``measured (<file stem>)``).

    Raises:
        InputError: if a run has no valid head pose at all (nothing to place the robot with).
    """
    if measured_name is None:
        measured_name = f"measured ({measured.source.stem})" if measured.source else "measured"
    taken: set[str] = set()
    tracks = []
    entries = [(measured_name, measured, MEASURED_COLOUR, False)]
    entries += [(name, run, GHOST_COLOURS[i % len(GHOST_COLOURS)], True)
                for i, (name, run) in enumerate(others)]
    for name, run, colour, ghost in entries:
        pose = hold_last_valid(np.column_stack([run.head_pos, run.head_quat]))
        if pose is None and not ghost and others:
            lead = others[0][1]
            pose = hold_last_valid(np.column_stack([np.interp(run.t, lead.t, col)
                                                    for col in np.column_stack([lead.head_pos, lead.head_quat]).T]))
        if pose is None:
            raise InputError(f"{run.source or name}: no sample has a head pose (head_* all empty); "
                             "cannot place the robot")
        quat = pose[:, 3:] / np.linalg.norm(pose[:, 3:], axis=1, keepdims=True)
        bodies = {body: filled for body, pos in run.bodies.items()
                  if (filled := hold_last_valid(pos)) is not None}
        tracks.append(Track(name, _node_name(name, taken), colour, ghost, run, pose[:, :3], quat, bodies))
    return tuple(tracks)
