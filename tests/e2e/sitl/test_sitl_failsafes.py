"""Every failsafe through the real process and real MAVLink: each is announced by STATUSTEXT.

Three SITL processes (a crashed vehicle stays crashed): battery; offboard loss
then data-link loss; geofence then a collision reported on the simulation link.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from e2e.sitl.harness import Gcs, run_sitl
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

pytestmark = pytest.mark.slow

M = mavlink2
LOITER = (4 << 16) | (3 << 24)
RTL = (4 << 16) | (5 << 24)
LAND = (4 << 16) | (6 << 24)
OFFBOARD = 6 << 16
NAN = math.nan
SPEED = "10"


def take_off(gcs: Gcs, altitude_m: float) -> None:
    gcs.wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK)
    assert gcs.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    home_alt = gcs.wait("HOME_POSITION").altitude / 1000.0  # type: ignore[attr-defined]
    assert gcs.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home_alt + altitude_m) == M.MAV_RESULT_ACCEPTED
    gcs.wait_mode(LOITER, 60)
    gcs.wait("GLOBAL_POSITION_INT", lambda m: abs(m.relative_alt / 1000.0 - altitude_m) < 0.5, 30)


def reposition_north(gcs: Gcs, north_m: float) -> None:
    home = gcs.wait("HOME_POSITION")
    lat = home.latitude * 1e-7 + math.degrees(north_m / 6_371_000.0)  # type: ignore[attr-defined]
    lon = home.longitude * 1e-7  # type: ignore[attr-defined]
    # DO_REPOSITION as MAVSDK's goto_location sends it: COMMAND_INT, frame GLOBAL_INT, change-mode flag
    gcs.conn.mav.command_int_send(1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_DO_REPOSITION, 0, 0,
                                  -1, 1, 0, NAN, round(lat * 1e7), round(lon * 1e7), NAN)  # fmt: skip
    ack = gcs.wait("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_DO_REPOSITION)
    assert ack.result == M.MAV_RESULT_ACCEPTED  # type: ignore[attr-defined]


def test_battery_low_returns_and_critical_lands(tmp_path: Path) -> None:
    extra = ["--set", "battery.initial_soc=0.19", "--set", "failsafe.battery_critical_remaining=0.12"]
    with run_sitl("failsafe_battery", tmp_path, speed=SPEED, extra=extra) as sitl:
        gcs = Gcs.listen(sitl.ports.gcs)
        take_off(gcs, 8.0)
        reposition_north(gcs, 50.0)
        text = gcs.wait_text("Low battery", 60)
        assert "returning" in text
        gcs.wait_mode(RTL, 5)
        status = gcs.wait("BATTERY_STATUS")
        assert status.charge_state == M.MAV_BATTERY_CHARGE_STATE_LOW  # type: ignore[attr-defined]
        # take over (PX4 lets the pilot override) and hover until the critical level
        assert gcs.cmd(M.MAV_CMD_DO_SET_MODE, 1, 4, 3) == M.MAV_RESULT_ACCEPTED
        text = gcs.wait_text("Critical battery", 120)
        assert "landing" in text
        gcs.wait_mode(LAND, 5)
        sys_status = gcs.wait("SYS_STATUS")
        assert sys_status.battery_remaining <= 12  # type: ignore[attr-defined]
        gcs.close()


def test_offboard_loss_then_datalink_loss(tmp_path: Path) -> None:
    with run_sitl("failsafe_links", tmp_path, speed=SPEED) as sitl:
        gcs = Gcs.listen(sitl.ports.gcs)
        take_off(gcs, 6.0)
        # offboard: refused without a stream; with one it switches; losing it holds position
        assert gcs.cmd(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_DENIED
        for _ in range(20):
            gcs.conn.mav.set_position_target_local_ned_send(0, 1, 1, M.MAV_FRAME_LOCAL_NED, 2552, 3.0, 0.0, -6.0,
                                                            0, 0, 0, 0, 0, 0, 0.0, 0)  # fmt: skip
            gcs.pump(0.02)
        assert gcs.cmd(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_ACCEPTED
        gcs.wait_mode(OFFBOARD, 5)
        text = gcs.wait_text("Offboard setpoints lost", 20)
        assert "holding position" in text
        gcs.wait_mode(LOITER, 5)
        # data link: configure the failsafe, then go silent (no more GCS heartbeats)
        gcs.set_param("NAV_DLL_ACT", 2, integer=True)
        gcs.set_param("COM_DL_LOSS_T", 3.0)
        text = gcs.wait_text("Data link lost", 30, heartbeats=False)
        assert "returning home" in text
        gcs.wait_mode(RTL, 5, heartbeats=False)
        gcs.heartbeat()
        gcs.wait_text("Data link regained", 10)
        gcs.close()


def test_geofence_breach_then_collision(tmp_path: Path) -> None:
    extra = ["--set", "failsafe.geofence_radius_m=25"]
    with run_sitl("failsafe_fence_collision", tmp_path, speed=SPEED, extra=extra) as sitl:
        gcs = Gcs.listen(sitl.ports.gcs)
        sim = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{sitl.ports.sim}", dialect="common", source_system=1, source_component=200
        )
        sim.mav.heartbeat_send(M.MAV_TYPE_GENERIC, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert sim.recv_match(type="ODOMETRY", blocking=True, timeout=10) is not None
        # a lockstep grant outside lockstep is DENIED (docs/architecture.md)
        sim.mav.command_long_send(1, 1, 31010, 0, 10, 0, 0, 0, 0, 0, 0)
        ack = sim.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
        assert ack is not None
        assert (ack.command, ack.result) == (31010, M.MAV_RESULT_DENIED)
        take_off(gcs, 6.0)
        reposition_north(gcs, 40.0)
        text = gcs.wait_text("Geofence", 40)
        assert "returning home" in text
        gcs.wait_mode(RTL, 5)
        # now the bridge reports a collision
        sim.mav.heartbeat_send(M.MAV_TYPE_GENERIC, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        sim.mav.collision_send(M.MAV_COLLISION_SRC_ADSB, 4242, M.MAV_COLLISION_ACTION_REPORT,
                               M.MAV_COLLISION_THREAT_LEVEL_HIGH, 0, 0, 0)  # fmt: skip
        text = gcs.wait_text("Collision (world object 4242)", 10)
        assert "crashed" in text
        hb = gcs.wait(
            "HEARTBEAT", lambda m: m.get_srcComponent() == 1 and m.system_status == M.MAV_STATE_FLIGHT_TERMINATION
        )
        assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED  # type: ignore[attr-defined]
        assert gcs.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196) == M.MAV_RESULT_DENIED
        sim_hb = sim.recv_match(type="HEARTBEAT", blocking=True, timeout=5,
                                condition="HEARTBEAT.system_status == 8")  # fmt: skip
        assert sim_hb is not None
        act = sim.recv_match(type="HIL_ACTUATOR_CONTROLS", blocking=True, timeout=5)
        assert act is not None
        assert not act.mode & M.MAV_MODE_FLAG_SAFETY_ARMED
        assert act.controls[:4] == [0.0, 0.0, 0.0, 0.0]
        sim.close()
        gcs.close()
