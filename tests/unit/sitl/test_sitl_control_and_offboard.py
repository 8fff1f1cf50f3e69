"""Control laws, the mixer and the offboard setpoint decoding."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from sitl.core.control import (
    ControlGains,
    Mixer,
    attitude_rate_setpoint,
    quat_from_yaw,
    sqrt_controller,
    thrust_to_attitude,
)
from sitl.core.offboard import OffboardRejection, setpoint_from_global_int, setpoint_from_local_ned
from sitl.core.params import ParamTable
from sitl.core.protocol import MavFrame
from uav_common.geo import GeoPoint, LocalProjection
from uav_common.rotations import euler_from_quat

NAN = math.nan
GAINS = ControlGains.from_params(ParamTable())
POS_YAW = 2552  # MAVSDK's PositionNedYaw mask
VEL_ONLY = 0b110111000111


@given(st.floats(-200, 200), st.floats(0.1, 5.0), st.floats(0.5, 10.0))
def test_sqrt_controller_can_always_brake(error: float, p: float, acc: float) -> None:
    v = sqrt_controller(error, p, acc)
    assert math.copysign(1.0, v) == math.copysign(1.0, error) or v == 0.0
    assert v * v <= 2.0 * acc * abs(error) + 1e-9, "stoppable within the remaining distance"


def test_hover_attitude_and_tilt_limit() -> None:
    q, thrust = thrust_to_attitude((0.0, 0.0, 0.0), 0.3, GAINS)
    roll, pitch, yaw = euler_from_quat(q)
    assert (round(roll, 6), round(pitch, 6), round(yaw, 6)) == (0.0, 0.0, 0.3)
    assert thrust == pytest.approx(GAINS.hover_thrust)
    q, thrust = thrust_to_attitude((100.0, 0.0, 0.0), 0.0, GAINS)  # far more than the tilt limit allows
    roll, pitch, _ = euler_from_quat(q)
    assert pitch == pytest.approx(-GAINS.tilt_max_rad, abs=1e-6), "nose down to accelerate north"
    assert thrust > GAINS.hover_thrust


def test_attitude_error_signs() -> None:
    rates = attitude_rate_setpoint(quat_from_yaw(0.0), quat_from_yaw(0.2), NAN, GAINS)
    assert rates[2] > 0
    assert rates[0] == 0
    assert rates[1] == 0
    rates = attitude_rate_setpoint(quat_from_yaw(0.0), quat_from_yaw(-3.0), NAN, GAINS)
    assert rates[2] <= 0, "the short way round"


@given(st.floats(0.0, 1.0), st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5))
def test_mixer_outputs_stay_in_range(thrust: float, roll: float, pitch: float, yaw: float) -> None:
    mixer = Mixer(1.68, 0.02)
    out = mixer.mix(thrust, (roll, pitch, yaw), 1.0)
    assert all(0.0 <= d <= 1.0 for d in out)


def test_mixer_directions() -> None:
    mixer = Mixer(1.0, 0.0)
    fr, al, fl, ar = mixer.mix(0.5, (0.4, 0.0, 0.0), 1.0)
    assert fl > fr, "positive roll (right wing down) lifts the left side"
    assert al > ar
    fr, al, fl, ar = mixer.mix(0.5, (0.0, 0.4, 0.0), 1.0)
    assert fr > ar, "positive pitch (nose up) lifts the front"
    assert fl > al
    fr, al, fl, ar = mixer.mix(0.5, (0.0, 0.0, 0.4), 1.0)
    assert fr > fl
    assert al > ar
    assert mixer.mix(0.5, (0.0, 0.0, 0.0), 0.5) == (0.25, 0.25, 0.25, 0.25), "battery voltage compensation"


def test_local_ned_type_masks_and_frames() -> None:
    kw = {"vehicle_pos": (1.0, 2.0, -10.0), "vehicle_yaw_rad": math.pi / 2}
    sp = setpoint_from_local_ned(MavFrame.LOCAL_NED, POS_YAW, (20, 10, -15), (NAN,) * 3, (NAN,) * 3, 0.5, NAN, **kw)
    assert not isinstance(sp, OffboardRejection)
    assert sp.pos == (20, 10, -15)
    assert math.isnan(sp.vel[0])
    assert sp.yaw_rad == 0.5
    sp = setpoint_from_local_ned(MavFrame.LOCAL_NED, VEL_ONLY, (NAN,) * 3, (1, 2, 0), (0,) * 3, 0, 0, **kw)
    assert not isinstance(sp, OffboardRejection)
    assert sp.vel == (1, 2, 0)
    assert math.isnan(sp.pos[0])
    sp = setpoint_from_local_ned(MavFrame.BODY_NED, VEL_ONLY, (0,) * 3, (1, 0, 0), (0,) * 3, 0, 0, **kw)
    assert not isinstance(sp, OffboardRejection)
    assert sp.vel[0] == pytest.approx(0.0, abs=1e-9), "body x = east at yaw 90"
    assert sp.vel[1] == pytest.approx(1.0)
    sp = setpoint_from_local_ned(MavFrame.LOCAL_OFFSET_NED, POS_YAW, (1, 1, -1), (0,) * 3, (0,) * 3, 0, 0, **kw)
    assert not isinstance(sp, OffboardRejection)
    assert sp.pos == (2.0, 3.0, -11.0)
    bad = setpoint_from_local_ned(MavFrame.LOCAL_NED, POS_YAW, (NAN, 0, 0), (0,) * 3, (0,) * 3, 0, 0, **kw)
    assert isinstance(bad, OffboardRejection)
    ignored_nan = setpoint_from_local_ned(MavFrame.LOCAL_NED, POS_YAW, (1, 2, 3), (NAN,) * 3, (NAN,) * 3, 0, NAN, **kw)
    assert not isinstance(ignored_nan, OffboardRejection), "NaN in ignored fields is fine (MAVSDK sends that)"
    assert isinstance(setpoint_from_local_ned(5, POS_YAW, (1, 2, 3), (0,) * 3, (0,) * 3, 0, 0, **kw), OffboardRejection)
    assert isinstance(setpoint_from_local_ned(1, 0xFFF, (1, 2, 3), (0,) * 3, (0,) * 3, 0, 0, **kw), OffboardRejection)


def test_global_int_setpoint() -> None:
    proj = LocalProjection(GeoPoint(47.0, 8.0, 400.0))
    geo = proj.to_geo(10.0, -5.0, 0.0)
    lat, lon = round(geo.lat_deg * 1e7), round(geo.lon_deg * 1e7)
    sp = setpoint_from_global_int(MavFrame.GLOBAL_RELATIVE_ALT_INT, POS_YAW, lat, lon, 20.0, (0,) * 3, (0,) * 3,
                                  0.0, 0.0, projection=proj)  # fmt: skip
    assert not isinstance(sp, OffboardRejection)
    assert sp.pos[0] == pytest.approx(10.0, abs=0.02)
    assert sp.pos[1] == pytest.approx(-5.0, abs=0.02)
    assert sp.pos[2] == -20.0
    sp = setpoint_from_global_int(MavFrame.GLOBAL_INT, POS_YAW, lat, lon, 430.0, (0,) * 3, (0,) * 3, 0, 0,
                                  projection=proj)  # fmt: skip
    assert not isinstance(sp, OffboardRejection)
    assert sp.pos[2] == -30.0
    bad = setpoint_from_global_int(MavFrame.GLOBAL_INT, POS_YAW, lat, lon, math.inf, (0,) * 3, (0,) * 3, 0, 0,
                                   projection=proj)  # fmt: skip
    assert isinstance(bad, OffboardRejection)


def test_attitude_law_aligns_the_thrust_axis_before_the_heading() -> None:
    # the setpoint: tilted 15 deg nose down (accelerating) and the heading reversed
    tilt = math.radians(15.0)
    pitched = (math.cos(-tilt / 2), 0.0, math.sin(-tilt / 2), 0.0)  # about body y
    yaw_half = quat_from_yaw(math.pi - 0.05)
    w1, x1, y1, z1 = yaw_half
    w2, x2, y2, z2 = pitched
    q_sp = (
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    )
    p, q, r = attitude_rate_setpoint(quat_from_yaw(0.0), q_sp, NAN, GAINS)
    # the roll/pitch demand is as large as for the tilt error alone: the heading error adds none
    p0, q0, _ = attitude_rate_setpoint(quat_from_yaw(0.0), _tilted_like(q_sp), NAN, GAINS)
    assert math.hypot(p, q) == pytest.approx(math.hypot(p0, q0), rel=1e-6)
    assert r > 0, "turns towards the heading, about the thrust axis"
    # a pure heading error never asks for roll or pitch, however large
    p, q, r = attitude_rate_setpoint(quat_from_yaw(0.0), quat_from_yaw(3.1), NAN, GAINS)
    assert (p, q) == pytest.approx((0.0, 0.0), abs=1e-9)
    assert r == pytest.approx(GAINS.max_rates_radps[2])


def _tilted_like(q_sp: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """The attitude with q_sp's thrust axis and heading 0 reached by the shortest tilt."""
    w, x, y, z = q_sp
    bz = (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))
    c = (-bz[1], bz[0], 0.0)  # (0, 0, 1) x bz
    qw = 1.0 + bz[2]
    n = math.sqrt(qw * qw + c[0] ** 2 + c[1] ** 2)
    return (qw / n, c[0] / n, c[1] / n, 0.0)
