"""Framing: CRC, MAVLink 1/2 and signed frames kept byte for byte, targets, garbage and resync."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mr_build import KEY, TABLE, command_long, heartbeat, pack, pack_v1, ping, system_time, unknown_frame
from pymavlink.dialects.v10 import ardupilotmega as v1

from mavlink_router.core.frames import NO_TARGET, FrameParser, MessageSpec, _x25_crc_binascii, frame_header, x25_crc


def reference_crc(data: bytes, crc: int = 0xFFFF) -> int:
    """MAVLink's crc_accumulate, bit by bit, as in the C library's checksum.h."""
    for byte in data:
        tmp = byte ^ (crc & 0xFF)
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


@given(st.binary(max_size=300), st.integers(0, 0xFFFF))
def test_crc_matches_the_mavlink_reference(data: bytes, initial: int) -> None:
    assert x25_crc(data, initial) == reference_crc(data, initial)
    assert _x25_crc_binascii(data, initial) == reference_crc(data, initial)


def test_known_crc_value() -> None:
    # CRC-16/MCRF4XX check value from the CRC catalogue.
    assert x25_crc(b"123456789") == 0x6F91


def test_v2_frame_is_returned_unchanged_with_header_fields() -> None:
    raw = pack(command_long(7, 9), sysid=42, compid=190, seq=77)
    [frame] = FrameParser(TABLE, stream=False).feed(raw)
    assert frame == (raw, 76, 42, 190, 77, 7, 9)
    assert frame_header(raw) == (76, 42, 190, 77, 10)


def test_v1_frame_is_returned_unchanged() -> None:
    raw = pack_v1(v1.MAVLink_command_long_message(3, 4, 400, 0, 1, 0, 0, 0, 0, 0, 0), sysid=5, compid=6, seq=1)
    assert raw[0] == 0xFE
    [frame] = FrameParser(TABLE, stream=False).feed(raw)
    assert frame == (raw, 76, 5, 6, 1, 3, 4)


def test_signed_frame_passes_through_with_its_signature() -> None:
    raw = pack(heartbeat(), key=KEY, timestamp=123456)
    assert raw[2] & 1
    assert len(raw) == 10 + raw[1] + 2 + 13
    [frame] = FrameParser(TABLE, stream=False).feed(raw)
    assert frame[0] == raw


def test_message_without_target_fields_has_no_target() -> None:
    [frame] = FrameParser(TABLE, stream=False).feed(pack(heartbeat()))
    assert frame[5:] == (NO_TARGET, NO_TARGET)


def test_truncated_zero_target_means_broadcast() -> None:
    # PING's target fields are the last payload bytes; MAVLink 2 trims them when zero.
    raw = pack(ping(0, 0))
    assert raw[1] < 14  # payload was truncated
    [frame] = FrameParser(TABLE, stream=False).feed(raw)
    assert frame[5:] == (0, 0)


def test_bad_crc_is_counted_and_dropped() -> None:
    raw = bytearray(pack(command_long(1, 1)))
    raw[-1] ^= 0xFF
    parser = FrameParser(TABLE, stream=False)
    assert parser.feed(bytes(raw)) == []
    assert parser.crc_errors == 1


def test_unknown_id_is_forwarded_without_crc_check() -> None:
    raw = unknown_frame()
    [frame] = FrameParser(TABLE, stream=False).feed(raw)
    assert frame == (raw, 0xABCDE, 9, 9, 0, NO_TARGET, NO_TARGET)


def test_unknown_id_followed_by_garbage_is_not_forwarded() -> None:
    parser = FrameParser(TABLE, stream=False)
    assert parser.feed(unknown_frame() + b"\x00\x11") == []
    assert parser.garbage_bytes > 0


def test_unknown_incompat_flags_are_rejected() -> None:
    raw = bytearray(pack(heartbeat()))
    raw[2] = 0x02
    assert FrameParser(TABLE, stream=False).feed(bytes(raw)) == []


def test_several_frames_in_one_datagram() -> None:
    frames = [pack(heartbeat(), seq=1), pack(command_long(1, 1), seq=2), pack_v1(v1.MAVLink_system_time_message(5, 6))]
    out = FrameParser(TABLE, stream=False).feed(b"".join(frames))
    assert [f[0] for f in out] == frames


def test_datagram_leftovers_are_garbage_not_carried_over() -> None:
    parser = FrameParser(TABLE, stream=False)
    raw = pack(heartbeat())
    assert parser.feed(raw[:5]) == []
    assert parser.feed(raw[5:]) == []
    assert parser.pending_bytes == 0
    assert parser.feed(raw)[0][0] == raw


def test_stream_reassembles_byte_by_byte() -> None:
    frames = [pack(command_long(1, 1), seq=i) for i in range(3)]
    data = b"".join(frames)
    parser = FrameParser(TABLE, stream=True)
    out = []
    for i in range(len(data)):
        out += parser.feed(data[i : i + 1])
    assert [f[0] for f in out] == frames
    assert parser.garbage_bytes == 0


def test_custom_table_controls_crc_and_targets() -> None:
    raw = pack(command_long(7, 9))
    # With a wrong crc_extra the frame is a CRC error; without an entry it is "unknown".
    wrong = {76: MessageSpec("COMMAND_LONG", crc_extra=1, target_system_ofs=30, target_component_ofs=31)}
    parser = FrameParser(wrong, stream=False)
    assert parser.feed(raw) == []
    assert parser.crc_errors == 1
    [frame] = FrameParser({}, stream=False).feed(raw)
    assert frame[5:] == (NO_TARGET, NO_TARGET)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), chunk=st.integers(1, 97))
def test_garbage_between_frames_is_skipped_and_every_frame_recovered(seed: int, chunk: int) -> None:
    rng = random.Random(seed)
    frames = [
        pack(rng.choice([heartbeat(), command_long(1, 1), system_time(rng.randrange(1 << 40))]), seq=i)
        for i in range(20)
    ]
    stream = b""
    for raw in frames:
        junk = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 40)))
        stream += junk + raw
    parser = FrameParser(TABLE, stream=True)
    out = []
    for i in range(0, len(stream), chunk):
        out += parser.feed(stream[i : i + chunk])
    out += parser.flush()  # the input is at rest
    got = [f[0] for f in out if f[1] in TABLE]
    # Every real frame comes out, in order; random junk almost never forms a valid
    # known-ID frame (16-bit CRC), and must never swallow a real one.
    assert [raw for raw in got if raw in frames] == frames


@pytest.mark.parametrize("junk", [b"\xfd", b"\xfd\xff\x00", b"\xfe\x05", b"\x00" * 300, b"\xfd" * 20, b"\xfe\xff"])
def test_stream_resyncs_after_false_start_markers(junk: bytes) -> None:
    frames = [pack(command_long(1, 1), seq=i) for i in range(10)]
    parser = FrameParser(TABLE, stream=True)
    out = parser.feed(junk + frames[0])
    for raw in frames[1:]:
        out += parser.feed(raw)
    # A false start claiming a long frame delays the real frames behind it until
    # enough bytes arrived to check it; none is lost.
    assert [f[0] for f in out] == frames


def test_false_start_at_rest_is_given_up_after_flush() -> None:
    raw = pack(command_long(1, 1))
    parser = FrameParser(TABLE, stream=True)
    assert parser.feed(b"\xfd\xff\x00" + raw) == []  # waiting for a 267-byte "frame"
    assert [f[0] for f in parser.flush()] == [raw]
    assert parser.pending_bytes == 0


def test_stream_holds_unknown_id_frame_until_the_next_byte() -> None:
    unknown = unknown_frame()
    known = pack(heartbeat())
    parser = FrameParser(TABLE, stream=True)
    assert parser.feed(unknown) == []
    assert [f[0] for f in parser.feed(known)] == [unknown, known]
    assert parser.feed(unknown) == []
    assert [f[0] for f in parser.flush()] == [unknown]
