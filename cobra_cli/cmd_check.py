"""``cobra check``: check runs before fitting (data findings, identifiability of the free parameters).

:func:`check_before_fit` is the same check as ``cobra fit`` and ``cobra diagnose`` run it before
they fit (``--no-check`` skips it there).
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Sequence, TextIO

from cobra_cli.common import add_contact_option, fit_start
from cobra_model.errors import InputError
from cobra_model.parameters import ModelParameters
from cobra_model.run import Run
from sysid.identification.datacheck import DataCheck, apply, check_runs
from sysid.identification.objective import Weights
from sysid.identification.splits import expand, read_runs

#: Horizon [s] of the identifiability Jacobian (see :func:`sysid.identification.datacheck.check_runs`).
DEFAULT_HORIZON_S = 3.0


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "check", help="check runs before a fit: gaps, dropouts, saturated joints, what they cannot identify",
        description="Inspect the runs (sample-rate gaps, motion-capture dropouts, joints at their limits or "
                    "flat, runs too short) and judge, from one finite-difference Jacobian over each run's "
                    "first --horizon seconds, which free parameters the runs cannot pin down and why. A "
                    "manifest.json among RUNS trains on its training runs; its validation runs are inspected "
                    "only. Exit 0 when the data can be fitted (possibly with parameters frozen), 2 when not.")
    p.add_argument("runs", nargs="+", metavar="RUNS", help="run CSVs or a dataset manifest.json")
    p.add_argument("--params", help="parameter file (default: nominal)")
    add_contact_option(p, "judge")
    p.add_argument("--free", help="comma-separated names to judge (default: every parameter not frozen that the "
                   "contact law reads)")
    p.add_argument("--frozen", help="comma-separated names to hold fixed")
    p.add_argument("--horizon", type=float, default=DEFAULT_HORIZON_S, metavar="S",
                   help=f"horizon of the identifiability Jacobian [s] (default {DEFAULT_HORIZON_S:g})")
    p.add_argument("--current", action="store_true",
                   help="judge with the motor currents as a channel too, as `cobra fit --current` and `cobra diagnose` "
                        "(when every run has them) fit them (needs current_1..current_11 in every training run)")
    p.add_argument("--json", action="store_true", help="print the check as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if not (args.horizon > 0):
        raise InputError(f"--horizon must be a positive number of seconds, got {args.horizon}")
    params = fit_start(args.params, args.contact, args.free, args.frozen, out=sys.stderr if args.json else sys.stdout,
                       friction_step=args.friction_step)
    train_paths, val_paths = expand(args.runs)
    if not train_paths:
        raise InputError(f"{', '.join(args.runs)}: no training runs")
    check = check_runs(read_runs(train_paths), params, horizon_s=args.horizon, threads=1,
                       held_out=read_runs(val_paths), weights=Weights(use_current=args.current))
    if args.json:
        print(json.dumps(check.to_json_dict(), indent=2))
    else:
        for line in check.messages():
            print(line)
        if check.ok:
            left = [n for n in params.free_names if n not in check.frozen_names]
            frozen = ", ".join(check.frozen_names) or "nothing"
            print(f"can be fitted: free {', '.join(left)}; to freeze: {frozen}")
    if not check.ok:
        raise InputError(check.fatal[0])
    return 0


def check_before_fit(train: Sequence[Run], params: ModelParameters, *, held_out: Sequence[Run] = (),
                     horizon_s: float = DEFAULT_HORIZON_S, out: TextIO | None = None,
                     weights: Weights | None = None) -> tuple[ModelParameters, DataCheck]:
    """The data check ``cobra fit`` and ``cobra diagnose`` run before fitting, on the channels
    the fit will weigh (``weights``: with ``use_current`` the currents pin parameters too).

    Prints the check's findings to ``out`` (default stdout) and ``freezing NAME: reason`` for
    every parameter it freezes.

    Returns:
        (``params`` with those parameters frozen, the check).

    Raises:
        InputError: the data cannot be fitted (its first fatal problem, naming the files or the
            parameters); ``--no-check`` skips the check.
    """
    out = out or sys.stdout
    check = check_runs(train, params, horizon_s=horizon_s, threads=1, held_out=held_out, weights=weights)
    for line in check.messages(parameters=False):
        print(line, file=out)
    if not check.ok:
        raise InputError(f"{check.fatal[0]} (--no-check skips the data check)")
    for name in check.frozen_names:
        print(f"freezing {name}: {check.reason(name)}", file=out)
    return apply(check, params), check
