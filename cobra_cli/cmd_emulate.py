"""``cobra emulate``: COBRA's servo bus on a pseudo-terminal, moved by the simulator.

Example (two terminals)::

    cobra emulate --port-link /tmp/cobra-bus
    cobra record --config examples/bus.toml --port /tmp/cobra-bus --duration 10 --out emu.csv

The emulator prints the pty path, makes ``--port-link`` a symlink to it (never replacing a file
that is not a symlink) and serves until Ctrl-C, ``--duration`` or an ``unplug`` fault. Pass the
recorder's ``--config`` to wire IDs, zero offsets and directions as that configuration says.
Faults: ``--fault KIND[:ID][@SECONDS][xCOUNT]`` (repeatable), seconds counted from the first
torque on; kinds crc, drop, silent, overload, overheating, voltage, cut, unplug.
``--encoder-offset-deg`` gives the encoders zero errors that the recorder's configuration does
not know (11 comma-separated angles in joint order, or one for every joint).
"""
from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time

from cobra_model.design import NUM_JOINTS
from cobra_model.errors import InputError
from hardware.config import load_bus_config
from hardware.control_table import XH540_W270_MODEL_NUMBER
from hardware.emulator import BusEmulator, EmulatorStats
from hardware.faults import parse_fault
from hardware.plant import KinematicPlant, Plant, SimulatorPlant


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``cobra emulate``."""
    p = subparsers.add_parser(
        "emulate", help="emulate the servo bus on a pty, driven by the simulator",
        description=__doc__.splitlines()[0])
    p.add_argument("--port-link", help="make this path a symlink to the pty (e.g. /tmp/cobra-bus)")
    p.add_argument("--config", help="bus configuration whose IDs, offsets, directions and model number to emulate")
    p.add_argument("--plant", choices=("simulator", "kinematic"), default="simulator",
                   help="what moves the servos: COBRA's simulator (default) or ideal servos")
    p.add_argument("--fault", action="append", default=[], metavar="SPEC",
                   help="inject a fault, e.g. crc@2x3, drop@2x5, silent:5@3, overload:3@4, voltage:2@1, "
                        "cut@4, unplug@5")
    p.add_argument("--encoder-offset-deg", metavar="DEG[,DEG...]",
                   help="what each encoder reads at joint angle 0 [deg], unknown to the recorder: "
                        f"{NUM_JOINTS} values in joint order or one for all")
    p.add_argument("--duration", type=float, help="stop after this many seconds of wall time")
    p.add_argument("--report-every", type=float, default=5.0,
                   help="print the real-time factor every this many seconds (0: never)")
    p.set_defaults(func=run)


def _describe(stats: EmulatorStats) -> str:
    return (f"emulated {stats.emulated_time_s:.1f} s in {stats.wall_time_s:.1f} s "
            f"(real-time factor {stats.real_time_factor:.2f}); {stats.packets} packets, "
            f"{stats.replies} replies, {stats.crc_errors} bad CRCs received, "
            f"{stats.dropped} replies dropped, {stats.corrupted} corrupted")


def parse_encoder_offsets(text: str | None) -> list[float] | None:
    """``--encoder-offset-deg``: one angle or one per joint [deg] -> (11,) [rad] (None if not given).

    Raises:
        InputError: naming the option and what was expected.
    """
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise InputError(f"--encoder-offset-deg {text!r}: expected numbers [deg] separated by commas") from None
    if len(values) == 1:
        values *= NUM_JOINTS
    if len(values) != NUM_JOINTS or not all(math.isfinite(v) and abs(v) <= 180.0 for v in values):
        raise InputError(f"--encoder-offset-deg {text!r}: expected 1 or {NUM_JOINTS} finite angles within "
                         f"+-180 deg, got {len(values)}")
    return [math.radians(v) for v in values]


def _stop_on_sigterm(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def run(args: argparse.Namespace) -> int:
    """Serve the emulated bus until Ctrl-C (or SIGTERM), ``--duration`` or an unplug fault."""
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise InputError(f"--duration must be > 0 s of wall time, got {args.duration}")
    if not args.report_every >= 0:
        raise InputError(f"--report-every must be >= 0 s (0: never), got {args.report_every}")
    faults = [parse_fault(spec) for spec in args.fault]
    encoder = parse_encoder_offsets(args.encoder_offset_deg)
    config = load_bus_config(args.config) if args.config else None
    plant: Plant = SimulatorPlant.nominal() if args.plant == "simulator" else KinematicPlant()
    emulator = BusEmulator(
        plant, faults=faults, joints=config.joints if config else None, encoder_offsets_rad=encoder,
        model_number=config.servo.model_number if config else XH540_W270_MODEL_NUMBER)
    in_main_thread = threading.current_thread() is threading.main_thread()
    if in_main_thread:  # `kill` ends a session as Ctrl-C does: the link is removed
        previous_sigterm = signal.signal(signal.SIGTERM, _stop_on_sigterm)
        # Ctrl-C ends it even when started in the background by a script, which ignores SIGINT
        previous_sigint = signal.signal(signal.SIGINT, signal.default_int_handler)
    port = emulator.start()
    try:
        print(f"pty: {port}", flush=True)
        if args.port_link:
            print(f"link: {emulator.link(args.port_link)} -> {port}", flush=True)
        deadline = time.monotonic() + args.duration if args.duration else None
        next_report = time.monotonic() + args.report_every if args.report_every > 0 else None
        try:
            while not emulator.wait_closed(0.2):
                now = time.monotonic()
                if deadline is not None and now >= deadline:
                    break
                if next_report is not None and now >= next_report:
                    print(_describe(emulator.stats()), flush=True)
                    next_report = now + args.report_every
        except KeyboardInterrupt:
            pass  # Ctrl-C (or SIGTERM) is how an emulator session normally ends
    finally:
        emulator.stop()
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous_sigterm)
            signal.signal(signal.SIGINT, previous_sigint)
        stats = emulator.stats()
        print(_describe(stats), flush=True)
        for note in stats.notes:
            print(f"note: {note}", flush=True)
    if stats.error:
        print(f"cobra emulate: the emulated robot failed: {stats.error}", file=sys.stderr)
        return 1
    return 0
