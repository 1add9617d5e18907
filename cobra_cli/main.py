"""Entry point of the ``cobra`` console script.

Each subcommand lives in its own module ``cobra_cli/cmd_<name>.py`` that defines
``add_parser(subparsers) -> None`` and ``run(args) -> int`` (stored as ``func`` by ``set_defaults``). Errors a user can fix (bad
files, bad parameters) are :class:`cobra_model.errors.InputError` and are printed as one clear
line, never as a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from cobra_cli.errors import USER_ERRORS

#: Subcommand modules, in the order ``cobra --help`` lists them.
COMMANDS: tuple[str, ...] = (
    "demo",
    "info",
    "simulate",
    "compare",
    "import-optitrack",
    "replay",
    "check",
    "fit",
    "diagnose",
    "check-bus",
    "record",
    "emulate",
)


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level parser with every registered subcommand."""
    parser = argparse.ArgumentParser(
        prog="cobra",
        description="COBRA snake robot: model, simulate, compare, identify, diagnose, record.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        module = importlib.import_module(f"cobra_cli.cmd_{name.replace('-', '_')}")
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run the chosen subcommand; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except USER_ERRORS as exc:
        print(f"cobra {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into e.g. `head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print(f"cobra {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
