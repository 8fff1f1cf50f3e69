"""Mode flows and failsafes of the autopilot core flying the real JSBSim model (in process)."""

from __future__ import annotations

import math

import pytest
from unit.sitl.sitl_builders import make_vehicle, pos, run, take_off

from sitl.core.autopilot import ManualInput
from sitl.core.control import Setpoint
from sitl.core.mission import MissionItem
from sitl.core.modes import FlightMode
from sitl.core.navigator import RtlPhase, RtlTask
from sitl.core.protocol import MavCmd, MavFrame, MavResult, MavSeverity, MissionState
from sitl.vehicle import Vehicle
from uav_common.geo import LocalProjection

NAN = math.nan


def texts(v: Vehicle) -> list[str]:
    return [t for _, t in v.autopilot.statustexts]


def wp(  # noqa: PLR0917
    v: Vehicle, seq: int, north: float, east: float, alt: float, cmd: int = MavCmd.NAV_WAYPOINT, p1: float = 0.0
) -> MissionItem:
    geo = LocalProjection(v.home).to_geo(north, east, 0.0)
    return MissionItem(seq, MavFrame.GLOBAL_RELATIVE_ALT_INT, cmd, 0, 1, p1, 0.0, 0.0, NAN,
                       round(geo.lat_deg * 1e7), round(geo.lon_deg * 1e7), alt)  # fmt: skip


def test_arming_needs_position_and_denies_in_land_mode() -> None:
    v = make_vehicle()
    ap = v.autopilot
    run(v, 0.1)
    assert ap.set_mode(FlightMode.AUTO_LAND) is MavResult.ACCEPTED
    assert ap.arm(force=False) is MavResult.DENIED
    assert any("Arming denied" in t for t in texts(v))
    assert ap.arm(force=True) is MavResult.ACCEPTED  # 21196 skips the checks
    assert ap.disarm(force=False) is MavResult.ACCEPTED


def test_preflight_auto_disarm() -> None:
    v = make_vehicle()
    ap = v.autopilot
    run(v, 0.1)
    assert ap.arm(force=False) is MavResult.ACCEPTED
    run(v, 9.0)
    assert ap.armed
    run(v, 2.0)
    assert not ap.armed
    assert any("preflight" in t for t in texts(v))


def test_disarm_in_air_needs_force_and_then_falls() -> None:
    v = make_vehicle()
    take_off(v, 5.0, settle_s=1.0)
    ap = v.autopilot
    assert ap.disarm(force=False) is MavResult.DENIED
    assert ap.disarm(force=True) is MavResult.ACCEPTED
    run(v, 3.0)
    assert pos(v)[2] > -0.5, "a disarmed vehicle must fall"


def test_takeoff_with_nan_altitude_uses_mis_takeoff_alt() -> None:
    v = make_vehicle(**{"params.defaults": {"MIS_TAKEOFF_ALT": 4.0}})
    ap = v.autopilot
    run(v, 0.1)
    assert ap.takeoff(alt_amsl_m=NAN, lat_deg=NAN, lon_deg=NAN, yaw_deg=NAN) is MavResult.ACCEPTED
    assert ap.mode is FlightMode.AUTO_TAKEOFF
    run(v, 2.0)
    assert ap.landed, "takeoff before arming waits for arming (QGC order)"
    assert ap.arm(force=False) is MavResult.ACCEPTED
    run(v, 20.0, until=lambda x: x.autopilot.mode is FlightMode.AUTO_LOITER)
    run(v, 5.0)
    assert ap.mode is FlightMode.AUTO_LOITER
    assert -pos(v)[2] == pytest.approx(4.0, abs=0.2)
    assert ap.takeoff(alt_amsl_m=math.inf, lat_deg=NAN, lon_deg=NAN, yaw_deg=NAN) is MavResult.DENIED


def test_rtl_climbs_returns_descends_and_lands() -> None:
    v = make_vehicle(**{"params.defaults": {"RTL_RETURN_ALT": 15.0, "RTL_DESCEND_ALT": 12.0}})
    take_off(v, 10.0, settle_s=1.0)
    ap = v.autopilot
    geo = v.projection.to_geo(30.0, 0.0, 0.0)
    assert ap.reposition(lat_deg=geo.lat_deg, lon_deg=geo.lon_deg, alt_amsl_m=NAN, yaw_rad=NAN, speed_mps=NAN,
                         change_mode=True) is MavResult.ACCEPTED  # fmt: skip
    run(v, 20.0)
    assert pos(v)[0] == pytest.approx(30.0, abs=0.3)
    assert ap.return_to_launch() is MavResult.ACCEPTED
    phases = []
    max_alt = 0.0
    for _ in range(round(90.0 / v.dt_s)):
        v.step(v.t_s)
        task = ap._task
        if isinstance(task, RtlTask) and (not phases or phases[-1] != task.phase):
            phases.append(task.phase)
        max_alt = max(max_alt, -pos(v)[2])
        if not ap.armed:
            break
    assert phases[:4] == [RtlPhase.CLIMB, RtlPhase.RETURN, RtlPhase.DESCEND, RtlPhase.LOITER] or phases[:3] == [
        RtlPhase.CLIMB, RtlPhase.RETURN, RtlPhase.DESCEND]  # fmt: skip
    assert RtlPhase.LAND in phases
    assert max_alt == pytest.approx(15.0, abs=0.5)
    assert not ap.armed
    assert ap.landed
    assert math.hypot(*pos(v)[:2]) < 0.5


def test_mission_flies_items_with_speed_change_hold_and_reached_events() -> None:
    v = make_vehicle()
    take_off(v, 10.0, settle_s=1.0)
    ap = v.autopilot
    items = [
        wp(v, 0, 20.0, 0.0, 10.0, p1=2.0),  # hold 2 s
        MissionItem(1, MavFrame.MISSION, MavCmd.DO_CHANGE_SPEED, 0, 1, 1.0, 9.0, -1.0, 0.0, 0, 0, 0.0),
        wp(v, 2, 20.0, 40.0, 12.0),
        wp(v, 3, 0.0, 40.0, 12.0, cmd=MavCmd.NAV_LOITER_TIME, p1=3.0),
        wp(v, 4, 0.0, 0.0, 0.0, cmd=MavCmd.NAV_LAND),
    ]
    ap.mission_store.replace(tuple(items))
    ap.mission_uploaded()
    assert ap.mission_state is MissionState.NOT_STARTED
    assert ap.set_mode(FlightMode.AUTO_MISSION) is MavResult.ACCEPTED
    reached: list[int] = []
    max_speed = 0.0
    for _ in range(round(150.0 / v.dt_s)):
        v.step(v.t_s)
        reached += ap.drain_reached()
        vn, ve, _ = v.truth().vel_ned_mps
        max_speed = max(max_speed, math.hypot(vn, ve))
        if not ap.armed:
            break
    assert reached == [0, 2, 3, 4]
    assert ap.mission_state is MissionState.COMPLETE
    assert 8.0 < max_speed < 9.6, f"DO_CHANGE_SPEED 9 m/s, flew {max_speed:.1f} m/s"
    assert not ap.armed
    assert ap.landed
    assert math.hypot(*pos(v)[:2]) < 1.0


def test_offboard_needs_a_stream_and_loss_triggers_hold() -> None:
    v = make_vehicle()
    take_off(v, 10.0, settle_s=1.0)
    ap = v.autopilot
    assert ap.set_mode(FlightMode.OFFBOARD) is MavResult.DENIED
    assert any("Offboard" in t for t in texts(v))
    sp = Setpoint(pos=(5.0, 5.0, -12.0), yaw_rad=NAN)
    for _ in range(10):
        ap.offboard_setpoint(sp, v.t_s, v.t_s)
        run(v, 0.05)
    assert ap.set_mode(FlightMode.OFFBOARD) is MavResult.ACCEPTED
    run(v, 5.0)  # the stream stops here
    assert ap.mode is FlightMode.AUTO_LOITER
    assert any("Offboard setpoints lost" in t for t in texts(v))


def test_low_battery_returns_and_critical_battery_lands() -> None:
    v = make_vehicle(
        **{"battery.initial_soc": 0.172, "params.defaults": {"RTL_RETURN_ALT": 10.0, "BAT_CRIT_THR": 0.12}}
    )
    take_off(v, 10.0, settle_s=1.0)
    ap = v.autopilot
    geo = v.projection.to_geo(60.0, 0.0, 0.0)
    ap.reposition(lat_deg=geo.lat_deg, lon_deg=geo.lon_deg, alt_amsl_m=NAN, yaw_rad=NAN, speed_mps=NAN,
                  change_mode=True)  # fmt: skip
    run(v, 120.0, until=lambda x: x.autopilot.mode is FlightMode.AUTO_RTL)
    assert ap.mode is FlightMode.AUTO_RTL
    assert any("Low battery" in t for t in texts(v))
    assert v.battery_reading.remaining <= 0.15
    # the pilot takes over (PX4 allows it) and keeps hovering until the critical level
    assert ap.set_mode(FlightMode.AUTO_LOITER) is MavResult.ACCEPTED
    run(v, 300.0, until=lambda x: x.autopilot.mode is FlightMode.AUTO_LAND)
    assert ap.mode is FlightMode.AUTO_LAND
    assert v.battery_reading.remaining <= 0.12
    sev = [s for s, t in ap.statustexts if "Critical battery" in t]
    assert sev == [MavSeverity.EMERGENCY]


def test_geofence_breach_returns_home() -> None:
    v = make_vehicle(**{"params.defaults": {"GF_MAX_HOR_DIST": 25.0, "RTL_RETURN_ALT": 10.0}})
    take_off(v, 10.0, settle_s=1.0)
    ap = v.autopilot
    geo = v.projection.to_geo(40.0, 0.0, 0.0)
    ap.reposition(lat_deg=geo.lat_deg, lon_deg=geo.lon_deg, alt_amsl_m=NAN, yaw_rad=NAN, speed_mps=NAN,
                  change_mode=True)  # fmt: skip
    run(v, 30.0, until=lambda x: x.autopilot.mode is FlightMode.AUTO_RTL)
    assert ap.mode is FlightMode.AUTO_RTL
    assert 25.0 < pos(v)[0] < 30.0
    assert any("Geofence" in t for t in texts(v))
    run(v, 60.0, until=lambda x: not x.autopilot.armed)
    assert math.hypot(*pos(v)[:2]) < 1.0


def test_datalink_loss_action_from_nav_dll_act() -> None:
    v = make_vehicle(**{"params.defaults": {"NAV_DLL_ACT": 2, "COM_DL_LOSS_T": 5.0}})
    take_off(v, 10.0, settle_s=1.0)
    ap = v.autopilot
    ap.datalink_heard(v.t_s, v.t_s)
    run(v, 4.0)
    assert ap.mode is FlightMode.AUTO_LOITER
    run(v, 3.0)
    assert ap.mode is FlightMode.AUTO_RTL
    assert any("Data link lost" in t for t in texts(v))
    ap.datalink_heard(v.t_s, v.t_s)
    run(v, 0.1)
    assert any("Data link regained" in t for t in texts(v))


def test_collision_crashes_and_disarms_for_good() -> None:
    v = make_vehicle()
    take_off(v, 5.0, settle_s=1.0)
    ap = v.autopilot
    ap.collision(42)
    assert ap.crashed
    assert not ap.armed
    assert ap.system_status.name == "FLIGHT_TERMINATION"
    assert any("Collision (world object 42)" in t for t in texts(v))
    run(v, 3.0)
    assert all(d == 0.0 for d in v.duty)
    assert ap.arm(force=True) is MavResult.DENIED
    assert ap.set_mode(FlightMode.AUTO_LAND) is MavResult.DENIED


def sticks(
    v: Vehicle, *, pitch: float = 0.0, roll: float = 0.0, throttle: float = 0.5, yaw: float = 0.0, seconds: float = 1.0
) -> None:  # fmt: skip
    """Hold MANUAL_CONTROL sticks for ``seconds`` (sent at 50 Hz, like a joystick)."""
    for _ in range(round(seconds * 50)):
        v.autopilot.manual_control(ManualInput(pitch, roll, throttle, yaw), v.t_s, v.t_s)
        run(v, 0.02)


def test_posctl_sticks_take_off_fly_and_hold() -> None:
    v = make_vehicle()
    ap = v.autopilot
    run(v, 0.1)
    sticks(v, seconds=0.2)
    assert ap.set_mode(FlightMode.POSCTL) is MavResult.ACCEPTED
    assert ap.arm(force=False) is MavResult.ACCEPTED
    sticks(v, throttle=0.5, seconds=1.0)
    assert ap.landed, "centred throttle stick: stay on the ground"
    sticks(v, throttle=1.0, seconds=3.0)
    assert not ap.landed
    assert -pos(v)[2] > 5.0
    sticks(v, pitch=1.0, seconds=3.0)  # full forward at heading north
    assert pos(v)[0] > 10.0
    sticks(v, seconds=4.0)  # sticks centred: brake and hold
    held = pos(v)
    sticks(v, seconds=3.0)
    assert math.dist(held, pos(v)) < 0.3
    run(v, 2.0)  # no more MANUAL_CONTROL: manual-control-loss failsafe (NAV_RCL_ACT 2 = return)
    assert ap.mode is FlightMode.AUTO_RTL
    assert any("Manual control lost" in t for t in texts(v))


def test_manual_mode_is_attitude_and_throttle() -> None:
    v = make_vehicle()
    ap = v.autopilot
    take_off(v, 10.0, settle_s=1.0)
    sticks(v, throttle=0.5, seconds=0.2)
    assert ap.set_mode(FlightMode.MANUAL) is MavResult.ACCEPTED
    z0 = pos(v)[2]
    sticks(v, throttle=0.5, roll=0.5, seconds=2.0)
    roll, _, _ = v.truth().euler_rad
    assert 0.1 < roll < math.radians(35.0) + 0.05, "roll stick commands a bank angle"
    assert pos(v)[1] > 1.0, "banked right: drifting east"
    sticks(v, throttle=0.9, seconds=2.0)
    assert pos(v)[2] < z0 - 1.0, "throttle up: climbing"


def test_mission_started_on_the_ground_takes_off_first() -> None:
    v = make_vehicle()
    ap = v.autopilot
    run(v, 0.1)
    ap.mission_store.replace((wp(v, 0, 15.0, 0.0, 8.0), wp(v, 1, 0.0, 0.0, 0.0, cmd=MavCmd.NAV_LAND)))
    ap.mission_uploaded()
    assert ap.set_mode(FlightMode.AUTO_MISSION) is MavResult.ACCEPTED
    assert ap.arm(force=False) is MavResult.ACCEPTED
    run(v, 80.0, until=lambda x: not x.autopilot.armed)
    assert ap.mission_state is MissionState.COMPLETE
    assert ap.drain_reached() == [0, 1]
    assert not ap.armed


def test_terrain_from_the_bridge_moves_the_ground() -> None:
    """Landing on a roof: the ground under the vehicle is 4 m above home."""
    v = make_vehicle()
    take_off(v, 10.0, settle_s=1.0)
    assert v.set_terrain_amsl(v.home.alt_amsl_m + 4.0)
    run(v, 0.1)
    expected_agl = -pos(v)[2] - 4.0 - v.fdm.ground_clearance_m
    assert v.truth().height_above_ground_m == pytest.approx(expected_agl, abs=0.02)
    v.autopilot.land(lat_deg=NAN, lon_deg=NAN)
    run(v, 40.0, until=lambda x: not x.autopilot.armed)
    assert not v.autopilot.armed
    assert -pos(v)[2] == pytest.approx(4.0 + v.fdm.ground_clearance_m, abs=0.05)
    # a report above the landing gear (inside an obstacle) is clamped, never buried
    assert not v.set_terrain_amsl(v.home.alt_amsl_m + 50.0)
    run(v, 1.0)
    assert -pos(v)[2] == pytest.approx(4.0 + v.fdm.ground_clearance_m, abs=0.05)
