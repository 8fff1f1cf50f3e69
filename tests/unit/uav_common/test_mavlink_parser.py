"""uav_common.mavlink_parser.reset_parser: a parser reset in the middle of garbage parses the next frame."""

from __future__ import annotations

import contextlib

from pymavlink.dialects.v20 import common as mavlink

from uav_common.mavlink_parser import reset_parser


def frame() -> bytes:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    return bytes(mav.heartbeat_encode(6, 8, 0, 0, 4).pack(mav))


def test_a_reset_parser_reads_the_next_whole_frame_after_any_garbage() -> None:
    for garbage in (b"\xfd\x09", b"\x00\x01\x02", b"\xfe", frame()[:10], b"\xfd" * 40):
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        with contextlib.suppress(mavlink.MAVError):
            parser.parse_buffer(garbage)
        reset_parser(parser)
        assert parser.buf_len() == 0
        assert not parser.have_prefix_error
        msgs = parser.parse_buffer(frame()) or []
        assert [m.get_type() for m in msgs] == ["HEARTBEAT"], garbage


def test_the_reset_matches_a_fresh_parser() -> None:
    """If pymavlink grows parser state, a fresh parser and a reset one would differ here."""
    fresh = mavlink.MAVLink(None)
    used = mavlink.MAVLink(None)
    used.parse_buffer(b"\xfd" * 7)
    reset_parser(used)
    for name in ("buf", "buf_index", "expected_length", "have_prefix_error"):
        assert getattr(used, name) == getattr(fresh, name), name
