"""Start a real ``uav-sitl`` process on free ports for the e2e tests."""

from __future__ import annotations

import os
import re
import shutil
import socket
import struct
import subprocess
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from helpers.procs import Proc, free_port, free_udp_port

os.environ["MAVLINK20"] = "1"

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2


@dataclass(frozen=True)
class SitlPorts:
    gcs: int
    gcs_local: int
    api: int
    api_local: int
    tcp: int
    sim: int

    @classmethod
    def allocate(cls) -> SitlPorts:
        return cls(free_udp_port(), free_udp_port(), free_udp_port(), free_udp_port(), free_port(), free_udp_port())

    def argv(self) -> list[str]:
        return [
            "--gcs-port", str(self.gcs), "--gcs-local-port", str(self.gcs_local),
            "--api-port", str(self.api), "--api-local-port", str(self.api_local),
            "--tcp-port", str(self.tcp), "--sim-port", str(self.sim),
        ]  # fmt: skip


@dataclass
class Sitl:
    proc: Proc
    ports: SitlPorts
    params_file: Path


@contextmanager
def run_sitl(
    name: str, tmp: Path, *, speed: str = "5", extra: Sequence[str] = (), ports: SitlPorts | None = None
) -> Iterator[Sitl]:
    """A ``uav-sitl`` child with every link on a free port and a private parameter file."""
    ports = ports or SitlPorts.allocate()
    params_file = tmp / f"{name}-params.json"
    argv = [
        "uav-sitl",
        *ports.argv(),
        "--params-file", str(params_file),
        "--speed-factor", speed,
        "--set", "mavlink.stats_period_s=5",
        *extra,
    ]  # fmt: skip
    proc = Proc(name, argv)
    try:
        _wait_udp_bound(ports.gcs_local, proc)
        yield Sitl(proc, ports, params_file)
    finally:
        proc.stop()


def _wait_udp_bound(port: int, proc: Proc, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not proc.alive():
            msg = f"{proc.name} exited with {proc.popen.returncode}:\n{proc.tail()}"
            raise RuntimeError(msg)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return
        time.sleep(0.05)
    msg = f"{proc.name} did not bind UDP {port} within {timeout_s} s:\n{proc.tail()}"
    raise TimeoutError(msg)


def connect(port: int, *, source_system: int = 255, source_component: int = 190) -> mavutil.mavfile:
    """A pymavlink GCS listening where the SITL sends (``udpin``), after the first heartbeat."""
    conn = mavutil.mavlink_connection(
        f"udpin:127.0.0.1:{port}", dialect="common", source_system=source_system, source_component=source_component
    )
    hb = conn.wait_heartbeat(timeout=30)
    if hb is None:
        msg = f"no heartbeat on UDP {port}"
        raise TimeoutError(msg)
    return conn


class Gcs:
    """A small pymavlink ground station for the e2e tests: remembers the latest of each message."""

    def __init__(self, conn: mavutil.mavfile) -> None:
        self.conn = conn
        self.latest: dict[str, object] = {}
        self.texts: list[str] = []
        self._chunks: dict[int, dict[int, str]] = {}
        self._last_hb = 0.0

    @classmethod
    def listen(cls, port: int, **kw: int) -> Gcs:
        return cls(connect(port, **kw))

    def _statustext(self, msg: object) -> None:
        """Collect texts, reassembling MAVLink 2 chunks (id != 0) like QGC does."""
        text, chunk_id, seq = msg.text, msg.id, msg.chunk_seq  # type: ignore[attr-defined]
        if chunk_id == 0:
            self.texts.append(text)
            return
        parts = self._chunks.setdefault(chunk_id, {})
        parts[seq] = text
        if len(text) < 50:
            self.texts.append("".join(parts[i] for i in sorted(parts)))
            del self._chunks[chunk_id]

    def heartbeat(self) -> None:
        self.conn.mav.heartbeat_send(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        self._last_hb = time.monotonic()

    def pump(self, timeout_s: float = 0.05, *, heartbeats: bool = True) -> None:
        deadline = time.monotonic() + timeout_s
        while True:
            if heartbeats and time.monotonic() - self._last_hb >= 1.0:
                self.heartbeat()
            msg = self.conn.recv_match(blocking=True, timeout=max(0.0, min(0.05, deadline - time.monotonic())))
            if msg is not None:
                kind = msg.get_type()
                self.latest[kind] = msg
                if kind == "STATUSTEXT":
                    self._statustext(msg)
            if time.monotonic() >= deadline:
                return

    def wait(self, kind: str, pred: object = None, timeout_s: float = 30.0, *, heartbeats: bool = True) -> object:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.latest.pop(kind, None)
            self.pump(0.05, heartbeats=heartbeats)
            msg = self.latest.get(kind)
            if msg is not None and (pred is None or pred(msg)):  # type: ignore[operator]
                return msg
        msg = f"no {kind} matching the condition within {timeout_s} s; texts: {self.texts[-5:]}"
        raise TimeoutError(msg)

    def wait_text(self, fragment: str, timeout_s: float = 30.0, *, heartbeats: bool = True) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for text in self.texts:
                if fragment in text:
                    return text
            self.pump(0.1, heartbeats=heartbeats)
        msg = f"no STATUSTEXT containing {fragment!r} within {timeout_s} s; got {self.texts}"
        raise TimeoutError(msg)

    def cmd(self, command: int, *params: float, timeout_s: float = 5.0) -> int:
        p = [*params, *([0.0] * 7)][:7]
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        ack = self.wait("COMMAND_ACK", lambda m: m.command == command, timeout_s)
        return int(ack.result)  # type: ignore[attr-defined]

    def mode(self) -> int:
        hb = self.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1)
        return int(hb.custom_mode)  # type: ignore[attr-defined]

    def wait_mode(self, custom_mode: int, timeout_s: float = 30.0, *, heartbeats: bool = True) -> None:
        self.wait(
            "HEARTBEAT",
            lambda m: m.get_srcComponent() == 1 and m.custom_mode == custom_mode,
            timeout_s,
            heartbeats=heartbeats,
        )

    def set_param(self, name: str, value: float, *, integer: bool = False) -> None:
        wire = struct.unpack("<f", struct.pack("<i", int(value)))[0] if integer else float(value)
        ptype = mavlink2.MAV_PARAM_TYPE_INT32 if integer else mavlink2.MAV_PARAM_TYPE_REAL32
        self.conn.mav.param_set_send(1, 1, name.encode(), wire, ptype)
        self.wait("PARAM_VALUE", lambda m: m.param_id == name and m.param_value == wire)

    def relative_alt_m(self) -> float:
        gpi = self.wait("GLOBAL_POSITION_INT")
        return float(gpi.relative_alt) / 1000.0  # type: ignore[attr-defined]

    def close(self) -> None:
        self.conn.close()


class MavProxy:
    def __init__(self, master: str, workdir: Path) -> None:
        exe = shutil.which("mavproxy.py")
        assert exe is not None, "mavproxy.py is not on PATH (scripts/in_env)"
        self.lines: list[str] = []
        self.proc = subprocess.Popen(
            [exe, f"--master={master}", "--state-basedir", str(workdir)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=workdir,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    def send(self, command: str) -> int:
        mark = len(self.lines)
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        return mark

    def expect(self, pattern: str, timeout_s: float = 30.0, since: int = 0) -> re.Match[str]:
        deadline = time.monotonic() + timeout_s
        rx = re.compile(pattern)
        while time.monotonic() < deadline:
            for line in self.lines[since:]:
                m = rx.search(line)
                if m:
                    return m
            time.sleep(0.05)
        tail = "\n".join(self.lines[-30:])
        pytest.fail(f"MAVProxy did not print /{pattern}/ within {timeout_s} s; last lines:\n{tail}")

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
