"""The real Router shell in-process, on real sockets, with an injected monotonic clock.

Behaviour that depends on time (UDP client revert after 5 s of silence, the idle
flush of byte streams) or on the vehicle's state (LogMode = while-armed) is
driven step by step here instead of waiting in real time.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from helpers.procs import free_port, free_udp_port
from mr_harness import drain, encoder, udp_sink, v2

from mavlink_router.core.config import parse_config_text
from mavlink_router.shell.dialect import load_message_table
from mavlink_router.shell.mainloop import Router

pytestmark = pytest.mark.timeout(30)
TABLE = load_message_table()


class FakeMonotonic:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@contextmanager
def running(text: str) -> Iterator[tuple[Router, FakeMonotonic]]:
    clock = FakeMonotonic()
    router = Router(parse_config_text(text), TABLE, monotonic=clock)
    router.start()
    try:
        yield router, clock
    finally:
        router.shutdown()


def pump(router: Router, until: object = None, timeout_s: float = 5.0) -> None:
    """Run loop iterations until ``until()`` is true (or just a few if no condition)."""
    deadline = time.monotonic() + timeout_s
    for _ in range(3):
        router.run_once(0.01)
    while callable(until) and not until():
        if time.monotonic() > deadline:
            msg = "condition not reached"
            raise TimeoutError(msg)
        router.run_once(0.01)


def heartbeat(sysid: int, *, armed: bool = False, autopilot: int = 12) -> bytes:
    return encoder(sysid, 1).pack(v2.MAVLink_heartbeat_message(2, autopilot, 129 if armed else 1, 0, 4, 3))


def test_udp_client_answers_the_last_sender_then_reverts_after_5_s() -> None:
    configured, source_port = free_udp_port(), free_udp_port()
    text = (
        f"[General]\nTcpServerPort = 0\n"
        f"[UdpEndpoint gcs]\nMode = Normal\nAddress = 127.0.0.1\nPort = {configured}\n"
        f"[UdpEndpoint src]\nMode = Server\nAddress = 127.0.0.1\nPort = {source_port}\n"
    )
    home, other = udp_sink(configured), udp_sink(free_udp_port())
    src = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with running(text) as (router, clock):
        got: list[tuple[bytes, tuple[str, int]]] = []

        def receive(sock: socket.socket) -> bool:
            try:
                got.append(sock.recvfrom(2048))
            except BlockingIOError:
                return False
            return True

        src.sendto(heartbeat(1), ("127.0.0.1", source_port))
        pump(router, lambda: receive(home))
        router_port = got[-1][1]
        other.sendto(heartbeat(255, autopilot=8), router_port)  # a new peer talks to the client endpoint
        pump(router)
        src.sendto(heartbeat(1), ("127.0.0.1", source_port))
        pump(router, lambda: receive(other))
        assert not drain(home), "replies go to the last sender, not to Address:Port"
        clock.now += 5.5  # 5 s of silence from the new peer
        pump(router)
        src.sendto(heartbeat(1), ("127.0.0.1", source_port))
        pump(router, lambda: receive(home))
        assert not drain(other)


def test_while_armed_logging_opens_and_closes_files(tmp_path: Path) -> None:
    vehicle_port = free_udp_port()
    text = (
        f"[General]\nTcpServerPort = 0\nLog = {tmp_path}\nLogMode = while-armed\n"
        f"[UdpEndpoint vehicle]\nMode = Server\nAddress = 127.0.0.1\nPort = {vehicle_port}\n"
    )
    vehicle = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    with running(text) as (router, _):
        assert router.tlog is not None

        def send(frame: bytes) -> None:
            vehicle.sendto(frame, ("127.0.0.1", vehicle_port))
            pump(router, lambda: router.core.stats(0).rx_msgs >= sent[0])

        sent = [0]
        for armed in (False, True, True, False, False, True):
            sent[0] += 1
            send(heartbeat(1, armed=armed))
        assert router.tlog.active
    files = sorted(tmp_path.glob("*.tlog"))
    assert len(files) == 2, "one file per armed period"
    assert files[0].stat().st_size == 2 * (8 + len(heartbeat(1))), "the two armed heartbeats"


def test_stream_releases_a_held_unknown_frame_when_idle() -> None:
    gcs_port, server_port = free_udp_port(), free_port()
    text = (
        f"[General]\nTcpServerPort = {server_port}\n"
        f"[UdpEndpoint gcs]\nMode = Normal\nAddress = 127.0.0.1\nPort = {gcs_port}\n"
    )
    gcs = udp_sink(gcs_port)
    unknown = bytes((0xFD, 3, 0, 0, 0, 9, 9, 0xDE, 0xBC, 0x0A, 1, 2, 3, 0x55, 0xAA))
    with running(text) as (router, clock), socket.create_connection(("127.0.0.1", server_port)) as tcp:
        pump(router, lambda: len(router.endpoints) == 2)
        tcp.sendall(unknown)
        pump(router, lambda: router.core.pending_bytes(1) > 0)  # held: the next byte would confirm it
        assert drain(gcs) == []
        clock.now += 0.3
        pump(router)  # first tick notes the position
        assert drain(gcs) == []
        clock.now += 0.3
        received: list[bytes] = []
        pump(router, lambda: received.extend(drain(gcs)) or received)  # second idle tick releases it
        assert received == [unknown]
