"""MuJoCo's joint friction (``frictionloss``) against our joint Coulomb law, on the gait's motion.

The confusion matrix (``benchmarks/diagnose_matrix.py``) hides a joint friction on MuJoCo's side
as each hinge's ``frictionloss`` and names it as our ``joint_coulomb_friction``, the torque
``-tau_c tanh(qdot / eps)`` (``eps``: :attr:`integrators.simulator.SimSettings.joint_coulomb_eps`).
The two laws share the value ``tau_c`` at speed but not their shape near rest: MuJoCo's is a
soft constraint on the joint's speed (its force is whatever holds the speed at zero, up to
``frictionloss``, relaxed with the constraint's regulariser), ours a smooth function of speed.

This script runs MuJoCo's twin through the sidewinding gait (the matrix's twin configuration,
nominal parameters, linearised-and-saturating servos as its runs), reads each hinge's friction
force from MuJoCo's constraint forces (``efc_force`` of the ``mjCNSTR_FRICTION_DOF`` rows)
after every step, and reports:

- the value of our law that reproduces MuJoCo's friction torques best in the least-squares
  sense on that motion (``tau_best = -<s, f> / <s, s>``, ``s = tanh(qdot / eps)``), as a fraction
  of the ``frictionloss`` set: the part of a fitted value's bias that the shapes alone explain;
- MuJoCo's mean friction magnitude in bands of joint speed, beside our law's at the band's mean
  speed.

It measures the laws, not a diagnosis: a fit matches trajectories, where the friction's shape
also trades against the damping and the motor's constant.

Writes ``benchmarks/results/frictionloss_shape.{json,md,png}``.
Run: ``.venv/bin/python benchmarks/frictionloss_shape.py [--freqs 0.35,0.5,0.65] [--duration 3]``.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks._args import number_list  # noqa: E402
from benchmarks._results import RESULTS_DIR, write_results  # noqa: E402
from benchmarks.diagnose_matrix import near_limit  # noqa: E402
from cobra_model import CobraModel, ModelParameters, SidewindingGait  # noqa: E402
from integrators import mujoco_twin  # noqa: E402
from integrators.simulator import SimSettings, Simulator  # noqa: E402
from sysid.discrepancy.effects import EffectLibrary  # noqa: E402
from sysid.generators.mujoco_recording import rollout_with_torques, twin_options  # noqa: E402

#: Joint-speed bands [rad/s] of the table: where the two laws differ is near rest.
SPEED_BANDS = (0.0, 0.005, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, np.inf)


def friction_on_gait(frictionloss: float, freq_hz: float, duration_s: float,
                     model: CobraModel) -> tuple[np.ndarray, np.ndarray]:
    """Joint speeds [rad/s] and MuJoCo's joint friction torques [N m], both (steps, 11), after
    each step of the twin (``frictionloss`` on every hinge) sidewinding at ``freq_hz`` for
    ``duration_s`` from rest at the gait's first pose, its servos' duty saturating as in the
    matrix's runs."""
    import mujoco

    options = dataclasses.replace(twin_options(ModelParameters.nominal()), frictionloss=frictionloss)
    mj_model = mujoco_twin.build(model.urdf_path, options)
    gait = SidewindingGait(freq_hz)
    q0 = Simulator(model).rest_state(gait.q_ref(np.zeros(1))[0]).q
    friction_rows = mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF
    speed, torque = [], []

    def read_friction(data: mujoco.MjData) -> None:
        mujoco.mj_forward(mj_model, data)  # the constraint forces at the new state
        f = np.zeros(mj_model.nv)
        rows = data.efc_type[:data.nefc] == friction_rows
        f[data.efc_id[:data.nefc][rows]] = data.efc_force[:data.nefc][rows]
        speed.append(data.qvel[6:].copy())
        torque.append(f[6:])

    rollout_with_torques(mj_model, q0, gait.q_ref, duration_s,
                         error_limit_rad=mujoco_twin.servo_error_limit(options), after_step=read_friction)
    return np.array(speed), np.array(torque)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--freqs", default="0.35,0.5,0.65", help="gait frequencies [Hz] (default 0.35,0.5,0.65)")
    parser.add_argument("--duration", type=float, default=3.0, help="seconds per run (default 3, the matrix's)")
    args = parser.parse_args(argv)
    freqs = number_list(parser, "--freqs", args.freqs, kind=float)
    if not args.duration > 0:
        parser.error(f"--duration must be > 0 s, got {args.duration}")
    library = EffectLibrary()
    eps = SimSettings().joint_coulomb_eps
    magnitudes = (("realistic", library["joint_coulomb_friction"].realistic),
                  ("near_limit", near_limit("joint_coulomb_friction", args.duration)))
    model = CobraModel.load()
    rows, curves = [], {}
    for level, tau in magnitudes:
        for freq in freqs:
            v, f = (a.ravel() for a in friction_on_gait(tau, freq, args.duration, model))
            s = np.tanh(v / eps)
            best = float(-(s @ f) / (s @ s))
            bands = []
            for lo, hi in zip(SPEED_BANDS[:-1], SPEED_BANDS[1:]):
                k = (np.abs(v) >= lo) & (np.abs(v) < hi)
                bands.append({"low": lo, "high": hi, "samples": int(k.sum()),
                              "mujoco_mean_abs_nm": float(np.mean(np.abs(f[k]))) if k.any() else None,
                              "ours_at_mean_speed_nm":
                                  float(tau * np.tanh(np.mean(np.abs(v[k])) / eps)) if k.any() else None})
            rows.append({"level": level, "frictionloss_nm": tau, "freq_hz": freq, "samples": int(v.size),
                         "tau_best_nm": best, "tau_best_ratio": best / tau,
                         "rms_residual_nm": float(np.sqrt(np.mean((f + best * s) ** 2))),
                         "share_below_eps": float(np.mean(np.abs(v) < eps)), "bands": bands})
            curves[(level, freq)] = (v, f, tau)
            print(f"{level} frictionloss {tau:g} N m, {freq:g} Hz: our law's best value {best:.4f} N m "
                  f"({best / tau:.3f} x)", flush=True)
    lines = [f"MuJoCo's joint friction (`frictionloss`, a soft constraint on each hinge's speed) against our "
             f"`joint_coulomb_friction` (`-tau_c tanh(qdot / {eps:g} rad/s)`), on the twin's sidewinding from rest "
             f"({args.duration:g} s per gait, nominal parameters, every step). Best value: our law's `tau_c` that "
             f"reproduces MuJoCo's friction torques best (least squares over all joints and steps), as a fraction "
             f"of the `frictionloss` set.", "",
             "| level | frictionloss [N m] | gait [Hz] | our law's best value [N m] | fraction | RMS left [N m] | "
             f"steps below {eps:g} rad/s |", "|---|---:|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['level']} | {r['frictionloss_nm']:g} | {r['freq_hz']:g} | {r['tau_best_nm']:.4f} | "
              f"{r['tau_best_ratio']:.3f} | {r['rms_residual_nm']:.4f} | {r['share_below_eps']:.1%} |" for r in rows]
    ref = rows[[r["freq_hz"] for r in rows].index(0.5)] if 0.5 in freqs else rows[0]
    lines += ["", f"MuJoCo's mean friction magnitude by joint speed ({ref['level']}, {ref['frictionloss_nm']:g} N m, "
              f"{ref['freq_hz']:g} Hz), beside our law's at the band's mean speed:", "",
              "| joint speed [rad/s] | steps | MuJoCo [N m] | ours [N m] |", "|---|---:|---:|---:|"]
    lines += [f"| {b['low']:g}-{b['high']:g} | {b['samples']} | "
              + (f"{b['mujoco_mean_abs_nm']:.4f} | {b['ours_at_mean_speed_nm']:.4f} |" if b["samples"] else "- | - |")
              for b in ref["bands"]]
    meta = {"freqs_hz": freqs, "duration_s": args.duration, "joint_coulomb_eps_rad_s": eps,
            "magnitudes_nm": dict(magnitudes), "twin": "sysid.generators.mujoco_recording.twin_options(nominal)"}
    json_path, md_path = write_results("frictionloss_shape", rows, meta,
                                       "# MuJoCo's joint friction against our joint Coulomb law\n\n"
                                       + "\n".join(lines) + "\n\n![MuJoCo's friction torque against joint speed]"
                                       "(frictionloss_shape.png)")
    png = plot(curves, ref, eps)
    print("\n".join(lines))
    print(f"wrote {json_path}, {md_path} and {png}")


def plot(curves: dict, ref: dict, eps: float) -> Path:
    """MuJoCo's friction torque against joint speed for ``ref``'s run, with our law at the set
    value and at its best value; returns the PNG's path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    v, f, tau = curves[(ref["level"], ref["freq_hz"])]
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(v, -f, ".", ms=1.5, alpha=0.25, color="tab:blue", label="MuJoCo frictionloss (every joint and step)")
    grid = np.linspace(-0.4, 0.4, 801)
    ax.plot(grid, tau * np.tanh(grid / eps), color="k", label=f"ours, tau_c = {tau:g} N m")
    ax.plot(grid, ref["tau_best_nm"] * np.tanh(grid / eps), "--", color="tab:red",
            label=f"ours, best value {ref['tau_best_nm']:.3f} N m")
    ax.set_xlim(-0.4, 0.4)
    ax.set_xlabel("joint speed [rad/s]")
    ax.set_ylabel("friction torque opposing the motion [N m]")
    ax.set_title(f"{ref['freq_hz']:g} Hz sidewinding, frictionloss {tau:g} N m")
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    path = RESULTS_DIR / "frictionloss_shape.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


if __name__ == "__main__":
    main()
