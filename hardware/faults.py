"""Faults the bus emulator can inject, and their command-line spelling.

A fault starts ``at_s`` seconds of emulated time after the first Torque Enable = 1 (when a
driver starts moving the robot), so a schedule means the same thing whatever the connect phase
took. Spelling: ``KIND[:ID][@SECONDS][xCOUNT]``, e.g. ``crc@1.5x3`` (corrupt the CRC of the
next 3 status packets from 1.5 s on), ``silent:5@2`` (servo 5 stops answering at 2 s),
``overload:3@2.5``, ``cut@3``, ``unplug@4``.

Kinds:

* ``crc`` (ID optional, COUNT): the next COUNT status packets (of that servo, or of any) carry
  a wrong CRC.
* ``drop`` (ID optional, COUNT): the next COUNT status packets are not sent.
* ``silent`` (ID): the servo ignores every packet from then on.
* ``overload``, ``overheating`` (ID): Hardware Error Status gets that bit and, as the default
  Shutdown (63) register says, the servo turns its torque off.
* ``voltage`` (ID): a brownout: Present Input Voltage (144) sags to
  :data:`BROWNOUT_VOLTAGE_V`, below the Min Voltage Limit, and the input-voltage bit is set,
  which the default Shutdown leaves torque on for.
* ``cut``: the bus cable between the adapter and the servos is cut: no servo hears the host
  or answers any more, the port stays open, and each servo's Bus Watchdog (98) is all that
  stops it.
* ``unplug``: the pty is closed, as when the USB cable of the adapter is pulled.

The host can fail too: :func:`full_disk_after` makes the run file's disk fill up.
"""
from __future__ import annotations

import contextlib
import errno
import math
import os
import re
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any, Iterator

from cobra_model.errors import InputError
from hardware.control_table import HardwareError


class FaultKind(Enum):
    """What goes wrong."""

    CRC = "crc"
    DROP = "drop"
    SILENT = "silent"
    OVERLOAD = "overload"
    OVERHEATING = "overheating"
    VOLTAGE = "voltage"
    CUT = "cut"
    UNPLUG = "unplug"


#: Hardware Error Status bit set by each hardware fault.
HARDWARE_FAULT_BITS: dict[FaultKind, HardwareError] = {
    FaultKind.OVERLOAD: HardwareError.OVERLOAD,
    FaultKind.OVERHEATING: HardwareError.OVERHEATING,
    FaultKind.VOLTAGE: HardwareError.INPUT_VOLTAGE,
}
#: Present Input Voltage during a ``voltage`` fault [V] (the XH540's Min Voltage Limit is 9.5 V).
BROWNOUT_VOLTAGE_V = 8.5
_NEEDS_ID = {FaultKind.SILENT, *HARDWARE_FAULT_BITS}
_WHOLE_BUS = {FaultKind.UNPLUG, FaultKind.CUT}
_COUNTED = {FaultKind.CRC, FaultKind.DROP}


@dataclass(frozen=True)
class Fault:
    """One scheduled fault.

    Attributes:
        kind: what goes wrong.
        at_s: start [s of emulated time after the first torque on].
        servo_id: the servo concerned (None: any servo, for ``crc``/``drop``).
        count: status packets affected (``crc``/``drop`` only).

    Raises:
        InputError: inconsistent fields.
    """

    kind: FaultKind
    at_s: float = 0.0
    servo_id: int | None = None
    count: int = 1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.at_s) and self.at_s >= 0):
            raise InputError(f"fault {self.kind.value}: start time must be >= 0 s, got {self.at_s}")
        if self.kind in _NEEDS_ID and self.servo_id is None:
            raise InputError(f"fault {self.kind.value} needs a servo ID ({self.kind.value}:ID@SECONDS)")
        if self.kind in _WHOLE_BUS and self.servo_id is not None:
            raise InputError(f"fault {self.kind.value} concerns the whole bus; give no servo ID")
        if self.servo_id is not None and not 0 <= self.servo_id <= 252:
            raise InputError(f"fault {self.kind.value}: servo ID must be 0..252, got {self.servo_id}")
        if self.count < 1 or (self.count != 1 and self.kind not in _COUNTED):
            raise InputError(f"fault {self.kind.value}: a count (xN, N >= 1) applies to crc and drop only")


_SPEC = re.compile(r"^(?P<kind>[a-z]+)(?::(?P<id>\d+))?(?:@(?P<at>[0-9.]+))?(?:x(?P<count>\d+))?$")


def parse_fault(spec: str) -> Fault:
    """Parse ``KIND[:ID][@SECONDS][xCOUNT]`` (see the module docstring).

    Raises:
        InputError: naming the spec and the expected form.
    """
    match = _SPEC.match(spec.strip().lower())
    kinds = ", ".join(k.value for k in FaultKind)
    if match is None:
        raise InputError(f"fault {spec!r}: expected KIND[:ID][@SECONDS][xCOUNT], e.g. crc@1.5x3 "
                         f"or silent:5@2 (kinds: {kinds})")
    try:
        kind = FaultKind(match["kind"])
    except ValueError:
        raise InputError(f"fault {spec!r}: unknown kind {match['kind']!r}; expected one of {kinds}") from None
    try:
        at_s = float(match["at"]) if match["at"] else 0.0
    except ValueError:
        raise InputError(f"fault {spec!r}: {match['at']!r} is not a number of seconds") from None
    return Fault(kind, at_s=at_s, servo_id=int(match["id"]) if match["id"] else None,
                 count=int(match["count"]) if match["count"] else 1)


class _FullDisk:
    """A file whose disk fills up at its ``writes``-th write: that write puts 7 bytes down,
    then fails with ENOSPC, as write(2) does."""

    def __init__(self, fh: Any, writes: int) -> None:
        self.fh, self.left = fh, writes

    def write(self, data: Any) -> int:
        self.left -= 1
        if self.left > 0:
            return self.fh.write(data)
        self.fh.write(bytes(data[:7]))
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.fh, name)


@contextlib.contextmanager
def full_disk_after(samples: int) -> Iterator[None]:
    """Meanwhile every :class:`~hardware.runwriter.IncrementalRunWriter` has room for its header
    and ``samples`` lines (the next write fails part-way with ENOSPC), and cannot replace its
    sidecar once it has written the first one: a disk filling up during a recording."""
    from hardware.runwriter import IncrementalRunWriter

    opened, sidecar = IncrementalRunWriter._open, IncrementalRunWriter._write_sidecar
    written: set[Path] = set()

    def full_sidecar(self: IncrementalRunWriter, meta: Any) -> None:
        if self.path in written:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        written.add(self.path)
        sidecar(self, meta)

    IncrementalRunWriter._open = lambda self, mode: _FullDisk(opened(self, mode), samples + 2)
    IncrementalRunWriter._write_sidecar = full_sidecar
    try:
        yield
    finally:
        IncrementalRunWriter._open, IncrementalRunWriter._write_sidecar = opened, sidecar
