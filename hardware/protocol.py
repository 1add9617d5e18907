"""Dynamixel Protocol 2.0 packets: CRC-16, byte stuffing, encoding and a streaming parser.

The driver talks to the servos through ``dynamixel_sdk``; this module is the project's own
implementation of the wire format, used by the bus emulator (which must parse what the SDK
sends and answer as a servo would) and by the tests that check both against each other.

Packet layout (all multi-byte fields little endian)::

    instruction: FF FF FD 00 | ID | LEN_L LEN_H | INST        | PARAM ... | CRC_L CRC_H
    status:      FF FF FD 00 | ID | LEN_L LEN_H | 0x55  ERROR | PARAM ... | CRC_L CRC_H

``LEN`` counts the bytes after itself (instruction, error, parameters after stuffing, CRC).
Byte stuffing: wherever ``FF FF FD`` appears in the instruction/parameter bytes, an extra
``FD`` is inserted after it, so the header pattern never appears inside a packet. The CRC is
CRC-16 with polynomial ``0x8005`` (x^16 + x^15 + x^2 + 1), initial value 0, no reflection,
computed over the whole stuffed packet from the first header byte to the last parameter.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from typing import Iterator

HEADER = bytes((0xFF, 0xFF, 0xFD, 0x00))
#: Bytes before the instruction: header (4), ID (1), LEN (2).
PREFIX_LEN = 7
BROADCAST_ID = 0xFE
#: Longest packet (after the length field) this implementation accepts [bytes].
MAX_LENGTH_FIELD = 1024
#: Status packets carry this in the instruction position.
STATUS_INSTRUCTION = 0x55
#: Error byte bit set when the servo has a hardware error (see Hardware Error Status).
ALERT_BIT = 0x80

_STUFF_PATTERN = bytes((0xFF, 0xFF, 0xFD))
_CRC_POLYNOMIAL = 0x8005


class Instruction(IntEnum):
    """Protocol 2.0 instruction codes."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class StatusError(IntEnum):
    """Error numbers of a status packet's error byte (bits 0-6; bit 7 is :data:`ALERT_BIT`)."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ _CRC_POLYNOMIAL) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16 (polynomial 0x8005, MSB first, initial value ``crc``) of ``data``."""
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes | bytearray) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` in ``body`` (instruction and parameters)."""
    out = bytearray()
    for byte in body:
        out.append(byte)
        if byte == 0xFD and out[-3:] == _STUFF_PATTERN:
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes | bytearray) -> bytes:
    """Inverse of :func:`stuff`: drop the ``FD`` that follows every ``FF FF FD``."""
    out = bytearray()
    skip_next_fd = False
    for byte in body:
        if skip_next_fd:
            skip_next_fd = False
            if byte == 0xFD:
                continue
        out.append(byte)
        if byte == 0xFD and out[-3:] == _STUFF_PATTERN:
            skip_next_fd = True
    return bytes(out)


def _frame(servo_id: int, body: bytes) -> bytes:
    stuffed = stuff(body)
    length = len(stuffed) + 2
    packet = HEADER + bytes((servo_id, length & 0xFF, length >> 8)) + stuffed
    crc = crc16(packet)
    return packet + bytes((crc & 0xFF, crc >> 8))


def encode_instruction(servo_id: int, instruction: int, params: bytes = b"") -> bytes:
    """Complete instruction packet (header, stuffing and CRC) for ``servo_id``."""
    return _frame(servo_id, bytes((instruction,)) + params)


def encode_status(servo_id: int, error: int, params: bytes = b"") -> bytes:
    """Complete status packet of ``servo_id`` with error byte ``error``."""
    return _frame(servo_id, bytes((STATUS_INSTRUCTION, error)) + params)


@dataclass(frozen=True)
class Packet:
    """A parsed packet.

    Attributes:
        servo_id: the ID byte (``BROADCAST_ID`` for broadcasts).
        instruction: instruction byte (``STATUS_INSTRUCTION`` for status packets).
        params: parameter bytes after unstuffing (for a status packet: error byte first).
        crc_ok: False when the received CRC did not match; the content is then untrusted.
    """

    servo_id: int
    instruction: int
    params: bytes
    crc_ok: bool = True


class PacketParser:
    """Incremental parser: feed it bytes as they arrive, get complete packets back.

    Bytes before a header are skipped; a packet with a wrong CRC is returned with
    ``crc_ok=False`` (a servo answers those with a CRC error); an implausible length field makes
    the parser drop one byte and search for the next header. A packet left incomplete for longer
    than ``stale_after_s`` is discarded when more bytes arrive, as a servo's receive timeout does.
    """

    def __init__(self, *, stale_after_s: float = 0.1) -> None:
        self._buffer = bytearray()
        self._stale_after_s = stale_after_s
        self._last_rx_s: float | None = None

    def feed(self, data: bytes, now_s: float) -> Iterator[Packet]:
        """Add ``data`` received at time ``now_s`` [s] and yield every packet completed by it."""
        if (
            self._buffer
            and self._last_rx_s is not None
            and now_s - self._last_rx_s > self._stale_after_s
        ):
            self._buffer.clear()
        self._last_rx_s = now_s
        self._buffer += data
        while True:
            start = self._buffer.find(HEADER)
            if start < 0:
                # Keep a possible partial header at the end.
                del self._buffer[: max(0, len(self._buffer) - (len(HEADER) - 1))]
                return
            del self._buffer[:start]
            if len(self._buffer) < PREFIX_LEN:
                return
            length = self._buffer[5] | (self._buffer[6] << 8)
            if not 3 <= length <= MAX_LENGTH_FIELD:
                del self._buffer[0]
                continue
            total = PREFIX_LEN + length
            if len(self._buffer) < total:
                return
            raw = bytes(self._buffer[:total])
            del self._buffer[:total]
            crc_ok = crc16(raw[:-2]) == (raw[-2] | (raw[-1] << 8))
            body = unstuff(raw[PREFIX_LEN:-2])
            yield Packet(servo_id=raw[4], instruction=body[0], params=body[1:], crc_ok=crc_ok)
