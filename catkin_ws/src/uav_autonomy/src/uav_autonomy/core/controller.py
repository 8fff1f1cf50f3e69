"""The waypoint controller's decision logic: a pure state machine with time passed in.

The MAVLink shell (:mod:`uav_autonomy.mavlink.link`) calls
:meth:`WaypointController.step` at ``setpoint_rate_hz`` with the latest
:class:`Telemetry` and executes the returned actions; ROS services call
:meth:`WaypointController.request`. Positions are ``map`` ENU metres (z up, relative
to home), yaw is ENU radians (from East, counter-clockwise); the shell converts to
NED through :mod:`uav_common.frames`.

States and transitions (see docs/autonomy.md for the full table):

* ``IDLE``: sends nothing. Requests: TAKEOFF (on the ground), any flying state
  (from the ground through TAKEOFF first), RTL/LAND (armed).
* ``TAKEOFF``, ``AUTONOMOUS``, ``SCRIPTED``, ``MANUAL``, ``HOLD`` ("offboard states"):
  stream a fresh position setpoint every step. On entry from outside OFFBOARD the
  stream runs for ``prestream_s`` (>= 1 s, >= 10 setpoints per second) before
  OFFBOARD is requested; the mode counts as confirmed only when the heartbeat
  shows it, and the request is repeated every ``mode_retry_s`` up to
  ``max_mode_attempts`` times. TAKEOFF then arms (retried likewise) and climbs
  ``takeoff_height_m``; on reaching it the controller enters the state that was
  asked for (HOLD by default). SCRIPTED ends in HOLD at the last waypoint.
  On ArduPilot (GUIDED) the climb is the autopilot's: after arming the controller
  sends MAV_CMD_NAV_TAKEOFF (again every ``mode_retry_s`` while the vehicle is still
  on the ground, up to ``max_mode_attempts`` times) and sends no setpoint until the
  takeoff altitude is reached, because ArduCopter lets a position target replace a
  takeoff that has not left the ground.
* ``RTL``, ``LAND``: no setpoints; the autopilot's mode is requested until the
  heartbeat confirms it; back to IDLE once landed and disarmed.
* Yielding: if the heartbeat shows another mode while the controller owns the
  vehicle (a failsafe, or a pilot), it stops sending setpoints at once and
  reports it: state RTL or LAND if that is the new mode, IDLE otherwise. A disarm
  while under control must be confirmed (:meth:`WaypointController._disarm_confirmed`:
  two in-order heartbeats saying disarmed, or one followed by EXTENDED_SYS_STATE
  saying landed); until then the controller carries on and asks for nothing new
  (no arm request), so one stale or reordered frame over a lossy link never ends
  a flight. The shell orders the autopilot's frames (:class:`TelemetryOrder`) and
  ignores the older ones. If the
  link drops (no heartbeat for ``link_timeout_s``) or position telemetry goes
  stale, it stops sending setpoints and goes to IDLE; after the link returns it
  sends nothing until it is asked again, so no stale setpoint is ever sent.
* The pose the rest of the autonomy plans on (:class:`PoseCheck`, when the shell
  watches one): if it goes stale or turns NaN/inf, or the autopilot's own position
  does, the controller stops commanding at once: no more setpoints, the autopilot is
  asked to hold (its LOITER), the state is IDLE and ``last_event`` says why. It
  refuses every offboard state until the pose is fit again. When it goes bad while the controller is not
  commanding (IDLE, or following the autopilot's RTL/LAND after a failsafe), ``last_event`` says so too.

Time: every timeout and retry interval is measured in the caller's (simulated)
time. When the shell also passes a wall clock, a timeout (link, position) or a
give-up (after the last mode or arm request) happens only once ``wall_floor_s``
wall seconds have passed as well: a lockstep simulation may run ten times faster
than real time, and a process starved of CPU for a fraction of a wall second (or
a router forwarding in a burst) would otherwise look like a lost link. The SITL's
failsafes use the same rule. Retries stay on simulated time alone, so lockstep
runs stay deterministic; only failure paths wait for the wall clock. At real time
the floor is below every interval, so it changes nothing on a real vehicle.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from uav_autonomy.errors import InvalidInputError, InvalidTransitionError
from uav_common.autopilot_modes import Autopilot, FlightMode, decode_custom_mode, mode_name
from uav_common.validate import require_finite_vector

__all__ = [
    "OFFBOARD_STATES",
    "Action",
    "ControllerConfig",
    "ControllerState",
    "ControllerStatus",
    "PoseCheck",
    "RequestArm",
    "RequestMode",
    "RequestTakeoff",
    "SendSetpoint",
    "Telemetry",
    "TelemetryOrder",
    "WaypointController",
]

Vec3 = tuple[float, float, float]


class ControllerState(enum.Enum):
    IDLE = "IDLE"
    TAKEOFF = "TAKEOFF"
    AUTONOMOUS = "AUTONOMOUS"
    SCRIPTED = "SCRIPTED"
    MANUAL = "MANUAL"
    HOLD = "HOLD"
    RTL = "RTL"
    LAND = "LAND"


OFFBOARD_STATES = frozenset(
    {
        ControllerState.TAKEOFF,
        ControllerState.AUTONOMOUS,
        ControllerState.SCRIPTED,
        ControllerState.MANUAL,
        ControllerState.HOLD,
    }
)
_AUTOPILOT_STATES = {ControllerState.RTL: FlightMode.AUTO_RTL, ControllerState.LAND: FlightMode.AUTO_LAND}


@dataclass(frozen=True)
class ControllerConfig:
    """Settings of the waypoint controller (section ``controller`` of ``config/autonomy.yaml``)."""

    connection_url: str = "udpin:0.0.0.0:14540"
    source_system: int = 1
    source_component: int = 191
    target_system: int = 1
    target_component: int = 1
    setpoint_rate_hz: float = 20.0
    prestream_s: float = 1.5
    mode_retry_s: float = 1.0
    max_mode_attempts: int = 5
    arm_retry_s: float = 1.0
    max_arm_attempts: int = 5
    link_timeout_s: float = 2.0
    reconnect_after_s: float = 5.0
    position_timeout_s: float = 1.0
    #: The watched pose estimate (the node's ``~pose_topic``) is stale after this long without a fresh one.
    pose_timeout_s: float = 1.0
    wall_floor_s: float = 0.5
    takeoff_height_m: float = 10.0
    altitude_tolerance_m: float = 1.0
    acceptance_radius_m: float = 3.0
    lookahead_m: float = 25.0
    scripted_altitude_m: float = 50.0
    state_rate_hz: float = 5.0
    odom_rate_hz: float = 20.0
    battery_capacity_mah: float | None = None

    def __post_init__(self) -> None:
        if not self.setpoint_rate_hz >= 10.0:
            msg = f"setpoint_rate_hz must be >= 10 (PX4 needs > 2 Hz; we keep a margin), got {self.setpoint_rate_hz}"
            raise ValueError(msg)
        if not self.prestream_s >= 1.0:
            msg = f"prestream_s must be >= 1.0 s before OFFBOARD is requested, got {self.prestream_s}"
            raise ValueError(msg)
        positive = (
            "mode_retry_s",
            "arm_retry_s",
            "link_timeout_s",
            "reconnect_after_s",
            "position_timeout_s",
            "pose_timeout_s",
            "takeoff_height_m",
            "altitude_tolerance_m",
            "acceptance_radius_m",
            "state_rate_hz",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f"{name} must be a finite number > 0, got {value}"
                raise ValueError(msg)
        if not (math.isfinite(self.wall_floor_s) and 0.0 <= self.wall_floor_s <= 60.0):
            msg = f"wall_floor_s must be in [0, 60] s (0 = simulated time only), got {self.wall_floor_s}"
            raise ValueError(msg)
        if not (math.isfinite(self.odom_rate_hz) and self.odom_rate_hz >= 0.0):
            msg = f"odom_rate_hz must be >= 0 (0 = do not publish odometry), got {self.odom_rate_hz}"
            raise ValueError(msg)
        if not (math.isfinite(self.lookahead_m) and self.lookahead_m >= 0.0):
            msg = f"lookahead_m must be >= 0 (0 = send waypoints as they are), got {self.lookahead_m}"
            raise ValueError(msg)
        if not math.isfinite(self.scripted_altitude_m):
            msg = f"scripted_altitude_m must be finite, got {self.scripted_altitude_m}"
            raise ValueError(msg)
        if self.max_mode_attempts < 1 or self.max_arm_attempts < 1:
            msg = "max_mode_attempts and max_arm_attempts must be >= 1"
            raise ValueError(msg)
        if self.reconnect_after_s < self.link_timeout_s:
            msg = f"reconnect_after_s ({self.reconnect_after_s}) must be >= link_timeout_s ({self.link_timeout_s})"
            raise ValueError(msg)


@dataclass(frozen=True)
class Telemetry:
    """What the shell last heard from the autopilot; times are on the caller's clock.

    Attributes:
        heartbeat_s: arrival time of the last autopilot HEARTBEAT (None: never).
        heartbeat_wall_s: the same arrival on the wall clock (None: the shell has no wall clock).
        custom_mode: its ``custom_mode``.
        autopilot: mode table of the autopilot.
        armed: ``base_mode`` has the armed flag.
        in_air: the vehicle is flying (EXTENDED_SYS_STATE, or armed and > 1 m up).
        position_enu_m: last LOCAL_POSITION_NED converted to ENU (None: never).
        position_s: arrival time of that position.
        position_wall_s: the same arrival on the wall clock (None: the shell has no wall clock).
        yaw_enu_rad: last ATTITUDE yaw in ENU (None: never).
        position_invalid: why the last LOCAL_POSITION_NED could not be used ("" if it could): NaN/inf.
        disarmed_heartbeats: how many in-order heartbeats in a row have said disarmed (0: the last said armed);
            None when the shell does not count them (then one is taken as confirmed).
        landed_since_disarmed: an EXTENDED_SYS_STATE saying MAV_LANDED_STATE_ON_GROUND came after the first of
            those disarmed heartbeats.
    """

    heartbeat_s: float | None = None
    custom_mode: int = 0
    autopilot: Autopilot = Autopilot.PX4
    armed: bool = False
    in_air: bool = False
    position_enu_m: Vec3 | None = None
    position_s: float | None = None
    yaw_enu_rad: float | None = None
    heartbeat_wall_s: float | None = None
    position_wall_s: float | None = None
    position_invalid: str = ""
    disarmed_heartbeats: int | None = None
    landed_since_disarmed: bool = False

    @property
    def mode(self) -> FlightMode | None:
        """The decoded mode; ``None`` for one outside the table (or before the first heartbeat)."""
        return decode_custom_mode(self.autopilot, self.custom_mode)

    @property
    def mode_name(self) -> str:
        return "" if self.heartbeat_s is None else mode_name(self.autopilot, self.custom_mode)


class TelemetryOrder:
    """Which of one autopilot's frames carry newer information than what the shell already holds (pure).

    Over a lossy, reordering link a frame can arrive after a newer one (jitter, a reordering radio) or twice.
    Frames with a ``time_boot_ms`` (LOCAL_POSITION_NED, ATTITUDE...) are ordered by it: one not newer than
    the last of its kind is stale, unless it is more than ``reboot_back_ms`` older (the autopilot restarted).
    The others (HEARTBEAT, EXTENDED_SYS_STATE...) are ordered by the MAVLink sequence number of the sender's
    link, which wraps at 256: every frame is placed in the sender's stream relative to the newest seen (up to
    128 ahead or 127 behind), and a frame placed no later than the last of its kind is stale. The stream is
    taken afresh (the next frame is the newest) after ``resync_after_s`` of the caller's time without a newer
    frame, or after ``resync_after_behind`` frames in a row that look old (a restarted link, or a fade of more
    than 128 frames).
    """

    def __init__(
        self, *, resync_after_s: float = 1.0, resync_after_behind: int = 32, reboot_back_ms: int = 3000
    ) -> None:
        self.resync_after_s = resync_after_s
        self.resync_after_behind = resync_after_behind
        self.reboot_back_ms = reboot_back_ms
        self._head: int | None = None  # the newest frame's place in the stream (unwrapped sequence number)
        self._head_s = 0.0
        self._behind = 0
        self._last: dict[str, int] = {}
        self._last_ms: dict[str, int] = {}
        #: Frames found stale (older than, or the same as, the last of their kind).
        self.stale = 0

    def newer(self, kind: str, seq: int, now_s: float, time_boot_ms: int | None = None) -> bool:
        """Does this frame (``kind``, sequence number ``seq``, received at ``now_s``) bring newer information?"""
        place = self._place(seq & 0xFF, now_s)
        if time_boot_ms is not None:
            last_ms = self._last_ms.get(kind)
            if last_ms is not None and time_boot_ms <= last_ms and last_ms - time_boot_ms <= self.reboot_back_ms:
                self.stale += 1
                return False
            self._last_ms[kind] = time_boot_ms
            return True
        last = self._last.get(kind)
        if last is not None and place <= last:
            self.stale += 1
            return False
        self._last[kind] = place
        return True

    def _place(self, seq: int, now_s: float) -> int:
        head = self._head
        if head is None:
            self._head, self._head_s = seq, now_s
            return seq
        ahead = (seq - head) % 256
        if now_s - self._head_s > self.resync_after_s or self._behind >= self.resync_after_behind:
            place = head + (ahead or 256)  # taken afresh: the newest
        elif ahead == 0:
            return head  # the newest frame again (a duplicate)
        elif ahead <= 128:
            place = head + ahead
        else:
            self._behind += 1
            return head - (256 - ahead)
        self._head, self._head_s, self._behind = place, now_s, 0
        return place


@dataclass(frozen=True)
class PoseCheck:
    """Whether the pose estimate the autonomy plans on can be flown on (the shell's watchdog decides).

    Attributes:
        ok: fresh and finite.
        reason: why not (e.g. "no fresh estimate for 1.4 s (timeout 1 s)").
        source: what was watched (e.g. the odometry topic), for the messages.
    """

    ok: bool
    reason: str = ""
    source: str = "pose estimate"


@dataclass(frozen=True)
class SendSetpoint:
    """Send one SET_POSITION_TARGET_LOCAL_NED (position + yaw)."""

    position_enu_m: Vec3
    yaw_enu_rad: float


@dataclass(frozen=True)
class RequestMode:
    """Ask the autopilot for a mode (fire-and-forget; confirmed from the heartbeat)."""

    mode: FlightMode


@dataclass(frozen=True)
class RequestArm:
    """Arm (True) or disarm (False)."""

    arm: bool


@dataclass(frozen=True)
class RequestTakeoff:
    """MAV_CMD_NAV_TAKEOFF to ``height_m`` above the ground (ArduPilot GUIDED needs it)."""

    height_m: float


Action = SendSetpoint | RequestMode | RequestArm | RequestTakeoff


@dataclass(frozen=True)
class ControllerStatus:
    """What ``uav_msgs/ControllerState`` reports."""

    state: ControllerState
    autopilot_mode: str
    armed: bool
    in_air: bool
    link_ok: bool
    last_event: str


@dataclass
class _Engagement:
    """Progress of taking control through OFFBOARD (one per entry from outside OFFBOARD)."""

    first_setpoint_s: float | None = None
    setpoints_sent: int = 0
    offboard_confirmed: bool = False
    mode_attempts: int = 0
    last_mode_request_s: float | None = None
    last_mode_request_wall_s: float | None = None
    arm_attempts: int = 0
    last_arm_request_s: float | None = None
    last_arm_request_wall_s: float | None = None
    armed_seen: bool = False
    takeoff_sent: bool = False
    takeoff_attempts: int = 0
    last_takeoff_request_s: float | None = None
    #: The autopilot's mode when OFFBOARD was first requested (a later RTL/LAND is a failsafe's, not ours).
    mode_at_request: FlightMode | None = None
    #: A heartbeat said disarmed and the event was logged (until it is confirmed, or armed again).
    disarm_noted: bool = False


@dataclass
class _AutopilotModeRequest:
    mode: FlightMode
    attempts: int = 0
    last_request_s: float | None = None
    last_request_wall_s: float | None = None
    confirmed: bool = False


@dataclass
class _Follower:
    """Follows a waypoint array; ``index`` is the waypoint being flown to."""

    waypoints: npt.NDArray[np.float64]
    index: int = 0
    finished: bool = False


@dataclass
class _Targets:
    """Per-state targets, kept between steps."""

    takeoff_enu_m: Vec3 | None = None
    hold_enu_m: Vec3 | None = None
    yaw_enu_rad: float = 0.0
    stare_at_enu_m: Vec3 | None = None
    manual_enu_m: Vec3 | None = None
    manual_yaw_enu_rad: float | None = None
    autonomous: _Follower | None = None
    scripted: _Follower | None = None


class WaypointController:
    """Pure state machine; see the module docstring."""

    def __init__(self, config: ControllerConfig) -> None:
        self.config = config
        self._state = ControllerState.IDLE
        self._after_takeoff = ControllerState.HOLD
        self._engagement: _Engagement | None = None
        self._mode_request: _AutopilotModeRequest | None = None
        self._targets = _Targets()
        self._telemetry = Telemetry()
        self._pose: PoseCheck | None = None
        self._pose_ok = False  # the watched pose was fit at the last step (for the "went bad" event)
        self._link_ok = False
        self._now_wall_s: float | None = None
        self._last_event = "started"
        self._queued: list[Action] = []
        self._events: list[str] = []

    # ----------------------------------------------------------------- queries
    @property
    def state(self) -> ControllerState:
        return self._state

    def status(self) -> ControllerStatus:
        t = self._telemetry
        return ControllerStatus(self._state, t.mode_name, t.armed, t.in_air, self._link_ok, self._last_event)

    def pop_events(self) -> list[str]:
        """Events since the last call, oldest first (for logging)."""
        out, self._events = self._events, []
        return out

    # ---------------------------------------------------------------- commands
    def request(
        self,
        target: ControllerState,
        now_s: float,
        *,
        waypoints_enu_m: npt.ArrayLike | None = None,
        stare_at_enu_m: npt.ArrayLike | None = None,
    ) -> ControllerState:
        """Ask for a state; returns the state entered (TAKEOFF when flying states start on the ground).

        Args:
            target: the state wanted.
            now_s: current time.
            waypoints_enu_m: ``(N, 3)`` pattern for SCRIPTED (required there).
            stare_at_enu_m: point HOLD faces (optional).

        Raises:
            InvalidTransitionError: not possible now (no link, not armed, already
                flying for TAKEOFF, SCRIPTED without waypoints).
            InvalidInputError: NaN/inf or malformed waypoints or stare point.
        """
        pattern = None
        if waypoints_enu_m is not None:
            pattern = np.asarray(waypoints_enu_m, dtype=np.float64).reshape(-1, 3)
            if pattern.shape[0] == 0 or not np.isfinite(pattern).all():
                msg = f"waypoints must be >= 1 finite [x, y, z] points, got {pattern.tolist()}"
                raise InvalidInputError(msg)
        stare = (
            None
            if stare_at_enu_m is None
            else require_finite_vector("stare_at", stare_at_enu_m, 3, error=InvalidInputError)
        )
        if target is ControllerState.IDLE:
            self._release("IDLE requested: released control")
            return self._state
        self._check_can_enter(target, has_pattern=pattern is not None)
        if target in _AUTOPILOT_STATES:
            self._enter(target, f"{target.value} requested")
            return self._state
        if pattern is not None:
            self._targets.scripted = _Follower(pattern)
        if stare is not None:
            self._targets.stare_at_enu_m = (stare[0], stare[1], stare[2])
        if not self._telemetry.in_air:
            self._after_takeoff = ControllerState.HOLD if target is ControllerState.TAKEOFF else target
            self._enter(ControllerState.TAKEOFF, f"{target.value} requested on the ground: taking off first")
        else:
            self._enter(target, f"{target.value} requested")
        del now_s  # transitions take effect at the next step(); kept for the API's symmetry
        return self._state

    def _check_can_enter(self, target: ControllerState, *, has_pattern: bool) -> None:
        t = self._telemetry
        problem = ""
        if not self._link_ok:
            problem = "no MAVLink link to the autopilot"
        elif target in _AUTOPILOT_STATES:
            problem = "" if t.armed else "the vehicle is not armed"
        elif target is ControllerState.SCRIPTED and not has_pattern:
            problem = "SCRIPTED needs waypoints (a waypoint list, lawnmower or expanding square)"
        elif t.position_enu_m is None:
            problem = "no position telemetry yet"
        elif t.position_invalid:
            problem = f"the autopilot's position estimate is invalid ({t.position_invalid})"
        elif self._pose is not None and not self._pose.ok:
            problem = f"the {self._pose.source} cannot be flown on ({self._pose.reason})"
        elif target is ControllerState.TAKEOFF and t.in_air:
            problem = "already in the air (request HOLD, AUTONOMOUS, SCRIPTED or MANUAL)"
        if problem:
            msg = f"cannot enter {target.value}: {problem}"
            raise InvalidTransitionError(msg)

    def set_path(self, path_enu_m: npt.ArrayLike) -> None:
        """New planner path ``(N, 3)`` ENU for AUTONOMOUS (replaces the old one at once).

        Raises:
            InvalidInputError: empty or non-finite; the previous path is kept.
        """
        path = np.asarray(path_enu_m, dtype=np.float64)
        if path.ndim != 2 or path.shape[1] != 3 or path.shape[0] == 0 or not np.isfinite(path).all():
            msg = f"path must be (N >= 1, 3) finite ENU points, got shape {path.shape}"
            raise InvalidInputError(msg)
        # The planner's first waypoint is where the drone was when it planned: skip it.
        self._targets.autonomous = _Follower(path.copy(), index=1 if path.shape[0] > 1 else 0)

    def set_manual_setpoint(self, position_enu_m: npt.ArrayLike, yaw_enu_rad: float | None, now_s: float) -> None:
        """Operator override: fly to this point now; switches to MANUAL when flying.

        Raises:
            InvalidInputError: NaN/inf position or yaw; nothing changes.
            InvalidTransitionError: via :meth:`request` when MANUAL cannot be entered.
        """
        pos = require_finite_vector("manual setpoint", position_enu_m, 3, error=InvalidInputError)
        if yaw_enu_rad is not None and not math.isfinite(yaw_enu_rad):
            msg = f"manual yaw must be finite, got {yaw_enu_rad}"
            raise InvalidInputError(msg)
        self._targets.manual_enu_m = (pos[0], pos[1], pos[2])
        self._targets.manual_yaw_enu_rad = yaw_enu_rad
        if self._state is not ControllerState.MANUAL:
            self.request(ControllerState.MANUAL, now_s)

    # -------------------------------------------------------------------- step
    def step(
        self, now_s: float, telemetry: Telemetry, now_wall_s: float | None = None, pose: PoseCheck | None = None
    ) -> list[Action]:
        """Advance to ``now_s`` with fresh telemetry; returns what to send now.

        Args:
            now_s: current (simulated) time, the clock of ``telemetry``'s ``*_s`` stamps.
            telemetry: what the shell last heard.
            now_wall_s: current wall-clock time, the clock of its ``*_wall_s`` stamps (None: judge every
                interval in ``now_s`` alone; see the module docstring).
            pose: the state of the pose estimate the autonomy plans on (None: not watched).
        """
        self._telemetry = telemetry
        self._pose = pose
        self._now_wall_s = now_wall_s
        pose_was_ok, self._pose_ok = self._pose_ok, pose is None or pose.ok
        if pose is not None and pose_was_ok and not pose.ok and self._state not in OFFBOARD_STATES:
            # Not commanding anyway (idle, or following the autopilot's RTL/LAND), but say so: a GPS failure
            # seen from here is first the autopilot's failsafe, then the estimate going stale.
            self._event(f"{pose.source} cannot be flown on ({pose.reason}): not commanding on it")
        cfg = self.config
        actions, self._queued = self._queued, []
        link_ok = telemetry.heartbeat_s is not None and not self._timed_out(
            now_s, telemetry.heartbeat_s, telemetry.heartbeat_wall_s, cfg.link_timeout_s
        )
        if not link_ok:
            if self._link_ok:
                self._event("MAVLink link lost (no heartbeat): stopped sending setpoints")
            self._link_ok = False
            if self._state in OFFBOARD_STATES:
                self._go_idle("link lost: yielded control")
            return []
        if not self._link_ok:
            self._link_ok = True
            self._event(f"MAVLink link up: autopilot in {telemetry.mode_name}, armed={telemetry.armed}")
        if self._state is ControllerState.IDLE:
            return actions
        if self._state in _AUTOPILOT_STATES:
            return actions + self._step_autopilot_mode(now_s, telemetry)
        return actions + self._step_offboard(now_s, telemetry)

    # ------------------------------------------------------------- internals
    def _timed_out(self, now_s: float, since_s: float, since_wall_s: float | None, timeout_s: float) -> bool:
        """More than ``timeout_s`` of caller time since ``since_s``, and the wall floor (see the module docstring)."""
        return now_s - since_s > timeout_s and self._wall_floor_passed(since_wall_s)

    def _wall_floor_passed(self, since_wall_s: float | None) -> bool:
        """``wall_floor_s`` wall seconds since ``since_wall_s`` (True without a wall clock)."""
        if self._now_wall_s is None or since_wall_s is None:
            return True
        return self._now_wall_s - since_wall_s >= self.config.wall_floor_s

    def _event(self, text: str) -> None:
        self._last_event = text
        self._events.append(text)

    def _go_idle(self, reason: str) -> None:
        self._state = ControllerState.IDLE
        self._engagement = None
        self._mode_request = None
        self._event(reason)

    def _take_queued(self) -> list[Action]:
        actions, self._queued = self._queued, []
        return actions

    def _release(self, reason: str) -> None:
        """IDLE on request: while flying in OFFBOARD, hand the vehicle to the autopilot's hold mode."""
        t = self._telemetry
        if self._state in OFFBOARD_STATES and t.in_air and t.mode is FlightMode.OFFBOARD:
            self._queued.append(RequestMode(FlightMode.AUTO_LOITER))
            reason += "; asked the autopilot to hold (LOITER)"
        self._go_idle(reason)

    def _yield_to(self, mode: FlightMode | None, what: str) -> None:
        """The autopilot changed mode under us: stop at once and mirror RTL/LAND."""
        text = f"{what}: autopilot now in {self._telemetry.mode_name}; yielded control"
        for state, state_mode in _AUTOPILOT_STATES.items():
            if mode is state_mode:
                self._state = state
                self._engagement = None
                self._mode_request = _AutopilotModeRequest(mode, confirmed=True)
                self._event(text)
                return
        self._go_idle(text)

    def _enter(self, target: ControllerState, reason: str) -> None:
        t = self._telemetry
        previous = self._state
        self._state = target
        if target in _AUTOPILOT_STATES:
            self._engagement = None
            self._mode_request = _AutopilotModeRequest(_AUTOPILOT_STATES[target])
            self._event(reason)
            return
        if previous not in OFFBOARD_STATES or self._engagement is None:
            self._engagement = _Engagement()
        pos = t.position_enu_m or (0.0, 0.0, 0.0)
        yaw = t.yaw_enu_rad if t.yaw_enu_rad is not None else self._targets.yaw_enu_rad
        tg = self._targets
        tg.yaw_enu_rad = yaw
        if target is ControllerState.TAKEOFF:
            tg.takeoff_enu_m = (pos[0], pos[1], pos[2] + self.config.takeoff_height_m)
        elif target is ControllerState.HOLD or target is ControllerState.MANUAL or target is ControllerState.AUTONOMOUS:
            tg.hold_enu_m = pos
        self._event(reason)

    def _step_autopilot_mode(self, now_s: float, t: Telemetry) -> list[Action]:
        req = self._mode_request
        if req is None:  # pragma: no cover - _enter always sets it
            req = self._mode_request = _AutopilotModeRequest(_AUTOPILOT_STATES[self._state])
        mode = t.mode
        if mode is req.mode:
            if not req.confirmed:
                req.confirmed = True
                self._event(f"autopilot confirmed {t.mode_name}")
            if not t.armed and not t.in_air:
                self._go_idle(f"{self._state.value} complete: landed and disarmed")
            return []
        if req.confirmed:
            self._yield_to(mode, f"autopilot left {req.mode.name_for(t.autopilot)}")
            return []
        if req.last_request_s is None or now_s - req.last_request_s >= self.config.mode_retry_s:
            if req.attempts >= self.config.max_mode_attempts:
                if not self._wall_floor_passed(req.last_request_wall_s):
                    return []
                self._go_idle(f"autopilot did not enter {req.mode.name_for(t.autopilot)} after {req.attempts} requests")
                return []
            req.attempts += 1
            req.last_request_s = now_s
            req.last_request_wall_s = self._now_wall_s
            return [RequestMode(req.mode)]
        return []

    def _step_offboard(self, now_s: float, t: Telemetry) -> list[Action]:  # noqa: PLR0911
        cfg = self.config
        eng = self._engagement
        if eng is None:  # pragma: no cover - _enter always sets it
            eng = self._engagement = _Engagement()
        fresh = (
            t.position_s is not None
            and t.position_enu_m is not None
            and not self._timed_out(now_s, t.position_s, t.position_wall_s, cfg.position_timeout_s)
        )
        if not fresh:
            self._go_idle("position telemetry stale: stopped sending setpoints")
            return []
        if t.position_invalid:
            self._release(f"the autopilot's position estimate is invalid ({t.position_invalid}): stopped commanding")
            return self._take_queued()
        pose = self._pose
        if pose is not None and not pose.ok:
            self._release(f"{pose.source} cannot be flown on ({pose.reason}): stopped commanding")
            return self._take_queued()
        mode = t.mode
        if eng.offboard_confirmed and mode is not FlightMode.OFFBOARD:
            self._yield_to(mode, "autopilot left OFFBOARD (failsafe or pilot)")
            return []
        checked = self._check_disarm(t, eng)
        if checked is None:
            return []
        t = checked
        if t.armed and eng.offboard_confirmed:
            eng.armed_seen = True
        actions: list[Action] = []
        position, yaw = self._setpoint(t)
        guided_climb = (
            self._state is ControllerState.TAKEOFF and t.autopilot is Autopilot.ARDUPILOT and eng.takeoff_sent
        )
        if not guided_climb:  # ArduCopter: a target would replace the takeoff the autopilot is flying
            actions.append(SendSetpoint(position, yaw))
        eng.setpoints_sent += 1
        if eng.first_setpoint_s is None:
            eng.first_setpoint_s = now_s
        if not eng.offboard_confirmed:
            handshake = self._offboard_handshake(now_s, t, eng)
            if handshake is None:
                return []
            actions.extend(handshake)
        if eng.offboard_confirmed and self._state is ControllerState.TAKEOFF:
            actions.extend(self._arm_and_takeoff(now_s, t, eng))
        return [] if self._state not in OFFBOARD_STATES else actions

    def _check_disarm(self, t: Telemetry, eng: _Engagement) -> Telemetry | None:
        """None after a confirmed disarm while under control (the state is then IDLE); else the telemetry to act
        on: a disarm not yet confirmed is taken as still armed, so nothing new (an arm request) is asked for on
        its word."""
        if not (eng.armed_seen and not t.armed):
            eng.disarm_noted = False
            return t
        if self._disarm_confirmed(t):
            self._go_idle("vehicle disarmed while under control")
            return None
        if not eng.disarm_noted:
            eng.disarm_noted = True
            self._event("a heartbeat says disarmed: carrying on until the next one confirms it")
        return replace(t, armed=True)

    @staticmethod
    def _disarm_confirmed(t: Telemetry) -> bool:
        """A disarm while under control counts once two in-order heartbeats say so, or one and then
        EXTENDED_SYS_STATE saying landed (one stale or reordered frame must not end a flight); a shell that does
        not count heartbeats (``disarmed_heartbeats`` None) is taken at its word."""
        n = t.disarmed_heartbeats
        return n is None or n >= 2 or (n >= 1 and t.landed_since_disarmed)

    def _offboard_handshake(self, now_s: float, t: Telemetry, eng: _Engagement) -> list[Action] | None:
        """Confirm OFFBOARD from the heartbeat, or request it once the pre-stream is long enough.

        Returns the actions to add, or None after giving up (the state is then IDLE) or yielding to a failsafe.
        """
        cfg = self.config
        if t.mode is FlightMode.OFFBOARD:
            eng.offboard_confirmed = True
            self._event(f"autopilot confirmed {t.mode_name}")
            return []
        if (
            eng.mode_attempts > 0
            and t.mode in (FlightMode.AUTO_RTL, FlightMode.AUTO_LAND)
            and t.mode is not eng.mode_at_request
        ):
            # A failsafe (or the pilot) sent the vehicle home or down while OFFBOARD was being requested,
            # possibly after the autopilot had already accepted it: never fight that with a retry.
            self._yield_to(t.mode, "autopilot switched while OFFBOARD was being requested (failsafe or pilot)")
            return None
        first = eng.first_setpoint_s if eng.first_setpoint_s is not None else now_s
        enough = now_s - first >= cfg.prestream_s and eng.setpoints_sent >= math.ceil(10.0 * cfg.prestream_s)
        due = eng.last_mode_request_s is None or now_s - eng.last_mode_request_s >= cfg.mode_retry_s
        if not (enough and due):
            return []
        if eng.mode_attempts >= cfg.max_mode_attempts:
            if not self._wall_floor_passed(eng.last_mode_request_wall_s):
                return []
            self._go_idle(f"autopilot did not enter OFFBOARD after {eng.mode_attempts} requests")
            return None
        if eng.mode_attempts > 0:
            self._event(f"OFFBOARD not confirmed (autopilot in {t.mode_name}); retrying")
        if eng.mode_attempts == 0:
            eng.mode_at_request = t.mode
        eng.mode_attempts += 1
        eng.last_mode_request_s = now_s
        eng.last_mode_request_wall_s = self._now_wall_s
        return [RequestMode(FlightMode.OFFBOARD)]

    def _arm_and_takeoff(self, now_s: float, t: Telemetry, eng: _Engagement) -> list[Action]:  # noqa: PLR0911
        cfg = self.config
        if not t.armed:
            due = eng.last_arm_request_s is None or now_s - eng.last_arm_request_s >= cfg.arm_retry_s
            if not due:
                return []
            if eng.arm_attempts >= cfg.max_arm_attempts:
                if not self._wall_floor_passed(eng.last_arm_request_wall_s):
                    return []
                self._go_idle(f"vehicle did not arm after {eng.arm_attempts} requests")
                return []
            eng.arm_attempts += 1
            eng.last_arm_request_s = now_s
            eng.last_arm_request_wall_s = self._now_wall_s
            return [RequestArm(arm=True)]
        if t.autopilot is not Autopilot.ARDUPILOT or t.in_air:
            return []
        due = eng.last_takeoff_request_s is None or now_s - eng.last_takeoff_request_s >= cfg.mode_retry_s
        if due and eng.takeoff_attempts < cfg.max_mode_attempts:
            eng.takeoff_sent = True
            eng.takeoff_attempts += 1
            eng.last_takeoff_request_s = now_s
            return [RequestTakeoff(cfg.takeoff_height_m)]
        return []

    def _setpoint(self, t: Telemetry) -> tuple[Vec3, float]:
        """The setpoint for the current state; may move on (takeoff done, pattern done)."""
        pos = t.position_enu_m or (0.0, 0.0, 0.0)
        handlers = {
            ControllerState.TAKEOFF: self._setpoint_takeoff,
            ControllerState.HOLD: self._setpoint_hold,
            ControllerState.MANUAL: self._setpoint_manual,
            ControllerState.AUTONOMOUS: self._setpoint_autonomous,
            ControllerState.SCRIPTED: self._setpoint_scripted,
        }
        return handlers[self._state](t, pos)

    def _setpoint_takeoff(self, t: Telemetry, pos: Vec3) -> tuple[Vec3, float]:
        tg = self._targets
        target = tg.takeoff_enu_m or pos
        eng = self._engagement
        climbed = pos[2] >= target[2] - self.config.altitude_tolerance_m
        if eng is not None and eng.armed_seen and eng.offboard_confirmed and climbed:
            after = self._after_takeoff
            self._after_takeoff = ControllerState.HOLD
            self._enter(after, f"takeoff complete at {pos[2]:.1f} m: entering {after.value}")
            tg.hold_enu_m = target  # hold where the takeoff aimed, not where it was declared done
            return self._setpoint(t)
        return target, tg.yaw_enu_rad

    def _setpoint_hold(self, t: Telemetry, pos: Vec3) -> tuple[Vec3, float]:
        del t
        tg = self._targets
        hold = tg.hold_enu_m or pos
        if tg.stare_at_enu_m is not None:
            dx, dy = tg.stare_at_enu_m[0] - hold[0], tg.stare_at_enu_m[1] - hold[1]
            if math.hypot(dx, dy) > 0.5:
                tg.yaw_enu_rad = math.atan2(dy, dx)
        return hold, tg.yaw_enu_rad

    def _setpoint_manual(self, t: Telemetry, pos: Vec3) -> tuple[Vec3, float]:
        del t
        tg = self._targets
        if tg.manual_enu_m is None:
            return tg.hold_enu_m or pos, tg.yaw_enu_rad
        if tg.manual_yaw_enu_rad is not None:
            tg.yaw_enu_rad = tg.manual_yaw_enu_rad
        return tg.manual_enu_m, tg.yaw_enu_rad

    def _setpoint_autonomous(self, t: Telemetry, pos: Vec3) -> tuple[Vec3, float]:
        del t
        tg = self._targets
        if tg.autonomous is None:
            return tg.hold_enu_m or pos, tg.yaw_enu_rad
        return self._follow(tg.autonomous, pos)

    def _setpoint_scripted(self, t: Telemetry, pos: Vec3) -> tuple[Vec3, float]:
        del t
        tg = self._targets
        follower = tg.scripted
        if follower is None:  # pragma: no cover - request() refuses SCRIPTED without waypoints
            return pos, tg.yaw_enu_rad
        setpoint = self._follow(follower, pos)
        if not follower.finished:
            return setpoint
        last = follower.waypoints[-1]
        self._enter(ControllerState.HOLD, "scripted pattern complete: holding at its last waypoint")
        tg.hold_enu_m = (float(last[0]), float(last[1]), float(last[2]))
        return tg.hold_enu_m, tg.yaw_enu_rad

    def _follow(self, follower: _Follower, pos: Vec3) -> tuple[Vec3, float]:
        """Carrot along the waypoints: advance within ``acceptance_radius_m``, cap the lead at ``lookahead_m``."""
        cfg = self.config
        wps = follower.waypoints
        p = np.asarray(pos)
        while follower.index < len(wps) - 1 and np.linalg.norm(wps[follower.index] - p) <= cfg.acceptance_radius_m:
            follower.index += 1
        target = wps[follower.index]
        delta = target - p
        dist = float(np.linalg.norm(delta))
        if follower.index == len(wps) - 1 and dist <= cfg.acceptance_radius_m:
            follower.finished = True
        horizontal = math.hypot(float(delta[0]), float(delta[1]))
        if horizontal > 2.0:
            self._targets.yaw_enu_rad = math.atan2(float(delta[1]), float(delta[0]))
        lead = cfg.lookahead_m > 0.0 and dist > cfg.lookahead_m
        sp = p + delta * (cfg.lookahead_m / dist) if lead else target
        return (float(sp[0]), float(sp[1]), float(sp[2])), self._targets.yaw_enu_rad
