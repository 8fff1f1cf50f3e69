"""The bridge's sim-link end over real localhost UDP, against pymavlink-encoded SITL traffic."""

from __future__ import annotations

import math
import socket
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from uav_common.geo import GeoPoint, LocalProjection
from uav_sim_bridge.shell.simlink import SIM_STEP, LinkCounters, SimLinkClient, SimLinkTracker

HOME = GeoPoint(47.397742, 8.545594, 488.0)


@pytest.fixture
def link():
    sitl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sitl.bind(("127.0.0.1", 0))
    sitl.settimeout(2.0)
    counters = LinkCounters()
    client = SimLinkClient("127.0.0.1", sitl.getsockname()[1], counters=counters)
    yield sitl, client, SimLinkTracker(counters=counters)
    client.close()
    sitl.close()


def _sitl_state(mav: mavlink.MAVLink, t_s: float, ned: tuple[float, float, float], yaw: float, *, lockstep: int = 1):
    q = [math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)]
    nan21 = [math.nan] + [0.0] * 20
    geo = LocalProjection(HOME).to_geo(*ned)
    usec = round(t_s * 1e6)
    return [
        mavlink.MAVLink_odometry_message(usec, 1, 12, *ned, q, 0, 0, 0, 0, 0, 0, nan21, nan21, 0, 0, 100).pack(mav),
        mavlink.MAVLink_hil_state_quaternion_message(
            usec,
            q,
            0,
            0,
            0,
            round(geo.lat_deg * 1e7),
            round(geo.lon_deg * 1e7),
            round(geo.alt_amsl_m * 1e3),
            0,
            0,
            0,
            0,
            0,
            0,
            0,
            0,
        ).pack(mav),
        mavlink.MAVLink_hil_actuator_controls_message(usec, [0.5] * 4 + [0] * 12, 128, lockstep).pack(mav),
    ]


def _receive_all(client: SimLinkClient, tracker: SimLinkTracker, n: int) -> None:
    deadline = time.monotonic() + 3.0
    while tracker.counters.rx_datagrams < n and time.monotonic() < deadline:
        for m in client.receive(0.1):
            tracker.update(m)


def test_state_home_and_flags_from_sitl_messages(link) -> None:
    sitl, client, tracker = link
    client.send_heartbeat()
    _, addr = sitl.recvfrom(1024)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    for buf in _sitl_state(mav, 3.5, (100.0, -50.0, -40.0), math.pi / 2):
        sitl.sendto(buf, addr)
    sitl.sendto(
        mavlink.MAVLink_heartbeat_message(2, 12, 128, 0, mavlink.MAV_STATE_FLIGHT_TERMINATION, 3).pack(mav), addr
    )
    _receive_all(client, tracker, 4)
    snap = tracker.snapshot
    assert snap.state is not None
    assert snap.state.sim_time_s == pytest.approx(3.5)
    np.testing.assert_allclose(snap.state.position_m, [-50.0, 100.0, 40.0])
    assert snap.state.t_map_base.yaw_rad == pytest.approx(0.0, abs=1e-9)  # facing east
    assert snap.armed
    assert snap.lockstep
    assert snap.crashed
    assert snap.motor_outputs == (0.5, 0.5, 0.5, 0.5)
    assert snap.home is not None
    assert snap.home.lat_deg == pytest.approx(HOME.lat_deg, abs=1e-7)
    assert snap.home.lon_deg == pytest.approx(HOME.lon_deg, abs=1e-7)
    assert snap.home.alt_amsl_m == pytest.approx(HOME.alt_amsl_m, abs=0.002)


def test_garbage_foreign_and_invalid_are_counted_not_raised(link) -> None:
    sitl, client, tracker = link
    client.send_heartbeat()
    _, addr = sitl.recvfrom(1024)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    other = mavlink.MAVLink(None, srcSystem=42, srcComponent=1)
    good = _sitl_state(mav, 1.0, (0.0, 0.0, -10.0), 0.0)[0]
    corrupt = bytearray(good)
    corrupt[-3] ^= 0xFF  # bad CRC
    nan_odo = mavlink.MAVLink_odometry_message(
        1, 1, 12, math.nan, 0, 0, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0, [0] * 21, [0] * 21, 0, 0, 0
    ).pack(mav)
    for data in (
        b"",
        b"\x00" * 50,
        bytes(range(256)),
        bytes(corrupt),
        _sitl_state(other, 1, (0, 0, 0), 0)[0],
        nan_odo,
        good,
    ):
        sitl.sendto(data, addr)
    _receive_all(client, tracker, 6)
    c = tracker.counters
    assert c.rx_bad >= 2
    assert c.rx_foreign == 1
    assert c.rx_invalid_state == 1
    assert tracker.snapshot.state is not None  # the good one still got through
    assert tracker.snapshot.state.position_m[2] == pytest.approx(10.0)


def test_client_messages_follow_the_contract(link) -> None:
    sitl, client, _ = link
    client.send_collision(1234)
    client.send_terrain_report(47.4, 8.55, 512.25, 30.5)
    client.send_sim_step(5)
    client.send_heartbeat()
    parser = mavlink.MAVLink(None)
    got = {}
    for _ in range(4):
        data, _ = sitl.recvfrom(1024)
        for m in parser.parse_buffer(data) or []:
            got[m.get_type()] = m
            assert (m.get_srcSystem(), m.get_srcComponent()) == (1, 200)
    col = got["COLLISION"]
    assert (col.id, col.action, col.threat_level) == (
        1234,
        mavlink.MAV_COLLISION_ACTION_REPORT,
        mavlink.MAV_COLLISION_THREAT_LEVEL_HIGH,
    )
    ter = got["TERRAIN_REPORT"]
    assert (ter.lat, ter.lon) == (474000000, 85500000)
    assert ter.terrain_height == pytest.approx(512.25)
    assert ter.current_height == pytest.approx(30.5)
    cmd = got["COMMAND_LONG"]
    assert (cmd.command, cmd.param1, cmd.target_system) == (SIM_STEP, 5.0, 1)
    assert got["HEARTBEAT"].type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
