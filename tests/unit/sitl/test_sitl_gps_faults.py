"""GPS STUCK, GARBAGE and INTERMITTENT failures (MAV_CMD_INJECT_FAILURE): the estimator core, then in flight.

The core tests drive the real estimator with a scripted truth; the flight tests inject through the real
gateway into the real autopilot flying JSBSim, and check what PX4 would do: a frozen fix is fused until
EKF2's innovation gate rejects it, garbage is rejected at once, short gaps are ridden through.
"""

from __future__ import annotations

import math

import pytest
from unit.sitl.sitl_builders import Rig, pos, run, take_off

from sitl.core.estimator import Estimator
from sitl.core.failsafe import FailsafeKind
from sitl.core.faults import (
    GPS_POS_GATE_SD,
    GPS_POS_NOISE_MIN_M,
    NO_AID_TIMEOUT_S,
    FailureType,
    FailureUnit,
)
from sitl.core.modes import FlightMode
from sitl.core.protocol import MavResult, MsgId
from sitl.core.state import VehicleState
from sitl.shell.links import mavlink
from uav_common.geo import GeoPoint, LocalProjection

HOME = GeoPoint(47.397742, 8.545594, 488.0)
PROJ = LocalProjection(HOME)
DT = 0.02  # the outer loop's period
INJECT = mavlink.MAV_CMD_INJECT_FAILURE
GPS = mavlink.FAILURE_UNIT_SENSOR_GPS


def at(t_s: float, north_m: float, vn_mps: float = 0.0) -> VehicleState:
    geo = PROJ.to_geo(north_m, 0.0, -10.0)
    return VehicleState(t_s, geo.lat_deg, geo.lon_deg, geo.alt_amsl_m, (vn_mps, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0),
                        (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), 10.0)  # fmt: skip


# ---- the estimator core ------------------------------------------------------------------------------------------


def test_a_stuck_fix_is_fused_while_hovering_and_rejected_once_the_vehicle_moves() -> None:
    est = Estimator(PROJ, None)
    est.update(at(0.0, 0.0))
    est.gps_fault = FailureType.STUCK
    t = 0.0
    for _ in range(round(30.0 / DT)):  # 30 s of hover: nothing to notice
        t += DT
        s = est.update(at(t, 0.0))
        assert s.gps_ok
        assert s.pos_valid
    assert est.rejected_samples == 0
    assert est.gps_report is not None
    assert (est.gps_report.lat_deg, est.gps_report.lon_deg) == pytest.approx((HOME.lat_deg, HOME.lon_deg))
    # it flies north at 4 m/s: the estimate lags at the frozen fix until the innovation leaves the gate
    gate = GPS_POS_GATE_SD * GPS_POS_NOISE_MIN_M  # 2.5 m with the truth's reported 0.5 m
    north, rejected_at, invalid_at = 0.0, None, None
    for _ in range(round(20.0 / DT)):
        t += DT
        north += 4.0 * DT
        s = est.update(at(t, north, 4.0))
        if rejected_at is None and not s.gps_ok:
            rejected_at = t
            assert north - s.pos_ned_m[0] > 0.5, "the estimate lagged behind the truth"
            assert s.pos_ned_m[0] >= gate * 0.9, "and was rejected only once it was a gate away from the fix"
        if invalid_at is None and not s.pos_valid:
            invalid_at = t
    assert rejected_at is not None
    assert invalid_at is not None
    assert 30.5 < rejected_at < 35.0
    assert invalid_at - rejected_at == pytest.approx(NO_AID_TIMEOUT_S, abs=0.05)
    # after the rejection it dead-reckons: the error is frozen at what it was, not growing with the distance flown
    assert north - s.pos_ned_m[0] < 5.0
    assert north > 60.0
    # the frozen fix still reads home in GPS_RAW_INT's source
    assert est.gps_report.lat_deg == pytest.approx(HOME.lat_deg)
    # OK: back to the truth at once
    est.gps_fault = FailureType.OK
    t += DT
    s = est.update(at(t, north))
    assert s.gps_ok
    assert s.pos_valid
    assert s.pos_ned_m[0] == pytest.approx(north)
    assert est.gps_report is None


def test_garbage_is_rejected_at_once_and_reported_as_random_fixes() -> None:
    est = Estimator(PROJ, None, seed=7)
    est.update(at(0.0, 0.0))
    est.gps_fault = FailureType.GARBAGE
    reports, t, invalid_at = [], 0.0, None
    for _ in range(round(6.0 / DT)):
        t += DT
        s = est.update(at(t, 0.0))
        assert not s.gps_ok
        assert est.gps_report is not None
        reports.append((est.gps_report.lat_deg, est.gps_report.lon_deg))
        if invalid_at is None and not s.pos_valid:
            invalid_at = t
        assert s.pos_valid == (invalid_at is None), "invalid for good once the timeout passed"
    assert invalid_at == pytest.approx(DT + NO_AID_TIMEOUT_S, abs=DT + 1e-6)
    assert len(set(reports)) == len(reports), "every sample is a different random fix"
    assert max(abs(lat - HOME.lat_deg) for lat, _ in reports) > 10.0
    again = Estimator(PROJ, None, seed=7)
    again.update(at(0.0, 0.0))
    again.gps_fault = FailureType.GARBAGE
    again.update(at(DT, 0.0))
    assert again.gps_report is not None
    assert (again.gps_report.lat_deg, again.gps_report.lon_deg) == reports[0], "seeded"


def gaps_of(seed: int, seconds: float) -> tuple[list[float], list[bool], list[bool]]:
    """Run an INTERMITTENT fault on a hovering truth: the gap lengths, gps_ok and pos_valid per step."""
    est = Estimator(PROJ, None, seed=seed)
    est.update(at(0.0, 0.0))
    est.gps_fault = FailureType.INTERMITTENT
    ok, valid, gaps, start = [], [], [], None
    for k in range(1, round(seconds / DT) + 1):
        s = est.update(at(k * DT, 0.0))
        ok.append(s.gps_ok)
        valid.append(s.pos_valid)
        if not s.gps_ok and start is None:
            start = k * DT
        elif s.gps_ok and start is not None:
            gaps.append(k * DT - start)
            start = None
    assert est.gaps >= len(gaps)
    return gaps, ok, valid


def test_intermittent_gaps_are_seeded_and_the_position_survives_gaps_shorter_than_the_timeout() -> None:
    gaps, ok, valid = gaps_of(seed=0, seconds=600.0)
    assert gaps_of(seed=0, seconds=600.0)[1] == ok, "same seed, same gaps"
    assert gaps_of(seed=1, seconds=600.0)[1] != ok
    assert 100 < len(gaps) < 200, "a gap every ~4 s"
    assert sum(gaps) / len(gaps) == pytest.approx(1.0, rel=0.25)
    assert 0.15 < 1.0 - sum(ok) / len(ok) < 0.35, "no fix about a quarter of the time"
    long_gaps = [g for g in gaps if g >= NO_AID_TIMEOUT_S]
    # the position is invalid exactly in gaps that outlast EKF2_NOAID_TOUT
    invalid_steps = valid.count(False)
    assert invalid_steps == pytest.approx(sum(g - NO_AID_TIMEOUT_S for g in long_gaps) / DT, abs=len(long_gaps) + 1)
    # a seed with short gaps only keeps the position valid throughout
    short = next(s for s in range(20) if max(gaps_of(seed=s, seconds=60.0)[0]) < NO_AID_TIMEOUT_S)
    assert all(gaps_of(seed=short, seconds=60.0)[2])


# ---- in flight: what the autopilot does -----------------------------------------------------------------------------


def flying_rig(**overrides: object) -> Rig:
    rig = Rig(**{"params.defaults": {"SYS_FAILURE_EN": 1}, **overrides})
    take_off(rig.v, 10.0, settle_s=2.0)
    return rig


def go_north(rig: Rig, metres: float) -> None:
    target = rig.v.projection.to_geo(metres, 0.0, -10.0)
    result = rig.v.autopilot.reposition(
        lat_deg=target.lat_deg, lon_deg=target.lon_deg, alt_amsl_m=math.nan, yaw_rad=math.nan, speed_mps=math.nan,
        change_mode=True,
    )  # fmt: skip
    assert result is MavResult.ACCEPTED


def gps_healthy(rig: Rig) -> bool:
    health = rig.gw.encoder.build(MsgId.SYS_STATUS).onboard_control_sensors_health
    return bool(health & mavlink.MAV_SYS_STATUS_SENSOR_GPS)


def test_stuck_gps_holds_a_hover_then_a_move_is_rejected_and_the_failsafe_descends() -> None:
    rig = flying_rig()
    v, ap = rig.v, rig.v.autopilot
    assert rig.cmd(INJECT, GPS, mavlink.FAILURE_TYPE_STUCK, 0).result == mavlink.MAV_RESULT_ACCEPTED
    assert any("gps stuck" in t.lower() for t in rig.gcs.texts())
    frozen = rig.gw.encoder.build(MsgId.GPS_RAW_INT)
    run(v, 8.0)
    # hovering on a frozen fix: nothing to notice, the hold stays put
    assert ap.mode is FlightMode.AUTO_LOITER
    assert ap.position_valid
    assert gps_healthy(rig)
    assert math.hypot(*pos(v)[:2]) < 0.5
    gps = rig.gw.encoder.build(MsgId.GPS_RAW_INT)
    assert (gps.fix_type, gps.lat, gps.lon) == (mavlink.GPS_FIX_TYPE_3D_FIX, frozen.lat, frozen.lon)
    # told to go 40 m north it runs away from its frozen estimate until EKF2's gate rejects the fix
    go_north(rig, 40.0)
    t0 = v.t_s
    run(v, 10.0, until=lambda x: not x.est.gps_ok)
    rejected_after = v.t_s - t0
    assert rejected_after < 5.0
    assert not gps_healthy(rig)
    assert pos(v)[0] - v.est.pos_ned_m[0] > 1.0, "the estimate lagged the truth when the fix was rejected"
    assert ap.position_valid, "dead reckoning for EKF2_NOAID_TOUT first"
    run(v, NO_AID_TIMEOUT_S + 0.2)
    assert not ap.position_valid
    assert FailsafeKind.POSITION_LOST in ap.failsafe.active
    assert ap.mode is FlightMode.AUTO_LAND  # PX4's Descend
    assert rig.gw.encoder.build(MsgId.LOCAL_POSITION_NED) is None
    run(v, 60.0, until=lambda x: not x.autopilot.armed)
    assert not ap.armed


def test_garbage_gps_shows_random_fixes_and_the_failsafe_descends_after_the_timeout() -> None:
    rig = flying_rig()
    v, ap = rig.v, rig.v.autopilot
    assert rig.cmd(INJECT, GPS, mavlink.FAILURE_TYPE_GARBAGE, 0).result == mavlink.MAV_RESULT_ACCEPTED
    run(v, 1.0)
    gps = rig.gw.encoder.build(MsgId.GPS_RAW_INT)
    assert gps.fix_type == mavlink.GPS_FIX_TYPE_3D_FIX, "the receiver claims a fix"
    assert abs(gps.lat * 1e-7 - v.home.lat_deg) > 0.01 or abs(gps.lon * 1e-7 - v.home.lon_deg) > 0.01
    assert not gps_healthy(rig)
    assert ap.mode is FlightMode.AUTO_LOITER  # dead reckoning, still holding
    assert ap.position_valid
    run(v, NO_AID_TIMEOUT_S)
    assert not ap.position_valid
    assert ap.mode is FlightMode.AUTO_LAND
    assert ap.set_mode(FlightMode.POSCTL) is MavResult.DENIED


def test_intermittent_gps_with_short_gaps_keeps_holding() -> None:
    rig = flying_rig(**{"estimator.seed": 2})
    v, ap = rig.v, rig.v.autopilot
    assert ap.inject_failure(FailureUnit.SENSOR_GPS, FailureType.INTERMITTENT, 0) is MavResult.ACCEPTED
    no_fix_seen = fix_seen = False
    worst = 0.0
    for _ in range(30):
        run(v, 1.0)
        fix = rig.gw.encoder.build(MsgId.GPS_RAW_INT).fix_type
        no_fix_seen |= fix == mavlink.GPS_FIX_TYPE_NO_FIX
        fix_seen |= fix == mavlink.GPS_FIX_TYPE_3D_FIX
        worst = max(worst, math.hypot(*pos(v)[:2]))
        assert ap.position_valid, f"a gap outlasted EKF2_NOAID_TOUT at {v.t_s:.1f} s (seed 2 has none)"
    assert v.estimator.gaps >= 5
    assert no_fix_seen
    assert fix_seen
    assert ap.mode is FlightMode.AUTO_LOITER
    assert worst < 1.0, f"the hold wandered {worst:.2f} m through the gaps"
    assert ap.inject_failure(FailureUnit.SENSOR_GPS, FailureType.OK, 0) is MavResult.ACCEPTED
    run(v, 0.5)
    assert v.est.gps_ok
    assert not ap.faults.any
