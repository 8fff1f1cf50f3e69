"""The autopilot's estimate in ROS conventions: ODOMETRY and LOCAL_POSITION_NED + ATTITUDE_QUATERNION agree,
covariances follow the frames, bad estimates are refused with the reason; the clock mapping (TIMESYNC, the
arrival fallback, a reboot); the watchdog (fresh, stale with the wall floor, invalid at once); and the
controller's MAVLink shell refusing a NaN position."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from uav_autonomy.core.pose_estimate import (
    SOURCE_LOCAL_POSITION,
    SOURCE_ODOMETRY,
    AssumedAccuracy,
    AutopilotOdometryConfig,
    EstimateState,
    EstimateWatchdog,
    TimeSync,
    estimate_from_local_position,
    estimate_from_odometry,
    relative_yaw_rad,
    target_from_position_target,
)
from uav_autonomy.errors import InvalidInputError
from uav_common.config import ConfigError, from_mapping
from uav_common.rotations import quat_from_euler, rotate

NAN21 = [math.nan] + [0.0] * 20
ASSUMED = AssumedAccuracy(position_sigma_m=2.0, attitude_sigma_rad=0.1, velocity_sigma_mps=0.5, rate_sigma_radps=0.2)


def urt(matrix: np.ndarray) -> list[float]:
    return [float(v) for v in matrix[np.triu_indices(6)]]


def odometry(**kw: object):  # type: ignore[no-untyped-def]
    args: dict[str, object] = {
        "frame_id": 1,
        "child_frame_id": 12,
        "position_ned_m": (10.0, 5.0, -20.0),
        "q_ned_frd_wxyz": tuple(quat_from_euler(0.0, 0.0, math.pi / 2)),  # heading east
        "velocity_child_mps": (2.0, 0.0, 0.0),  # forward
        "rates_frd_radps": (0.0, 0.0, 0.3),  # yawing right
        "pose_covariance_urt": NAN21,
        "velocity_covariance_urt": NAN21,
        "quality": 100,
        "assumed": ASSUMED,
    }
    args.update(kw)
    return estimate_from_odometry(12_345_678, **args)  # type: ignore[arg-type]


def test_odometry_is_converted_to_enu_flu_with_the_autopilots_stamp() -> None:
    est = odometry()
    assert est.source == SOURCE_ODOMETRY
    assert est.t_autopilot_s == pytest.approx(12.345678)
    np.testing.assert_allclose(est.position_enu_m, (5.0, 10.0, 20.0))
    np.testing.assert_allclose(np.abs(est.q_enu_flu_wxyz), (1.0, 0.0, 0.0, 0.0), atol=1e-12)  # east = ENU yaw 0
    assert est.yaw_enu_rad == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(est.velocity_flu_mps, (2.0, 0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(est.angular_flu_radps, (0.0, 0.0, -0.3), atol=1e-12)
    # no covariance from the autopilot (NaN first element): the assumed accuracy, said so
    assert not est.covariance_from_autopilot
    np.testing.assert_allclose(np.diag(np.reshape(est.pose_covariance, (6, 6))), [4.0] * 3 + [0.01] * 3)
    np.testing.assert_allclose(np.diag(np.reshape(est.twist_covariance, (6, 6))), [0.25] * 3 + [0.04] * 3)


def test_the_autopilots_covariances_follow_the_frames() -> None:
    pose = np.diag([4.0, 1.0, 9.0, 0.01, 0.02, 0.03])
    pose[0, 1] = pose[1, 0] = 0.5  # north-east correlation
    pose[0, 2] = pose[2, 0] = 0.3  # north-down
    twist = np.diag([0.1, 0.2, 0.3, 0.01, 0.01, 0.01])
    twist[0, 1] = twist[1, 0] = 0.05  # forward-right
    est = odometry(pose_covariance_urt=urt(pose), velocity_covariance_urt=urt(twist))
    assert est.covariance_from_autopilot
    c = np.reshape(est.pose_covariance, (6, 6))
    np.testing.assert_allclose(np.diag(c), [1.0, 4.0, 9.0, 0.02, 0.01, 0.03])  # east, north, up
    assert c[0, 1] == pytest.approx(0.5)  # east-north: the same correlation
    assert c[1, 2] == pytest.approx(-0.3)  # north-up = -(north-down)
    np.testing.assert_allclose(c, c.T)
    t = np.reshape(est.twist_covariance, (6, 6))
    assert t[0, 1] == pytest.approx(-0.05)  # forward-left = -(forward-right)
    assert np.all(np.linalg.eigvalsh(c) > 0)


def test_local_position_with_attitude_quaternion_gives_the_same_estimate() -> None:
    """The fallback of an autopilot that sends no ODOMETRY: the same state through the other messages."""
    rng = np.random.default_rng(4)
    for _ in range(20):
        roll, pitch, yaw = rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), rng.uniform(-math.pi, math.pi)
        q = tuple(quat_from_euler(roll, pitch, yaw))
        v_body = rng.normal(0.0, 3.0, 3)
        v_ned = rotate(q, v_body)  # body FRD -> NED
        pos = tuple(rng.normal(0.0, 50.0, 3))
        rates = tuple(rng.normal(0.0, 0.5, 3))
        a = odometry(position_ned_m=pos, q_ned_frd_wxyz=q, velocity_child_mps=tuple(v_body), rates_frd_radps=rates)
        b = estimate_from_local_position(
            12_345, pos, velocity_ned_mps=tuple(v_ned), q_ned_frd_wxyz=q, rates_frd_radps=rates, assumed=ASSUMED
        )
        assert b.source == SOURCE_LOCAL_POSITION
        assert b.t_autopilot_s == pytest.approx(12.345)
        np.testing.assert_allclose(a.position_enu_m, b.position_enu_m, atol=1e-9)
        assert relative_yaw_rad(a.q_enu_flu_wxyz, b.q_enu_flu_wxyz) == pytest.approx(0.0, abs=1e-9)
        np.testing.assert_allclose(a.velocity_flu_mps, b.velocity_flu_mps, atol=1e-9)
        np.testing.assert_allclose(a.angular_flu_radps, b.angular_flu_radps, atol=1e-12)


@pytest.mark.parametrize(
    ("kw", "text"),
    [
        ({"position_ned_m": (math.nan, 0.0, 0.0)}, "ODOMETRY position is not finite"),
        ({"q_ned_frd_wxyz": (math.nan, 0.0, 0.0, 0.0)}, "attitude quaternion is not finite"),
        ({"q_ned_frd_wxyz": (0.0, 0.0, 0.0, 0.0)}, "is not a rotation"),
        ({"quality": -1}, "quality -1: the autopilot says its odometry has failed"),
        ({"frame_id": 20}, "frame_id 20 is not a local NED frame"),
        ({"child_frame_id": 7}, "child_frame_id 7"),
        ({"pose_covariance_urt": [1.0, math.inf] + [0.0] * 19}, "covariance has non-finite values"),
    ],
)
def test_estimates_that_cannot_be_flown_on_are_refused_with_the_reason(kw: dict[str, object], text: str) -> None:
    with pytest.raises(InvalidInputError, match=text):
        odometry(**kw)


def test_unknown_velocity_is_marked_unknown_not_passed_as_nan() -> None:
    est = odometry(velocity_child_mps=(math.nan, 0.0, 0.0))
    assert est.velocity_flu_mps == (0.0, 0.0, 0.0)
    assert np.reshape(est.twist_covariance, (6, 6))[0, 0] >= 1e6
    with pytest.raises(InvalidInputError, match="LOCAL_POSITION_NED position is not finite"):
        estimate_from_local_position(
            0, (0.0, math.nan, 0.0), velocity_ned_mps=(0, 0, 0), q_ned_frd_wxyz=(1, 0, 0, 0),
            rates_frd_radps=(0, 0, 0), assumed=ASSUMED,
        )  # fmt: skip


# ---- time ---------------------------------------------------------------------------------------------------


def test_timesync_recovers_the_offset_and_ignores_slow_answers() -> None:
    """ROS time = autopilot time + 100 s. Answers over a jittery link: the fastest round trip wins."""
    offset = 100.0
    sync = TimeSync(window=10)
    assert sync.method == "none"
    assert math.isnan(sync.offset_s)
    rng = random.Random(1)
    now = 200.0
    for _ in range(10):
        up, down = 0.005 + rng.uniform(0, 0.2), 0.005 + rng.uniform(0, 0.2)  # delays each way
        ts1 = now
        tc1 = ts1 + up - offset  # the autopilot's clock when it answers
        now = ts1 + up + down
        assert sync.on_timesync(ts1, tc1, now)
        now += 0.5
    assert sync.method == "timesync"
    # exact up to half the difference of the two legs of the fastest exchange
    assert abs(sync.offset_s - offset) <= sync.rtt_s / 2 + 1e-9
    assert sync.rtt_s < 0.2
    assert sync.to_local(5.0) == pytest.approx(105.0, abs=0.1)
    assert not sync.on_timesync(300.0, 199.0, 302.0)  # a 2 s round trip (over max_rtt_s): ignored
    assert not sync.on_timesync(300.0, 199.0, 299.0)  # an answer before its question: ignored
    assert sync.rejected == 2


def test_without_timesync_the_arrival_envelope_maps_stamps_at_most_the_least_latency_late() -> None:
    sync = TimeSync(window=20)
    rng = random.Random(2)
    for k in range(40):
        stamp = 10.0 + 0.02 * k
        sync.on_arrival(stamp, stamp + 50.0 + 0.003 + rng.uniform(0.0, 0.1))  # offset 50 s, latency 3-103 ms
    assert sync.method == "arrival"
    assert 50.003 <= sync.offset_s <= 50.02


def test_an_autopilot_reboot_resets_the_mapping() -> None:
    sync = TimeSync(window=5)
    sync.on_timesync(100.0, 500.0, 100.01)
    assert sync.offset_s == pytest.approx(-399.995)
    sync.on_arrival(3.0, 101.0)  # its clock went back: rebooted
    assert sync.resets == 1
    assert sync.method == "arrival"
    assert sync.offset_s == pytest.approx(98.0)


# ---- fit to fly on? -----------------------------------------------------------------------------------------


def test_watchdog_fresh_stale_invalid() -> None:
    dog = EstimateWatchdog(timeout_s=1.0, wall_floor_s=2.0)
    assert dog.state(0.0, 0.0) == (EstimateState.WAITING, "no valid estimate yet")
    dog.valid(10.0, 10.02, 100.0)
    assert dog.state(10.5, 100.2)[0] == EstimateState.OK
    # 3 simulated s of silence but 0.3 wall s (a lockstep simulation running ahead): not stale yet
    assert dog.state(13.0, 100.3)[0] == EstimateState.OK
    state, reason = dog.state(13.0, 102.1)
    assert state == EstimateState.STALE
    assert reason == "no fresh estimate for 3.0 s (timeout 1 s)"
    # an estimate that arrives 1.5 s after its stamp is not fresh
    dog.valid(12.0, 13.5, 102.2)
    assert dog.late_count == 1
    assert dog.state(13.5, 102.2)[0] == EstimateState.STALE
    dog.valid(13.45, 13.5, 102.2)
    assert dog.state(13.6, 102.3)[0] == EstimateState.OK
    # a NaN estimate: invalid at once, until a valid one comes
    dog.invalid("ODOMETRY position is not finite: [nan, 0.0, 0.0]")
    assert dog.state(13.6, 102.3) == (EstimateState.INVALID, "ODOMETRY position is not finite: [nan, 0.0, 0.0]")
    dog.valid(13.6, 13.62, 102.31)
    assert dog.state(13.7, 102.4)[0] == EstimateState.OK
    assert (dog.valid_count, dog.invalid_count) == (4, 1)
    # one NaN between two checks, a valid estimate right after it: still reported once
    dog.invalid("a message with NaN/inf at 13.70 s")
    dog.valid(13.72, 13.72, 102.42)
    assert dog.state(13.75, 102.45) == (EstimateState.INVALID, "a message with NaN/inf at 13.70 s")
    assert dog.state(13.76, 102.46)[0] == EstimateState.OK


def test_autopilot_odometry_config_validation() -> None:
    cfg = from_mapping(AutopilotOdometryConfig, {"source": "local_position"}, source="t")
    assert cfg.source == "local_position"
    assert cfg.assumed_accuracy.position_sigma_m == 1.0
    for data, text in (
        ({"source": "gps"}, "source must be auto, odometry or local_position"),
        ({"stale_timeout_s": 0}, "stale_timeout_s must be a finite number > 0"),
        ({"odometry_rate_hz": -1}, r"odometry_rate_hz must be in \[0, 1000\]"),
        ({"odom_frame": "map"}, "three different names"),
        ({"assumed_accuracy": {"position_sigma_m": 0}}, "position_sigma_m must be a finite number > 0"),
        ({"stale_timeut_s": 1}, "unknown key"),
    ):
        with pytest.raises(ConfigError, match=text):
            from_mapping(AutopilotOdometryConfig, data, source="t")


# ---- the controller's MAVLink shell ------------------------------------------------------------------------


def _frame(name: str, *fields: object):  # type: ignore[no-untyped-def]
    import os  # noqa: PLC0415

    os.environ["MAVLINK20"] = "1"
    from pymavlink.dialects.v20 import common as mavlink2  # noqa: PLC0415

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    packed = getattr(mav, f"{name}_encode")(*fields).pack(mav)
    return mav.decode(bytearray(packed))


def test_the_link_never_takes_a_nan_position() -> None:
    from uav_autonomy.mavlink.link import MavlinkLink  # noqa: PLC0415

    link = MavlinkLink("udpin:127.0.0.1:0", source_system=1, source_component=191, target_system=1,
                       target_component=1, reconnect_after_s=5.0)  # fmt: skip
    link._handle(_frame("local_position_ned", 1000, 10.0, 5.0, -20.0, 0.0, 0.0, 0.0), 1.0)
    link._handle(_frame("local_position_ned", 1020, math.nan, math.nan, math.nan, 0.0, 0.0, 0.0), 2.0)
    t = link.telemetry()
    assert t.position_enu_m == pytest.approx((5.0, 10.0, 20.0))
    assert t.position_s == 1.0  # the NaN message refreshed nothing
    assert "non-finite position" in t.position_invalid
    link._handle(_frame("local_position_ned", 1040, 11.0, 5.0, -20.0, 0.0, 0.0, 0.0), 3.0)
    assert link.telemetry().position_invalid == ""
    assert link.telemetry().position_s == 3.0


def test_the_autopilots_position_target_in_map_enu() -> None:
    # POSITION_TARGET_LOCAL_NED as the SITL and PX4 send it in HOLD: position used, velocity/accel/yaw rate ignored
    target = target_from_position_target(12_500, 64 | 128 | 256 | 2048, (10.0, -4.0, -15.0))
    assert target is not None
    assert target.t_autopilot_s == pytest.approx(12.5)
    assert target.position_enu_m == pytest.approx((-4.0, 10.0, 15.0))  # east, north, up
    assert target_from_position_target(1, 1 | 2 | 4, (0.0, 0.0, 0.0)) is None  # no position target (on the ground)
    assert target_from_position_target(1, 4, (1.0, 2.0, 0.0)) is None  # z ignored: not a full position target
    assert target_from_position_target(1, 0, (math.nan, 0.0, -5.0)) is None
