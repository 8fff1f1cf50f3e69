"""PX4 features that MAVSDK and QGC clients use beyond the basics: uploaded geofences, offboard attitude
(SET_ATTITUDE_TARGET), DO_ORBIT, follow-me (FOLLOW_TARGET, FLW_TGT_*), the mission items of QGC plans,
and AUTOPILOT_VERSION advertising what is implemented. Through the real gateway and JSBSim."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink
from sitl_builders import Rig, pos, take_off

from sitl.core.control import ControlGains, attitude_rate_setpoint, attitude_rate_setpoint_reference
from sitl.core.modes import FlightMode
from sitl.core.params import ParamTable
from sitl.core.personality import ARDUCOPTER, PX4
from sitl.core.protocol import MavProtocolCapability as Cap
from sitl.shell.wire import STREAMED, WirePackers
from uav_common.geo import LocalProjection

M = mavlink


def fly(r: Rig, seconds: float) -> None:
    for _ in range(round(seconds / r.v.dt_s)):
        r.step()


def airborne_rig(alt_m: float = 10.0, **overrides: object) -> Rig:
    r = Rig(**overrides)
    take_off(r.v, alt_m, settle_s=1.0)
    return r


def texts(r: Rig) -> list[str]:
    return r.gcs.texts()


def quat(roll: float, pitch: float, yaw: float) -> list[float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return [cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy]  # fmt: skip


# ---------------------------------------------------------------------------------------------- geofence
def upload(r: Rig, items: list[object], mission_type: int) -> list[int]:
    r.gcs.clear()
    r.feed(r.client.mav.mission_count_encode(1, 1, len(items), mission_type))
    for it in items:
        r.feed(it)
    return [a.type for a in r.gcs.of_type("MISSION_ACK")]


def fence_item(r: Rig, seq: int, cmd: int, p1: float, n: float, e: float) -> object:  # noqa: PLR0917
    g = LocalProjection(r.v.home).to_geo(n, e, 0.0)
    return r.client.mav.mission_item_int_encode(
        1, 1, seq, M.MAV_FRAME_GLOBAL_INT, cmd, 0, 1, p1, 0, 0, 0, round(g.lat_deg * 1e7), round(g.lon_deg * 1e7), 0,
        M.MAV_MISSION_TYPE_FENCE,
    )  # fmt: skip


def square(r: Rig, half_m: float, seq0: int = 0) -> list[object]:
    corners = [(-half_m, -half_m), (-half_m, half_m), (half_m, half_m), (half_m, -half_m)]
    incl = M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
    return [fence_item(r, seq0 + i, incl, 4, n, e) for i, (n, e) in enumerate(corners)]


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_geofence_upload_download_and_breach(autopilot: str) -> None:
    r = Rig(autopilot=autopilot)
    items = [*square(r, 30.0), fence_item(r, 4, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 5.0, 20.0, 20.0)]
    assert upload(r, items, M.MAV_MISSION_TYPE_FENCE) == [M.MAV_MISSION_ACCEPTED]
    r.gcs.clear()
    r.feed(r.client.mav.mission_request_list_encode(1, 1, M.MAV_MISSION_TYPE_FENCE))
    assert r.gcs.of_type("MISSION_COUNT")[0].count == 5
    r.feed(r.client.mav.mission_request_int_encode(1, 1, 4, M.MAV_MISSION_TYPE_FENCE))
    back = r.gcs.of_type("MISSION_ITEM_INT")[0]
    assert (back.command, back.param1, back.mission_type) == (M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 5.0, 1)
    # fly out of the inclusion square: the fence action (return) follows
    v = r.v
    take_off(v, 10.0, settle_s=1.0) if autopilot == "px4" else _guided_takeoff(r)
    ap = v.autopilot
    ap.reposition(lat_deg=LocalProjection(v.home).to_geo(60.0, 0.0, 0.0).lat_deg, lon_deg=v.home.lon_deg,
                  alt_amsl_m=math.nan, yaw_rad=math.nan, speed_mps=math.nan, change_mode=True)  # fmt: skip
    for _ in range(round(30.0 / v.dt_s)):
        r.step()
        if ap.mode is FlightMode.AUTO_RTL:
            break
    assert ap.mode is FlightMode.AUTO_RTL
    assert any("outside inclusion polygon 1" in t for t in texts(r))
    assert pos(v)[0] < 36.0
    # a fence whose polygon lacks vertices is refused whole, the stored one stays
    assert upload(r, square(r, 10.0)[:3], M.MAV_MISSION_TYPE_FENCE) == [M.MAV_MISSION_INVALID_PARAM1]
    assert len(ap.fence_store) == 5
    r.gcs.clear()
    r.feed(r.client.mav.mission_clear_all_encode(1, 1, M.MAV_MISSION_TYPE_FENCE))
    assert len(ap.fence_store) == 0


def _guided_takeoff(r: Rig) -> None:
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 4).result == 0
    assert r.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
    assert r.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10).result == 0
    fly(r, 12.0)


def test_geofence_refuses_arming_outside_and_rally_points_are_unsupported() -> None:
    r = Rig()
    off_home = [fence_item(r, i, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, 3, n, e)
                for i, (n, e) in enumerate([(50, 50), (50, 80), (80, 80)])]  # fmt: skip
    assert upload(r, off_home, M.MAV_MISSION_TYPE_FENCE) == [M.MAV_MISSION_ACCEPTED]
    assert r.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_DENIED
    assert "outside the geofence" in texts(r)[-1]
    rally = r.client.mav.mission_item_int_encode(1, 1, 0, 3, M.MAV_CMD_NAV_RALLY_POINT, 0, 1, 0, 0, 0, 0, 1, 1, 10, 2)
    assert upload(r, [rally], M.MAV_MISSION_TYPE_RALLY) == [M.MAV_MISSION_UNSUPPORTED]
    bad = r.client.mav.mission_item_int_encode(1, 1, 0, 5, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0, 1, -3, 0, 0, 0,
                                               473977420, 85455940, 0, 1)  # fmt: skip
    assert upload(r, [bad], M.MAV_MISSION_TYPE_FENCE) == [M.MAV_MISSION_INVALID_PARAM1]


# ---------------------------------------------------------------------------------------------- offboard
def test_offboard_attitude_and_body_rates() -> None:
    r = airborne_rig()
    ap = r.v.autopilot
    # no stream yet: OFFBOARD is refused, as PX4 does
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_DENIED
    hover = ap.gains.hover_thrust
    for _ in range(20):
        r.feed(r.client.mav.set_attitude_target_encode(0, 1, 1, 7, quat(0, 0, 0), 0, 0, 0, hover))
        fly(r, 0.05)
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_ACCEPTED
    n0 = pos(r.v)[0]
    for _ in range(40):  # nose down 10 degrees, a little more thrust: the vehicle accelerates north
        r.feed(r.client.mav.set_attitude_target_encode(0, 1, 1, 7, quat(0, math.radians(-10), 0), 0, 0, 0,
                                                       hover * 1.03))  # fmt: skip
        fly(r, 0.05)
    roll, pitch, _ = r.v.truth().euler_rad
    assert pitch == pytest.approx(math.radians(-10), abs=math.radians(1.0))
    assert abs(roll) < math.radians(1.0)
    assert pos(r.v)[0] - n0 > 2.0
    assert r.v.truth().vel_ned_mps[0] > 1.0
    # body rates (ATTITUDE_IGNORE): a yaw rate
    for _ in range(30):
        r.feed(r.client.mav.set_attitude_target_encode(0, 1, 1, 128, [1, 0, 0, 0], 0, 0, 0.5, hover))
        fly(r, 0.05)
    assert r.v.truth().rates_frd_radps[2] == pytest.approx(0.5, abs=0.05)
    # bad targets are dropped and counted; the stream then dies and the offboard failsafe holds
    before = r.gcs.stats.rx_invalid_values
    r.feed(r.client.mav.set_attitude_target_encode(0, 1, 1, 7, [2, 0, 0, 0], 0, 0, 0, hover))
    r.feed(r.client.mav.set_attitude_target_encode(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 1.5))
    r.feed(r.client.mav.set_attitude_target_encode(0, 1, 1, 7, [math.nan, 0, 0, 0], 0, 0, 0, hover))
    r.feed(r.client.mav.set_attitude_target_encode(0, 1, 1, 32, [1, 0, 0, 0], 0, 0, 0, hover))
    assert r.gcs.stats.rx_invalid_values == before + 4
    fly(r, 3.0)
    assert ap.mode is FlightMode.AUTO_LOITER


def test_offboard_velocity_in_body_frame() -> None:
    r = airborne_rig()
    ap = r.v.autopilot
    body_ned_velocity = 0b110111000111  # MAVSDK set_velocity_body: velocities + yaw rate, frame BODY_NED
    for k in range(80):
        r.feed(r.client.mav.set_position_target_local_ned_encode(0, 1, 1, M.MAV_FRAME_BODY_NED,
                                                                 body_ned_velocity, 0, 0, 0, 0, 2.0, 0, 0, 0, 0,
                                                                 0, 0))  # fmt: skip
        if k == 20:
            assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == 0
        fly(r, 0.05)
    assert ap.mode is FlightMode.OFFBOARD
    vn, ve, _ = r.v.truth().vel_ned_mps
    assert ve == pytest.approx(2.0, abs=0.3)  # heading north: body right is east
    assert abs(vn) < 0.3


# ---------------------------------------------------------------------------------------------- orbit
def test_do_orbit_circles_and_reports_px4s_orbit_mode() -> None:
    r = airborne_rig(12.0)
    ap = r.v.autopilot
    centre_geo = LocalProjection(r.v.home).to_geo(20.0, 0.0, 0.0)
    ack = r.cmd(M.MAV_CMD_DO_ORBIT, 15.0, 3.0, 0, math.nan, centre_geo.lat_deg, centre_geo.lon_deg, math.nan)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    hb = r.gw.encoder.heartbeat()
    assert hb.custom_mode == (3 << 16) | (1 << 24)  # POSCTL / ORBIT, as PX4 reports it
    fly(r, 25.0)
    angles = []
    for _ in range(40):
        fly(r, 0.25)
        n, e, d = pos(r.v)
        assert math.hypot(n - 20.0, e) == pytest.approx(15.0, abs=0.6)
        assert -d == pytest.approx(12.0, abs=0.5)
        angles.append(math.atan2(e, n - 20.0))
        assert math.hypot(*r.v.truth().vel_ned_mps[:2]) == pytest.approx(3.0, abs=0.4)
    turned = sum(math.remainder(b - a, math.tau) for a, b in itertools.pairwise(angles))
    assert turned > 0.5, "positive radius: clockwise seen from above"
    # the nose points at the centre (yaw behaviour 0)
    n, e, _ = pos(r.v)
    assert math.remainder(r.v.truth().euler_rad[2] - math.atan2(-e, 20.0 - n), math.tau) == pytest.approx(0, abs=0.15)
    # a speed the radius cannot carry is refused, with the reason; on the ground it is refused too
    assert r.cmd(M.MAV_CMD_DO_ORBIT, 2.0, 10.0).result == M.MAV_RESULT_DENIED
    assert "Orbit denied" in texts(r)[-1]
    assert ap.mode is FlightMode.ORBIT
    ground = Rig()
    assert ground.cmd(M.MAV_CMD_DO_ORBIT, 10.0, 2.0).result == M.MAV_RESULT_DENIED


# ---------------------------------------------------------------------------------------------- follow-me
def test_follow_me_flies_behind_the_target() -> None:
    r = airborne_rig(9.0)
    ap = r.v.autopilot
    for name in ("FLW_TGT_HT", "FLW_TGT_DST", "FLW_TGT_FA", "FLW_TGT_RS", "FLW_TGT_ALT_M", "FLW_TGT_MAX_VEL"):
        assert name in r.v.params
    r.feed(r.client.mav.param_set_encode(1, 1, b"FLW_TGT_DST", 10.0, M.MAV_PARAM_TYPE_REAL32))
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 4, 8).result == M.MAV_RESULT_ACCEPTED  # AUTO.FOLLOW_TARGET
    proj = LocalProjection(r.v.home)
    for k in range(40):  # the target walks east at 1.5 m/s, 1 Hz reports as MAVSDK sends them
        g = proj.to_geo(5.0, 20.0 + 1.5 * k, 0.0)
        r.feed(r.client.mav.follow_target_encode(k * 1000, 1, round(g.lat_deg * 1e7), round(g.lon_deg * 1e7),
                                                 r.v.home.alt_amsl_m, [0, 1.5, 0], [0, 0, 0], [1, 0, 0, 0],
                                                 [0, 0, 0], [0, 0, 0], 0))  # fmt: skip
        fly(r, 1.0)
    n, e, d = pos(r.v)
    target_e = 20.0 + 1.5 * 39
    assert n == pytest.approx(5.0, abs=1.5)
    assert target_e - e == pytest.approx(10.0, abs=2.5), "FLW_TGT_DST behind (FLW_TGT_FA 180)"
    assert -d == pytest.approx(8.0, abs=0.7), "FLW_TGT_HT above home"
    assert math.remainder(r.v.truth().euler_rad[2] - math.pi / 2, math.tau) == pytest.approx(0, abs=0.25)
    assert ap.mode is FlightMode.AUTO_FOLLOW_TARGET
    # follow-me cannot be entered on the ground (PX4: the vehicle must be flying)
    assert Rig().cmd(M.MAV_CMD_DO_SET_MODE, 1, 4, 8).result == M.MAV_RESULT_DENIED


# ---------------------------------------------------------------------------------------------- missions
def test_qgc_mission_items_are_accepted_and_flown() -> None:
    r = airborne_rig(10.0)
    ap = r.v.autopilot
    proj = LocalProjection(r.v.home)

    def nav(seq: int, cmd: int, n: float, e: float, alt: float, p1: float = 0.0) -> object:  # noqa: PLR0917
        g = proj.to_geo(n, e, 0.0)
        return r.client.mav.mission_item_int_encode(
            1, 1, seq, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, cmd, 0, 1, p1, 0, 0, math.nan,
            round(g.lat_deg * 1e7), round(g.lon_deg * 1e7), alt, 0,
        )  # fmt: skip

    def do(seq: int, cmd: int, *p: float) -> object:
        params = [*p, 0, 0, 0, 0][:4]
        return r.client.mav.mission_item_int_encode(1, 1, seq, M.MAV_FRAME_MISSION, cmd, 0, 1, *params, 0, 0, 0, 0)

    items = [
        do(0, M.MAV_CMD_SET_CAMERA_MODE, 0, 0),
        do(1, M.MAV_CMD_DO_CHANGE_SPEED, 1, 6.0, -1),
        nav(2, M.MAV_CMD_NAV_WAYPOINT, 20.0, 0.0, 10.0),
        do(3, M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, 10.0, 0, 1),
        do(4, M.MAV_CMD_DO_MOUNT_CONTROL, -90, 0, 0),
        nav(5, M.MAV_CMD_NAV_WAYPOINT, 20.0, 20.0, 10.0),
        do(6, M.MAV_CMD_DO_JUMP, 2, 1),
        nav(7, M.MAV_CMD_NAV_DELAY, 0.0, 0.0, 0.0, p1=2.0),
        do(8, M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, 0, 0, 0),
        nav(9, M.MAV_CMD_NAV_LOITER_TO_ALT, 0.0, 20.0, 14.0),
    ]
    assert upload(r, items, 0) == [M.MAV_MISSION_ACCEPTED]
    assert r.cmd(M.MAV_CMD_DO_SET_MODE, 1, 4, 4).result == 0
    r.gcs.clear()
    fly(r, 60.0)
    reached = [m.seq for m in r.gcs.of_type("MISSION_ITEM_REACHED")]
    assert reached == [2, 5, 2, 5, 7, 9], "DO_JUMP back to item 2 once, then the delay and the climb"
    assert math.dist(pos(r.v), (0.0, 20.0, -14.0)) < 2.5
    assert ap.mission_state.name == "COMPLETE"
    # an item PX4 would not fly either is refused as UNSUPPORTED
    loiter_turns = nav(0, M.MAV_CMD_NAV_LOITER_TURNS, 10.0, 10.0, 10.0)
    assert upload(r, [loiter_turns], 0) == [M.MAV_MISSION_UNSUPPORTED]


def test_autopilot_version_advertises_what_is_implemented() -> None:
    for personality, autopilot in ((PX4, "px4"), (ARDUCOPTER, "ardupilot")):
        r = Rig(autopilot=autopilot)
        caps = Cap(r.gw.encoder.autopilot_version().capabilities)
        assert caps == personality.capabilities
        implemented = (Cap.MISSION_INT, Cap.COMMAND_INT, Cap.SET_ATTITUDE_TARGET, Cap.MISSION_FENCE, Cap.MAVLINK2,
                       Cap.SET_POSITION_TARGET_LOCAL_NED, Cap.SET_POSITION_TARGET_GLOBAL_INT)  # fmt: skip
        for cap in implemented:
            assert cap in caps
        for missing in (Cap.MISSION_RALLY, Cap.FTP, Cap.TERRAIN, Cap.FLIGHT_TERMINATION, Cap.COMPASS_CALIBRATION):
            assert missing not in caps
    assert Cap.PARAM_ENCODE_BYTEWISE in Cap(PX4.capabilities)
    assert Cap.PARAM_ENCODE_C_CAST in Cap(ARDUCOPTER.capabilities)


# ---------------------------------------------------------------------------------------------- speed work
def test_fast_packers_frame_exactly_like_pymavlink() -> None:
    packers = WirePackers()
    factory = mavlink.MAVLink(None)
    ref = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    for name in STREAMED:
        encode = getattr(factory, f"{name.lower()}_encode")
        cls = mavlink.mavlink_map[getattr(mavlink, f"MAVLINK_MSG_ID_{name}")]
        args = []
        for k, field in enumerate(cls.fieldnames):
            ftype = cls.fieldtypes[k]
            length = cls.array_lengths[cls.ordered_fieldnames.index(field)]
            value = (k * 37 + 11) % 120 + (0.25 if ftype in ("float", "double") else 0)
            args.append([value + i for i in range(length)] if length else value)
        fast = getattr(packers, name.lower())(*args)
        ref.seq = 7
        assert fast.frame(7, 1, 1) == encode(*args).pack(ref), name
        assert fast.get_type() == name


@settings(max_examples=300, deadline=None)
@given(
    st.lists(st.floats(-1.0, 1.0), min_size=8, max_size=8),
    st.one_of(st.just(math.nan), st.floats(-3.0, 3.0)),
)
def test_written_out_attitude_law_is_bit_identical(values: list[float], yaw_rate_ff: float) -> None:
    def unit(v: list[float]) -> tuple[float, float, float, float]:
        n = math.sqrt(sum(x * x for x in v)) or 1.0
        return (v[0] / n, v[1] / n, v[2] / n, v[3] / n)

    gains = ControlGains.from_params(ParamTable())
    q, q_sp = unit(values[:4]), unit(values[4:])
    assert attitude_rate_setpoint(q, q_sp, yaw_rate_ff, gains) == attitude_rate_setpoint_reference(
        q, q_sp, yaw_rate_ff, gains
    )
