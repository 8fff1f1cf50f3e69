"""Compass and barometer failures (MAV_CMD_INJECT_FAILURE SENSOR_MAG / SENSOR_BARO): the estimator core, then in flight.

The core tests drive the real estimator with a scripted truth; the flight tests inject through the real gateway
into the real autopilot flying JSBSim and read what a ground station would (SYS_STATUS, HIGHRES_IMU, STATUSTEXT).
What they check is what PX4's EKF2 does on a multicopter with one compass, one baro and a good GPS: the height
falls back to the GNSS (its error grows to GNSS-height grade, no failsafe), the heading to the gyro (it drifts in
a hover and is aligned by GNSS velocity in motion), frozen or garbage readings go through the innovation gates.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from unit.sitl.sitl_builders import Rig, pos, run, take_off

from sitl.core.estimator import Estimator, NoiseModel
from sitl.core.faults import (
    BARO_GATE_SD,
    BARO_NOISE_M,
    GYRO_YAW_DRIFT_SD_RADPS,
    HGT_FUSION_TIMEOUT_S,
    MAG_HEADING_GATE_RAD,
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
INJECT = mavlink.MAV_CMD_INJECT_FAILURE
MAG = mavlink.FAILURE_UNIT_SENSOR_MAG
BARO = mavlink.FAILURE_UNIT_SENSOR_BARO
BARO_BIT = mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
MAG_BIT = mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG


def at(t_s: float, *, north_m: float = 0.0, up_m: float = 10.0, vn_mps: float = 0.0, vu_mps: float = 0.0,
       yaw_rad: float = 0.0) -> VehicleState:  # fmt: skip
    geo = PROJ.to_geo(north_m, 0.0, -up_m)
    q = (math.cos(yaw_rad / 2), 0.0, 0.0, math.sin(yaw_rad / 2))
    return VehicleState(t_s, geo.lat_deg, geo.lon_deg, geo.alt_amsl_m, (vn_mps, 0.0, -vu_mps), q, (0.0, 0.0, yaw_rad),
                        (0.0, 0.0, 0.0), (0.0, 0.0, -9.8), up_m)  # fmt: skip


def up_error(est: Estimator, truth: VehicleState, up_m: float) -> float:
    return -est.update(truth).pos_ned_m[2] - up_m


def heading_error(est: Estimator, truth: VehicleState) -> float:
    yaw = est.update(truth).yaw_rad
    return (yaw - truth.euler_rad[2] + math.pi) % (2 * math.pi) - math.pi


# ---- the barometer on the estimator core ---------------------------------------------------------------------------


def test_baro_off_hands_the_height_to_the_gnss_whose_error_grows_from_zero_to_gnss_grade() -> None:
    dt, seconds = 0.1, 90.0
    early, late = [], []
    for seed in range(120):
        est = Estimator(PROJ, None, seed=seed)
        est.update(at(0.0))
        est.baro_fault = FailureType.OFF
        for k in range(1, round(seconds / dt) + 1):
            err = up_error(est, at(k * dt), 10.0)
            if k == 10:
                early.append(err)
        late.append(err)
        assert not est.baro_healthy
        assert not est.baro_reporting
        assert est.update(at(seconds + dt)).pos_valid, "a lost baro alone does not invalidate the estimate"
    sd = est.gnss_height_sd_m
    assert sd == pytest.approx(0.8)  # with the truth: GPS_RAW_INT's v_acc
    rms_late = float(np.sqrt(np.mean(np.square(late))))
    rms_early = float(np.sqrt(np.mean(np.square(early))))
    assert rms_late == pytest.approx(sd, rel=0.25), f"after 90 s: {rms_late:.2f} m rms, the GNSS height's {sd} m"
    assert rms_early < 0.3 * sd, "1 s after the loss the height has not jumped"


def test_gnss_height_grade_follows_the_preset() -> None:
    noise = NoiseModel(1.2, 1.5, 0.1, 0.005, 30.0, 1.2, 1.5, 0.0, 3.0, 0.3)
    est = Estimator(PROJ, noise, seed=1)
    assert est.gnss_height_sd_m == pytest.approx(1.5 * math.hypot(1.2, 1.2))  # 1.5 x the per-axis horizontal
    assert est.baro_weight == pytest.approx((1 / 3.5**2) / (1 / 3.5**2 + 1 / est.gnss_height_sd_m**2))


def test_a_stuck_baro_is_fused_in_a_hover_and_rejected_by_the_gate_in_a_climb() -> None:
    dt = 0.02
    est = Estimator(PROJ, None, seed=3)
    est.update(at(0.0))
    est.baro_fault = FailureType.STUCK
    t = 0.0
    for _ in range(round(20.0 / dt)):  # hover: the frozen reading agrees, nothing to notice
        t += dt
        assert abs(up_error(est, at(t), 10.0)) < 1e-6
        assert est.baro_healthy
    assert est.baro_report_alt_m == pytest.approx(HOME.alt_amsl_m + 10.0, abs=1e-6)
    up, rejected_at, errors = 10.0, None, []
    while t < 60.0:  # climb at 2 m/s
        t += dt
        up += 2.0 * dt
        errors.append(up_error(est, at(t, up_m=up, vu_mps=2.0), up))
        if rejected_at is None and not est.baro_healthy:
            rejected_at = up
            lag = errors[-1]
    assert rejected_at is not None
    gate = BARO_GATE_SD * BARO_NOISE_M
    # the frozen reading drags the estimate down by its weight until the innovation leaves the 17.5 m gate
    assert rejected_at - 10.0 == pytest.approx(gate / (1.0 - est.baro_weight), abs=0.2)
    assert lag == pytest.approx(-est.baro_weight * (rejected_at - 10.0), abs=0.3)
    assert lag < -0.5
    # rejected, the height is the GNSS's: the drag is gone, the error GNSS-grade
    assert abs(errors[-1]) < 4 * est.gnss_height_sd_m
    assert est.baro_rejected_samples > 0
    assert est.baro_report_alt_m == pytest.approx(HOME.alt_amsl_m + 10.0, abs=1e-6), "it still reads the frozen height"
    assert any("baro fusion failing" in m for m in est.messages), "stopped for good after hgt_fusion_timeout_max"
    # back down within the gate it stays out (EKF2's baro_fault) until the failure is cleared
    for _ in range(round(5.0 / dt)):
        t += dt
        est.update(at(t, up_m=12.0))
    assert not est.baro_healthy
    est.baro_fault = FailureType.OK
    assert abs(up_error(est, at(t + dt, up_m=12.0), 12.0)) < 1e-9, "OK: the height resets to the baro"
    assert est.baro_healthy
    assert est.baro_reporting
    assert est.baro_report_alt_m is None


def test_baro_stuck_rejection_takes_the_fusion_timeout_to_become_final() -> None:
    dt = 0.02
    est = Estimator(PROJ, None, seed=3)
    est.update(at(0.0))
    est.baro_fault = FailureType.STUCK
    t, up, first = 0.0, 10.0, None
    while True:
        t += dt
        up += 5.0 * dt
        est.update(at(t, up_m=up, vu_mps=5.0))
        if not est.baro_healthy:
            first = t
            break
    assert not est.messages
    while t - first < HGT_FUSION_TIMEOUT_S - 0.1:
        t += dt
        est.update(at(t, up_m=up))
    assert not est.messages
    for _ in range(10):
        t += dt
        est.update(at(t, up_m=up))
    assert est.messages == ["EKF2: baro fusion failing, height from GNSS"]


def test_garbage_baro_is_rejected_at_once_and_reports_wild_pressures() -> None:
    est = Estimator(PROJ, None, seed=4)
    est.update(at(0.0))
    est.baro_fault = FailureType.GARBAGE
    reported = []
    for k in range(1, 50):
        est.update(at(0.02 * k))
        assert not est.baro_healthy
        assert est.baro_report_alt_m is not None
        reported.append(est.baro_report_alt_m)
        assert abs(est.baro_report_alt_m - (HOME.alt_amsl_m + 10.0)) > BARO_GATE_SD * BARO_NOISE_M
    assert len(set(reported)) == len(reported), "a new random reading each sample"
    assert est.messages == ["EKF2: baro rejected, height from GNSS"]


def baro_gaps(seed: int, seconds: float, *, with_gps: bool = False) -> list[bool]:
    est = Estimator(PROJ, None, seed=seed)
    est.update(at(0.0))
    est.baro_fault = FailureType.INTERMITTENT
    if with_gps:
        est.gps_fault = FailureType.INTERMITTENT
    out = []
    for k in range(1, round(seconds / 0.02) + 1):
        est.update(at(0.02 * k))
        out.append(est.baro_reporting)
    return out


def test_intermittent_baro_is_seeded_and_on_its_own_stream() -> None:
    a = baro_gaps(5, 60.0)
    assert a == baro_gaps(5, 60.0)
    assert a != baro_gaps(6, 60.0)
    assert 0.6 < sum(a) / len(a) < 0.9, "fixes 3 s, gaps 1 s on average"
    assert a == baro_gaps(5, 60.0, with_gps=True), "GPS faults draw from their own stream"


# ---- the compass on the estimator core -----------------------------------------------------------------------------


def test_mag_off_in_a_hover_drifts_at_the_residual_gyro_bias() -> None:
    dt, seconds = 0.1, 60.0
    drifts = []
    for seed in range(150):
        est = Estimator(PROJ, None, seed=seed)
        est.update(at(0.0))
        est.mag_fault = FailureType.OFF
        for k in range(1, round(seconds / dt) + 1):
            err = heading_error(est, at(k * dt))
        drifts.append(err)
        assert not est.mag_healthy
        assert not est.mag_reporting
    expected = GYRO_YAW_DRIFT_SD_RADPS * seconds  # 1.2 deg after a minute
    sd = float(np.std(drifts))
    assert sd == pytest.approx(expected, rel=0.2)
    assert max(abs(d) for d in drifts) < 4.5 * expected, "bounded by the residual gyro bias"


def test_without_a_compass_gnss_velocity_aligns_the_heading_in_motion() -> None:
    noise = NoiseModel(0.0, 0.0, 0.0, 0.0, 30.0, 0.0, 0.0, 0.0, 3.0, 0.3, heading_bias_rad=math.radians(6.0))
    hover = Estimator(PROJ, noise, seed=8)
    moving = Estimator(PROJ, noise, seed=8)
    bias = math.degrees(hover.heading_error_rad)
    assert abs(bias) > 1.0
    for e in (hover, moving):
        e.update(at(0.0))
        e.mag_fault = FailureType.OFF
    for k in range(1, 3001):
        t = 0.02 * k
        err_hover = math.degrees(heading_error(hover, at(t)))
        err_moving = math.degrees(heading_error(moving, at(t, north_m=5.0 * t, vn_mps=5.0)))
    assert err_hover == pytest.approx(bias, abs=3.0), "in a hover the compass's last error is kept, drifting"
    assert abs(err_moving) < 0.2 * abs(bias), "moving, GNSS velocity pulls the heading to the truth (EKF-GSF)"


def test_a_stuck_compass_drags_a_slow_yaw_and_is_rejected_in_a_fast_one() -> None:
    def turn(rate_dps: float) -> tuple[Estimator, float]:
        est = Estimator(PROJ, None, seed=2)
        est.update(at(0.0))
        est.mag_fault = FailureType.STUCK
        for k in range(1, 500):  # 10 s of hover: the frozen field agrees
            assert abs(heading_error(est, at(0.02 * k))) < 1e-9
        assert est.mag_healthy
        yaw, t, err = 0.0, 10.0, 0.0
        while yaw < math.radians(90.0):
            t += 0.02
            yaw += math.radians(rate_dps) * 0.02
            err = heading_error(est, at(t, yaw_rad=yaw))
            if not est.mag_healthy:
                break
        return est, err

    slow, err_slow = turn(5.0)
    assert slow.mag_healthy, "a 5 deg/s turn never leaves the gate"
    assert math.degrees(err_slow) < -60.0, "EKF2 believed the frozen compass: the heading stayed behind"
    fast, err_fast = turn(45.0)
    assert not fast.mag_healthy, "a 45 deg/s turn leaves the gate"
    assert fast.mag_rejected_samples > 0
    assert -math.degrees(MAG_HEADING_GATE_RAD) < math.degrees(err_fast) < 0.0
    assert fast.messages == ["EKF2: compass rejected, heading from gyro and GNSS velocity"]


def test_garbage_compass_is_rejected_and_ok_brings_the_compass_back() -> None:
    noise = NoiseModel(0.0, 0.0, 0.0, 0.0, 30.0, 0.0, 0.0, 0.0, 3.0, 0.3, heading_bias_rad=math.radians(3.0))
    est = Estimator(PROJ, noise, seed=9)
    compass = est.heading_error_rad
    est.update(at(0.0))
    est.mag_fault = FailureType.GARBAGE
    for k in range(1, 100):
        est.update(at(0.02 * k))
        assert not est.mag_healthy
        assert est.mag_report_body is not None
        assert max(abs(c) for c in est.mag_report_body) >= 0.65
    est.mag_fault = FailureType.OK
    t = 2.0
    for _ in range(round(15.0 / 0.02)):
        t += 0.02
        err = heading_error(est, at(t))
        assert est.mag_healthy
    assert err == pytest.approx(compass, abs=1e-3)
    assert not est._mag_on, "recovered: back on the fast path"


def test_intermittent_compass_is_seeded() -> None:
    def gaps(seed: int) -> list[bool]:
        est = Estimator(PROJ, None, seed=seed)
        est.update(at(0.0))
        est.mag_fault = FailureType.INTERMITTENT
        out = []
        for k in range(1, 3000):
            est.update(at(0.02 * k))
            out.append(est.mag_healthy)
        return out

    a = gaps(1)
    assert a == gaps(1)
    assert a != gaps(2)
    assert False in a
    assert True in a


# ---- in flight, through the gateway ------------------------------------------------------------------------------


def flying_rig(**overrides: object) -> Rig:
    rig = Rig(**{"params.defaults": {"SYS_FAILURE_EN": 1}, **overrides})
    take_off(rig.v, 10.0, settle_s=2.0)
    return rig


def sys_status_bits(rig: Rig) -> tuple[int, int, int]:
    s = rig.gw.encoder.build(MsgId.SYS_STATUS)
    return s.onboard_control_sensors_present, s.onboard_control_sensors_enabled, s.onboard_control_sensors_health


def test_baro_off_in_flight_holds_the_altitude_on_gnss_height_and_reports_the_baro_unhealthy() -> None:
    rig = flying_rig()
    v, ap = rig.v, rig.v.autopilot
    assert rig.cmd(INJECT, BARO, mavlink.FAILURE_TYPE_OFF, 0).result == mavlink.MAV_RESULT_ACCEPTED
    assert any("sensor_baro off" in t for t in rig.gcs.texts())
    worst = 0.0
    for _ in range(60):
        run(v, 1.0)
        worst = max(worst, abs(-pos(v)[2] - 10.0))
    rig.step()
    present, enabled, health = sys_status_bits(rig)
    assert present & BARO_BIT
    assert enabled & BARO_BIT
    assert not health & BARO_BIT
    assert health & MAG_BIT
    imu = rig.gw.encoder.build(MsgId.HIGHRES_IMU)
    assert not imu.fields_updated & (1 << 9), "no new pressure"
    assert imu.fields_updated & (1 << 6), "the compass still reports"
    assert any("baro stopped, height from GNSS" in t for t in rig.gcs.texts())
    # no failsafe: the GNSS height holds it, within the GNSS height's error
    assert ap.mode is FlightMode.AUTO_LOITER
    assert not ap.failsafe.active
    assert ap.position_valid
    assert worst < 4 * v.estimator.gnss_height_sd_m, f"the hold strayed {worst:.2f} m vertically"
    assert abs(-v.est.pos_ned_m[2] + pos(v)[2]) > 0.01, "the height error is the GNSS's, not zero"
    assert rig.cmd(INJECT, BARO, mavlink.FAILURE_TYPE_OK, 0).result == mavlink.MAV_RESULT_ACCEPTED
    run(v, 0.5)
    assert sys_status_bits(rig)[2] & BARO_BIT
    assert rig.gw.encoder.build(MsgId.HIGHRES_IMU).fields_updated == 0x1FFF
    assert not ap.faults.any


def test_baro_stuck_in_flight_freezes_the_pressure_and_a_climb_is_rejected_by_the_gate() -> None:
    rig = flying_rig()
    v, ap = rig.v, rig.v.autopilot
    assert ap.inject_failure(FailureUnit.SENSOR_BARO, FailureType.STUCK, 1) is MavResult.ACCEPTED
    run(v, 0.1)  # the estimator takes it at its next update
    frozen = rig.gw.encoder.build(MsgId.HIGHRES_IMU).abs_pressure
    run(v, 5.0)
    assert rig.gw.encoder.build(MsgId.HIGHRES_IMU).abs_pressure == frozen
    assert sys_status_bits(rig)[2] & BARO_BIT, "hovering, the frozen reading passes the gate"
    target = v.projection.to_geo(0.0, 0.0, -40.0)
    assert ap.reposition(lat_deg=math.nan, lon_deg=math.nan, alt_amsl_m=target.alt_amsl_m, yaw_rad=math.nan,
                         speed_mps=math.nan, change_mode=True) is MavResult.ACCEPTED  # fmt: skip
    run(v, 30.0, until=lambda x: not x.estimator.baro_healthy)
    climbed = -pos(v)[2] - 10.0
    assert not sys_status_bits(rig)[2] & BARO_BIT
    assert 15.0 < climbed < 25.0, f"rejected after a {climbed:.1f} m climb (the gate is 17.5 m)"
    run(v, 30.0)
    rig.step()  # the gateway sends what the autopilot said
    assert rig.gw.encoder.build(MsgId.HIGHRES_IMU).abs_pressure == frozen
    assert ap.mode is FlightMode.AUTO_LOITER
    assert not ap.failsafe.active
    assert abs(-pos(v)[2] - 40.0) < 4 * v.estimator.gnss_height_sd_m, "it got there on the GNSS height"
    assert any("baro fusion failing" in t for t in rig.gcs.texts())


def test_mag_off_in_a_hover_lets_the_heading_drift_a_little_and_garbage_is_unhealthy() -> None:
    rig = flying_rig(**{"estimator.seed": 4})
    v, ap = rig.v, rig.v.autopilot
    assert rig.cmd(INJECT, MAG, mavlink.FAILURE_TYPE_OFF, 0).result == mavlink.MAV_RESULT_ACCEPTED
    run(v, 60.0)
    rig.step()
    drift = math.degrees(v.est.yaw_rad - v.truth().euler_rad[2])
    assert 0.0 < abs(drift) < 4.5 * math.degrees(GYRO_YAW_DRIFT_SD_RADPS) * 60.0
    present, _, health = sys_status_bits(rig)
    assert present & MAG_BIT
    assert not health & MAG_BIT
    assert health & BARO_BIT
    assert not rig.gw.encoder.build(MsgId.HIGHRES_IMU).fields_updated & (1 << 6)
    assert ap.mode is FlightMode.AUTO_LOITER
    assert not ap.failsafe.active
    assert math.hypot(*pos(v)[:2]) < 0.5
    assert rig.cmd(INJECT, MAG, mavlink.FAILURE_TYPE_GARBAGE, 0).result == mavlink.MAV_RESULT_ACCEPTED
    run(v, 1.0)
    imu = rig.gw.encoder.build(MsgId.HIGHRES_IMU)
    assert max(abs(imu.xmag), abs(imu.ymag), abs(imu.zmag)) >= 0.65, "a wild field"
    assert imu.fields_updated & (1 << 6)
    assert not sys_status_bits(rig)[2] & MAG_BIT
    assert rig.cmd(INJECT, MAG, mavlink.FAILURE_TYPE_OK, 0).result == mavlink.MAV_RESULT_ACCEPTED
    run(v, 15.0)
    assert sys_status_bits(rig)[2] & MAG_BIT
    assert abs(v.est.yaw_rad - v.truth().euler_rad[2]) < 1e-3, "the compass (exact here) has the heading back"


def test_sensor_faults_need_sys_failure_en_and_a_real_instance() -> None:
    rig = Rig()
    assert rig.cmd(INJECT, BARO, mavlink.FAILURE_TYPE_OFF, 0).result == mavlink.MAV_RESULT_DENIED
    rig = Rig(**{"params.defaults": {"SYS_FAILURE_EN": 1}})
    assert rig.cmd(INJECT, MAG, mavlink.FAILURE_TYPE_OFF, 2).result == mavlink.MAV_RESULT_DENIED
    assert any("no sensor_mag 2" in t for t in rig.gcs.texts())
    assert rig.cmd(INJECT, MAG, mavlink.FAILURE_TYPE_WRONG, 0).result == mavlink.MAV_RESULT_UNSUPPORTED
    assert rig.cmd(INJECT, BARO, mavlink.FAILURE_TYPE_SLOW, 0).result == mavlink.MAV_RESULT_UNSUPPORTED


def test_a_failed_compass_or_baro_refuses_arming_until_cleared() -> None:
    rig = Rig(**{"params.defaults": {"SYS_FAILURE_EN": 1}})
    arm = (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    for unit, text in ((BARO, "barometer 0 failed"), (MAG, "compass 0 failed")):
        assert rig.cmd(INJECT, unit, mavlink.FAILURE_TYPE_STUCK, 0).result == mavlink.MAV_RESULT_ACCEPTED
        rig.step()
        assert not sys_status_bits(rig)[2] & mavlink.MAV_SYS_STATUS_PREARM_CHECK
        assert rig.cmd(*arm).result == mavlink.MAV_RESULT_DENIED
        assert any(text in t for t in rig.gcs.texts())
        assert not rig.v.autopilot.armed
        assert rig.cmd(INJECT, unit, mavlink.FAILURE_TYPE_OK, 0).result == mavlink.MAV_RESULT_ACCEPTED
        rig.step()
    assert sys_status_bits(rig)[2] & mavlink.MAV_SYS_STATUS_PREARM_CHECK
    assert rig.cmd(*arm).result == mavlink.MAV_RESULT_ACCEPTED
    assert rig.v.autopilot.armed
