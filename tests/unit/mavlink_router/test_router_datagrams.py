"""Packing frames routed together into UDP datagrams (never splitting a frame)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st
from mr_build import TABLE, command_long, pack

from mavlink_router.core.frames import FrameParser
from mavlink_router.shell.endpoints import MAX_DATAGRAM_BYTES, pack_datagrams


@given(st.lists(st.integers(1, 280), max_size=40))
def test_packing_keeps_order_limit_and_frames(sizes: list[int]) -> None:
    frames = [bytes([i % 256]) * n for i, n in enumerate(sizes)]
    packed = pack_datagrams(frames)
    assert b"".join(d for d, _ in packed) == b"".join(frames)
    assert sum(c for _, c in packed) == len(frames)
    for data, count in packed:
        assert len(data) <= MAX_DATAGRAM_BYTES or count == 1


def test_packed_datagram_parses_back_into_the_same_frames() -> None:
    frames = [pack(command_long(1, 1), 255, 190, seq=i) for i in range(50)]
    out = []
    for data, _ in pack_datagrams(frames):
        out += [f[0] for f in FrameParser(TABLE, stream=False).feed(data)]
    assert out == frames
