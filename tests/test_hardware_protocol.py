"""Protocol 2.0 codec: CRC-16, byte stuffing, packet encoding and the streaming parser.

The reference for the CRC is the ping instruction packet of the Protocol 2.0 documentation;
the reference for stuffing and CRC on arbitrary data is ROBOTIS's own ``dynamixel_sdk``.
"""
from __future__ import annotations

import numpy as np
import pytest
from dynamixel_sdk import Protocol2PacketHandler

from hardware.protocol import (
    BROADCAST_ID,
    Instruction,
    PacketParser,
    StatusError,
    crc16,
    encode_instruction,
    encode_status,
    stuff,
    unstuff,
)

#: Ping of ID 1 as printed in the Protocol 2.0 documentation: CRC 0x4E19, sent low byte first.
DOC_PING = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")


def test_crc_of_documented_ping_packet() -> None:
    assert crc16(DOC_PING[:-2]) == 0x4E19
    assert encode_instruction(1, Instruction.PING) == DOC_PING


def test_crc_matches_the_sdk_on_random_data() -> None:
    sdk = Protocol2PacketHandler()
    rng = np.random.default_rng(0)
    for n in (0, 1, 7, 64, 300):
        data = bytes(rng.integers(0, 256, n, dtype=np.uint8))
        assert crc16(data) == sdk.updateCRC(0, list(data), n)


@pytest.mark.parametrize("body", [
    b"",
    bytes.fromhex("03 74 00 FF FF FD"),           # the pattern at the end
    bytes.fromhex("FF FF FD FD 00"),              # the pattern followed by FD already
    bytes.fromhex("FF FF FD FF FF FD FF FF"),     # twice, and a partial pattern at the end
    bytes(range(256)) * 2,
])
def test_stuffing_round_trip(body: bytes) -> None:
    stuffed = stuff(body)
    assert unstuff(stuffed) == body
    # After stuffing every FF FF FD is followed by FD, so no header can appear inside a packet.
    for k in range(len(stuffed) - 3):
        if stuffed[k:k + 3] == b"\xff\xff\xfd":
            assert stuffed[k + 3] == 0xFD
    assert stuffed.count(b"\xff\xff\xfd") == body.count(b"\xff\xff\xfd")


def test_encoding_with_stuffing_matches_the_sdk() -> None:
    # Write 4 bytes FF FF FD 01 at address 116 of ID 3: the parameters need stuffing.
    params = bytes.fromhex("74 00 FF FF FD 01")
    sdk = Protocol2PacketHandler()
    packet = [0xFF, 0xFF, 0xFD, 0x00, 3, len(params) + 3, 0, Instruction.WRITE, *params, 0, 0]
    packet = sdk.addStuffing(packet)
    length = packet[5] | (packet[6] << 8)
    crc = sdk.updateCRC(0, packet, length + 5)
    packet[length + 5:length + 7] = [crc & 0xFF, crc >> 8]
    assert encode_instruction(3, Instruction.WRITE, params) == bytes(packet[:length + 7])


def test_parser_recovers_packets_between_noise_and_split_reads() -> None:
    a = encode_instruction(1, Instruction.READ, bytes.fromhex("84 00 04 00"))
    b = encode_instruction(BROADCAST_ID, Instruction.SYNC_WRITE, bytes.fromhex("74 00 04 00 01 FF FF FD 00"))
    c = encode_status(2, StatusError.NONE, bytes.fromhex("FF FF FD"))
    stream = b"\x00\xff\x12" + a + b"\xff\xff" + b + c
    parser = PacketParser()
    packets = []
    for k in range(0, len(stream), 5):  # arrive in pieces
        packets.extend(parser.feed(stream[k:k + 5], now_s=0.0))
    assert [(p.servo_id, p.instruction, p.crc_ok) for p in packets] == [
        (1, Instruction.READ, True), (BROADCAST_ID, Instruction.SYNC_WRITE, True), (2, 0x55, True)]
    assert packets[1].params == bytes.fromhex("74 00 04 00 01 FF FF FD 00")
    assert packets[2].params == bytes.fromhex("00 FF FF FD")  # error byte, then the unstuffed data


def test_parser_flags_a_wrong_crc_and_goes_on() -> None:
    good = encode_instruction(4, Instruction.PING)
    bad = good[:-1] + bytes((good[-1] ^ 0x01,))
    packets = list(PacketParser().feed(bad + good, now_s=0.0))
    assert [(p.servo_id, p.crc_ok) for p in packets] == [(4, False), (4, True)]


def test_parser_drops_a_stale_partial_packet_and_an_implausible_length() -> None:
    parser = PacketParser(stale_after_s=0.1)
    ping = encode_instruction(7, Instruction.PING)
    assert list(parser.feed(ping[:6], now_s=0.0)) == []
    # The rest never came: 0.5 s later a new packet arrives and is parsed on its own.
    assert [p.servo_id for p in parser.feed(ping, now_s=0.5)] == [7]
    # A header with a length beyond 1024 is noise: the parser resynchronises on the next header.
    junk = bytes.fromhex("FF FF FD 00 01 FF 7F")
    assert [p.servo_id for p in parser.feed(junk + ping, now_s=0.6)] == [7]
