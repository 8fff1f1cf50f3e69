"""The MAVLink step markers (docs/lockstep.md): the codec, and a client's LockstepClient over a real UDP socket.

The codec must read back what it writes through pymavlink (an independent encoder), tell other V2_EXTENSIONs
from ours, and refuse a malformed marker of ours. The client must count what it sends whoever sends it, read a
step up to the peer's marker and refuse a step whose count does not balance or that is not the next one.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time

import pytest

os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from uav_common.errors import StopRequestedError, UavCommonError, WaitTimeoutError
from uav_common.lockstep.markers import (
    MESSAGE_TYPE,
    PAYLOAD_LEN,
    Marker,
    MarkerError,
    decode_payload,
    decode_wire_payload,
    encode_payload,
)
from uav_common.shell.mavlink_lockstep import LockstepClient

M = mavlink2


def test_markers_round_trip_through_pymavlink() -> None:
    sender = M.MAVLink(None, srcSystem=1, srcComponent=191)
    parser = M.MAVLink(None)
    for marker in (Marker.hello(3), Marker.end_of_step(12, 1_200_000, 7), Marker.end_of_step(2**40, 2**50, 0)):
        payload = encode_payload(marker)
        assert len(payload) == PAYLOAD_LEN
        frame = sender.v2_extension_encode(0, 1, 1, MESSAGE_TYPE, payload).pack(sender)
        (msg,) = parser.parse_buffer(frame)
        assert decode_payload(bytes(msg.payload), message_type=msg.message_type) == marker
        # the router reads it from the raw frame, where MAVLink 2 truncated the trailing zeros
        wire = decode_wire_payload(frame[10 : 10 + frame[1]])
        assert wire is not None
        assert (wire.target_system, wire.target_component, wire.marker) == (1, 1, marker)
    assert Marker.end_of_step(12, 1_200_000, 7).describe() == "STEP(12, t 1.200000 s, count 7)"
    assert Marker.hello(3).describe() == "HELLO(lookahead 3)"


def test_the_layout_is_the_contract() -> None:
    payload = encode_payload(Marker.end_of_step(0x0102, 0x0A0B, 0x99))
    assert payload[:4] == b"LKST"
    assert payload[4:6] == bytes((1, 2))  # version 1, kind STEP
    assert payload[6:8] == bytes(2)  # lookahead 0
    assert payload[8:16] == (0x0102).to_bytes(8, "little")
    assert payload[16:24] == (0x0A0B).to_bytes(8, "little")
    assert payload[24:28] == (0x99).to_bytes(4, "little")
    assert not any(payload[28:])
    assert encode_payload(Marker.hello(5))[6:8] == (5).to_bytes(2, "little")


def test_other_extensions_are_not_markers() -> None:
    assert decode_payload(bytes(PAYLOAD_LEN)) is None  # no magic
    assert decode_payload(encode_payload(Marker.hello(1)), message_type=MESSAGE_TYPE + 1) is None
    assert decode_payload(b"LKSX" + bytes(PAYLOAD_LEN - 4)) is None
    assert decode_wire_payload(bytes((0x39, 0x30, 0, 1, 1)) + b"LKST") is None  # message type 12345


@pytest.mark.parametrize(
    ("payload", "why"),
    [
        (b"LKST\x02\x02" + bytes(PAYLOAD_LEN - 6), "version 2"),
        (b"LKST\x01\x07" + bytes(PAYLOAD_LEN - 6), "kind 7"),
        (b"LKST\x01\x02" + bytes(PAYLOAD_LEN - 10), "must be 249 bytes, got 245"),
        (b"LKST\x01\x01" + bytes(PAYLOAD_LEN - 6), "lookahead"),  # a HELLO with lookahead 0
        (b"LKST\x01\x02\x01\x00" + bytes(PAYLOAD_LEN - 8), "lookahead 0"),  # a STEP with a lookahead
        (encode_payload(Marker.hello(1))[:-1] + b"\x01", "non-zero bytes"),
    ],
)
def test_a_malformed_marker_of_ours_is_an_error(payload: bytes, why: str) -> None:
    with pytest.raises(MarkerError, match=why) as err:
        decode_payload(payload)
    assert isinstance(err.value, UavCommonError)


def test_marker_fields_are_checked() -> None:
    with pytest.raises(MarkerError, match="count"):
        Marker.end_of_step(1, 0, -1)
    with pytest.raises(MarkerError, match="kind"):
        Marker(3)
    with pytest.raises(MarkerError, match="is longer than 254"):
        decode_wire_payload(bytes(300))


# ---------------------------------------------------------------------------------------------- the client


class Peer:
    """The router's side of a UDP link, by hand: an independent pymavlink encoder on a plain socket."""

    def __init__(self, client_port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(2.0)
        self.dest = ("127.0.0.1", client_port)
        self.mav = M.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = M.MAVLink(None)

    def send(self, *msgs: object) -> None:
        data = b"".join(m.pack(self.mav) for m in msgs)  # type: ignore[attr-defined]
        self.sock.sendto(data, self.dest)

    def marker(self, marker: Marker, target: tuple[int, int] = (1, 191)) -> object:
        return M.MAVLink_v2_extension_message(0, *target, MESSAGE_TYPE, encode_payload(marker))

    def receive(self) -> list[object]:
        data, _ = self.sock.recvfrom(65535)
        return list(self.parser.parse_buffer(data) or [])

    def close(self) -> None:
        self.sock.close()


def heartbeat() -> object:
    return M.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3)


def register(client: LockstepClient, peer: Peer) -> None:
    """HELLO, answered with STEP(0) (a message first: a udpin connection learns the peer's address from it)."""
    peer.send(heartbeat())
    threading.Timer(0.2, lambda: peer.send(peer.marker(Marker.end_of_step(0, 0, 0)))).start()
    assert client.hello(1, watchdog_s=5.0) == 0


@pytest.fixture
def link() -> tuple[LockstepClient, Peer, object]:
    conn = mavutil.mavlink_connection("udpin:127.0.0.1:0", dialect="common", source_system=1, source_component=191)
    peer = Peer(conn.port.getsockname()[1])
    client = LockstepClient(conn, name="test link")
    yield client, peer, conn
    conn.close()
    peer.close()


def test_a_client_counts_what_it_sends_and_reads_steps_up_to_the_markers(
    link: tuple[LockstepClient, Peer, object],
) -> None:
    client, peer, conn = link
    # a udpin connection cannot speak first: the peer's invitation (its HELLO) tells it where to send
    peer.send(peer.marker(Marker.hello(1), (0, 0)), heartbeat())
    peer_port = peer.sock.getsockname()[1]
    answer = threading.Timer(0.2, lambda: peer.send(heartbeat(), peer.marker(Marker.end_of_step(4, 400_000, 0))))
    answer.start()
    assert client.hello(2, watchdog_s=5.0) == 4
    (hello,) = peer.receive()
    assert decode_payload(bytes(hello.payload)) == Marker.hello(2)  # type: ignore[attr-defined]
    assert conn.clients == {("127.0.0.1", peer_port)}  # type: ignore[attr-defined]

    # step 5: three messages (one from another component, one of an unknown id counts too), then the marker
    other = M.MAVLink(None, srcSystem=1, srcComponent=2)
    peer.send(heartbeat(), M.MAVLink_system_time_message(5, 500))
    peer.sock.sendto(M.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(other), peer.dest)
    peer.send(peer.marker(Marker.end_of_step(5, 500_000, 3)), heartbeat())  # a message of step 6 right after
    msgs = client.read_step(5, watchdog_s=5.0)
    assert [m.get_type() for m in msgs] == ["HEARTBEAT", "SYSTEM_TIME", "HEARTBEAT"]
    # everything sent through the connection is counted, by whoever sends it (markers excluded)
    conn.mav.heartbeat_send(18, 8, 0, 0, 0)  # type: ignore[attr-defined]
    conn.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # type: ignore[attr-defined]
    sent = client.end_step(5, 0.5)
    assert sent == Marker.end_of_step(5, 500_000, 2)
    got = [peer.receive() for _ in range(3)]
    assert [m.get_type() for batch in got for m in batch] == ["HEARTBEAT", "COMMAND_LONG", "V2_EXTENSION"]
    assert decode_payload(bytes(got[2][0].payload)) == sent  # type: ignore[attr-defined]

    # step 6: the message that came right after marker 5 is step 6's
    peer.send(peer.marker(Marker.end_of_step(6, 600_000, 1)))
    assert [m.get_type() for m in client.read_step(6, watchdog_s=5.0)] == ["HEARTBEAT"]
    assert client.end_step(6, 0.6).count == 0


def test_a_count_that_does_not_balance_names_the_link_and_the_counts(
    link: tuple[LockstepClient, Peer, object],
) -> None:
    client, peer, _ = link
    register(client, peer)
    peer.send(heartbeat(), peer.marker(Marker.end_of_step(1, 100_000, 2)))  # says 2, sent 1: one was lost
    with pytest.raises(MarkerError, match=r"test link: step 1: the peer says it sent 2 messages, 1 were received"):
        client.read_step(1, watchdog_s=5.0)


def test_a_gap_or_a_step_out_of_order_is_an_error(link: tuple[LockstepClient, Peer, object]) -> None:
    client, peer, _ = link
    register(client, peer)
    with pytest.raises(MarkerError, match="out of order"):
        client.read_step(2, watchdog_s=5.0)
    with pytest.raises(MarkerError, match="before read_step"):
        client.end_step(1, 0.1)
    peer.send(peer.marker(Marker.end_of_step(2, 200_000, 0)))  # STEP(1) never came
    with pytest.raises(MarkerError, match=r"expected the peer's STEP\(1\) marker, got STEP\(2.*a gap"):
        client.read_step(1, watchdog_s=5.0)


def test_markers_for_someone_else_are_neither_messages_nor_ours(link: tuple[LockstepClient, Peer, object]) -> None:
    client, peer, _ = link
    register(client, peer)
    peer.send(
        heartbeat(),
        peer.marker(Marker.end_of_step(1, 100_000, 5), (1, 192)),  # the odometry node's marker on a shared port
        peer.marker(Marker.end_of_step(1, 100_000, 1)),
    )
    assert [m.get_type() for m in client.read_step(1, watchdog_s=5.0)] == ["HEARTBEAT"]


def test_the_watchdog_logs_and_then_raises(
    link: tuple[LockstepClient, Peer, object], monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    client, peer, _ = link
    register(client, peer)
    monkeypatch.setattr("uav_common.shell.mavlink_lockstep.LOG_EVERY_S", 0.1)
    peer.send(heartbeat())
    with caplog.at_level(logging.WARNING), pytest.raises(WaitTimeoutError, match=r"STEP\(1\) marker on test link"):
        client.read_step(1, watchdog_s=0.35)
    assert "still waiting for the peer's STEP(1) marker on test link" in caplog.text
    assert "(1 messages so far)" in caplog.text


def test_a_wait_ends_when_the_program_shuts_down(link: tuple[LockstepClient, Peer, object]) -> None:
    client, peer, _ = link
    register(client, peer)
    stopping = threading.Event()
    client._should_stop = stopping.is_set  # as a node passes rospy.is_shutdown
    threading.Timer(0.3, stopping.set).start()
    t0 = time.monotonic()
    with pytest.raises(StopRequestedError, match=r"stopped while waiting for the peer's STEP\(1\) marker"):
        client.read_step(1, watchdog_s=30.0)
    assert time.monotonic() - t0 < 3.0, "a node shutting down must not sit out its watchdog"


def test_udp_sockets_get_a_large_receive_buffer(link: tuple[LockstepClient, Peer, object]) -> None:
    _, _, conn = link
    rcvbuf = conn.port.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)  # type: ignore[attr-defined]
    with open("/proc/sys/net/core/rmem_max", encoding="ascii") as f:
        rmem_max = int(f.read())
    assert rcvbuf >= min(4 << 20, 2 * rmem_max)  # Linux reports twice what it grants
