"""The autopilot's own state estimate, in ROS conventions, with its time mapped onto ours (pure).

On a real vehicle the only pose there is comes from the autopilot's estimator over MAVLink. This module
turns those messages into :class:`PoseEstimate` records (``map`` ENU, ``base_link`` FLU, covariances)
and keeps the two things that make them usable and safe:

* :class:`TimeSync` maps the autopilot's clock (``time_usec`` / ``time_boot_ms``: time since *its* boot)
  onto the companion's clock (ROS time: simulated time under ``/clock``, wall time on a real vehicle).
  With TIMESYNC (what PX4, ArduPilot and MAVROS use): the companion sends ``ts1`` = its time, the
  autopilot answers ``tc1`` = its time; with the round trip ``rtt = now - ts1`` the offset is
  ``(ts1 + now) / 2 - tc1``, exact when the two legs take the same time, and off by at most ``rtt / 2``
  otherwise. Of the last ``window`` answers the one with the smallest round trip wins, so a delayed
  or reordered answer (a lossy radio) does not move the estimate. Before the first answer (or from an
  autopilot that never answers) the offset is the lower envelope of ``arrival - stamp`` over the last
  ``window`` messages: the true offset plus the smallest latency seen, so stamps come out at most that
  latency late. Which of the two is in force is reported (``method``).
* :class:`EstimateWatchdog` says whether the estimate can be flown on: fresh (a valid estimate arrived
  within ``timeout_s``, judged on the caller's clock with a wall-clock floor as the controller's own
  timeouts are) and finite. A NaN/inf estimate makes it *invalid* at once, with the reason.

Frames go through :mod:`uav_common.frames` only.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from uav_autonomy.errors import InvalidInputError
from uav_common.frames import (
    covariance_urt21,
    frd_to_flu,
    ned_to_enu,
    pose_covariance_ned_to_enu,
    quat_ned_frd_to_enu_flu,
    twist_covariance_frd_to_flu,
)
from uav_common.rotations import quat_conjugate, quat_multiply, rotate

__all__ = [
    "AssumedAccuracy",
    "AutopilotOdometryConfig",
    "EstimateState",
    "EstimateWatchdog",
    "PoseEstimate",
    "PositionTarget",
    "TimeSync",
    "estimate_from_local_position",
    "estimate_from_odometry",
    "target_from_position_target",
]

Vec3 = tuple[float, float, float]
FloatArray = npt.NDArray[np.float64]
Vec4 = tuple[float, float, float, float]

# MAV_FRAME values of ODOMETRY.frame_id whose axes are North-East-Down from the local origin.
_NED_WORLD_FRAMES = {1: "LOCAL_NED", 14: "MOCAP_NED", 16: "VISION_NED", 18: "ESTIM_NED"}
_MAV_FRAME_BODY_FRD = 12
_MAV_FRAME_BODY_NED = 8  # deprecated "body, NED-aligned": MAVLink's older name for body FRD
_ODOMETRY_FAILED = -1

SOURCE_ODOMETRY = "ODOMETRY"
SOURCE_LOCAL_POSITION = "LOCAL_POSITION_NED+ATTITUDE_QUATERNION"


@dataclass(frozen=True)
class AssumedAccuracy:
    """Standard deviations used when the autopilot gives no covariance (LOCAL_POSITION_NED has none; an
    ODOMETRY with NaN covariance says "unknown"). Defaults: a GPS-grade EKF."""

    position_sigma_m: float = 1.0
    attitude_sigma_rad: float = 0.02
    velocity_sigma_mps: float = 0.2
    rate_sigma_radps: float = 0.05

    def __post_init__(self) -> None:
        for name in ("position_sigma_m", "attitude_sigma_rad", "velocity_sigma_mps", "rate_sigma_radps"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f"{name} must be a finite number > 0, got {value}"
                raise ValueError(msg)

    def pose_covariance(self) -> FloatArray:
        return np.diag([self.position_sigma_m**2] * 3 + [self.attitude_sigma_rad**2] * 3)

    def twist_covariance(self) -> FloatArray:
        return np.diag([self.velocity_sigma_mps**2] * 3 + [self.rate_sigma_radps**2] * 3)


@dataclass(frozen=True)
class AutopilotOdometryConfig:
    """Settings of the ``autopilot_odometry`` node (section ``autopilot_odometry`` of ``config/autonomy.yaml``)."""

    connection_url: str = "udpin:0.0.0.0:14542"
    source_system: int = 1
    source_component: int = 192
    target_system: int = 1
    target_component: int = 1
    #: ``auto``: ODOMETRY while the autopilot sends it, else LOCAL_POSITION_NED + ATTITUDE_QUATERNION;
    #: ``odometry`` or ``local_position``: only that.
    source: str = "auto"
    #: Ask the autopilot for ODOMETRY at this rate on this link (MAV_CMD_SET_MESSAGE_INTERVAL; 0 = leave it).
    odometry_rate_hz: float = 50.0
    #: ``auto``: without an ODOMETRY for this long, fall back to LOCAL_POSITION_NED + ATTITUDE_QUATERNION.
    odometry_fallback_s: float = 1.0
    #: How the autopilot's stamps become ROS time: ``timesync`` (a real vehicle: TIMESYNC, else the arrival
    #: envelope) or ``shared`` (the autopilot's clock *is* ROS time: the SITL, whose time since boot is the
    #: simulation time ``/clock`` carries; TIMESYNC still runs and its offset is reported, not used).
    time_sync: str = "timesync"
    #: TIMESYNC requests per second (0 = map the autopilot's time by arrival only).
    timesync_rate_hz: float = 2.0
    timesync_window: int = 20
    #: Stale: no fresh estimate this long (and ``wall_floor_s`` wall seconds).
    stale_timeout_s: float = 1.0
    wall_floor_s: float = 0.5
    reconnect_after_s: float = 5.0
    status_rate_hz: float = 2.0
    map_frame: str = "map"
    odom_frame: str = "odom"
    base_frame: str = "base_link"
    assumed_accuracy: AssumedAccuracy = field(default_factory=AssumedAccuracy)

    def __post_init__(self) -> None:
        if self.source not in ("auto", "odometry", "local_position"):
            msg = f"source must be auto, odometry or local_position, got {self.source!r}"
            raise ValueError(msg)
        if self.time_sync not in ("timesync", "shared"):
            msg = f"time_sync must be timesync (a real autopilot) or shared (the SITL), got {self.time_sync!r}"
            raise ValueError(msg)
        for name in ("odometry_rate_hz", "timesync_rate_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1000.0):
                msg = f"{name} must be in [0, 1000] Hz (0 = off), got {value}"
                raise ValueError(msg)
        for name in ("odometry_fallback_s", "stale_timeout_s", "reconnect_after_s", "status_rate_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f"{name} must be a finite number > 0, got {value}"
                raise ValueError(msg)
        if not (math.isfinite(self.wall_floor_s) and 0.0 <= self.wall_floor_s <= 60.0):
            msg = f"wall_floor_s must be in [0, 60] s, got {self.wall_floor_s}"
            raise ValueError(msg)
        if self.timesync_window < 1:
            msg = f"timesync_window must be >= 1, got {self.timesync_window}"
            raise ValueError(msg)
        frames = (self.map_frame, self.odom_frame, self.base_frame)
        if len(set(frames)) != 3 or not all(frames):
            msg = f"map_frame, odom_frame and base_frame must be three different names, got {frames}"
            raise ValueError(msg)


@dataclass(frozen=True)
class PoseEstimate:
    """One estimate of the vehicle's state in ROS conventions.

    Attributes:
        t_autopilot_s: when it was valid, on the autopilot's clock (seconds since its boot).
        position_enu_m: ``base_link`` in ``map`` (ENU, origin = home).
        q_enu_flu_wxyz: attitude of the FLU body in ENU, ``[w, x, y, z]``.
        velocity_flu_mps, angular_flu_radps: twist in ``base_link`` (nav_msgs/Odometry's convention).
        pose_covariance, twist_covariance: 6x6 row-major (36 values), in those frames.
        covariance_from_autopilot: False when :class:`AssumedAccuracy` filled them in.
        source: which messages it came from (:data:`SOURCE_ODOMETRY` or :data:`SOURCE_LOCAL_POSITION`).
    """

    t_autopilot_s: float
    position_enu_m: Vec3
    q_enu_flu_wxyz: Vec4
    velocity_flu_mps: Vec3
    angular_flu_radps: Vec3
    pose_covariance: tuple[float, ...]
    twist_covariance: tuple[float, ...]
    covariance_from_autopilot: bool
    source: str

    @property
    def yaw_enu_rad(self) -> float:
        w, x, y, z = self.q_enu_flu_wxyz
        return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def _vec3(values: FloatArray) -> Vec3:
    return (float(values[0]), float(values[1]), float(values[2]))


def _finite(name: str, values: Sequence[float]) -> None:
    if not all(math.isfinite(float(v)) for v in values):
        msg = f"{name} is not finite: {[float(v) for v in values]}"
        raise InvalidInputError(msg)


def _attitude(q_ned_frd_wxyz: Sequence[float]) -> FloatArray:
    _finite("attitude quaternion", q_ned_frd_wxyz)
    norm = math.sqrt(sum(float(v) * float(v) for v in q_ned_frd_wxyz))
    if not 0.5 < norm < 1.5:
        msg = f"attitude quaternion {list(q_ned_frd_wxyz)} is not a rotation (norm {norm:.3f})"
        raise InvalidInputError(msg)
    return quat_ned_frd_to_enu_flu(q_ned_frd_wxyz)


def _twist(velocity: FloatArray, rates_frd: Sequence[float]) -> tuple[Vec3, Vec3, bool]:
    """Velocity (already FLU) and body rates; a non-finite part becomes 0 with an "unknown" flag."""
    known = bool(np.isfinite(velocity).all()) and all(math.isfinite(float(r)) for r in rates_frd)
    if not known:
        return (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), False
    return _vec3(velocity), _vec3(frd_to_flu(rates_frd)), True


def _flat(matrix: FloatArray) -> tuple[float, ...]:
    return tuple(float(v) for v in np.asarray(matrix, dtype=np.float64).reshape(36))


@functools.lru_cache(maxsize=8)
def _assumed(assumed: AssumedAccuracy) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The assumed pose and twist covariances, flat (computed once per setting: this runs at 50 Hz)."""
    return _flat(assumed.pose_covariance()), _flat(assumed.twist_covariance())


_UNKNOWN_TWIST = tuple(float(v) for v in np.diag([1e6] * 6).reshape(36))


def estimate_from_odometry(
    time_usec: int,
    *,
    frame_id: int,
    child_frame_id: int,
    position_ned_m: Sequence[float],
    q_ned_frd_wxyz: Sequence[float],
    velocity_child_mps: Sequence[float],
    rates_frd_radps: Sequence[float],
    pose_covariance_urt: Sequence[float],
    velocity_covariance_urt: Sequence[float],
    quality: int,
    assumed: AssumedAccuracy,
) -> PoseEstimate:
    """A MAVLink ODOMETRY (#331) as a :class:`PoseEstimate`.

    Raises:
        InvalidInputError: NaN/inf position or attitude, quality -1 ("odometry has failed"), a frame that is
            not NED from the local origin, a child frame other than body FRD, or a broken covariance.
    """
    if quality == _ODOMETRY_FAILED:
        msg = "ODOMETRY quality -1: the autopilot says its odometry has failed"
        raise InvalidInputError(msg)
    if frame_id not in _NED_WORLD_FRAMES:
        msg = f"ODOMETRY frame_id {frame_id} is not a local NED frame ({sorted(_NED_WORLD_FRAMES)})"
        raise InvalidInputError(msg)
    _finite("ODOMETRY position", position_ned_m)
    q = _attitude(q_ned_frd_wxyz)
    velocity = np.asarray(velocity_child_mps, dtype=np.float64)
    if child_frame_id in (_MAV_FRAME_BODY_FRD, _MAV_FRAME_BODY_NED):
        velocity = frd_to_flu(velocity)
    elif child_frame_id in _NED_WORLD_FRAMES:  # world velocity: into the body (FLU) frame
        velocity = rotate(quat_conjugate(q), ned_to_enu(velocity))
    else:
        msg = f"ODOMETRY child_frame_id {child_frame_id} is neither body FRD nor local NED"
        raise InvalidInputError(msg)
    v, w, twist_known = _twist(velocity, rates_frd_radps)
    try:
        pose_cov = covariance_urt21(pose_covariance_urt)
        twist_cov = covariance_urt21(velocity_covariance_urt)
    except ValueError as err:
        msg = f"ODOMETRY covariance: {err}"
        raise InvalidInputError(msg) from err
    from_autopilot = pose_cov is not None
    assumed_pose, assumed_twist = _assumed(assumed)
    pose = _flat(pose_covariance_ned_to_enu(pose_cov)) if pose_cov is not None else assumed_pose
    if not twist_known:
        twist: tuple[float, ...] = _UNKNOWN_TWIST
    elif twist_cov is not None and child_frame_id in (_MAV_FRAME_BODY_FRD, _MAV_FRAME_BODY_NED):
        twist = _flat(twist_covariance_frd_to_flu(twist_cov))
    else:
        twist = assumed_twist
    p = ned_to_enu(position_ned_m)
    return PoseEstimate(
        t_autopilot_s=time_usec * 1e-6,
        position_enu_m=_vec3(p),
        q_enu_flu_wxyz=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
        velocity_flu_mps=v,
        angular_flu_radps=w,
        pose_covariance=pose,
        twist_covariance=twist,
        covariance_from_autopilot=from_autopilot,
        source=SOURCE_ODOMETRY,
    )


def estimate_from_local_position(
    time_boot_ms: int,
    position_ned_m: Sequence[float],
    *,
    velocity_ned_mps: Sequence[float],
    q_ned_frd_wxyz: Sequence[float],
    rates_frd_radps: Sequence[float],
    assumed: AssumedAccuracy,
) -> PoseEstimate:
    """LOCAL_POSITION_NED (#32) with the latest ATTITUDE_QUATERNION (#31) as a :class:`PoseEstimate`
    (stamped with the position's ``time_boot_ms``; covariances from :class:`AssumedAccuracy`).

    Raises:
        InvalidInputError: NaN/inf position or attitude.
    """
    _finite("LOCAL_POSITION_NED position", position_ned_m)
    q = _attitude(q_ned_frd_wxyz)
    velocity = rotate(quat_conjugate(q), ned_to_enu(np.asarray(velocity_ned_mps, dtype=np.float64)))
    v, w, twist_known = _twist(velocity, rates_frd_radps)
    p = ned_to_enu(position_ned_m)
    assumed_pose, assumed_twist = _assumed(assumed)
    return PoseEstimate(
        t_autopilot_s=time_boot_ms * 1e-3,
        position_enu_m=_vec3(p),
        q_enu_flu_wxyz=(float(q[0]), float(q[1]), float(q[2]), float(q[3])),
        velocity_flu_mps=v,
        angular_flu_radps=w,
        pose_covariance=assumed_pose,
        twist_covariance=assumed_twist if twist_known else _UNKNOWN_TWIST,
        covariance_from_autopilot=False,
        source=SOURCE_LOCAL_POSITION,
    )


#: POSITION_TARGET_LOCAL_NED type_mask bits that say "ignore x / y / z".
_IGNORE_POSITION_BITS = (1, 2, 4)


@dataclass(frozen=True)
class PositionTarget:
    """The autopilot's own position target (POSITION_TARGET_LOCAL_NED, #85) in the map frame (ENU)."""

    t_autopilot_s: float
    position_enu_m: Vec3


def target_from_position_target(
    time_boot_ms: int, type_mask: int, position_ned_m: Sequence[float]
) -> PositionTarget | None:
    """POSITION_TARGET_LOCAL_NED as a :class:`PositionTarget`; ``None`` when it holds no position target (the
    mask ignores x, y or z, e.g. on the ground or in a velocity-only mode) or a non-finite one."""
    if any(type_mask & bit for bit in _IGNORE_POSITION_BITS):
        return None
    if not all(math.isfinite(float(v)) for v in position_ned_m):
        return None
    return PositionTarget(time_boot_ms * 1e-3, _vec3(ned_to_enu(position_ned_m)))


def relative_yaw_rad(q_a_wxyz: Sequence[float], q_b_wxyz: Sequence[float]) -> float:
    """Yaw of ``q_b`` relative to ``q_a`` (both ENU/FLU), wrapped to ``[-pi, pi)``."""
    d = quat_multiply(quat_conjugate(q_a_wxyz), q_b_wxyz)
    w, x, y, z = (float(v) for v in d)
    return (math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)) + math.pi) % (2.0 * math.pi) - math.pi


class TimeSync:
    """Autopilot clock -> our clock (see the module docstring).

    Args:
        window: how many TIMESYNC answers (or, before the first, arrivals) the estimate looks back over.
        max_rtt_s: answers with a longer round trip are ignored.
    """

    def __init__(self, *, window: int = 20, max_rtt_s: float = 1.0) -> None:
        if window < 1 or not max_rtt_s > 0.0:
            msg = f"window must be >= 1 and max_rtt_s > 0, got {window}, {max_rtt_s}"
            raise ValueError(msg)
        self.window = window
        self.max_rtt_s = max_rtt_s
        self._sync: deque[tuple[float, float]] = deque(maxlen=window)  # (rtt, offset)
        self._arrivals: deque[float] = deque(maxlen=window)  # arrival - stamp
        self._last_autopilot_s: float | None = None
        self.resets = 0
        self.rejected = 0

    @property
    def method(self) -> str:
        """``timesync``, ``arrival`` or ``none`` (nothing heard yet)."""
        if self._sync:
            return "timesync"
        return "arrival" if self._arrivals else "none"

    @property
    def offset_s(self) -> float:
        """Our time minus the autopilot's (NaN before anything was heard)."""
        if self._sync:
            return min(self._sync)[1]
        return min(self._arrivals) if self._arrivals else math.nan

    @property
    def rtt_s(self) -> float:
        """Round trip of the TIMESYNC answer in force (NaN without one)."""
        return min(self._sync)[0] if self._sync else math.nan

    def on_timesync(self, ts1_s: float, tc1_s: float, now_s: float) -> bool:
        """An answer to our TIMESYNC sent at ``ts1_s`` (our clock), stamped ``tc1_s`` by the autopilot.

        Returns whether the sample was used.
        """
        rtt = now_s - ts1_s
        if not (math.isfinite(rtt) and math.isfinite(tc1_s)) or rtt < 0.0 or rtt > self.max_rtt_s:
            self.rejected += 1
            return False
        self._check_reboot(tc1_s)
        self._sync.append((rtt, 0.5 * (ts1_s + now_s) - tc1_s))
        return True

    def on_arrival(self, autopilot_s: float, now_s: float) -> None:
        """A stamped message from the autopilot arrived at ``now_s`` (the fallback; also detects a reboot)."""
        self._check_reboot(autopilot_s)
        self._arrivals.append(now_s - autopilot_s)

    def to_local(self, autopilot_s: float) -> float:
        """An autopilot time on our clock (NaN before anything was heard)."""
        return autopilot_s + self.offset_s

    def _check_reboot(self, autopilot_s: float) -> None:
        last = self._last_autopilot_s
        if last is not None and autopilot_s < last - 1.0:  # its clock went back: it rebooted
            self._sync.clear()
            self._arrivals.clear()
            self.resets += 1
        self._last_autopilot_s = autopilot_s if last is None else max(autopilot_s, last - 1.0)


class EstimateState:
    """What :meth:`EstimateWatchdog.state` says."""

    WAITING = "WAITING"
    OK = "OK"
    STALE = "STALE"
    INVALID = "INVALID"


@dataclass
class EstimateWatchdog:
    """Is the pose estimate fit to fly on? Times are the caller's clock (``now_s``) plus an optional wall clock.

    A valid estimate counts as *fresh* when it arrives no later than ``timeout_s`` after the time it is
    stamped with. The estimate is stale once ``timeout_s`` has passed (and, with a wall clock, ``wall_floor_s``
    wall seconds: a lockstep simulation runs faster than real time, docs/autonomy.md) since the last fresh
    one arrived; it is invalid from the moment an estimate with NaN/inf (or one the autopilot flags as
    failed) arrives until a valid one does, and :meth:`state` reports it at least once even when a valid one
    followed at once (a single NaN between two checks still stops whoever flies on it).
    """

    timeout_s: float = 1.0
    wall_floor_s: float = 0.0
    _fresh_s: float | None = None
    _fresh_wall_s: float | None = None
    _invalid: str = ""
    _invalid_unreported: str = ""
    valid_count: int = 0
    invalid_count: int = 0
    late_count: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.timeout_s) and self.timeout_s > 0.0):
            msg = f"timeout_s must be a finite number > 0, got {self.timeout_s}"
            raise ValueError(msg)
        if not (math.isfinite(self.wall_floor_s) and 0.0 <= self.wall_floor_s <= 60.0):
            msg = f"wall_floor_s must be in [0, 60], got {self.wall_floor_s}"
            raise ValueError(msg)

    def valid(self, stamp_s: float, now_s: float, now_wall_s: float | None = None) -> None:
        """A finite estimate stamped ``stamp_s`` (our clock) arrived at ``now_s``."""
        self.valid_count += 1
        self._invalid = ""
        if math.isfinite(stamp_s) and now_s - stamp_s > self.timeout_s:
            self.late_count += 1  # it says where the vehicle was too long ago: no fresher than before
            return
        self._fresh_s = now_s
        self._fresh_wall_s = now_wall_s

    def invalid(self, reason: str) -> None:
        """An estimate that cannot be flown on (NaN/inf, failed) arrived."""
        self.invalid_count += 1
        self._invalid = reason
        self._invalid_unreported = reason

    def state(self, now_s: float, now_wall_s: float | None = None) -> tuple[str, str]:
        """``(state, reason)``: :class:`EstimateState` and, unless OK, why."""
        if self._invalid or self._invalid_unreported:
            reason = self._invalid or self._invalid_unreported
            self._invalid_unreported = ""
            return EstimateState.INVALID, reason
        if self._fresh_s is None:
            return EstimateState.WAITING, "no valid estimate yet"
        age = now_s - self._fresh_s
        wall_ok = (
            now_wall_s is None or self._fresh_wall_s is None or now_wall_s - self._fresh_wall_s >= self.wall_floor_s
        )
        if age > self.timeout_s and wall_ok:
            return EstimateState.STALE, f"no fresh estimate for {age:.1f} s (timeout {self.timeout_s:g} s)"
        return EstimateState.OK, ""

    @property
    def last_fresh_s(self) -> float | None:
        return self._fresh_s

    @property
    def last_fresh_wall_s(self) -> float | None:
        return self._fresh_wall_s
