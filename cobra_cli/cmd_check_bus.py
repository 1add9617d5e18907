"""``cobra check-bus``: bring-up check of the servo bus against its configuration.

Example::

    cobra check-bus --config examples/bus.toml
    cobra check-bus --config examples/bus.toml --port /tmp/cobra-bus --json

Pings every ID on the bus and reads each configured servo's model number, firmware, operating
mode, position limits, input voltage and temperature (``hardware.bringup``); writes nothing and
leaves torque as it is. Prints a table and one line per mismatch naming the servo.
Exit status: 0 the bus matches the configuration, 1 a mismatch or the port cannot be opened,
2 bad input.
"""
from __future__ import annotations

import argparse
import json
import sys

from hardware.bringup import survey_bus
from hardware.config import load_bus_config
from hardware.driver import BusError


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    """Register ``cobra check-bus``."""
    p = subparsers.add_parser("check-bus", help="bring-up: does the bus hold the servos the configuration describes?",
                              description=__doc__.splitlines()[0])
    p.add_argument("--config", required=True, help="bus configuration (.toml, .yaml)")
    p.add_argument("--port", help="serial port, overriding the configuration's (e.g. the emulator's link)")
    p.add_argument("--json", action="store_true", help="print the survey as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Survey the bus; returns the exit status."""
    config = load_bus_config(args.config)
    if args.port:
        config = config.with_port(args.port)
    try:
        survey = survey_bus(config)
    except BusError as exc:
        print(f"cobra check-bus: error: {exc}", file=sys.stderr)
        return 1
    mismatches = survey.mismatches
    if args.json:
        print(json.dumps(survey.to_json(), indent=2))
    else:
        print(f"bus on {survey.port} ({config.baud_rate} baud), configuration {config.source or args.config}:")
        print(survey.table())
        if mismatches:
            print(f"{len(mismatches)} mismatch{'es' if len(mismatches) > 1 else ''} with the configuration:")
            for line in mismatches:
                print(f"  {line}")
        else:
            print(f"all {len(survey.servos)} servos match the configuration")
    return 1 if mismatches else 0
