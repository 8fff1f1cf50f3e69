"""Failures injected in flight (MAV_CMD_INJECT_FAILURE, SYS_FAILURE_EN) through the real gateway and JSBSim."""

from __future__ import annotations

import math

import pytest
from unit.sitl.sitl_builders import Rig, pos, run, take_off

from sitl.core.failsafe import FailsafeKind
from sitl.core.faults import MOTOR_WRONG_FACTOR, FailureType, FailureUnit
from sitl.core.modes import FlightMode
from sitl.core.protocol import MavResult, MsgId
from sitl.shell.links import mavlink

INJECT = mavlink.MAV_CMD_INJECT_FAILURE
ENABLED = {"params.defaults": {"SYS_FAILURE_EN": 1}}


def _flying_rig(**overrides: object) -> Rig:
    rig = Rig(**{**ENABLED, **overrides})
    take_off(rig.v, 10.0, settle_s=3.0)
    return rig


def _fly(rig: Rig, seconds: float) -> None:
    for _ in range(round(seconds / rig.v.dt_s)):
        rig.step()


def test_failure_injection_is_refused_while_sys_failure_en_is_0() -> None:
    rig = Rig()
    assert rig.v.params["SYS_FAILURE_EN"] == 0
    ack = rig.cmd(INJECT, mavlink.FAILURE_UNIT_SENSOR_GPS, mavlink.FAILURE_TYPE_OFF, 0)
    assert ack.result == mavlink.MAV_RESULT_DENIED
    assert any("SYS_FAILURE_EN" in t for t in rig.gcs.texts())
    assert not rig.v.autopilot.faults.any


@pytest.mark.parametrize(
    ("unit", "ftype", "instance", "result"),
    [
        (mavlink.FAILURE_UNIT_SENSOR_GYRO, mavlink.FAILURE_TYPE_OFF, 0, mavlink.MAV_RESULT_UNSUPPORTED),
        (mavlink.FAILURE_UNIT_SENSOR_BARO, mavlink.FAILURE_TYPE_WRONG, 0, mavlink.MAV_RESULT_UNSUPPORTED),
        (mavlink.FAILURE_UNIT_SENSOR_GPS, mavlink.FAILURE_TYPE_SLOW, 0, mavlink.MAV_RESULT_UNSUPPORTED),
        (mavlink.FAILURE_UNIT_SENSOR_GPS, mavlink.FAILURE_TYPE_WRONG, 0, mavlink.MAV_RESULT_UNSUPPORTED),
        (mavlink.FAILURE_UNIT_SYSTEM_MAVLINK_SIGNAL, mavlink.FAILURE_TYPE_OFF, 0, mavlink.MAV_RESULT_UNSUPPORTED),
        (77, mavlink.FAILURE_TYPE_OFF, 0, mavlink.MAV_RESULT_UNSUPPORTED),
        (mavlink.FAILURE_UNIT_SYSTEM_MOTOR, mavlink.FAILURE_TYPE_OFF, 5, mavlink.MAV_RESULT_DENIED),
        (mavlink.FAILURE_UNIT_SYSTEM_MOTOR, 1.5, 1, mavlink.MAV_RESULT_DENIED),
        (mavlink.FAILURE_UNIT_SENSOR_GPS, math.nan, 0, mavlink.MAV_RESULT_DENIED),
    ],
)
def test_unmodelled_or_invalid_failures_are_refused(unit: float, ftype: float, instance: int, result: int) -> None:
    rig = Rig(**ENABLED)
    assert rig.cmd(INJECT, unit, ftype, instance).result == result
    assert not rig.v.autopilot.faults.any


def test_ardupilot_has_no_failure_injection() -> None:
    rig = Rig(autopilot="ardupilot")
    ack = rig.cmd(INJECT, mavlink.FAILURE_UNIT_SENSOR_GPS, mavlink.FAILURE_TYPE_OFF, 0)
    assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED


def test_gps_off_loses_the_position_and_descends_as_px4() -> None:
    rig = _flying_rig(**{"wind.speed_mps": 5.0, "wind.from_deg": 270.0})
    v, ap = rig.v, rig.v.autopilot
    assert rig.cmd(INJECT, mavlink.FAILURE_UNIT_SENSOR_GPS, mavlink.FAILURE_TYPE_OFF, 0).result == 0
    assert ap.faults.gps_off
    _fly(rig, 1.0)
    gps = rig.gw.encoder.build(MsgId.GPS_RAW_INT)
    assert gps.fix_type == mavlink.GPS_FIX_TYPE_NO_FIX
    # dead reckoning for EKF2_NOAID_TOUT: still holding, position still reported
    assert ap.mode is FlightMode.AUTO_LOITER
    assert rig.gw.encoder.build(MsgId.LOCAL_POSITION_NED) is not None
    _fly(rig, 4.5)
    assert not ap.position_valid
    assert FailsafeKind.POSITION_LOST in ap.failsafe.active
    assert ap.mode is FlightMode.AUTO_LAND  # PX4's Descend is reported as AUTO.LAND
    assert any("no local position" in t for _, t in ap.statustexts) or any(
        "no local position" in t for t in rig.gcs.texts()
    )
    for msg in (MsgId.LOCAL_POSITION_NED, MsgId.GLOBAL_POSITION_INT, MsgId.ODOMETRY):
        assert rig.gw.encoder.build(msg) is None, f"message {msg} still sent without a position"
    assert ap.set_mode(FlightMode.POSCTL) is MavResult.DENIED
    # level descent without position control: the wind carries it east, and it lands and disarms
    east_before = pos(v)[1]
    run(v, 40.0, until=lambda x: not x.autopilot.armed)
    assert not ap.armed
    assert ap.landed
    assert pos(v)[1] - east_before > 3.0, "a descent without position control should drift with a 5 m/s wind"


def test_gps_back_ok_restores_the_position_but_not_the_mode() -> None:
    rig = _flying_rig()
    ap = rig.v.autopilot
    ap.inject_failure(FailureUnit.SENSOR_GPS, FailureType.OFF, 0)
    _fly(rig, 6.0)
    assert ap.mode is FlightMode.AUTO_LAND
    assert ap.inject_failure(FailureUnit.SENSOR_GPS, FailureType.OK, 0) is MavResult.ACCEPTED
    _fly(rig, 0.5)
    assert ap.position_valid
    assert FailsafeKind.POSITION_LOST not in ap.failsafe.active
    assert ap.mode is FlightMode.AUTO_LAND  # PX4 stays in the failsafe mode until told otherwise
    assert ap.set_mode(FlightMode.AUTO_LOITER) is MavResult.ACCEPTED


def test_battery_off_reads_empty_and_lands() -> None:
    rig = _flying_rig()
    v, ap = rig.v, rig.v.autopilot
    assert ap.inject_failure(FailureUnit.SYSTEM_BATTERY, FailureType.OFF, 0) is MavResult.ACCEPTED
    _fly(rig, 0.5)
    assert ap.mode is FlightMode.AUTO_LAND
    assert rig.gw.encoder.build(MsgId.BATTERY_STATUS).battery_remaining == 0
    assert v.battery.soc > 0.9  # the pack itself is full: the reading failed
    run(v, 40.0, until=lambda x: not x.autopilot.armed)
    assert not ap.armed


def test_motor_wrong_still_holds_and_motor_off_falls() -> None:
    rig = _flying_rig()
    v, ap = rig.v, rig.v.autopilot
    assert ap.inject_failure(FailureUnit.SYSTEM_MOTOR, FailureType.WRONG, 1) is MavResult.ACCEPTED
    assert ap.faults.motor_factors == (MOTOR_WRONG_FACTOR, 1.0, 1.0, 1.0)
    worst = 0.0
    for _ in range(10):
        run(v, 1.0)
        worst = max(worst, math.dist(pos(v), (0.0, 0.0, -10.0)))
    assert worst < 1.0, f"a degraded motor moved the hold {worst:.2f} m"
    # the rate loop's integrator makes up for it: motor 1 is commanded more and delivers as the others
    assert v.duty[0] > 1.3 * max(v.duty[1:])
    assert ap.inject_failure(FailureUnit.SYSTEM_MOTOR, FailureType.OFF, 1) is MavResult.ACCEPTED
    worst = tilt = 0.0
    for _ in range(round(3.0 / v.dt_s)):
        v.step(v.t_s)
        worst = max(worst, math.dist(pos(v), (0.0, 0.0, -10.0)))
        roll, pitch, _ = v.truth().euler_rad
        tilt = max(tilt, abs(roll), abs(pitch))
    assert v.fdm.motors()[0].throttle == 0.0
    # a quadrotor with a motor off tumbles (PX4 has no motor-failure recovery on a quad)
    assert tilt > math.radians(60.0)
    assert worst > 3.0
