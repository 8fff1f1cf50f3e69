"""Full chain: uav-sitl <-> uav-mavlink-router <-> {MAVSDK, MAVProxy, pymavlink}, all at once.

The router runs the shipped ``config/router.conf`` with its ports replaced by free
ones. Each client commands the vehicle; each must get its own COMMAND_ACK and no
other client's.
"""

from __future__ import annotations

import asyncio
import re
import shutil
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from helpers.procs import REPO, Proc, free_port, free_udp_port, wait_for_port
from mr_harness import Peer, wait_until
from pymavlink import mavutil

pytestmark = pytest.mark.timeout(120)

MAV_CMD_REQUEST_MESSAGE = 512
AUTOPILOT_VERSION = 148


def shipped_config_with_ports(ports: dict[str, int], tcp_server_port: int, log_dir: Path) -> str:
    """config/router.conf, unchanged except for the ports of each section and the log directory."""
    out = []
    section = ""
    for line in (REPO / "config" / "router.conf").read_text().splitlines():
        header = re.match(r"\[(\w+)(?: (\w+))?\]", line)
        if header:
            section = (header.group(2) or header.group(1)).lower()
        key = line.split("=")[0].strip().lower() if "=" in line and not line.startswith("#") else ""
        replacement = {"port": f"Port = {ports.get(section)}", "tcpserverport": f"TcpServerPort = {tcp_server_port}"}
        replacement["log"] = f"Log = {log_dir}"
        out.append(replacement.get(key, line))
    return "\n".join(out) + "\n"


class PymavlinkClient(threading.Thread):
    """The autonomy controller's identity (1/191): heartbeats, one command, records every ACK."""

    def __init__(self, port: int) -> None:
        super().__init__(daemon=True)
        self.peer = Peer(f"udpin:127.0.0.1:{port}", 1, 191)
        self.acks: list[Any] = []
        self.saw_autopilot_version = False
        self.stop = threading.Event()
        self.sent_command = threading.Event()

    def run(self) -> None:
        next_hb = 0.0
        while not self.stop.is_set():
            now = time.monotonic()
            if now >= next_hb:
                self.peer.mav.heartbeat_send(18, 8, 0, 0, 4)  # MAV_TYPE_ONBOARD_CONTROLLER, autopilot INVALID
                next_hb = now + 0.5
            for msg in self.peer.poll(0.05):
                if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == 1 and not self.sent_command.is_set():
                    self.peer.mav.command_long_send(
                        1, 1, MAV_CMD_REQUEST_MESSAGE, 0, AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0
                    )
                    self.sent_command.set()
                elif msg.get_type() == "COMMAND_ACK":
                    self.acks.append(msg)
                elif msg.get_type() == "AUTOPILOT_VERSION":
                    self.saw_autopilot_version = True


async def mavsdk_arm_disarm(port: int) -> None:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk  # noqa: PLC0415 - heavy import
    from mavsdk.asyncio.plugins.action import ActionAsync  # noqa: PLC0415
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync  # noqa: PLC0415

    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)  # 245/190
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://0.0.0.0:{port}")
        system = await mavsdk.first_autopilot(timeout_s=20.0)
        assert system is not None, "MAVSDK saw no autopilot through the router"

        async def armable() -> None:  # the SITL denies arming until its GPS has a fix
            async for health in TelemetryAsync(system).subscribe_health():
                if health.is_armable:
                    return

        await asyncio.wait_for(armable(), timeout=30.0)
        action = ActionAsync(system)
        await action.arm()  # raises ActionError unless the ACK comes back to MAVSDK
        await action.disarm()


def test_sitl_router_mavsdk_mavproxy_pymavlink(artifacts: Path) -> None:
    sitl_port, server_port = free_port(), free_port()
    ports = {"sitl": sitl_port, "gcs": free_udp_port(), "controller": free_udp_port(), "mavsdk": free_udp_port()}
    ports["adhoc"] = free_udp_port()
    log_dir = artifacts / "router_logs"
    shutil.rmtree(log_dir, ignore_errors=True)  # artifacts/ outlives test runs
    conf = artifacts / "router.conf"
    conf.write_text(shipped_config_with_ports(ports, server_port, log_dir))
    conf_dir = artifacts / "conf.d"
    conf_dir.mkdir(exist_ok=True)
    sitl = Proc(
        "fullchain_sitl",
        ["uav-sitl", "--no-gcs", "--no-api", "--no-sim-link", "--no-params-file", "--tcp-port", str(sitl_port)],
    )
    router = Proc("fullchain_router", ["uav-mavlink-router", "-c", str(conf), "-d", str(conf_dir)])
    mavproxy_log = artifacts / "mavproxy.log"
    mavproxy: subprocess.Popen[bytes] | None = None
    client = None
    try:
        wait_for_port(sitl_port, timeout_s=60, proc=sitl)
        wait_for_port(server_port, timeout_s=20, proc=router)
        client = PymavlinkClient(ports["controller"])
        client.start()
        with mavproxy_log.open("wb") as log:
            mavproxy = subprocess.Popen(
                [
                    "mavproxy.py",
                    f"--master=udpin:127.0.0.1:{ports['gcs']}",
                    "--source-system=255",
                    "--source-component=190",
                    "--default-modules=arm",
                    f"--state-basedir={artifacts}",
                    f"--logfile={artifacts / 'mavproxy.tlog'}",
                ],
                stdin=subprocess.PIPE,
                stdout=log,
                stderr=subprocess.STDOUT,
                cwd=artifacts,
                start_new_session=True,
            )
        wait_until(lambda: "online system 1" in mavproxy_log.read_text(), 30, "MAVProxy to see the vehicle", 0.1)
        wait_until(client.sent_command.is_set, 10, "pymavlink to see the vehicle")

        asyncio.run(mavsdk_arm_disarm(ports["mavsdk"]))

        assert mavproxy.stdin is not None
        ack_line = "Got COMMAND_ACK: COMPONENT_ARM_DISARM: ACCEPTED"
        for number, command in enumerate((b"arm throttle\n", b"disarm\n"), start=1):
            mavproxy.stdin.write(command)
            mavproxy.stdin.flush()
            acked = lambda n=number: mavproxy_log.read_text().count(ack_line) >= n  # noqa: E731
            wait_until(acked, 10, f"MAVProxy ACK {number}", 0.1)
        time.sleep(1.0)
    finally:
        if client is not None:
            client.stop.set()
            client.join(5)
        if mavproxy is not None:
            mavproxy.terminate()
            try:
                mavproxy.wait(5)
            except subprocess.TimeoutExpired:
                mavproxy.kill()
                mavproxy.wait(5)
        router.stop()
        sitl.stop()

    # pymavlink: its command was ACKed to it, and it never got an ACK meant for someone else.
    assert client is not None
    ours = [a for a in client.acks if a.command == MAV_CMD_REQUEST_MESSAGE]
    assert ours, "pymavlink got no ACK for its REQUEST_MESSAGE"
    assert all((a.target_system, a.target_component) == (1, 191) for a in client.acks), [
        (a.command, a.target_system, a.target_component) for a in client.acks
    ]
    assert client.saw_autopilot_version

    # MAVProxy: exactly its own two ARM_DISARM ACKs (MAVSDK's two were not routed to it).
    text = mavproxy_log.read_text()
    assert text.count(ack_line) == 2, text[-2000:]

    # The router logged the whole session to a .tlog that pymavlink reads, with every client's traffic.
    [tlog] = log_dir.glob("*.tlog")
    reader = mavutil.mavlink_connection(str(tlog))
    acks_to: set[tuple[int, int]] = set()
    sources: set[tuple[int, int]] = set()
    while (msg := reader.recv_match()) is not None:
        sources.add((msg.get_srcSystem(), msg.get_srcComponent()))
        if msg.get_type() == "COMMAND_ACK":
            acks_to.add((msg.target_system, msg.target_component))
    assert {(1, 1), (1, 191), (245, 190), (255, 190)} <= sources
    assert {(1, 191), (245, 190), (255, 190)} <= acks_to
    assert "final:" in router.log_path.read_text(), "the router printed its final statistics on shutdown"
