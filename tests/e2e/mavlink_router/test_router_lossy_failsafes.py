"""The autopilot's link failsafes, triggered by a lossy router link as a fading radio would trigger them.

``uav-sitl`` (TCP link only) behind ``uav-mavlink-router`` with three UDP endpoints:

* ``pilot`` (a perfect link): the test arms, takes off and sets parameters here; it sends no heartbeat
  that counts as a data link (MAV_TYPE_GENERIC), except while it stands in as the GCS in the first part;
* ``offboard``: an offboard client streams position setpoints at 20 Hz; its uplink fades (50 % of the frames
  lost, in bursts of 40 frames on average: ~2 s at 20 Hz), so the stream stops for longer than
  ``COM_OF_LOSS_T`` and the autopilot holds position, as PX4 does;
* ``gcs``: a ground station heartbeats at 2 Hz over an uplink that fades (50 %, bursts of 6); once it is the
  only data link, a fade longer than ``COM_DL_LOSS_T`` makes the autopilot return home (``NAV_DLL_ACT`` 2),
  and the link coming back is announced.

The router's statistics must show the losses it made, per endpoint and direction: exactly those of its seeded
model (the same seed and the same frames lose the same frames).
"""

from __future__ import annotations

import json
import math
import random
import threading
import time
from pathlib import Path

import pytest
from e2e.sitl.harness import Gcs, run_sitl
from helpers.procs import Proc, free_port, free_udp_port, wait_for_port
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from mavlink_router.core.impairment import ImpairmentConfig, LinkDirection, LinkImpairment

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]
M = mavlink2
LOITER = (4 << 16) | (3 << 24)
RTL = (4 << 16) | (5 << 24)
OFFBOARD = 6 << 16
NAN = math.nan


class Pilot(Gcs):
    """The test's own clean link; its heartbeats do not keep the data link alive unless it stands in as the GCS."""

    as_gcs = True

    def heartbeat(self) -> None:
        kind = M.MAV_TYPE_GCS if self.as_gcs else M.MAV_TYPE_GENERIC
        self.conn.mav.heartbeat_send(kind, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        self._last_hb = time.monotonic()


class Streamer(threading.Thread):
    """Sends one message kind at a fixed wall rate over its own endpoint (no heartbeats of its own)."""

    def __init__(self, port: int, rate_hz: float, send: str, sysid: int, compid: int) -> None:
        super().__init__(daemon=True)
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", dialect="common", source_system=sysid, source_component=compid
        )
        self.period_s = 1.0 / rate_hz
        self.send = send
        self.sent = 0  # the streamed messages
        self.commands = 0  # COMMAND_LONGs sent over the same endpoint (the router counts them too)
        self.stop = threading.Event()
        self.acks: list[object] = []

    def run(self) -> None:
        while not self.stop.is_set():
            if self.send == "setpoint":
                self.conn.mav.set_position_target_local_ned_send(
                    0, 1, 1, M.MAV_FRAME_LOCAL_NED, 2552, 0.0, 0.0, -6.0, 0, 0, 0, 0, 0, 0, 0.0, 0
                )
            else:
                self.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self.sent += 1
            while (msg := self.conn.recv_match(blocking=False)) is not None:
                if msg.get_type() == "COMMAND_ACK":
                    self.acks.append(msg)
            time.sleep(self.period_s)

    def command(self, command: int, *params: float) -> None:
        p = [*params, *([0.0] * 7)][:7]
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        self.commands += 1

    def close(self) -> None:
        self.stop.set()
        self.join(timeout=2.0)
        self.conn.close()


def router_conf(sitl_tcp: int, ports: dict[str, int], log_dir: Path) -> str:
    fading = {
        "offboard": "LossPercent = 50\nLossBurst = 40\nLinkDirection = in\nLinkSeed = 4\n",
        "gcs": "LossPercent = 50\nLossBurst = 6\nLinkDirection = in\nLinkSeed = 4\n",
    }
    text = (
        f"[General]\nLog = {log_dir}\nStatsInterval = 0.5\n[TcpEndpoint sitl]\nAddress = 127.0.0.1\nPort = {sitl_tcp}\n"
    )
    for name, port in ports.items():
        text += f"[UdpEndpoint {name}]\nMode = Normal\nAddress = 127.0.0.1\nPort = {port}\n{fading.get(name, '')}"
    return text


FADES = {"offboard": 40.0, "gcs": 6.0}  # LossBurst of each fading uplink (LossPercent 50, seed 4)


def model_drops(name: str, offered: int) -> int:
    """How many of the first ``offered`` frames the router's seeded model loses on ``name``'s uplink."""
    config = ImpairmentConfig(loss_pct=50.0, loss_burst=FADES[name], direction=LinkDirection.IN, seed=4)
    link: LinkImpairment[int] = LinkImpairment(config, random.Random(f"4:{name}:in").random)  # the router's seeding
    for k in range(offered):
        link.offer(k, 0.0)
    return link.counters.dropped


def links(stats_file: Path) -> dict[str, dict[str, dict[str, int]]]:
    stats = json.loads(stats_file.read_text())
    return {e["name"]: e.get("link", {}) for e in stats["endpoints"]}


def test_a_fading_uplink_triggers_the_offboard_and_data_link_failsafes(tmp_path: Path) -> None:
    ports = {"pilot": free_udp_port(), "offboard": free_udp_port(), "gcs": free_udp_port()}
    # its own GCS and API links send to free ports nobody listens on: the router is the only way in
    extra = ["--set", "params.defaults={NAV_DLL_ACT: 2, COM_DL_LOSS_T: 3.0}"]
    with run_sitl("lossy_failsafes_sitl", tmp_path, speed="3", extra=extra) as sitl:
        conf = tmp_path / "router.conf"
        conf.write_text(router_conf(sitl.ports.tcp, ports, tmp_path / "router"))
        tcp = free_port()
        (tmp_path / "conf.d").mkdir()
        router = Proc("lossy_failsafes_router", ["uav-mavlink-router", "-c", str(conf), "-d", str(tmp_path / "conf.d"),
                                                 "-t", str(tcp)])  # fmt: skip
        streamers: list[Streamer] = []
        try:
            wait_for_port(tcp, timeout_s=20.0, proc=router)
            pilot = Pilot(mavutil.mavlink_connection(f"udpin:127.0.0.1:{ports['pilot']}", dialect="common",
                                                     source_system=255, source_component=190))  # fmt: skip
            pilot.heartbeat()
            pilot.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 30)
            # take off under the pilot (standing in as the GCS: a perfect data link)
            pilot.wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK)
            assert pilot.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
            home_alt = pilot.wait("HOME_POSITION").altitude / 1000.0  # type: ignore[attr-defined]
            assert pilot.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home_alt + 6.0) == M.MAV_RESULT_ACCEPTED
            pilot.wait_mode(LOITER, 60)

            # 1. offboard over the fading uplink: once in OFFBOARD, the first long fade stops the stream
            offboard = Streamer(ports["offboard"], 20.0, "setpoint", 1, 191)
            streamers.append(offboard)
            offboard.start()
            deadline = time.monotonic() + 30.0
            while pilot.mode() != OFFBOARD:  # the mode command may be lost on the fading uplink: retry
                assert time.monotonic() < deadline, f"never in OFFBOARD; texts {pilot.texts[-5:]}"
                offboard.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0)
                pilot.pump(0.5)
            text = pilot.wait_text("Offboard setpoints lost", 60)
            assert "holding position" in text
            pilot.wait_mode(LOITER, 10)
            offboard.close()

            # 2. the GCS on its fading uplink becomes the only data link: a long fade returns the vehicle home
            gcs = Streamer(ports["gcs"], 2.0, "heartbeat", 250, 190)
            streamers.append(gcs)
            gcs.start()
            time.sleep(1.5)  # it is heard before the pilot stops standing in
            pilot.as_gcs = False
            text = pilot.wait_text("Data link lost", 90)
            assert "returning home" in text, text
            pilot.wait_mode(RTL, 10)
            pilot.wait_text("Data link regained", 60)  # the fade ends: heartbeats get through again

            # the router lost those frames, and only on the links that fade (and only uplink)
            time.sleep(1.0)
            counted = links(tmp_path / "router" / "router-stats.json")
            for name in ("offboard", "gcs"):
                up = counted[name]["in"]
                assert "out" not in counted[name]
                assert up["offered"] >= 5, counted
                assert up["dropped"] == model_drops(name, up["offered"]), counted
                assert 0 < up["dropped"] < up["offered"], counted
            assert counted["pilot"] == {}
            assert counted["offboard"]["in"]["offered"] <= offboard.sent + offboard.commands
        finally:
            for s in streamers:
                s.close()
            router.stop()
