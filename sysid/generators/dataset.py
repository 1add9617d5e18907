"""The shipped reference dataset: a stand-in for COBRA hardware recordings.

No public COBRA recordings exist, so ``data/reference/`` holds 25 runs made by this script with
a fixed seed from a *ground-truth* robot that differs from the nominal model the way a real one
would: other ground and actuator parameters, plus a physical effect the nominal model does not
have (which one is recorded in ``truth.json`` and deliberately not advertised: finding it is the
discrepancy workflow's job). Measurement is realistic:

- joint log at 50 Hz with +-0.5 ms timing jitter, encoder quantisation of 4096 counts per turn;
- motion capture at 120 Hz with 0.5 mm position noise and 0.2 deg orientation noise, occasional
  marker dropouts (bursts of 1 to 12 frames), merged onto the joint log's times by linear
  interpolation (no interpolation across a dropout);
- the paper's split: 25 runs over the three gaits (0.35, 0.5, 0.65 Hz) from varied initial
  headings and positions, each at least three gait cycles long; one run per gait held out for
  validation (``manifest.json``).

Regenerate with ``python -m sysid.generators.dataset --out DIR`` (``--force`` to overwrite; ``tests/test_dataset.py``
checks that the shipped files are what the generator writes).
"""
from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from cobra_model.errors import InputError
from cobra_model.gait import PAPER_FREQUENCIES_HZ, SidewindingGait
from cobra_model.model import CobraModel
from cobra_model.parameters import ModelParameters
from cobra_model.resample import interpolate_quaternions, interpolate_rows
from cobra_model.run import Run
from cobra_model.run_files import write_run
from cobra_model.servo import AMP_PER_CURRENT_UNIT, CURRENT_NOISE_A, RAD_PER_PULSE
from cobra_model.shipped import shipped_path
from integrators.simulate import TRACKED_BODIES
from integrators.simulator import Simulator, effect_parameter

#: ``data/reference``, as installed (package data ``sysid.reference``).
DATA_DIR = shipped_path("sysid.reference")
SEED = 20240521
N_RUNS = 25
JOINT_RATE_HZ = 50.0
MOCAP_RATE_HZ = 120.0
MOCAP_NOISE_M = 0.5e-3
MOCAP_ANGLE_NOISE_RAD = np.deg2rad(0.2)
TIMING_JITTER_S = 0.5e-3


def ground_truth() -> ModelParameters:
    """The stand-in robot's true parameters (nominal model + a hidden effect)."""
    p = ModelParameters.nominal().with_values(
        armature=0.045, joint_damping=0.25, motor_km=0.0095,
        k1=1.6e4, k2=45.0, mu_c=0.22, mu_s=0.34, mu_v=1.2, v_s=0.03,
    )
    return p.with_parameters([replace(effect_parameter("joint_coulomb"), value=0.35)])


@dataclass(frozen=True)
class RunPlan:
    """What one run of the dataset does."""

    name: str
    freq_hz: float
    duration_s: float
    head_xy: tuple[float, float]
    heading_rad: float
    split: str


def plan(rng: np.random.Generator) -> list[RunPlan]:
    """25 runs: 8 or 9 per gait, each >= 3 cycles after a 1 s smooth start; first of each gait held out."""
    plans: list[RunPlan] = []
    for i in range(N_RUNS):
        f = PAPER_FREQUENCIES_HZ[i % 3]
        duration = float(np.ceil(1.0 + 3.5 / f))
        xy = (float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1)))
        split = "validation" if i < 3 else "train"
        plans.append(RunPlan(f"run_{i + 1:02d}_{f:.2f}hz".replace(".", "p"), f, duration, xy,
                             float(rng.uniform(0, 2 * np.pi)), split))
    return plans


def _noisy_quats(rng, quat_wxyz: np.ndarray) -> np.ndarray:
    """Perturb (N, 4) quaternions by small random rotations (std MOCAP_ANGLE_NOISE_RAD per axis)."""
    dv = rng.normal(0, MOCAP_ANGLE_NOISE_RAD, (len(quat_wxyz), 3))
    ang = np.linalg.norm(dv, axis=1)
    axis = dv / np.where(ang > 0, ang, 1)[:, None]
    dq = np.column_stack([np.cos(ang / 2), axis * np.sin(ang / 2)[:, None]])
    w0, x0, y0, z0 = quat_wxyz.T
    w1, x1, y1, z1 = dq.T
    return np.column_stack([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1, w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                            w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1, w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1])


def _dropouts(rng, n: int) -> np.ndarray:
    """Boolean (n,) mask of lost mocap frames: about 2 % of frames in bursts of 1 to 12."""
    lost = np.zeros(n, dtype=bool)
    for start in np.flatnonzero(rng.random(n) < 0.004):
        lost[start:start + int(rng.integers(1, 13))] = True
    return lost


#: Spacing [s] of the configurations whose tracked-body positions are computed (then interpolated).
BODY_SAMPLE_S = 0.02
#: Note in a stand-in run's sidecar.
REFERENCE_NOTE = f"reference dataset stand-in run (seed {SEED})"


def measure(t: np.ndarray, q_pin: np.ndarray, q_joint_meas: np.ndarray, run_plan: RunPlan,
            rng: np.random.Generator, model: CobraModel, *, source: str = "hardware",
            note: str = REFERENCE_NOTE, current: np.ndarray | None = None) -> Run:
    """'Measure' a true trajectory the way the reference dataset was measured (module docstring).

    Args:
        t: (N,) sample times [s] of the true trajectory, from 0, evenly spaced (a few ms apart)
            and spanning ``run_plan.duration_s``.
        q_pin: (N, nq) configurations in Pinocchio's convention (head position [m] and
            orientation quaternion (x, y, z, w) in the world frame, then the 11 joint angles [rad]).
        q_joint_meas: (N, 11) what the encoders would read without quantisation [rad].
        run_plan: the run (gait frequency for the logged commands, initial heading for the sidecar).
        rng: the noise source; draws in a fixed order (timing jitter, head noise, orientation
            noise, head dropouts, then per tracked body its noise and dropouts).
        model: places the tracked bodies (``model.body_centres``).
        source, note: the sidecar's ``"source"`` and the first words of its note.
        current: (N, 11) true motor currents [A] at ``t``, logged like the servos' Present
            Current (:data:`~cobra_model.servo.CURRENT_NOISE_A` of noise, then rounded to
            :data:`~cobra_model.servo.AMP_PER_CURRENT_UNIT`); None: no current columns. Its
            noise comes from a generator spawned from ``rng``, which leaves ``rng``'s own draws
            as they are: with or without currents, runs are otherwise the same.

    Returns:
        The run on the 50 Hz jittered joint-log times: commands ``q_ref`` (the gait's), quantised
        encoders ``q``, head pose and :data:`~integrators.simulate.TRACKED_BODIES` with mocap noise
        and dropouts (NaN), and the motor currents if ``current`` is given.

    Raises:
        InputError: naming the argument whose shape does not fit ``t``.
    """
    t, q_pin, q_joint_meas = (np.asarray(a, dtype=float) for a in (t, q_pin, q_joint_meas))
    if t.ndim != 1 or len(t) < 2:
        raise InputError(f"measure: t must be a 1-D array of at least 2 times, got shape {t.shape}")
    n = len(t)
    if q_pin.shape != (n, model.nq):
        raise InputError(f"measure: q_pin must be ({n}, {model.nq}) to match t, got {q_pin.shape}")
    if q_joint_meas.shape != (n, model.n_joints):
        raise InputError(f"measure: q_joint_meas must be ({n}, {model.n_joints}) to match t, got {q_joint_meas.shape}")
    if current is not None and np.shape(current) != (n, model.n_joints):
        raise InputError(f"measure: current must be ({n}, {model.n_joints}) to match t, got {np.shape(current)}")
    gait = SidewindingGait(run_plan.freq_hz)
    # joint log: 50 Hz with jitter, quantised encoders, the goals that were sent
    n_j = int(run_plan.duration_s * JOINT_RATE_HZ)
    t_j = np.arange(n_j) / JOINT_RATE_HZ + rng.uniform(-TIMING_JITTER_S, TIMING_JITTER_S, n_j)
    t_j[0] = 0.0
    t_j = np.round(t_j, 6)
    q_true = interpolate_rows(t_j, t, q_joint_meas)
    count = RAD_PER_PULSE
    q_meas = np.round(q_true / count) * count
    q_ref = gait.q_ref(t_j)
    # motion capture: 120 Hz, noise, dropouts, merged onto the joint log's times
    t_m = np.arange(int(run_plan.duration_s * MOCAP_RATE_HZ) + 1) / MOCAP_RATE_HZ
    head = interpolate_rows(t_m, t, q_pin[:, 0:3]) + rng.normal(0, MOCAP_NOISE_M, (len(t_m), 3))
    quat = interpolate_quaternions(t_m, t, np.column_stack([q_pin[:, 6], q_pin[:, 3:6]]))
    quat = _noisy_quats(rng, quat)
    lost = _dropouts(rng, len(t_m))
    head[lost] = np.nan
    quat[lost] = np.nan
    bodies = {}
    every = max(1, int(round(BODY_SAMPLE_S / (t[1] - t[0]))))
    tracks = model.body_tracks(q_pin[::every], TRACKED_BODIES)
    for name in TRACKED_BODIES:
        pos = interpolate_rows(t_m, t[::every], tracks[name]) + rng.normal(0, MOCAP_NOISE_M, (len(t_m), 3))
        pos[_dropouts(rng, len(t_m))] = np.nan
        bodies[name] = np.round(interpolate_rows(t_j, t_m, pos, max_gap_samples=0), 5)
    logged = None
    if current is not None:
        logged = interpolate_rows(t_j, t, np.asarray(current, dtype=float))
        noise = rng.spawn(1)[0].normal(0, CURRENT_NOISE_A, logged.shape)
        logged = np.round((logged + noise) / AMP_PER_CURRENT_UNIT) * AMP_PER_CURRENT_UNIT
    meta = {
        "format": "cobra-run/1", "source": source, "gait": gait.to_json(),
        "notes": [f"{note}; joint log {JOINT_RATE_HZ:g} Hz, "
                  f"motion capture {MOCAP_RATE_HZ:g} Hz merged onto the joint log's times"],
        "initial_heading_rad": run_plan.heading_rad,
    }
    return Run(t=t_j, q_ref=np.round(q_ref, 7), q=q_meas,
               head_pos=np.round(interpolate_rows(t_j, t_m, head, max_gap_samples=0), 5),
               head_quat=np.round(interpolate_quaternions(t_j, t_m, quat, max_gap_samples=0), 6),
               bodies=bodies, meta=meta, current=logged)


def record(sim: Simulator, run_plan: RunPlan, rng: np.random.Generator, model: CobraModel, *,
           log_current: bool = False) -> Run:
    """Simulate one run on the ground-truth robot and 'measure' it (:func:`measure`; with
    ``log_current`` also the motor currents, as the servos' Present Current)."""
    gait = SidewindingGait(run_plan.freq_hz)
    state = sim.rest_state(gait.q_ref(0.0), head_xy=run_plan.head_xy, heading_rad=run_plan.heading_rad)
    traj = sim.rollout(state, gait.q_ref, run_plan.duration_s, record_every=2)
    return measure(traj.t, traj.q, traj.q_meas, run_plan, rng, model, current=traj.current if log_current else None)


def generate(out_dir: Path, *, force: bool = False, progress: Callable[[str], None] | None = None) -> list[Path]:
    """Write the 25 runs, ``manifest.json`` and ``truth.json`` into ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(SEED)
    model = CobraModel.load()
    truth = ground_truth()
    sim = Simulator(model, truth)
    paths = []
    plans = plan(rng)
    for k, rp in enumerate(plans):
        if progress:
            progress(f"[{k + 1}/{len(plans)}] {rp.name}")
        paths.append(write_run(record(sim, rp, rng, model), out_dir / f"{rp.name}.csv", force=force))
    manifest = {
        "format": "cobra-dataset/1",
        "description": "COBRA reference dataset (stand-in hardware runs); see sysid/generators/dataset.py",
        "train": [f"{rp.name}.csv" for rp in plans if rp.split == "train"],
        "validation": [f"{rp.name}.csv" for rp in plans if rp.split == "validation"],
        "runs": {f"{rp.name}.csv": {"frequency_hz": rp.freq_hz, "duration_s": rp.duration_s,
                                     "head_xy_m": list(rp.head_xy), "heading_rad": rp.heading_rad,
                                     "split": rp.split} for rp in plans},
    }
    for name, content in (("manifest.json", manifest), ("truth.json", truth.to_json_dict())):
        target = out_dir / name
        if target.exists() and not force:
            raise FileExistsError(f"{target} exists; pass --force to overwrite it")
        target.write_text(json.dumps(content, indent=2) + "\n")
    return paths


def load_manifest(path: Path) -> tuple[list[Path], list[Path]]:
    """(train, validation) run paths of a dataset manifest (paths relative to the manifest).

    Raises:
        InputError: naming the file, if it is not JSON or has no ``"train"`` list.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("train"), list):
        raise InputError(f"{path}: a dataset manifest needs \"train\" (and \"validation\") lists of run files")
    base = path.parent
    return [base / n for n in data["train"]], [base / n for n in data.get("validation", [])]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Generate the COBRA reference dataset.")
    parser.add_argument("--out", type=Path, default=DATA_DIR)
    parser.add_argument("--force", action="store_true", help="overwrite existing files")
    args = parser.parse_args(argv)
    generate(args.out, force=args.force, progress=print)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
