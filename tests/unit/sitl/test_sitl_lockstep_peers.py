"""The SITL's lockstep peers (sitl.shell.lockstep_links): HELLO, markers, queued messages, counts, on fake links.

What a user would notice: a grant executes only once every peer has ended the step before it, with exactly the
messages that came before that marker; a lost message stops the run naming the peer and the counts; nothing is
waited for from a peer that is gone; a free-running SITL ignores HELLO.
"""

from __future__ import annotations

import logging
from collections.abc import Hashable
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from sitl.errors import LockstepError
from sitl.shell.links import Received
from sitl.shell.lockstep_links import LockstepPeers
from uav_common.lockstep.markers import MESSAGE_TYPE, Marker, encode_payload

M = mavlink2
ROUTER = ("tcp", 1)
CLIENT = ("api", ("127.0.0.1", 14540))


class FakeLinks:
    """PeerIo that records the markers sent and lets the test say how much went to each peer."""

    def __init__(self) -> None:
        self.sent: dict[Hashable, int] = {}
        self.markers: list[tuple[Hashable, Marker, tuple[int, int]]] = []
        self.pinned: set[Hashable] = set()

    def send_marker(self, route: Hashable, marker: Marker, target: tuple[int, int]) -> None:
        self.markers.append((route, marker, target))
        self.sent[route] = self.sent.get(route, 0) + 1  # a link counts the marker too: the bookkeeping must not

    def sent_count(self, route: Hashable) -> int:
        return self.sent.get(route, 0)

    def pin(self, route: Hashable) -> None:
        self.pinned.add(route)

    def unpin(self, route: Hashable) -> None:
        self.pinned.discard(route)

    def describe(self, route: Hashable) -> str:
        return f"peer {route}"

    def telemetry(self, route: Hashable, n: int) -> None:
        self.sent[route] = self.sent.get(route, 0) + n


def rx(msg: Any, route: Hashable, src: tuple[int, int] = (1, 240)) -> Received:
    frame = msg.pack(M.MAVLink(None, srcSystem=src[0], srcComponent=src[1]))
    (parsed,) = M.MAVLink(None).parse_buffer(frame)
    return Received(parsed, route)


def marker(m: Marker, route: Hashable, src: tuple[int, int] = (1, 240)) -> Received:
    return rx(M.MAVLink_v2_extension_message(0, 1, 1, MESSAGE_TYPE, encode_payload(m)), route, src)


def command(route: Hashable, n: int) -> Received:
    return rx(M.MAVLink_command_long_message(1, 1, 400, 0, n, 0, 0, 0, 0, 0, 0), route, (1, 191))


def peers(*, lockstep: bool = True) -> tuple[LockstepPeers, FakeLinks]:
    links = FakeLinks()
    return LockstepPeers(lockstep=lockstep, io=links, t_sim_us=lambda: 0), links


def test_hello_registers_at_the_current_step_and_is_answered() -> None:
    p, links = peers()
    p.end_step(3, 300_000)  # three grants before anyone said HELLO
    assert p.offer(marker(Marker.hello(1), ROUTER))
    assert links.markers == [(ROUTER, Marker.end_of_step(3, 0, 0), (1, 240))]  # addressed to the HELLO's source
    assert links.pinned == {ROUTER}
    assert p.ready(3)  # HELLO counts as its STEP(3): grant 4 does not wait
    assert not p.ready(4)
    assert p.routes() == frozenset({ROUTER})


def test_a_grant_takes_exactly_the_messages_before_the_peers_marker() -> None:
    p, _ = peers()
    p.offer(marker(Marker.hello(1), ROUTER))
    assert p.offer(command(ROUTER, 1))
    assert p.offer(command(ROUTER, 2))
    assert p.release(0) == []  # nothing closed yet
    assert p.offer(marker(Marker.end_of_step(1, 100_000, 2), ROUTER))
    assert p.offer(command(ROUTER, 3))  # after the marker: the peer's step 2
    assert p.ready(1)
    assert [m.msg.param1 for m in p.release(1)] == [1.0, 2.0]
    assert p.release(1) == []
    p.offer(marker(Marker.end_of_step(2, 200_000, 1), ROUTER))
    assert [m.msg.param1 for m in p.release(2)] == [3.0]


def test_every_frame_counts_but_only_messages_are_handled() -> None:
    p, _ = peers()
    p.offer(marker(Marker.hello(1), ROUTER))
    unknown = M.MAVLink(None).parse_buffer(bytes.fromhex("fd030000000909dcbc0a010203aabb"))  # an unknown id
    assert unknown is not None
    assert unknown[0].get_type().startswith("UNKNOWN_")
    p.offer(Received(unknown[0], ROUTER))
    p.offer(command(ROUTER, 1))
    p.offer(marker(Marker.end_of_step(1, 100_000, 2), ROUTER))  # the router sent two frames
    assert [m.msg.get_type() for m in p.release(1)] == ["COMMAND_LONG"]


def test_markers_count_what_was_sent_to_each_peer_since_the_previous_marker() -> None:
    p, links = peers()
    p.offer(marker(Marker.hello(1), ROUTER))
    p.offer(marker(Marker.hello(2), CLIENT, (1, 191)))
    links.telemetry(ROUTER, 40)
    links.telemetry(CLIENT, 7)
    p.end_step(1, 100_000)
    links.telemetry(ROUTER, 5)
    p.end_step(2, 200_000)
    steps = [(route, m.step, m.count) for route, m, _ in links.markers if m.step > 0]
    assert steps == [(ROUTER, 1, 40), (CLIENT, 1, 7), (ROUTER, 2, 5), (CLIENT, 2, 0)]


def test_a_count_that_does_not_balance_stops_the_run_naming_the_peer() -> None:
    p, _ = peers()
    p.offer(marker(Marker.hello(1), ROUTER))
    p.offer(command(ROUTER, 1))
    with pytest.raises(LockstepError, match=r"peer \('tcp', 1\): step 1: it says it sent 2 messages, 1 were received"):
        p.offer(marker(Marker.end_of_step(1, 100_000, 2), ROUTER))


def test_a_marker_for_an_unexpected_step_stops_the_run() -> None:
    p, _ = peers()
    p.offer(marker(Marker.hello(1), ROUTER))
    with pytest.raises(LockstepError, match=r"expected its STEP\(1\) marker, got STEP\(2"):
        p.offer(marker(Marker.end_of_step(2, 200_000, 0), ROUTER))


def test_a_malformed_marker_stops_the_run() -> None:
    p, _ = peers()
    bad = M.MAVLink_v2_extension_message(0, 1, 1, MESSAGE_TYPE, b"LKST\x05" + bytes(244))
    with pytest.raises(LockstepError, match=r"malformed lockstep marker from peer \('tcp', 1\)"):
        p.offer(rx(bad, ROUTER))


def test_a_peer_that_is_gone_is_waited_for_no_more(caplog: pytest.LogCaptureFixture) -> None:
    p, links = peers()
    p.offer(marker(Marker.hello(1), ROUTER))
    p.end_step(1, 100_000)
    assert not p.ready(1)
    with caplog.at_level(logging.ERROR):
        p.forget(ROUTER)
    assert "lockstep peer peer ('tcp', 1) disconnected" in caplog.text
    assert p.ready(1)
    assert links.pinned == set()
    assert not p.offer(command(ROUTER, 1))  # a new client on the same id is no lockstep peer


def test_other_routes_are_handled_as_they_come() -> None:
    p, _ = peers()
    p.offer(marker(Marker.hello(1), ROUTER))
    assert not p.offer(command(CLIENT, 1))
    assert not p.offer(rx(M.MAVLink_v2_extension_message(0, 1, 1, 7, bytes(249)), CLIENT))  # not a marker


def test_a_free_running_sitl_ignores_hello(caplog: pytest.LogCaptureFixture) -> None:
    p, links = peers(lockstep=False)
    with caplog.at_level(logging.INFO):
        assert p.offer(marker(Marker.hello(1), ROUTER))  # consumed, never handled as a message
        assert p.offer(marker(Marker.hello(1), ROUTER))
    assert links.markers == []
    assert caplog.text.count("not answered, the SITL runs free") == 1
    assert not p.offer(command(ROUTER, 1))
    assert p.ready(100)
