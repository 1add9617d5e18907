"""Command-line values shared by the benchmarks: comma-separated lists of numbers."""
from __future__ import annotations

import argparse
from typing import Callable, TypeVar

Number = TypeVar("Number", int, float)


def number_list(parser: argparse.ArgumentParser, option: str, text: str,
                kind: Callable[[str], Number] = int) -> list[Number]:
    """The comma-separated values of ``option`` (its text ``text``), each read by ``kind``; blanks
    between commas are skipped. A value ``kind`` cannot read, or no value at all, is a parser
    error naming the option and what it got (exit 2, no traceback)."""
    noun = "integers" if kind is int else "numbers"
    try:
        values = [kind(s) for s in text.split(",") if s.strip()]
    except ValueError:
        parser.error(f"{option}: expected comma-separated {noun}, got {text!r}")
    if not values:
        parser.error(f"{option}: give at least one value, got {text!r}")
    return values
