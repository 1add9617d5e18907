"""COBRA's physical design and the generator of ``urdf/cobra.urdf``.

Public COBRA drawings are not available, so every number here is marked as a **datasheet**
value (ROBOTIS XH540-W270 e-manual) or an **estimate** (from the paper's description: a
daisy chain of 12 modules, each holding a servo, a LiPo cell and a microcontroller, about
0.13 m long and 0.09 m in diameter, about 0.55 kg).

This module is only the *generator*: the simulator never reads it. ``urdf/cobra.urdf`` is the
one place that holds the geometry (links, joints, inertias and the collision cylinders from
which the ground-contact points are derived); the test suite checks that the committed URDF
equals what :func:`render_urdf` produces. Regenerate with ``python -m cobra_model.design``.

Frames: the head module's frame sits at its geometric centre with ``x`` pointing forward (away
from the tail) and ``z`` up when the snake lies flat; the chain extends along ``-x``. Every other
module's frame sits at the joint in front of it, its cylinder centred ``MODULE_PITCH_M / 2``
behind that. Odd joints pitch (axis ``y``), even joints yaw (axis ``z``).
"""
from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from pathlib import Path

from cobra_model.servo import (SERVO_GEAR_RATIO, SERVO_MASS_KG, SERVO_NO_LOAD_RPM, SERVO_NO_LOAD_SPEED_RAD_S,
                               SERVO_STALL_TORQUE_NM)
from cobra_model.shipped import shipped_path

NUM_MODULES = 12
NUM_JOINTS = 11

# The servo (ROBOTIS XH540-W270) and its datasheet values: cobra_model.servo.

# --- Modules (estimates) ---------------------------------------------------------------------
MODULE_PITCH_M = 0.13            # estimate: joint-to-joint distance ("about 0.13 m long")
MODULE_RADIUS_M = 0.045          # estimate: "about 0.09 m diameter"
MODULE_LENGTH_M = 0.13           # estimate: collision cylinder length
JOINT_LIMIT_RAD = math.pi / 2.0  # +-90 deg mechanical range (issue spec)


@dataclass(frozen=True)
class ModuleSpec:
    """One module of the chain.

    Attributes:
        name: link name in the URDF (``head``, ``link_2`` .. ``link_11``, ``tail``).
        mass_kg: total mass [kg] (servo 0.165 kg datasheet + cell, electronics, shell: estimate).
        note: where the mass estimate comes from.
    """

    name: str
    mass_kg: float
    note: str


MODULES: tuple[ModuleSpec, ...] = (
    ModuleSpec("head", 0.60, "estimate: servo + cell + main controller board"),
    *(ModuleSpec(f"link_{k}", 0.55, "estimate: servo + cell + module board + shell")
      for k in range(2, NUM_MODULES)),
    ModuleSpec("tail", 0.50, "estimate: servo + cell, lighter end cap"),
)


def cylinder_inertia(mass_kg: float, radius_m: float, length_m: float) -> tuple[float, float, float]:
    """Principal inertia [kg m^2] of a solid cylinder along ``x`` about its centre: (Ixx, Iyy, Izz).

    A solid cylinder is a physically consistent stand-in (positive definite, satisfies the
    triangle inequality) for a module whose mass is spread through its shell.
    """
    ixx = 0.5 * mass_kg * radius_m**2
    iyy = mass_kg * (3.0 * radius_m**2 + length_m**2) / 12.0
    return ixx, iyy, iyy


def joint_axis(k: int) -> tuple[int, int, int]:
    """Axis of joint ``k`` (1-based): odd joints pitch about ``y``, even joints yaw about ``z``."""
    return (0, 1, 0) if k % 2 == 1 else (0, 0, 1)


def _link_xml(spec: ModuleSpec, centre_x: float) -> str:
    ixx, iyy, izz = cylinder_inertia(spec.mass_kg, MODULE_RADIUS_M, MODULE_LENGTH_M)
    origin = f'<origin xyz="{centre_x:.6g} 0 0" rpy="0 {math.pi / 2:.17g} 0"/>'
    shape = f'<cylinder radius="{MODULE_RADIUS_M:.6g}" length="{MODULE_LENGTH_M:.6g}"/>'
    colour = "0.85 0.35 0.1 1" if spec.name == "head" else "0.2 0.2 0.22 1"
    return f"""  <!-- {spec.name}: {spec.mass_kg} kg ({spec.note}) -->
  <link name="{spec.name}">
    <inertial>
      <origin xyz="{centre_x:.6g} 0 0" rpy="0 0 0"/>
      <mass value="{spec.mass_kg:.6g}"/>
      <inertia ixx="{ixx:.9g}" ixy="0" ixz="0" iyy="{iyy:.9g}" iyz="0" izz="{izz:.9g}"/>
    </inertial>
    <visual>
      {origin}
      <geometry>{shape}</geometry>
      <material name="{spec.name}_colour"><color rgba="{colour}"/></material>
    </visual>
    <collision>
      {origin}
      <geometry>{shape}</geometry>
    </collision>
  </link>
"""


def _joint_xml(k: int, parent: str, child: str, x_in_parent: float) -> str:
    ax = joint_axis(k)
    kind = "pitch" if k % 2 == 1 else "yaw"
    return f"""  <joint name="joint_{k}" type="revolute">  <!-- {kind} -->
    <parent link="{parent}"/>
    <child link="{child}"/>
    <origin xyz="{x_in_parent:.6g} 0 0" rpy="0 0 0"/>
    <axis xyz="{ax[0]} {ax[1]} {ax[2]}"/>
    <limit lower="{-JOINT_LIMIT_RAD:.12g}" upper="{JOINT_LIMIT_RAD:.12g}" effort="{SERVO_STALL_TORQUE_NM:.6g}" velocity="{SERVO_NO_LOAD_SPEED_RAD_S:.9g}"/>
  </joint>
"""


def render_urdf() -> str:
    """Return the text of ``urdf/cobra.urdf``."""
    header = f"""<?xml version="1.0"?>
<!--
  COBRA (Crater Observing Bio-inspired Rolling Articulator): 12 modules, 11 revolute joints.
  GENERATED by `python -m cobra_model.design`; do not edit by hand (a test checks it).

  Datasheet values (ROBOTIS XH540-W270 at 12 V): servo mass {SERVO_MASS_KG} kg, gear ratio
  {SERVO_GEAR_RATIO}:1, stall torque {SERVO_STALL_TORQUE_NM} N m (joint effort limit), no-load speed
  {SERVO_NO_LOAD_RPM} rpm = {SERVO_NO_LOAD_SPEED_RAD_S:.4f} rad/s (joint velocity limit).
  Estimates (no public COBRA drawings): module pitch {MODULE_PITCH_M} m, collision cylinder radius
  {MODULE_RADIUS_M} m and length {MODULE_LENGTH_M} m, module masses (head 0.60 kg, middle 0.55 kg,
  tail 0.50 kg), solid-cylinder inertias about each module's centre, joint range +-90 deg.
  Frames: head frame at the head's centre, x forward, z up when flat; the chain extends along -x.
  Odd joints pitch (axis y), even joints yaw (axis z). The collision cylinders are the only
  contact geometry: the simulator derives its ground-contact points from them.
-->
<robot name="cobra">
"""
    parts = [header]
    half = MODULE_PITCH_M / 2.0
    for i, spec in enumerate(MODULES):
        parts.append(_link_xml(spec, 0.0 if i == 0 else -half))
        if i + 1 < NUM_MODULES:
            x_joint = -half if i == 0 else -MODULE_PITCH_M
            parts.append(_joint_xml(i + 1, spec.name, MODULES[i + 1].name, x_joint))
    parts.append("</robot>\n")
    return "".join(parts)


#: ``urdf/cobra.urdf``, as installed (package data ``cobra_model.urdf``).
DEFAULT_URDF_PATH = shipped_path("cobra_model.urdf", "cobra.urdf")


def main(argv: list[str] | None = None) -> None:
    """Write ``urdf/cobra.urdf`` (or ``--out``) from the design table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_URDF_PATH)
    args = parser.parse_args(argv)
    args.out.write_text(render_urdf())
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
