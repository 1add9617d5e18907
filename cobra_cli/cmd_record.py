"""``cobra record``: run the paper's sidewinding gait on the robot and record the run.

Example::

    cobra record --config examples/bus.toml --freq 0.5 --duration 20 --out runs/side_05.csv
    cobra record --config examples/bus.toml --freq 0.5 --duration 20 --dry-run

The run is written as it arrives (``NAME.csv`` + ``NAME.json``); motion capture is merged later,
so the ``head_*`` cells are empty. A run stopped early (Ctrl-C, hardware error, lost servo or
port, SIGTERM or SIGHUP) is still a valid run file whose sidecar notes ``partial run: <reason>``,
and torque is off before the command exits.
Exit status: 0 completed, 1 stopped early or the bus failed, 2 bad input, 130 Ctrl-C,
128 + N when stopped by signal N (143 SIGTERM, 129 SIGHUP).
"""
from __future__ import annotations

import argparse
import signal
import sys

from cobra_model.errors import InputError
from cobra_model.gait import SidewindingGait
from hardware.config import load_bus_config
from hardware.driver import BusError
from hardware.recorder import StopReason, describe_plan, record_gait
from hardware.runwriter import check_run_path


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``cobra record``."""
    p = subparsers.add_parser(
        "record", help="run the sidewinding gait on the robot and record the run",
        description=__doc__.splitlines()[0])
    p.add_argument("--config", required=True, help="bus configuration (.toml, .yaml)")
    p.add_argument("--freq", type=float, default=0.5, help="gait frequency [Hz] (default 0.5)")
    p.add_argument("--duration", type=float, default=20.0, help="recording length [s] (default 20)")
    p.add_argument("--out", help="run file NAME.csv (sidecar NAME.json)")
    p.add_argument("--force", action="store_true", help="overwrite an existing run")
    p.add_argument("--settle", type=float, default=2.0,
                   help="time to move into the gait's first pose before recording [s] (default 2)")
    p.add_argument("--port", help="serial port, overriding the configuration's (e.g. the emulator's link)")
    p.add_argument("--dry-run", action="store_true", help="print what would be sent; open no port")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Record (or describe) one run; returns the exit status."""
    if not args.duration > 0:
        raise InputError(f"--duration must be > 0 s, got {args.duration}")
    if not args.settle >= 0:
        raise InputError(f"--settle must be >= 0 s, got {args.settle}")
    config = load_bus_config(args.config)
    if args.port:
        config = config.with_port(args.port)
    gait = SidewindingGait(freq_hz=args.freq)
    if args.out is not None:
        check_run_path(args.out, force=args.force)
    if args.dry_run:
        print(describe_plan(config, gait, duration_s=args.duration, settle_s=args.settle))
        return 0
    if args.out is None:
        raise InputError("--out is required to record (or use --dry-run)")
    try:
        result = record_gait(config, gait, duration_s=args.duration, out=args.out, force=args.force,
                             settle_s=args.settle, progress=lambda msg: print(msg, flush=True))
    except BusError as exc:
        print(f"cobra record: error: {exc}", file=sys.stderr)
        return 1
    if result.timing is not None:
        t = result.timing
        print(f"{result.samples} samples, {t.cycles} cycles at {t.achieved_rate_hz:.2f} Hz "
              f"(requested {t.requested_rate_hz:g}), period jitter {1e3 * t.period_std_s:.2f} ms, "
              f"max lateness {1e3 * t.lateness_max_s:.2f} ms, {t.skipped_cycles} skipped, "
              f"{result.comm.reads_failed} failed reads")
    if result.path is not None:
        print(f"wrote {result.path}" + ("" if result.status is StopReason.COMPLETED else " (partial run)"))
    if result.status is StopReason.COMPLETED:
        print(result.message)
        return 0
    print(f"cobra record: stopped: {result.message}", file=sys.stderr)
    if result.status is StopReason.TERMINATED and result.signal_name:
        return 128 + int(signal.Signals[result.signal_name])
    return 130 if result.status is StopReason.INTERRUPTED else 1
