"""The ArduPilot personality (``uav-sitl --autopilot ardupilot``) through the real gateway and JSBSim:
heartbeat, ArduCopter modes as MAVProxy sends them, GUIDED takeoff, ArduPilot parameter names and
encoding, mission item 0 = home, failsafe behaviour, and the errors for another autopilot's names.
"""

from __future__ import annotations

import math

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink
from sitl_builders import Client, Rig, make_config, pos

from sitl.config import load_sitl_config
from sitl.core.modes import FlightMode
from sitl.core.personality import ARDUCOPTER, PX4, UnknownPersonalityError, personality_named
from sitl.errors import SitlConfigError
from uav_common.autopilot_modes import Autopilot, decode_custom_mode, mode_name
from uav_common.geo import LocalProjection

M = mavlink


def rig(**overrides: object) -> Rig:
    return Rig(autopilot="ardupilot", **overrides)


def fly(r: Rig, seconds: float, until: object = None) -> None:
    for _ in range(round(seconds / r.v.dt_s)):
        r.step()
        if until is not None and until(r):  # type: ignore[operator]
            return


def texts(r: Rig) -> list[str]:
    return r.gcs.texts()


def guided_takeoff(r: Rig, alt_m: float = 10.0) -> None:
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 4).result == M.MAV_RESULT_ACCEPTED  # MAVProxy: "mode GUIDED"
    assert r.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
    ack = r.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, alt_m)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    fly(r, 20.0, until=lambda x: -pos(x.v)[2] > alt_m - 0.3)


def test_heartbeat_says_arducopter_and_mavproxy_reads_its_modes() -> None:
    r = rig()
    hb = r.gw.encoder.heartbeat()
    assert (hb.type, hb.autopilot) == (M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA)
    assert hb.custom_mode == 0  # ArduCopter boots in STABILIZE
    assert hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert mavutil.mode_string_v10(hb) == "STABILIZE"
    for number, name in ((4, "GUIDED"), (5, "LOITER"), (6, "RTL"), (2, "ALT_HOLD"), (9, "LAND")):
        assert r.cmd(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, number).result == 0, name
        hb = r.gw.encoder.heartbeat()
        assert hb.custom_mode == number
        assert mavutil.mode_string_v10(hb) == name
    assert mode_name(Autopilot.ARDUPILOT, 3) == "AUTO"
    # MAVProxy's mode table for a quadrotor (what "mode GUIDED" looks up) is ArduCopter's numbers
    assert mavutil.mode_mapping_byname(M.MAV_TYPE_QUADROTOR)["GUIDED"] == 4
    # modes ArduCopter has but this emulator does not fly are refused, with the reason
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 1).result == M.MAV_RESULT_DENIED  # ACRO
    assert "unsupported mode (base 1, number 1)" in texts(r)[-1]


def test_guided_takeoff_semantics() -> None:
    r = rig()
    ap = r.v.autopilot
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 4).result == 0
    # takeoff before arming fails (ArduCopter: MAV_RESULT_FAILED), and a position target does not lift it
    assert r.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10).result == M.MAV_RESULT_FAILED
    assert "not armed" in texts(r)[-1]
    assert r.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    up = r.client.mav.set_position_target_local_ned_encode(0, 1, 1, 1, 2552, 0, 0, -10, 0, 0, 0, 0, 0, 0, 0, 0)
    r.feed(up)
    fly(r, 2.0)
    assert ap.landed, "GUIDED on the ground: a target alone does not take off"
    # NAV_TAKEOFF's param7 is metres above home; the vehicle climbs and stays in GUIDED
    assert r.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 12).result == 0
    fly(r, 20.0)
    n, e, d = pos(r.v)
    assert abs(-d - 12.0) < 0.4
    assert math.hypot(n, e) < 0.5
    assert ap.mode is FlightMode.OFFBOARD
    assert r.gw.encoder.heartbeat().custom_mode == 4
    # airborne: a takeoff is refused; targets fly the vehicle
    assert r.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 20).result == M.MAV_RESULT_FAILED
    r.feed(r.client.mav.set_position_target_local_ned_encode(0, 1, 1, 1, 2552, 15, -5, -14, 0, 0, 0, 0, 0, 0, 0, 0))
    fly(r, 15.0)
    assert math.dist(pos(r.v), (15.0, -5.0, -14.0)) < 0.5


def test_rtl_climbs_to_rtl_alt_waits_and_lands_then_disarms() -> None:
    r = rig()
    guided_takeoff(r, 8.0)
    ap = r.v.autopilot
    r.feed(r.client.mav.set_position_target_local_ned_encode(0, 1, 1, 1, 2552, 30, 0, -8, 0, 0, 0, 0, 0, 0, 0, 0))
    fly(r, 15.0)
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 6).result == 0  # MAVProxy: "mode RTL"
    top = 0.0
    for _ in range(round(80.0 / r.v.dt_s)):
        r.step()
        top = max(top, -pos(r.v)[2])
        if not ap.armed:
            break
    assert 14.5 < top < 16.0, f"RTL_ALT is 15 m: climbed to {top:.1f} m"
    assert not ap.armed
    assert ap.landed
    assert math.hypot(*pos(r.v)[:2]) < 1.0


def test_parameters_have_arducopter_names_units_and_float_encoding() -> None:
    r = rig()
    n = len(r.v.params)
    r.gcs.clear()
    r.feed(r.client.mav.param_request_list_encode(1, 1))
    values = {v.param_id: v for v in r.gcs.of_type("PARAM_VALUE")}
    assert len(values) == n
    for name in ("WPNAV_SPEED", "RTL_ALT", "FENCE_ENABLE", "FENCE_RADIUS", "BATT_LOW_MAH", "FS_GCS_ENABLE",
                 "BATT_FS_LOW_ACT", "GUID_TIMEOUT"):  # fmt: skip
        assert name in values, name
    assert not [p for p in values if p.startswith(("MPC_", "COM_", "NAV_", "GF_"))], "no PX4 names"
    # integers travel as plain floats (ArduPilot's encoding), with ArduPilot's types
    assert values["FENCE_ENABLE"].param_value == 1.0
    assert values["FENCE_ENABLE"].param_type == M.MAV_PARAM_TYPE_INT8
    assert values["RTL_LOIT_TIME"].param_value == 5000.0
    assert values["BATT_LOW_MAH"].param_value == pytest.approx(525.0)  # 15 % of 3500 mAh (failsafe config)
    r.gcs.clear()
    r.feed(r.client.mav.param_set_encode(1, 1, b"WPNAV_SPEED", 600.0, M.MAV_PARAM_TYPE_REAL32))
    r.feed(r.client.mav.param_set_encode(1, 1, b"FS_GCS_ENABLE", 5.0, M.MAV_PARAM_TYPE_INT8))
    fly(r, 0.1)
    s = r.v.autopilot.settings
    assert s.cruise_speed_mps == pytest.approx(6.0)  # cm/s -> m/s
    assert s.datalink_action is not None
    assert s.datalink_action.value == "land"
    # a PX4 name is refused with the reason
    r.gcs.clear()
    r.feed(r.client.mav.param_set_encode(1, 1, b"MPC_XY_CRUISE", 3.0, M.MAV_PARAM_TYPE_REAL32))
    joined = "".join(texts(r))
    assert "MPC_XY_CRUISE is a PX4 parameter" in joined
    assert "--autopilot px4" in joined
    assert not r.gcs.of_type("PARAM_VALUE")


def test_other_autopilots_parameter_in_the_config_is_a_config_error() -> None:
    with pytest.raises(SitlConfigError, match=r"MPC_XY_CRUISE is a PX4 parameter.*--autopilot px4"):
        load_sitl_config(None, {"autopilot": "ardupilot", "params.defaults": {"MPC_XY_CRUISE": 3.0}})
    with pytest.raises(SitlConfigError, match=r"WPNAV_SPEED is a ArduPilot parameter.*--autopilot ardupilot"):
        load_sitl_config(None, {"params.defaults": {"WPNAV_SPEED": 500}})
    with pytest.raises(SitlConfigError, match=r"autopilot.*'px4', 'ardupilot'"):
        load_sitl_config(None, {"autopilot": "betaflight"})
    with pytest.raises(UnknownPersonalityError, match="px4"):
        personality_named("inav")
    assert personality_named(" ArduPilot ") is ARDUCOPTER
    assert make_config().personality is PX4


def test_mission_item_zero_is_home() -> None:
    r = rig()
    ap = r.v.autopilot
    proj = LocalProjection(r.v.home)

    def item(seq: int, cmd: int, n: float, e: float, alt: float) -> object:
        g = proj.to_geo(n, e, 0.0)
        return r.client.mav.mission_item_int_encode(
            1, 1, seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, cmd, 0, 1, 0, 0, 0, math.nan,
            round(g.lat_deg * 1e7), round(g.lon_deg * 1e7), alt, 0,
        )  # fmt: skip

    # item 0 is home whatever it holds (here a point 500 m away): only 1..3 are flown
    items = [item(0, M.MAV_CMD_NAV_WAYPOINT, 500, 500, 0), item(1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 10),
             item(2, M.MAV_CMD_NAV_WAYPOINT, 25, 0, 10), item(3, M.MAV_CMD_NAV_WAYPOINT, 25, 20, 12)]  # fmt: skip
    r.gcs.clear()
    r.feed(r.client.mav.mission_count_encode(1, 1, len(items), 0))
    for it in items:
        r.feed(it)
    assert [a.type for a in r.gcs.of_type("MISSION_ACK")] == [M.MAV_MISSION_ACCEPTED]
    r.gcs.clear()
    r.feed(r.client.mav.mission_request_int_encode(1, 1, 0, 0))
    home = r.gcs.of_type("MISSION_ITEM_INT")[0]
    assert (home.x, home.y, home.z) == (round(r.v.home.lat_deg * 1e7), round(r.v.home.lon_deg * 1e7), 488.0)
    # AUTO cannot be armed in (ArduCopter): arm in GUIDED, then AUTO takes off with the mission's takeoff
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 3).result == 0
    assert r.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_DENIED
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 4).result == 0
    assert r.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 3).result == 0
    r.gcs.clear()
    fly(r, 45.0)
    reached = [m.seq for m in r.gcs.of_type("MISSION_ITEM_REACHED")]
    assert reached == [1, 2, 3]
    current = r.gcs.of_type("MISSION_CURRENT")[-1]
    assert (current.seq, current.total, current.mission_state) == (3, 3, M.MISSION_STATE_COMPLETE)
    assert math.dist(pos(r.v), (25.0, 20.0, -12.0)) < 2.5  # WPNAV_RADIUS 2 m
    assert ap.mode is FlightMode.AUTO_MISSION  # ArduCopter holds in AUTO after the last item


def test_mission_without_takeoff_item_stays_on_the_ground() -> None:
    r = rig()
    proj = LocalProjection(r.v.home)
    g = proj.to_geo(20.0, 0.0, 0.0)
    wp = r.client.mav.mission_item_int_encode(
        1, 1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, math.nan,
        round(g.lat_deg * 1e7), round(g.lon_deg * 1e7), 10.0, 0,
    )  # fmt: skip
    home = r.client.mav.mission_item_int_encode(1, 1, 0, 0, M.MAV_CMD_NAV_WAYPOINT, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0)
    r.feed(r.client.mav.mission_count_encode(1, 1, 2, 0))
    r.feed(home)
    r.feed(wp)
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 4).result == 0
    assert r.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 3).result == 0
    fly(r, 5.0)
    assert r.v.autopilot.landed


def test_battery_failsafe_uses_batt_codes_and_disarms_on_the_ground() -> None:
    r = rig(**{"battery.initial_soc": 0.16})  # BATT_LOW_MAH 525 of 3500: just above
    ap = r.v.autopilot
    guided_takeoff(r, 6.0)
    fly(r, 120.0, until=lambda x: x.v.autopilot.mode is FlightMode.AUTO_RTL)
    assert ap.mode is FlightMode.AUTO_RTL, "BATT_FS_LOW_ACT 2: RTL"
    assert any("Low battery" in t for t in texts(r))
    # on the ground and armed, ArduCopter disarms instead of flying the failsafe action
    g = rig()
    assert g.cmd(M.MAV_CMD_DO_SET_MODE, 1, 4).result == 0
    assert g.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    g.feed(g.client.mav.param_set_encode(1, 1, b"BATT_CRT_MAH", 4000.0, M.MAV_PARAM_TYPE_REAL32))
    fly(g, 0.5)
    assert not g.v.autopilot.armed
    assert any("Critical battery" in t for t in texts(g))


def test_gcs_failsafe_counts_only_sysid_mygcs_heartbeats() -> None:
    r = rig(**{"failsafe.datalink_loss_action": "return", "failsafe.datalink_loss_timeout_s": 3.0})
    ap = r.v.autopilot
    assert r.v.params["FS_GCS_ENABLE"] == 1
    guided_takeoff(r, 6.0)
    sdk = Client(245, 190)  # a second client: MAVSDK's 245/190 is not SYSID_MYGCS (255)
    r.feed(r.client.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0))  # 255: the GCS
    for _ in range(10):
        r.feed(sdk.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0), client=sdk)
        fly(r, 1.0)
    assert ap.mode is FlightMode.AUTO_RTL, "the GCS (sysid 255) fell silent; heartbeats from 245 do not count"
    assert any("Data link lost" in t for t in texts(r))


def test_guided_velocity_target_expires_after_guid_timeout() -> None:
    r = rig()
    guided_takeoff(r, 8.0)
    r.feed(r.client.mav.set_position_target_local_ned_encode(0, 1, 1, 1, 0b110111000111, 0, 0, 0, 3, 0, 0,
                                                              0, 0, 0, 0, 0))  # fmt: skip
    fly(r, 2.0)
    assert r.v.truth().vel_ned_mps[0] > 2.0
    fly(r, 6.0)  # GUID_TIMEOUT 3 s: the vehicle stops
    assert abs(r.v.truth().vel_ned_mps[0]) < 0.3
    assert r.v.autopilot.mode is FlightMode.OFFBOARD


def test_alt_hold_holds_altitude_and_tilts_on_the_sticks() -> None:
    r = rig()
    guided_takeoff(r, 10.0)
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 2).result == 0  # ALT_HOLD
    for _ in range(60):  # 3 s of pitch forward, throttle centred
        r.feed(r.client.mav.manual_control_encode(1, 500, 0, 500, 0, 0))
        fly(r, 0.05)
    n, _, d = pos(r.v)
    assert n > 3.0
    assert abs(-d - 10.0) < 1.0
    for _ in range(60):  # throttle up: climb
        r.feed(r.client.mav.manual_control_encode(1, 0, 0, 900, 0, 0))
        fly(r, 0.05)
    assert -pos(r.v)[2] > 12.0


def test_do_orbit_is_refused_with_the_reason() -> None:
    r = rig()
    guided_takeoff(r, 8.0)
    assert r.cmd(M.MAV_CMD_DO_ORBIT, 10, 2).result == M.MAV_RESULT_UNSUPPORTED
    assert "not supported by ArduCopter" in texts(r)[-1]


def test_arducopter_mode_numbers_round_trip_the_shared_table() -> None:
    for mode in ARDUCOPTER.flown_modes:
        number = ARDUCOPTER.custom_mode(mode)
        assert decode_custom_mode(Autopilot.ARDUPILOT, number) is mode
        assert ARDUCOPTER.mode_from_set_mode_params(1, number, 0) is mode
    assert ARDUCOPTER.mode_from_set_mode_params(0, 4, 0) is None  # no custom-mode flag
    assert ARDUCOPTER.mode_from_set_mode_params(1, 4.5, 0) is None
