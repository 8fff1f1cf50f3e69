"""Offboard setpoints: SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT to a :class:`Setpoint`, SET_ATTITUDE_TARGET
to an :class:`AttitudeSetpoint`.

``type_mask`` bits mark fields to *ignore*. Per axis, a position wins over a
velocity, a velocity over an acceleration (PX4's rules). Frames: LOCAL_NED,
LOCAL_OFFSET_NED (position relative to the vehicle), BODY_NED (velocity and
acceleration rotated by the heading), BODY_OFFSET_NED (both); for the global
message GLOBAL_INT (AMSL) and GLOBAL_RELATIVE_ALT_INT (above home).
Any non-finite value in a used field rejects the whole setpoint.

SET_ATTITUDE_TARGET (PX4 OFFBOARD, ArduCopter GUIDED): an attitude quaternion (FRD -> NED) with a
collective thrust 0..1, or body rates with a thrust (``ATTITUDE_IGNORE`` set), as MAVSDK's
``set_attitude`` and ``set_attitude_rate`` send them. ``THRUST_BODY_SET`` (a thrust vector) is
refused, as PX4 multicopters do.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.core.control import Setpoint
from sitl.core.protocol import AttitudeTargetMask, MavFrame, PositionTargetMask
from uav_common.geo import GeoPoint, LocalProjection

__all__ = [
    "AttitudeSetpoint",
    "OffboardRejection",
    "attitude_setpoint",
    "setpoint_from_global_int",
    "setpoint_from_local_ned",
]

NAN = math.nan
M = PositionTargetMask
Vec3 = tuple[float, float, float]

LOCAL_FRAMES = frozenset({MavFrame.LOCAL_NED, MavFrame.LOCAL_OFFSET_NED, MavFrame.BODY_NED, MavFrame.BODY_OFFSET_NED})
GLOBAL_FRAMES = frozenset(
    {MavFrame.GLOBAL_INT, MavFrame.GLOBAL_RELATIVE_ALT_INT, MavFrame.GLOBAL, MavFrame.GLOBAL_RELATIVE_ALT}
)


@dataclass(frozen=True)
class OffboardRejection:
    reason: str


def _pick(mask: int, bits: tuple[int, int, int], values: Vec3) -> tuple[Vec3, bool]:
    out = tuple(NAN if mask & bit else v for bit, v in zip(bits, values, strict=True))
    used = [v for bit, v in zip(bits, values, strict=True) if not mask & bit]
    return (out[0], out[1], out[2]), all(math.isfinite(v) for v in used)


def _yaw(mask: int, yaw: float, yaw_rate: float) -> tuple[float, float, bool]:
    y = NAN if mask & M.YAW_IGNORE else yaw
    r = NAN if mask & M.YAW_RATE_IGNORE else yaw_rate
    ok = (bool(mask & M.YAW_IGNORE) or math.isfinite(yaw)) and (
        bool(mask & M.YAW_RATE_IGNORE) or math.isfinite(yaw_rate)
    )
    return y, r, ok


def _rotate_yaw(v: Vec3, yaw_rad: float) -> Vec3:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return (
        v[0] * c - v[1] * s if math.isfinite(v[0]) and math.isfinite(v[1]) else NAN,
        v[0] * s + v[1] * c if math.isfinite(v[0]) and math.isfinite(v[1]) else NAN,
        v[2],
    )


def _check(pos: Vec3, vel: Vec3, acc: Vec3, mask: int) -> OffboardRejection | None:
    if mask & M.FORCE_SET:
        return OffboardRejection("force setpoints are not supported")
    nothing = all(math.isnan(a) and math.isnan(b) and math.isnan(c) for a, b, c in zip(pos, vel, acc, strict=True))
    if nothing and mask & M.YAW_IGNORE and mask & M.YAW_RATE_IGNORE:
        return OffboardRejection("setpoint ignores every field")
    return None


def setpoint_from_local_ned(  # noqa: PLR0917 - mirrors the message fields
    frame: int,
    type_mask: int,
    pos: Vec3,
    vel: Vec3,
    acc: Vec3,
    yaw_rad: float,
    yaw_rate_radps: float,
    *,
    vehicle_pos: Vec3,
    vehicle_yaw_rad: float,
) -> Setpoint | OffboardRejection:
    """Decode a SET_POSITION_TARGET_LOCAL_NED into LOCAL_NED terms."""
    if frame not in LOCAL_FRAMES:
        return OffboardRejection(f"unsupported coordinate frame {frame}")
    p, ok_p = _pick(type_mask, (M.X_IGNORE, M.Y_IGNORE, M.Z_IGNORE), pos)
    v, ok_v = _pick(type_mask, (M.VX_IGNORE, M.VY_IGNORE, M.VZ_IGNORE), vel)
    a, ok_a = _pick(type_mask, (M.AX_IGNORE, M.AY_IGNORE, M.AZ_IGNORE), acc)
    y, r, ok_y = _yaw(type_mask, yaw_rad, yaw_rate_radps)
    if not (ok_p and ok_v and ok_a and ok_y):
        return OffboardRejection("non-finite value in a used field")
    bad = _check(p, v, a, type_mask)
    if bad is not None:
        return bad
    if frame in (MavFrame.LOCAL_OFFSET_NED, MavFrame.BODY_OFFSET_NED):
        if frame == MavFrame.BODY_OFFSET_NED:
            p = _rotate_yaw(p, vehicle_yaw_rad)
        p = (p[0] + vehicle_pos[0], p[1] + vehicle_pos[1], p[2] + vehicle_pos[2])
    if frame in (MavFrame.BODY_NED, MavFrame.BODY_OFFSET_NED):
        v = _rotate_yaw(v, vehicle_yaw_rad)
        a = _rotate_yaw(a, vehicle_yaw_rad)
    return Setpoint(pos=p, vel=v, acc=a, yaw_rad=y, yaw_rate_radps=r)


def setpoint_from_global_int(  # noqa: PLR0917 - mirrors the message fields
    frame: int,
    type_mask: int,
    lat_int: int,
    lon_int: int,
    alt_m: float,
    vel: Vec3,
    acc: Vec3,
    yaw_rad: float,
    yaw_rate_radps: float,
    *,
    projection: LocalProjection,
) -> Setpoint | OffboardRejection:
    """Decode a SET_POSITION_TARGET_GLOBAL_INT into LOCAL_NED terms."""
    if frame not in GLOBAL_FRAMES:
        return OffboardRejection(f"unsupported coordinate frame {frame}")
    ignore_xy = type_mask & M.X_IGNORE or type_mask & M.Y_IGNORE
    if not ignore_xy and (abs(lat_int) > 900_000_000 or abs(lon_int) > 1_800_000_000):
        return OffboardRejection("latitude/longitude out of range")
    home_alt = projection.origin.alt_amsl_m
    if type_mask & M.Z_IGNORE:
        down = NAN
    elif not math.isfinite(alt_m):
        return OffboardRejection("non-finite altitude")
    elif frame in (MavFrame.GLOBAL_RELATIVE_ALT_INT, MavFrame.GLOBAL_RELATIVE_ALT):
        down = -alt_m
    else:
        down = home_alt - alt_m
    if ignore_xy:
        north = east = NAN
    else:
        north, east, _ = projection.to_ned(GeoPoint(lat_int * 1e-7, lon_int * 1e-7, home_alt))
    v, ok_v = _pick(type_mask, (M.VX_IGNORE, M.VY_IGNORE, M.VZ_IGNORE), vel)
    a, ok_a = _pick(type_mask, (M.AX_IGNORE, M.AY_IGNORE, M.AZ_IGNORE), acc)
    y, r, ok_y = _yaw(type_mask, yaw_rad, yaw_rate_radps)
    if not (ok_v and ok_a and ok_y):
        return OffboardRejection("non-finite value in a used field")
    p = (north, east, down)
    bad = _check(p, v, a, type_mask)
    if bad is not None:
        return bad
    return Setpoint(pos=p, vel=v, acc=a, yaw_rad=y, yaw_rate_radps=r)


A = AttitudeTargetMask


@dataclass(frozen=True)
class AttitudeSetpoint:
    """An attitude (``q`` FRD -> NED, ``None``: rates only) or body rates, and a collective thrust 0..1."""

    q: tuple[float, float, float, float] | None
    body_rates_radps: tuple[float, float, float]
    thrust: float


def attitude_setpoint(  # noqa: PLR0911 - one return per check
    type_mask: int, q: tuple[float, float, float, float], rates: Vec3, thrust: float
) -> AttitudeSetpoint | OffboardRejection:
    """Decode a SET_ATTITUDE_TARGET (``q`` as ``[w, x, y, z]``)."""
    if type_mask & A.THRUST_BODY_SET:
        return OffboardRejection("thrust vectors (THRUST_BODY_SET) are not supported by a multicopter")
    use_att = not type_mask & A.ATTITUDE_IGNORE
    rate_bits = (A.BODY_ROLL_RATE_IGNORE, A.BODY_PITCH_RATE_IGNORE, A.BODY_YAW_RATE_IGNORE)
    use_rates = [not type_mask & bit for bit in rate_bits]
    if type_mask & A.THROTTLE_IGNORE:
        return OffboardRejection("a thrust is required (THROTTLE_IGNORE is set)")
    if not math.isfinite(thrust) or not 0.0 <= thrust <= 1.0:
        return OffboardRejection(f"thrust must be in [0, 1], got {thrust}")
    quat: tuple[float, float, float, float] | None = None
    if use_att:
        if not all(math.isfinite(v) for v in q):
            return OffboardRejection("non-finite attitude quaternion")
        norm = math.sqrt(sum(v * v for v in q))
        if not 0.9 <= norm <= 1.1:
            return OffboardRejection(f"attitude quaternion is not a unit quaternion (|q| = {norm:.3f})")
        w, x, y, z = (v / norm for v in q)
        quat = (w, x, y, z) if w >= 0.0 else (-w, -x, -y, -z)
    elif not any(use_rates):
        return OffboardRejection("setpoint ignores both the attitude and the body rates")
    body = tuple(r if used else 0.0 for r, used in zip(rates, use_rates, strict=True))
    if not all(math.isfinite(v) for v in body):
        return OffboardRejection("non-finite body rate")
    return AttitudeSetpoint(quat, (body[0], body[1], body[2]), thrust)
