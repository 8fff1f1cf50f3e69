"""Start a real ``uav-sitl`` process on free ports for the e2e tests."""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from helpers.procs import Proc, free_port, free_udp_port

os.environ.setdefault("MAVLINK20", "1")

from pymavlink import mavutil


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
        f"udpin:127.0.0.1:{port}", source_system=source_system, source_component=source_component
    )
    hb = conn.wait_heartbeat(timeout=30)
    if hb is None:
        msg = f"no heartbeat on UDP {port}"
        raise TimeoutError(msg)
    return conn
