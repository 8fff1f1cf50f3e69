"""Multicopter control cascade: position -> velocity -> attitude -> rate -> mixer.

The structure and the parameter names follow PX4 (``mc_pos_control``,
``mc_att_control``, ``mc_rate_control``, the quad-X control allocation), so the
gains are PX4 parameters. The outer two loops run at a lower rate than the inner
two (``outer_loop_divider``), as on PX4.

Conventions: NED world frame, FRD body frame, quaternions ``(w, x, y, z)`` body
-> NED, angles in radians, thrust normalised to the sum of the motors' maximum
(``0..1``). Everything is plain ``float`` arithmetic: this runs 250 times per
simulated second and must be cheap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

__all__ = [
    "ControlGains",
    "Mixer",
    "MotionLimits",
    "PositionController",
    "RateController",
    "Setpoint",
    "VelocityController",
    "attitude_rate_setpoint",
    "position_to_velocity",
    "quat_from_yaw",
    "sqrt_controller",
]

GRAVITY_MPS2 = 9.80665
NAN = math.nan

Quat = tuple[float, float, float, float]
Vec3 = tuple[float, float, float]


class _ParamLookup(Protocol):
    def __getitem__(self, name: str, /) -> float: ...


@dataclass(frozen=True)
class ControlGains:
    """Gains and limits of the whole cascade, read from the parameter table."""

    xy_p: float
    z_p: float
    xy_vel_p: float
    xy_vel_i: float
    z_vel_p: float
    z_vel_i: float
    roll_p: float
    pitch_p: float
    yaw_p: float
    roll_rate_pid: Vec3
    pitch_rate_pid: Vec3
    yaw_rate_pid: Vec3
    max_rates_radps: Vec3
    hover_thrust: float
    tilt_max_rad: float

    @classmethod
    def from_params(cls, p: _ParamLookup) -> ControlGains:
        """The gains from PX4's parameter names (the ArduCopter personality maps its own names onto these)."""
        return cls(
            xy_p=p["MPC_XY_P"],
            z_p=p["MPC_Z_P"],
            xy_vel_p=p["MPC_XY_VEL_P_ACC"],
            xy_vel_i=p["MPC_XY_VEL_I_ACC"],
            z_vel_p=p["MPC_Z_VEL_P_ACC"],
            z_vel_i=p["MPC_Z_VEL_I_ACC"],
            roll_p=p["MC_ROLL_P"],
            pitch_p=p["MC_PITCH_P"],
            yaw_p=p["MC_YAW_P"],
            roll_rate_pid=(p["MC_ROLLRATE_P"], p["MC_ROLLRATE_I"], p["MC_ROLLRATE_D"]),
            pitch_rate_pid=(p["MC_PITCHRATE_P"], p["MC_PITCHRATE_I"], p["MC_PITCHRATE_D"]),
            yaw_rate_pid=(p["MC_YAWRATE_P"], p["MC_YAWRATE_I"], 0.0),
            max_rates_radps=(
                math.radians(p["MC_ROLLRATE_MAX"]),
                math.radians(p["MC_PITCHRATE_MAX"]),
                math.radians(p["MC_YAWRATE_MAX"]),
            ),
            hover_thrust=p["MPC_THR_HOVER"],
            tilt_max_rad=math.radians(p["MPC_TILTMAX_AIR"]),
        )


@dataclass(frozen=True)
class MotionLimits:
    """Speed and acceleration limits of the current flight task."""

    speed_xy_mps: float
    speed_up_mps: float
    speed_down_mps: float
    acc_xy_mps2: float
    acc_up_mps2: float
    acc_down_mps2: float


class Setpoint:
    """A trajectory setpoint, per axis; NaN means "not controlled" (PX4 ``trajectory_setpoint``).

    Position wins over velocity, velocity over acceleration; an axis with none of
    them holds its velocity at zero. ``yaw_rad`` NaN with ``yaw_rate_radps`` NaN
    holds the current heading.
    """

    __slots__ = ("acc", "pos", "vel", "yaw_rad", "yaw_rate_radps")

    def __init__(
        self,
        pos: Vec3 = (NAN, NAN, NAN),
        vel: Vec3 = (NAN, NAN, NAN),
        acc: Vec3 = (NAN, NAN, NAN),
        yaw_rad: float = NAN,
        yaw_rate_radps: float = NAN,
    ) -> None:
        self.pos = pos
        self.vel = vel
        self.acc = acc
        self.yaw_rad = yaw_rad
        self.yaw_rate_radps = yaw_rate_radps

    def __repr__(self) -> str:
        return (
            f"Setpoint(pos={self.pos}, vel={self.vel}, acc={self.acc}, yaw_rad={self.yaw_rad}, "
            f"yaw_rate_radps={self.yaw_rate_radps})"
        )


def sqrt_controller(error: float, p: float, acc_max: float) -> float:
    """Speed towards a target ``error`` metres away: linear near it, braking-limited far away.

    ``p * error`` inside ``acc / p^2``, ``sqrt(2 acc (|error| - acc / 2p^2))`` beyond,
    so the commanded speed can always be stopped from at ``acc_max``.
    """
    if p <= 0.0:
        return math.copysign(math.sqrt(2.0 * acc_max * abs(error)), error)
    linear_dist = acc_max / (p * p)
    dist = abs(error)
    if dist <= linear_dist:
        return p * error
    return math.copysign(math.sqrt(2.0 * acc_max * (dist - 0.5 * linear_dist)), error)


def position_to_velocity(sp: Setpoint, pos: Vec3, gains: ControlGains, limits: MotionLimits) -> Vec3:
    """Velocity setpoint (NED, m/s) from the position part of ``sp`` plus its velocity feed-forward."""
    px, py, pz = sp.pos
    fx, fy, fz = sp.vel
    isnan = math.isnan
    vx = 0.0 if isnan(fx) else fx
    vy = 0.0 if isnan(fy) else fy
    vz = 0.0 if isnan(fz) else fz
    if not isnan(px) and not isnan(py):
        ex, ey = px - pos[0], py - pos[1]
        dist = math.hypot(ex, ey)
        if dist > 1e-9:
            speed = sqrt_controller(dist, gains.xy_p, limits.acc_xy_mps2)
            vx += speed * ex / dist
            vy += speed * ey / dist
    else:
        if not isnan(px):
            vx += sqrt_controller(px - pos[0], gains.xy_p, limits.acc_xy_mps2)
        if not isnan(py):
            vy += sqrt_controller(py - pos[1], gains.xy_p, limits.acc_xy_mps2)
    if not isnan(pz):
        ez = pz - pos[2]
        acc = limits.acc_down_mps2 if ez > 0 else limits.acc_up_mps2
        vz += sqrt_controller(ez, gains.z_p, acc)
    speed_xy = math.hypot(vx, vy)
    if speed_xy > limits.speed_xy_mps:
        scale = limits.speed_xy_mps / speed_xy
        vx *= scale
        vy *= scale
    vz = min(limits.speed_down_mps, max(-limits.speed_up_mps, vz))
    return vx, vy, vz


class PositionController:
    """Position and velocity loops with a slew-limited velocity setpoint.

    The velocity setpoint from :func:`position_to_velocity` is limited in change
    by the task's acceleration limits, and that change is fed forward as
    acceleration (PX4's trajectory feed-forward); with the square-root braking
    curve this flies to a point without overshoot.
    """

    __slots__ = ("_vel_ctrl", "_vsp")

    def __init__(self) -> None:
        self._vel_ctrl = VelocityController()
        self._vsp: Vec3 = (0.0, 0.0, 0.0)

    def reset(self, vel: Vec3) -> None:
        """Start from the present velocity with empty integrators (on takeoff, after idle)."""
        self._vel_ctrl.reset()
        self._vsp = vel

    @property
    def velocity_setpoint(self) -> Vec3:
        return self._vsp

    def update(
        self,
        sp: Setpoint,
        pos: Vec3,
        vel: Vec3,
        yaw_sp_rad: float,
        *,
        dt_s: float,
        gains: ControlGains,
        limits: MotionLimits,
    ) -> tuple[Quat, float]:
        """Attitude setpoint and collective thrust for setpoint ``sp``."""
        target = position_to_velocity(sp, pos, gains, limits)
        px, py, pz = self._vsp
        dvx, dvy = target[0] - px, target[1] - py
        step_xy = limits.acc_xy_mps2 * dt_s
        mag = math.hypot(dvx, dvy)
        if mag > step_xy:
            dvx *= step_xy / mag
            dvy *= step_xy / mag
        dvz = min(limits.acc_down_mps2 * dt_s, max(-limits.acc_up_mps2 * dt_s, target[2] - pz))
        self._vsp = (px + dvx, py + dvy, pz + dvz)
        acc_add = (dvx / dt_s, dvy / dt_s, dvz / dt_s)
        q_sp, thrust, _ = self._vel_ctrl.update(
            self._vsp, vel, sp.acc, yaw_sp_rad, dt_s=dt_s, gains=gains, acc_add=acc_add
        )
        return q_sp, thrust


def quat_from_yaw(yaw_rad: float) -> Quat:
    return math.cos(0.5 * yaw_rad), 0.0, 0.0, math.sin(0.5 * yaw_rad)


def _quat_from_rotation(  # noqa: PLR0917 - the nine matrix entries
    r00: float, r01: float, r02: float, r10: float, r11: float, r12: float, r20: float, r21: float, r22: float
) -> Quat:
    trace = r00 + r11 + r22
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = (0.25 * s, (r21 - r12) / s, (r02 - r20) / s, (r10 - r01) / s)
    elif r00 > r11 and r00 > r22:
        s = 2.0 * math.sqrt(1.0 + r00 - r11 - r22)
        q = ((r21 - r12) / s, 0.25 * s, (r01 + r10) / s, (r02 + r20) / s)
    elif r11 > r22:
        s = 2.0 * math.sqrt(1.0 + r11 - r00 - r22)
        q = ((r02 - r20) / s, (r01 + r10) / s, 0.25 * s, (r12 + r21) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + r22 - r00 - r11)
        q = ((r10 - r01) / s, (r02 + r20) / s, (r12 + r21) / s, 0.25 * s)
    return q if q[0] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])


def thrust_to_attitude(acc_ned: Vec3, yaw_rad: float, gains: ControlGains) -> tuple[Quat, float]:
    """Attitude setpoint and normalised collective thrust that produce ``acc_ned`` (m/s^2).

    The specific force ``a - g`` gives the body z axis; the tilt is limited to
    ``MPC_TILTMAX_AIR`` by shrinking the horizontal part, and the thrust never
    drops below 10 % of hover (the vehicle stays controllable).
    """
    fx, fy, fz = acc_ned[0], acc_ned[1], acc_ned[2] - GRAVITY_MPS2
    fz = min(fz, -0.1 * GRAVITY_MPS2)
    horizontal = math.hypot(fx, fy)
    max_horizontal = -fz * math.tan(gains.tilt_max_rad)
    if horizontal > max_horizontal:
        scale = max_horizontal / horizontal
        fx *= scale
        fy *= scale
    norm = math.sqrt(fx * fx + fy * fy + fz * fz)
    zx, zy, zz = -fx / norm, -fy / norm, -fz / norm
    # body x from the desired heading, orthogonal to body z
    yc_x, yc_y = -math.sin(yaw_rad), math.cos(yaw_rad)
    xx, xy, xz = yc_y * zz, -yc_x * zz, yc_x * zy - yc_y * zx
    n = math.sqrt(xx * xx + xy * xy + xz * xz)
    xx, xy, xz = xx / n, xy / n, xz / n
    yx, yy, yz = zy * xz - zz * xy, zz * xx - zx * xz, zx * xy - zy * xx
    q = _quat_from_rotation(xx, yx, zx, xy, yy, zy, xz, yz, zz)
    thrust = norm / GRAVITY_MPS2 * gains.hover_thrust
    return q, thrust


class VelocityController:
    """PI velocity control (NED) producing an attitude setpoint and a collective thrust."""

    __slots__ = ("_ix", "_iy", "_iz")

    XY_INTEGRAL_LIMIT_MPS2 = 3.0
    Z_INTEGRAL_LIMIT_MPS2 = 6.0

    def __init__(self) -> None:
        self._ix = self._iy = self._iz = 0.0

    def reset(self) -> None:
        self._ix = self._iy = self._iz = 0.0

    def update(
        self,
        vel_sp: Vec3,
        vel: Vec3,
        acc_ff: Vec3,
        yaw_sp_rad: float,
        *,
        dt_s: float,
        gains: ControlGains,
        acc_add: Vec3 = (0.0, 0.0, 0.0),
    ) -> tuple[Quat, float, Vec3]:
        """``(attitude_sp, thrust, acc_sp)``.

        ``acc_add`` is the trajectory's acceleration, added as feed-forward; a
        finite ``acc_ff`` axis (an offboard acceleration setpoint) replaces that
        axis' feedback entirely.
        """
        ex, ey, ez = vel_sp[0] - vel[0], vel_sp[1] - vel[1], vel_sp[2] - vel[2]
        self._ix = _clamp(self._ix + ex * dt_s, self.XY_INTEGRAL_LIMIT_MPS2 / max(gains.xy_vel_i, 1e-6))
        self._iy = _clamp(self._iy + ey * dt_s, self.XY_INTEGRAL_LIMIT_MPS2 / max(gains.xy_vel_i, 1e-6))
        self._iz = _clamp(self._iz + ez * dt_s, self.Z_INTEGRAL_LIMIT_MPS2 / max(gains.z_vel_i, 1e-6))
        ax = gains.xy_vel_p * ex + gains.xy_vel_i * self._ix + acc_add[0]
        ay = gains.xy_vel_p * ey + gains.xy_vel_i * self._iy + acc_add[1]
        az = gains.z_vel_p * ez + gains.z_vel_i * self._iz + acc_add[2]
        if not math.isnan(acc_ff[0]):
            ax = acc_ff[0]
            self._ix = 0.0
        if not math.isnan(acc_ff[1]):
            ay = acc_ff[1]
            self._iy = 0.0
        if not math.isnan(acc_ff[2]):
            az = acc_ff[2]
        q, thrust = thrust_to_attitude((ax, ay, az), yaw_sp_rad, gains)
        return q, thrust, (ax, ay, az)


def _qmul(a: Quat, b: Quat) -> Quat:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def _qconj(q: Quat) -> Quat:
    return (q[0], -q[1], -q[2], -q[3])


def _body_z(q: Quat) -> Vec3:
    """The body z axis expressed in the world frame (third column of the rotation matrix)."""
    w, x, y, z = q
    return (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))


def _shortest_rotation(u: Vec3, v: Vec3) -> Quat | None:
    """Quaternion of the shortest rotation taking unit vector ``u`` onto ``v``; None when they oppose."""
    dot = u[0] * v[0] + u[1] * v[1] + u[2] * v[2]
    if dot < -1.0 + 1e-6:
        return None
    cx, cy, cz = u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]
    w = 1.0 + dot
    n = math.sqrt(w * w + cx * cx + cy * cy + cz * cz)
    return (w / n, cx / n, cy / n, cz / n)


def attitude_rate_setpoint(q: Quat, q_sp: Quat, yaw_rate_ff: float, gains: ControlGains) -> Vec3:  # noqa: PLR0915
    """Body rate setpoint (FRD, rad/s) from the attitude error, with roll and pitch first.

    PX4's multicopter attitude law (Brescianini, Hehn, D'Andrea 2013, "Nonlinear quadrocopter
    attitude control"): the thrust axis is aligned by the shortest rotation ("reduced
    attitude"), and only a fraction ``MC_YAW_P / mean(MC_ROLL_P, MC_PITCH_P)`` of the remaining
    heading error is added. A large heading change therefore turns the vehicle about its thrust
    axis instead of rolling it over on the way (a full-quaternion error would take the shortest
    path in SO(3), tilting a quadrotor tens of degrees during a 180 degree yaw).
    The error ``2 * imag(q^-1 q_d)`` times the roll/pitch gain gives the rates, clamped to the
    ``MC_*RATE_MAX`` limits; a yaw-rate feed-forward is a rotation about the world z axis.

    This runs every physics step: the quaternion products of :func:`_qmul`, :func:`_body_z` and
    :func:`_shortest_rotation` are written out here with the same operations in the same order
    (the result is bit for bit theirs, ``tests/unit/sitl`` compares the two).
    """
    rp_gain = 0.5 * (gains.roll_p + gains.pitch_p)
    if rp_gain > 0.0:
        yaw_w = gains.yaw_p / rp_gain
        yaw_w = yaw_w if yaw_w > 0.0 else 0.0
        yaw_w = yaw_w if yaw_w < 1.0 else 1.0
    else:
        yaw_w = 1.0
    w, x, y, z = q
    sw, sx, sy, sz = q_sp
    # body z axes of q and q_sp in the world frame
    u0, u1, u2 = 2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)
    v0, v1, v2 = 2.0 * (sx * sz + sw * sy), 2.0 * (sy * sz - sw * sx), 1.0 - 2.0 * (sx * sx + sy * sy)
    dot = u0 * v0 + u1 * v1 + u2 * v2
    # world-frame rotation of the thrust axis, applied to the current attitude; when the thrust
    # axes are exactly opposed there is no preferred path and the full attitude is used
    if dot < -1.0 + 1e-6:
        rw, rx, ry, rz = sw, sx, sy, sz
    else:
        cx, cy, cz = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
        cw = 1.0 + dot
        n = math.sqrt(cw * cw + cx * cx + cy * cy + cz * cz)
        aw, ax, ay, az = cw / n, cx / n, cy / n, cz / n
        rw = aw * w - ax * x - ay * y - az * z
        rx = aw * x + ax * w + ay * z - az * y
        ry = aw * y - ax * z + ay * w + az * x
        rz = aw * z + ax * y - ay * x + az * w
    # the remaining rotation about the thrust axis (conj(q_red) * q_sp), scaled by the yaw weight
    aw, ax, ay, az = rw, -rx, -ry, -rz
    mw = aw * sw - ax * sx - ay * sy - az * sz
    mz = aw * sz + ax * sy - ay * sx + az * sw
    if mw < 0.0:
        mw, mz = -mw, -mz
    mw = mw if mw > -1.0 else -1.0
    mw = mw if mw < 1.0 else 1.0
    mz = mz if mz > -1.0 else -1.0
    mz = mz if mz < 1.0 else 1.0
    half = yaw_w * math.acos(mw)
    half_z = yaw_w * math.asin(mz)
    bw, bz = math.cos(half), math.sin(half_z)
    # q_d = q_red * (bw, 0, 0, bz)
    dw = rw * bw - rx * 0.0 - ry * 0.0 - rz * bz
    dx = rw * 0.0 + rx * bw + ry * bz - rz * 0.0
    dy = rw * 0.0 - rx * bz + ry * bw + rz * 0.0
    dz = rw * bz + rx * 0.0 - ry * 0.0 + rz * bw
    # error conj(q) * q_d
    aw, ax, ay, az = w, -x, -y, -z
    ew = aw * dw - ax * dx - ay * dy - az * dz
    ex = aw * dx + ax * dw + ay * dz - az * dy
    ey = aw * dy - ax * dz + ay * dw + az * dx
    ez = aw * dz + ax * dy - ay * dx + az * dw
    if ew < 0.0:
        ex, ey, ez = -ex, -ey, -ez
    mr, mp, my = gains.max_rates_radps
    p = 2.0 * rp_gain * ex
    qr = 2.0 * rp_gain * ey
    r = 2.0 * rp_gain * ez
    if not math.isnan(yaw_rate_ff):
        # a yaw rate about the world z axis, in body axes: the world z axis seen from the body
        p += 2.0 * (x * z - w * y) * yaw_rate_ff
        qr += 2.0 * (y * z + w * x) * yaw_rate_ff
        r += (1.0 - 2.0 * (x * x + y * y)) * yaw_rate_ff
    # clamp to the rate limits (written out: this runs every step)
    p = mr if p > mr else (-mr if p < -mr else p)
    qr = mp if qr > mp else (-mp if qr < -mp else qr)
    r = my if r > my else (-my if r < -my else r)
    return p, qr, r


def attitude_rate_setpoint_reference(q: Quat, q_sp: Quat, yaw_rate_ff: float, gains: ControlGains) -> Vec3:
    """:func:`attitude_rate_setpoint` written with the quaternion helpers (the readable form; tests compare)."""
    rp_gain = 0.5 * (gains.roll_p + gains.pitch_p)
    yaw_w = min(1.0, max(0.0, gains.yaw_p / rp_gain)) if rp_gain > 0.0 else 1.0
    reduced = _shortest_rotation(_body_z(q), _body_z(q_sp))
    # world-frame rotation of the thrust axis, applied to the current attitude; when the thrust
    # axes are exactly opposed there is no preferred path and the full attitude is used
    q_red = q_sp if reduced is None else _qmul(reduced, q)
    # the remaining rotation about the thrust axis, scaled by the yaw weight
    mw, _mx, _my, mz = _qmul(_qconj(q_red), q_sp)
    if mw < 0.0:
        mw, mz = -mw, -mz
    mw = min(1.0, max(-1.0, mw))
    mz = min(1.0, max(-1.0, mz))
    half = yaw_w * math.acos(mw)
    half_z = yaw_w * math.asin(mz)
    q_d = _qmul(q_red, (math.cos(half), 0.0, 0.0, math.sin(half_z)))
    ew, ex, ey, ez = _qmul(_qconj(q), q_d)
    if ew < 0.0:
        ex, ey, ez = -ex, -ey, -ez
    mr, mp, my = gains.max_rates_radps
    p = 2.0 * rp_gain * ex
    qr = 2.0 * rp_gain * ey
    r = 2.0 * rp_gain * ez
    if not math.isnan(yaw_rate_ff):
        # a yaw rate about the world z axis, in body axes: the world z axis seen from the body
        w, x, y, z = q
        p += 2.0 * (x * z - w * y) * yaw_rate_ff
        qr += 2.0 * (y * z + w * x) * yaw_rate_ff
        r += (1.0 - 2.0 * (x * x + y * y)) * yaw_rate_ff
    # clamp to the rate limits (written out: this runs every step)
    p = mr if p > mr else (-mr if p < -mr else p)
    qr = mp if qr > mp else (-mp if qr < -mp else qr)
    r = my if r > my else (-my if r < -my else r)
    return p, qr, r


class RateController:
    """PID on body rates (derivative on measurement) producing normalised torques."""

    __slots__ = ("_ip", "_iq", "_ir", "_prev")

    INTEGRAL_LIMIT = 0.3

    def __init__(self) -> None:
        self._ip = self._iq = self._ir = 0.0
        self._prev: Vec3 | None = None

    def reset(self) -> None:
        self._ip = self._iq = self._ir = 0.0
        self._prev = None

    def update(self, rate_sp: Vec3, rates: Vec3, dt_s: float, gains: ControlGains, *, integrate: bool) -> Vec3:
        ep, eq, er = rate_sp[0] - rates[0], rate_sp[1] - rates[1], rate_sp[2] - rates[2]
        kp_r, ki_r, kd_r = gains.roll_rate_pid
        kp_p, ki_p, kd_p = gains.pitch_rate_pid
        kp_y, ki_y, _ = gains.yaw_rate_pid
        if integrate:
            lim = self.INTEGRAL_LIMIT
            if ki_r > 0.0:
                v, m = self._ip + ep * dt_s, lim / ki_r
                self._ip = m if v > m else (-m if v < -m else v)
            if ki_p > 0.0:
                v, m = self._iq + eq * dt_s, lim / ki_p
                self._iq = m if v > m else (-m if v < -m else v)
            if ki_y > 0.0:
                v, m = self._ir + er * dt_s, lim / ki_y
                self._ir = m if v > m else (-m if v < -m else v)
        prev = self._prev if self._prev is not None else rates
        self._prev = rates
        dp = (rates[0] - prev[0]) / dt_s
        dq = (rates[1] - prev[1]) / dt_s
        return (
            kp_r * ep + ki_r * self._ip - kd_r * dp,
            kp_p * eq + ki_p * self._iq - kd_p * dq,
            kp_y * er + ki_y * self._ir,
        )


class Mixer:
    """Quad-X allocation in PX4 motor order (= JSBSim F450 engine order).

    Motor 0 front right, 1 aft left, 2 front left, 3 aft right. Torque commands
    are normalised so that 1 moves each motor by ``authority`` of its maximum
    thrust. Roll and pitch have priority over collective thrust, yaw comes last
    (PX4's desaturation order). Output: duty cycles 0..1 after the thrust-curve
    inversion (``thrust = duty ** exponent``) and battery-voltage compensation.
    """

    ROLL = (-1.0, 1.0, 1.0, -1.0)
    PITCH = (1.0, -1.0, 1.0, -1.0)
    YAW = (1.0, 1.0, -1.0, -1.0)

    def __init__(self, thrust_curve_exponent: float, idle_thrust: float, authority: float = 0.25) -> None:
        self._inv_exp = 1.0 / thrust_curve_exponent
        self.idle_thrust = idle_thrust
        self.authority = authority

    def mix(self, thrust: float, torque: Vec3, voltage_scale: float) -> tuple[float, float, float, float]:
        a = self.authority
        idle = self.idle_thrust
        roll, pitch, yaw = torque[0] * a, torque[1] * a, torque[2] * a
        # roll/pitch part per motor (ROLL/PITCH signs written out: this runs every step)
        r0, r1, r2, r3 = -roll + pitch, roll - pitch, roll + pitch, -roll - pitch
        # min() / max() written out (first extreme wins, as the builtins): this runs every step
        lo = r0
        lo = r1 if r1 < lo else lo
        lo = r2 if r2 < lo else lo
        lo = r3 if r3 < lo else lo
        hi = r0
        hi = r1 if r1 > hi else hi
        hi = r2 if r2 > hi else hi
        hi = r3 if r3 > hi else hi
        spread = hi - lo
        if spread > 1.0 - idle:
            scale = (1.0 - idle) / spread
            r0, r1, r2, r3 = r0 * scale, r1 * scale, r2 * scale, r3 * scale
            lo, hi = lo * scale, hi * scale
        low = idle - lo
        thrust = low if low > thrust else thrust
        high = 1.0 - hi
        thrust = high if high < thrust else thrust
        # yaw (YAW = +, +, -, -): the largest magnitude up to the request that keeps every motor in range
        b0, b1, b2, b3 = thrust + r0, thrust + r1, thrust + r2, thrust + r3
        if yaw > 0.0:
            for c in (1.0 - b0, 1.0 - b1, b2 - idle, b3 - idle):
                yaw = c if c < yaw else yaw
            yaw = 0.0 if yaw < 0.0 else yaw
        elif yaw < 0.0:
            y = -yaw
            for c in (b0 - idle, b1 - idle, 1.0 - b2, 1.0 - b3):
                y = c if c < y else y
            yaw = -y
            yaw = 0.0 if yaw > 0.0 else yaw
        inv = self._inv_exp
        o0, o1, o2, o3 = b0 + yaw, b1 + yaw, b2 - yaw, b3 - yaw
        o0 = 1.0 if o0 > 1.0 else (idle if o0 < idle else o0)
        o1 = 1.0 if o1 > 1.0 else (idle if o1 < idle else o1)
        o2 = 1.0 if o2 > 1.0 else (idle if o2 < idle else o2)
        o3 = 1.0 if o3 > 1.0 else (idle if o3 < idle else o3)
        d0, d1, d2, d3 = (
            o0**inv * voltage_scale,
            o1**inv * voltage_scale,
            o2**inv * voltage_scale,
            o3**inv * voltage_scale,
        )
        return (
            1.0 if d0 > 1.0 else d0,
            1.0 if d1 > 1.0 else d1,
            1.0 if d2 > 1.0 else d2,
            1.0 if d3 > 1.0 else d3,
        )

    def idle(self, voltage_scale: float) -> tuple[float, float, float, float]:
        d = min(1.0, self.idle_thrust**self._inv_exp * voltage_scale)
        return d, d, d, d


def _clamp(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))
