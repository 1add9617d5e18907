"""``cobra info``: the model summary (masses, joints, parameters with units and bounds)."""
from __future__ import annotations

import argparse
import json

import numpy as np

from cobra_cli.common import load_params
from cobra_model import servo
from cobra_model.model import CobraModel


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="print the model summary and its parameters",
                       description="Print COBRA's masses, joints and the tunable parameters.")
    p.add_argument("--params", help="parameter file to show instead of the nominal one")
    p.add_argument("--json", action="store_true", help="print the parameter file (JSON) only")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    params = load_params(args.params)
    if args.json:
        print(json.dumps(params.to_json_dict(), indent=2))
        return 0
    model = CobraModel.load()
    lim = model.pin_model
    print(f"COBRA model: {model.urdf_path}")
    print(f"  nq = {model.nq}, nv = {model.nv} (free-flyer head + {model.n_joints} joints), "
          f"{len(model.features)} ground-contact points")
    print(f"  total mass {model.total_mass:.3f} kg")
    print("  modules:")
    for i, name in enumerate(model.body_names):
        print(f"    {name:8s} {model.pin_model.inertias[i + 1].mass:.3f} kg")
    print("  joints:")
    for k, name in enumerate(model.joint_names, start=1):
        kind = "pitch" if k % 2 == 1 else "yaw"
        iv = model.n_base + k - 1
        iq = model.nq - model.n_joints + k - 1
        print(f"    {name:9s} {kind:5s} range +-{np.rad2deg(lim.upperPositionLimit[iq]):.0f} deg, "
              f"effort {lim.effortLimit[iv]:.2f} N m, velocity {lim.velocityLimit[iv]:.3f} rad/s")
    print(f"  servo: XH540-W270, {servo.SERVO_GEAR_RATIO}:1, {servo.SUPPLY_VOLTAGE_V} V supply")
    print(f"  ground: {params.contact_law} contact law, {params.friction_step} friction step")
    print("  parameters:")
    print(f"    {'name':22s} {'value':>11s} {'unit':10s} {'min':>10s} {'max':>10s}  frozen  meaning")
    for prm in params:
        print(f"    {prm.name:22s} {prm.value:11.5g} {prm.unit:10s} {prm.min:10.4g} {prm.max:10.4g}  "
              f"{'yes' if prm.frozen else 'no':6s}  {prm.doc}")
    return 0
