"""Helpers for the router's end-to-end tests: start the real router, talk to it with pymavlink."""

from __future__ import annotations

import json
import os
import socket
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

os.environ["MAVLINK20"] = "1"  # pymavlink's mavutil picks its wire protocol from this at set_dialect time

from helpers.procs import Proc, free_port, wait_for_port
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as v2

mavutil.set_dialect("ardupilotmega")

__all__ = ["Peer", "encoder", "read_stats", "router", "v2", "wait_until"]


class Encoder:
    """Frames from one system/component, with a rolling sequence number (pymavlink encodes)."""

    def __init__(self, sysid: int, compid: int) -> None:
        self.mav = v2.MAVLink(None, srcSystem=sysid, srcComponent=compid)

    @property
    def seq(self) -> int:
        return int(self.mav.seq)

    @seq.setter
    def seq(self, value: int) -> None:
        self.mav.seq = value & 0xFF

    def pack(self, msg: Any) -> bytes:
        data = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) & 0xFF
        return data


def encoder(sysid: int, compid: int) -> Encoder:
    return Encoder(sysid, compid)


def wait_until(predicate: Callable[[], object], timeout_s: float, what: str, poll_s: float = 0.02) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(poll_s)
    msg = f"timed out after {timeout_s} s waiting for {what}"
    raise TimeoutError(msg)


@contextmanager
def router(name: str, args: Sequence[str], *, tcp_port: int | None = None) -> Iterator[tuple[Proc, int]]:
    """Run ``uav-mavlink-router ARGS -t PORT``; ready once its TCP server listens (opened last)."""
    port = tcp_port or free_port()
    conf_dir = Path(tempfile.mkdtemp(prefix="router-conf.d-"))  # empty: never read /etc/mavlink-router
    proc = Proc(name, ["uav-mavlink-router", *args, "-d", str(conf_dir), "-t", str(port)])
    try:
        wait_for_port(port, timeout_s=20.0, proc=proc)
        yield proc, port
    finally:
        proc.stop()
        conf_dir.rmdir()


def read_stats(path: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads(path.read_text())
    return data


def endpoint_stats(stats: dict[str, Any], name: str) -> dict[str, Any]:
    for entry in stats["endpoints"]:
        if entry["name"] == name:
            result: dict[str, Any] = entry
            return result
    msg = f"no endpoint {name!r} in stats: {[e['name'] for e in stats['endpoints']]}"
    raise KeyError(msg)


class Peer:
    """A pymavlink connection (udpin/udpout/tcp) that a test polls without blocking."""

    def __init__(self, url: str, sysid: int, compid: int) -> None:
        self.conn = mavutil.mavlink_connection(url, source_system=sysid, source_component=compid, autoreconnect=False)
        self.mav = self.conn.mav
        self.received: list[Any] = []

    def poll(self, timeout_s: float = 0.0) -> list[Any]:
        """Everything that arrived (waiting up to ``timeout_s`` for the first message)."""
        out = []
        deadline = time.monotonic() + timeout_s
        while True:
            msg = self.conn.recv_match(blocking=False)
            if msg is not None:
                if msg.get_type() != "BAD_DATA":
                    out.append(msg)
                continue
            if out or time.monotonic() >= deadline:
                break
            time.sleep(0.002)
        self.received += out
        return out

    def wait_for(self, predicate: Callable[[Any], bool], timeout_s: float, what: str) -> Any:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for msg in self.poll(0.05):
                if predicate(msg):
                    return msg
        msg = f"timed out after {timeout_s} s waiting for {what}; got {[m.get_type() for m in self.received[-10:]]}"
        raise TimeoutError(msg)

    def close(self) -> None:
        self.conn.close()


def udp_sink(port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", port))
    sock.setblocking(False)
    return sock


def drain(sock: socket.socket) -> list[bytes]:
    out = []
    while True:
        try:
            out.append(sock.recv(65535))
        except BlockingIOError:
            return out
