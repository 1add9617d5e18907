"""``cobra import-optitrack``: merge an OptiTrack Motive take and a joint log into a run."""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cobra_cli.common import check_writable
from cobra_model.errors import InputError
from cobra_model.run_files import write_run
from cobra_model.clock_alignment import estimate_clock_offset
from cobra_model.motive import (
    TARGET_NAMES,
    joint_arrays,
    merge_take_and_joints,
    read_joint_source,
    read_motive_csv,
    resolve_mapping,
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``cobra import-optitrack`` and its options."""
    p = sub.add_parser(
        "import-optitrack", help="merge an OptiTrack Motive take and a joint log into a run",
        description="Convert an OptiTrack Motive CSV export (rigid bodies) to the project's Z-up "
                    "world and merge it with a joint log (a run, or a CSV t, q_1..q_11 "
                    "[, q_ref_1..q_ref_11]) into a cobra-run/1 run on the joint log's times; a run "
                    "(what `cobra record` writes) keeps its velocities, currents, extra columns and "
                    "sidecar. Rigid bodies named head, link_2..link_11 or tail are mapped automatically.")
    p.add_argument("take", metavar="TAKE.csv", help="OptiTrack Motive CSV export (format 1.23)")
    p.add_argument("--joints", required=True, metavar="JOINTS.csv", help="joint log")
    p.add_argument("--out", required=True, metavar="RUN.csv", help="output run CSV (+ RUN.json)")
    p.add_argument("--map", action="append", default=[], metavar="NAME=BODY[,NAME=BODY...]",
                   help="map Motive rigid body NAME to BODY (head, link_2..link_11, tail); "
                        "comma-separated, repeatable")
    p.add_argument("--time-offset", type=float, default=None, metavar="S",
                   help="take time minus joint-log time of one instant [s] (default: estimated from the "
                        "data, by matching the tracked bodies' positions in the head's frame with the "
                        "joint angles' kinematics; needs a body besides the head)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.set_defaults(func=run)


def parse_map(values: Sequence[str]) -> dict[str, str]:
    """``--map`` values (each ``NAME=BODY[,NAME=BODY...]``) -> Motive name -> body name.

    Body names are case-insensitive and returned lower-case.

    Raises:
        InputError: naming ``--map`` and the item, for an item that is not ``NAME=BODY``, an
            empty name, a body not in head, link_2..link_11, tail, or a name given twice.
    """
    mapping: dict[str, str] = {}
    for value in values:
        for item in value.split(","):
            name, sep, body = (part.strip() for part in item.partition("="))
            if not sep or not name or not body or "=" in body:
                raise InputError(f"--map {value!r}: item {item!r} is not NAME=BODY "
                                 f"(e.g. --map Cobra_Head=head,Cobra_Tail=tail)")
            if body.lower() not in TARGET_NAMES:
                raise InputError(f"--map {value!r}: body {body!r} of {name!r} is not one of "
                                 f"head, link_2..link_11, tail")
            if name in mapping:
                raise InputError(f"--map: rigid body {name!r} is mapped twice "
                                 f"(to {mapping[name]!r} and {body.lower()!r})")
            mapping[name] = body.lower()
    return mapping


def output_path(out: str | Path, force: bool) -> Path:
    """The run CSV ``out`` after checking that it and its sidecar may be written.

    Raises:
        InputError: if ``out`` does not end in ``.csv``.
        FileExistsError: if the CSV or its ``.json`` sidecar exists and ``force`` is false.
        FileNotFoundError: if the output directory does not exist.
    """
    path = Path(out)
    if path.suffix.lower() != ".csv":
        raise InputError(f"--out {out}: expected a .csv path (the sidecar is written next to it "
                         f"as .json)")
    check_writable(path.with_suffix(".json"), force)
    return check_writable(path, force)


def run(args: argparse.Namespace) -> int:
    """Merge the take and the joint log and write the run; print what was merged."""
    mapping = parse_map(args.map)
    if args.time_offset is not None and not np.isfinite(args.time_offset):
        raise InputError(f"--time-offset must be a finite number of seconds, got {args.time_offset}")
    out = output_path(args.out, args.force)
    take = read_motive_csv(args.take)
    joints = read_joint_source(args.joints)  # a `cobra record` run keeps its currents, latency, sidecar
    try:
        resolved = resolve_mapping(take, mapping)
    except InputError as exc:
        raise InputError(f"{exc} (set the mapping with --map NAME=BODY,...)") from None
    estimate = None
    offset = args.time_offset
    if offset is None:
        estimate = estimate_clock_offset(take, joint_arrays(joints), mapping=resolved, joint_log=str(args.joints))
        offset = estimate.offset_s
    result = merge_take_and_joints(take, joints, mapping=resolved, time_offset=offset)
    if estimate is not None:
        result.meta["notes"].append(estimate.describe())
        result.meta["optitrack"]["time_offset_estimate"] = estimate.to_json()
    write_run(result, out, force=args.force)
    tracked = np.isfinite(result.head_pos).all(axis=1).mean()
    bodies = ", ".join(f"{name} -> {body}" for name, body in resolved.items())
    print(f"wrote {out} ({result.n_samples} samples, {result.t[0]:.3f}..{result.t[-1]:.3f} s; "
          f"rigid bodies {bodies}; head tracked in {100 * tracked:.0f}% of samples)")
    for note in result.meta["notes"]:
        print(f"  {note}")
    return 0
