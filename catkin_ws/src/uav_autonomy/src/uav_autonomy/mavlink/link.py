"""Thin MAVLink shell of the waypoint controller (pymavlink; no rospy, usable from plain Python).

It turns received messages into a :class:`~uav_autonomy.core.controller.Telemetry`
snapshot and executes the controller's actions. Every time is the caller's clock
(ROS time in the node, so a SITL running faster than real time keeps the setpoint
rate in simulated seconds). Frames: MAVLink NED <-> ROS ENU only through
:mod:`uav_common.frames`.

A second, wall clock is optional (``now_wall_s``): arrivals are stamped on both
clocks, so the controller can tell a lost link from a simulation that ran ahead of
a process starved of CPU.

Reconnection: without a heartbeat for ``reconnect_after_s`` (and, with a wall clock,
``wall_floor_s`` wall seconds as well) the socket is closed and opened again (a UDP
server forgets stale peers, a TCP client redials).

Reading is bounded: one :meth:`MavlinkLink.poll` handles at most ``poll_max_messages``
messages and reads for at most ``poll_max_wall_s`` wall seconds; what is left waits for the
next poll (a flood on the link cannot hold the caller's loop).

Newest information only: over a lossy, reordering link a frame can arrive after a newer one or
twice; the autopilot's frames are ordered (:class:`~uav_autonomy.core.controller.TelemetryOrder`:
``time_boot_ms`` where the message has one, else the MAVLink sequence number) and an older frame
changes nothing. Heartbeats saying disarmed are counted, in order, for the controller's
confirmation rule.

Lockstep (docs/lockstep.md, "Clients"): :meth:`MavlinkLink.start_lockstep` says HELLO through the
router; then, in every step, :meth:`MavlinkLink.read_step` handles exactly the messages the router
sent before its STEP marker (stamped with the step's simulated time on both clocks) and
:meth:`MavlinkLink.end_step` ends the step with this client's marker. :meth:`MavlinkLink.poll` is
refused then (it would take messages of later steps) and the link never reconnects on silence. A
marker that breaks the protocol raises :class:`uav_common.lockstep.markers.MarkerError`, a marker
that never comes :class:`uav_common.errors.WaitTimeoutError` after the watchdog (both exit status 1).
"""

from __future__ import annotations

import math
import os
import select
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from uav_autonomy.core.controller import (
    Action,
    RequestArm,
    RequestMode,
    RequestTakeoff,
    SendSetpoint,
    Telemetry,
    TelemetryOrder,
)
from uav_autonomy.core.pose_estimate import AssumedAccuracy, estimate_from_local_position
from uav_autonomy.errors import InvalidInputError, MavlinkLinkError
from uav_common.autopilot_modes import Autopilot, FlightMode, set_mode_params
from uav_common.frames import enu_to_ned, ned_to_enu, yaw_enu_to_ned, yaw_ned_to_enu
from uav_common.rotations import quat_from_euler
from uav_common.shell.mavlink_lockstep import LockstepClient

__all__ = [
    "POLL_MAX_MESSAGES",
    "POLL_MAX_WALL_S",
    "POSITION_YAW_TYPE_MASK",
    "BatteryReading",
    "MavlinkLink",
    "OdometryReading",
]

POSITION_YAW_TYPE_MASK = 2552
"""Ignore velocity, acceleration and yaw rate: position + yaw (MAVROS/MAVSDK use the same)."""

_MAV_TYPE_GCS = 6
_MAV_TYPE_ONBOARD_CONTROLLER = 18
_MAV_AUTOPILOT_INVALID = 8
_MAV_FRAME_LOCAL_NED = 1
_MAV_CMD_DO_SET_MODE = 176
_MAV_CMD_COMPONENT_ARM_DISARM = 400
_MAV_CMD_NAV_TAKEOFF = 22
_MAV_CMD_SET_MESSAGE_INTERVAL = 511
_MAV_MODE_FLAG_SAFETY_ARMED = 128
_LANDED_IN_AIR = (2, 3, 4)  # MAV_LANDED_STATE: IN_AIR, TAKEOFF, LANDING
_LANDED_ON_GROUND = 1
_EXT_STATE_FRESH_S = 3.0
#: One poll handles at most this many messages ...
POLL_MAX_MESSAGES = 1000
#: ... and reads for at most this many wall seconds; the rest waits for the next poll.
POLL_MAX_WALL_S = 0.05


@dataclass
class BatteryReading:
    """Latest battery telemetry; NaN where the autopilot did not say."""

    voltage_v: float = math.nan
    current_a: float = math.nan
    remaining_frac: float = math.nan
    consumed_mah: float = math.nan
    stamp_s: float | None = None


@dataclass(frozen=True)
class OdometryReading:
    """The autopilot's estimate in ROS conventions (``map`` ENU, ``base_link`` FLU).

    Attributes:
        position_enu_m: LOCAL_POSITION_NED converted to ENU.
        q_enu_flu_wxyz: ATTITUDE as the FLU body's attitude in ENU, ``[w, x, y, z]`` (identity before any).
        velocity_flu_mps: LOCAL_POSITION_NED's velocity rotated into the body frame (FLU), as
            nav_msgs/Odometry wants its twist.
        angular_flu_radps: ATTITUDE's body rates in FLU.
        stamp_s: arrival time of the position (caller's clock).
        pose_covariance, twist_covariance: 6x6 row-major; LOCAL_POSITION_NED carries none, so these are the
            :class:`~uav_autonomy.core.pose_estimate.AssumedAccuracy` defaults.
    """

    position_enu_m: tuple[float, float, float]
    q_enu_flu_wxyz: tuple[float, float, float, float]
    velocity_flu_mps: tuple[float, float, float]
    angular_flu_radps: tuple[float, float, float]
    stamp_s: float
    pose_covariance: tuple[float, ...] = ()
    twist_covariance: tuple[float, ...] = ()


@dataclass
class _State:
    heartbeat_s: float | None = None
    heartbeat_wall_s: float | None = None
    custom_mode: int = 0
    base_mode: int = 0
    autopilot: Autopilot = Autopilot.PX4
    position_ned: tuple[float, float, float] | None = None
    position_s: float | None = None
    position_wall_s: float | None = None
    position_invalid: str = ""
    invalid_positions: int = 0
    yaw_ned_rad: float | None = None
    velocity_ned_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    q_ned_frd_wxyz: tuple[float, float, float, float] | None = None
    rates_frd_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    landed_state: int | None = None
    landed_state_s: float | None = None
    battery: BatteryReading = field(default_factory=BatteryReading)
    status_texts: list[str] = field(default_factory=list)
    order: TelemetryOrder = field(default_factory=TelemetryOrder)
    disarmed_streak: int = 0  # in-order heartbeats in a row saying disarmed
    landed_since_disarmed: bool = False


class MavlinkLink:
    """One MAVLink connection to one autopilot (``target_system``/``target_component``)."""

    def __init__(
        self,
        url: str,
        *,
        source_system: int,
        source_component: int,
        target_system: int,
        target_component: int,
        reconnect_after_s: float,
        wall_floor_s: float = 0.0,
        on_message: Callable[[object, float, float | None], None] | None = None,
        poll_max_messages: int = POLL_MAX_MESSAGES,
        poll_max_wall_s: float = POLL_MAX_WALL_S,
        wall_clock: Callable[[], float] = time.monotonic,
    ) -> None:
        """``on_message(msg, now_s, now_wall_s)``: also called for every message from the target (after this
        link has taken what it needs, stale ones included), e.g. the estimate messages of the autopilot odometry
        node. ``poll_max_messages``, ``poll_max_wall_s``: the bound of one :meth:`poll` (``wall_clock`` measures
        it)."""
        self.url = url
        self.on_message = on_message
        self.source_system = source_system
        self.source_component = source_component
        self.target_system = target_system
        self.target_component = target_component
        self.reconnect_after_s = reconnect_after_s
        self.wall_floor_s = wall_floor_s
        self._conn: object | None = None
        self._st = _State()
        self._opened_s = 0.0
        self._opened_wall_s: float | None = None
        self._last_heartbeat_out_s: float | None = None
        self.reconnects = 0
        self.poll_max_messages = poll_max_messages
        self.poll_max_wall_s = poll_max_wall_s
        self._wall_clock = wall_clock
        self._lockstep: LockstepClient | None = None
        self._watchdog_s = 120.0
        #: Messages handled by the last :meth:`read_step`.
        self.step_messages = 0

    # ------------------------------------------------------------ lifecycle
    def open(self, now_s: float, now_wall_s: float | None = None) -> None:
        """Open the connection (binds for ``udpin:``/``tcpin:``).

        Raises:
            MavlinkLinkError: the URL is invalid or the socket cannot be opened.
        """
        # MAVLink 2 framing from the first packet (the autopilot may not speak first).
        os.environ["MAVLINK20"] = "1"
        from pymavlink import mavutil  # noqa: PLC0415 - after MAVLINK20 is set

        mavutil.set_dialect("common")
        try:
            kwargs = {"udp_timeout": self.reconnect_after_s} if self.url.startswith("udpin:") else {}
            self._conn = mavutil.mavlink_connection(
                self.url,
                source_system=self.source_system,
                source_component=self.source_component,
                autoreconnect=True,
                **kwargs,
            )
        except (OSError, ValueError) as err:
            msg = f"cannot open MAVLink connection '{self.url}': {err}"
            raise MavlinkLinkError(msg) from err
        self._opened_s = now_s
        self._opened_wall_s = now_wall_s

    def close(self) -> None:
        conn = self._conn
        self._conn = None
        self._lockstep = None
        if conn is not None:
            conn.close()  # type: ignore[attr-defined]

    # ------------------------------------------------------------- receive
    def wait_readable(self, timeout_s: float) -> None:
        """Block until a datagram or bytes are waiting, or ``timeout_s`` (for a reader thread)."""
        fd = getattr(self._require(), "fd", None)
        if fd is None:
            time.sleep(timeout_s)
            return
        try:
            select.select([fd], [], [], timeout_s)
        except (OSError, ValueError):  # the socket was closed and reopened meanwhile
            time.sleep(min(timeout_s, 0.01))

    def poll(
        self,
        now_s: float,
        now_wall_s: float | None = None,
        *,
        clock: Callable[[], tuple[float, float | None]] | None = None,
    ) -> int:
        """Read what is pending, within the bound (module doc); reopen the socket after ``reconnect_after_s`` of
        silence (see module doc). Returns the number of messages handled.

        Messages are stamped ``now_s``/``now_wall_s``, or, with ``clock`` (returning both), with its reading when
        each is taken: on a loaded machine a poll can last long enough for a simulation running faster than real
        time to move on by seconds (a lockstep run once went from 33.2 to 37.8 s during one), and a message
        read at its end did not arrive at its start.

        Raises:
            MavlinkLinkError: the link is in lockstep (read with :meth:`read_step`).
        """
        if self._lockstep is not None:
            text = f"MAVLink connection '{self.url}' is in lockstep: read it with read_step(), not poll()"
            raise MavlinkLinkError(text)
        conn = self._require()
        handled = 0
        started = self._wall_clock()
        cut_short = False
        while True:
            if handled >= self.poll_max_messages or self._wall_clock() - started >= self.poll_max_wall_s:
                cut_short = True  # the rest waits for the next poll
                break
            try:
                msg = conn.recv_match(blocking=False)  # type: ignore[attr-defined]
            except (OSError, ConnectionError):
                msg = None
            if msg is None:
                break
            if clock is not None:
                now_s, now_wall_s = clock()
            self._handle(msg, now_s, now_wall_s)
            handled += 1
        st = self._st
        last = st.heartbeat_s if st.heartbeat_s is not None else self._opened_s
        last_wall = st.heartbeat_wall_s if st.heartbeat_s is not None else self._opened_wall_s
        silent_wall = now_wall_s is None or last_wall is None or now_wall_s - last_wall >= self.wall_floor_s
        if not cut_short and now_s - last > self.reconnect_after_s and silent_wall:
            self.close()
            self.open(now_s, now_wall_s)
            self.reconnects += 1
            st.heartbeat_s = st.heartbeat_wall_s = None
        return handled

    # ------------------------------------------------------------ lockstep
    @property
    def lockstep(self) -> bool:
        """Is the link in lockstep (after :meth:`start_lockstep`)?"""
        return self._lockstep is not None

    def start_lockstep(
        self, lookahead_steps: int, watchdog_s: float = 120.0, *, should_stop: Callable[[], bool] | None = None
    ) -> int:
        """Say HELLO(``lookahead_steps``) to the router (or the SITL); returns the step it registered this client at.
        ``should_stop`` (e.g. ``rospy.is_shutdown``) ends a wait for the router with ``StopRequestedError``.

        Raises:
            MavlinkLinkError: the link is not open.
            MarkerError: a malformed marker, or HELLO said twice.
            WaitTimeoutError: no answer within ``watchdog_s`` wall seconds.
        """
        client = LockstepClient(
            self._require(),
            name=f"MAVLink link {self.url}",
            target_system=self.target_system,
            target_component=self.target_component,
            should_stop=should_stop,
        )
        self._watchdog_s = watchdog_s
        step = client.hello(lookahead_steps, watchdog_s=watchdog_s)
        self._lockstep = client
        return step

    def read_step(self, step: int, t_sim_s: float) -> None:
        """Handle every message of ``step`` (those before the router's STEP(``step``)), stamped ``t_sim_s`` on both
        clocks (:attr:`step_messages`: how many there were).

        Raises:
            MavlinkLinkError: not in lockstep.
            MarkerError: the step's count does not balance, or its marker is not the next one.
            WaitTimeoutError: no marker within the watchdog.
        """
        messages = self._require_lockstep().read_step(step, watchdog_s=self._watchdog_s)
        for msg in messages:
            self._handle(msg, t_sim_s, t_sim_s)
        self.step_messages = len(messages)

    def end_step(self, step: int, t_sim_s: float) -> None:
        """End ``step`` (after sending what it had to send): STEP(``step``, ``t_sim_s``, messages sent)."""
        self._require_lockstep().end_step(step, t_sim_s)

    def _require_lockstep(self) -> LockstepClient:
        if self._lockstep is None:
            msg = f"MAVLink connection '{self.url}' is not in lockstep: call start_lockstep() first"
            raise MavlinkLinkError(msg)
        return self._lockstep

    def _handle(self, msg: object, now_s: float, now_wall_s: float | None = None) -> None:
        mtype = msg.get_type()  # type: ignore[attr-defined]
        src_sys = msg.get_srcSystem()  # type: ignore[attr-defined]
        src_comp = msg.get_srcComponent()  # type: ignore[attr-defined]
        if src_sys != self.target_system or src_comp != self.target_component:
            return
        self._take(msg, mtype, now_s, now_wall_s)
        if self.on_message is not None:
            self.on_message(msg, now_s, now_wall_s)

    def _take(self, msg: object, mtype: str, now_s: float, now_wall_s: float | None) -> None:
        st = self._st
        if mtype == "STATUSTEXT":  # a text is an event, whenever it comes
            st.status_texts.append(str(msg.text))  # type: ignore[attr-defined]
            return
        boot_ms = getattr(msg, "time_boot_ms", None)
        if not st.order.newer(mtype, int(msg.get_seq()), now_s, None if boot_ms is None else int(boot_ms)):  # type: ignore[attr-defined]
            return  # older than what we hold (reordered, or a duplicate): it changes nothing
        if mtype == "HEARTBEAT":
            self._take_heartbeat(msg, now_s, now_wall_s)
        elif mtype == "LOCAL_POSITION_NED":
            position = (float(msg.x), float(msg.y), float(msg.z))  # type: ignore[attr-defined]
            if not all(math.isfinite(v) for v in position):
                # An estimator that lost its position says so with NaN: never a position to fly on.
                st.position_invalid = f"LOCAL_POSITION_NED with non-finite position {list(position)}"
                st.invalid_positions += 1
                return
            st.position_invalid = ""
            st.position_ned = position
            velocity = (float(msg.vx), float(msg.vy), float(msg.vz))  # type: ignore[attr-defined]
            st.velocity_ned_mps = velocity if all(math.isfinite(v) for v in velocity) else (0.0, 0.0, 0.0)
            st.position_s = now_s
            st.position_wall_s = now_wall_s
        elif mtype == "ATTITUDE":
            roll, pitch, yaw = float(msg.roll), float(msg.pitch), float(msg.yaw)  # type: ignore[attr-defined]
            if all(math.isfinite(v) for v in (roll, pitch, yaw)):
                st.yaw_ned_rad = yaw
                q = quat_from_euler(roll, pitch, yaw)
                st.q_ned_frd_wxyz = (float(q[0]), float(q[1]), float(q[2]), float(q[3]))
                rates = (float(msg.rollspeed), float(msg.pitchspeed), float(msg.yawspeed))  # type: ignore[attr-defined]
                st.rates_frd_radps = rates if all(math.isfinite(v) for v in rates) else (0.0, 0.0, 0.0)
        elif mtype == "EXTENDED_SYS_STATE":
            st.landed_state = int(msg.landed_state)  # type: ignore[attr-defined]
            st.landed_state_s = now_s
            if st.disarmed_streak and st.landed_state == _LANDED_ON_GROUND:
                st.landed_since_disarmed = True
        elif mtype in ("BATTERY_STATUS", "SYS_STATUS"):
            self._take_battery(msg, mtype, now_s)

    def _take_heartbeat(self, msg: object, now_s: float, now_wall_s: float | None) -> None:
        if msg.type == _MAV_TYPE_GCS or msg.autopilot == _MAV_AUTOPILOT_INVALID:  # type: ignore[attr-defined]
            return
        st = self._st
        st.heartbeat_s = now_s
        st.heartbeat_wall_s = now_wall_s
        st.custom_mode = int(msg.custom_mode)  # type: ignore[attr-defined]
        st.base_mode = int(msg.base_mode)  # type: ignore[attr-defined]
        st.autopilot = Autopilot.from_heartbeat(int(msg.autopilot))  # type: ignore[attr-defined]
        if st.base_mode & _MAV_MODE_FLAG_SAFETY_ARMED:
            st.disarmed_streak = 0
        else:
            st.disarmed_streak += 1
            if st.disarmed_streak == 1:
                st.landed_since_disarmed = False

    def _take_battery(self, msg: object, mtype: str, now_s: float) -> None:
        st = self._st
        if mtype == "BATTERY_STATUS":
            b = st.battery
            cells = [v for v in msg.voltages if v not in (0xFFFF, 0xFFFE)]  # type: ignore[attr-defined]
            if cells:
                b.voltage_v = sum(cells) / 1000.0
            b.current_a = msg.current_battery / 100.0 if msg.current_battery >= 0 else math.nan  # type: ignore[attr-defined]
            b.remaining_frac = msg.battery_remaining / 100.0 if msg.battery_remaining >= 0 else math.nan  # type: ignore[attr-defined]
            b.consumed_mah = float(msg.current_consumed) if msg.current_consumed >= 0 else math.nan  # type: ignore[attr-defined]
            b.stamp_s = now_s
        elif mtype == "SYS_STATUS" and st.battery.stamp_s is None:
            b = st.battery
            b.voltage_v = msg.voltage_battery / 1000.0 if msg.voltage_battery != 0xFFFF else math.nan  # type: ignore[attr-defined]
            b.current_a = msg.current_battery / 100.0 if msg.current_battery >= 0 else math.nan  # type: ignore[attr-defined]
            b.remaining_frac = msg.battery_remaining / 100.0 if msg.battery_remaining >= 0 else math.nan  # type: ignore[attr-defined]

    def telemetry(self) -> Telemetry:
        st = self._st
        armed = bool(st.base_mode & _MAV_MODE_FLAG_SAFETY_ARMED)
        pos_enu = None
        if st.position_ned is not None:
            v = ned_to_enu(st.position_ned)
            pos_enu = (float(v[0]), float(v[1]), float(v[2]))
        fresh_ext = st.landed_state is not None and st.landed_state_s is not None and st.heartbeat_s is not None
        fresh_ext = fresh_ext and abs((st.heartbeat_s or 0.0) - (st.landed_state_s or 0.0)) <= _EXT_STATE_FRESH_S
        flying_by_height = armed and pos_enu is not None and pos_enu[2] > 1.0
        in_air = st.landed_state in _LANDED_IN_AIR if fresh_ext else flying_by_height
        return Telemetry(
            heartbeat_s=st.heartbeat_s,
            custom_mode=st.custom_mode,
            autopilot=st.autopilot,
            armed=armed,
            in_air=in_air,
            position_enu_m=pos_enu,
            position_s=st.position_s,
            yaw_enu_rad=None if st.yaw_ned_rad is None else yaw_ned_to_enu(st.yaw_ned_rad),
            heartbeat_wall_s=st.heartbeat_wall_s,
            position_wall_s=st.position_wall_s,
            position_invalid=st.position_invalid,
            disarmed_heartbeats=st.disarmed_streak,
            landed_since_disarmed=st.landed_since_disarmed,
        )

    def battery(self) -> BatteryReading:
        return self._st.battery

    def odometry(self) -> OdometryReading | None:
        """The autopilot's position, attitude and velocities in ROS conventions (None before a position)."""
        st = self._st
        if st.position_ned is None or st.position_s is None:
            return None
        q_ned = st.q_ned_frd_wxyz if st.q_ned_frd_wxyz is not None else (1.0, 0.0, 0.0, 0.0)
        # The one conversion of the autopilot's estimate (core.pose_estimate); its stamp here is the arrival.
        est = estimate_from_local_position(
            0,
            st.position_ned,
            velocity_ned_mps=st.velocity_ned_mps,
            q_ned_frd_wxyz=q_ned,
            rates_frd_radps=st.rates_frd_radps,
            assumed=AssumedAccuracy(),
        )
        return OdometryReading(
            position_enu_m=est.position_enu_m,
            q_enu_flu_wxyz=est.q_enu_flu_wxyz,
            velocity_flu_mps=est.velocity_flu_mps,
            angular_flu_radps=est.angular_flu_radps,
            stamp_s=st.position_s,
            pose_covariance=est.pose_covariance,
            twist_covariance=est.twist_covariance,
        )

    def pop_status_texts(self) -> list[str]:
        out, self._st.status_texts = self._st.status_texts, []
        return out

    # ---------------------------------------------------------------- send
    def send_heartbeat_if_due(self, now_s: float, period_s: float = 1.0) -> None:
        if self._last_heartbeat_out_s is not None and now_s - self._last_heartbeat_out_s < period_s:
            return
        self._last_heartbeat_out_s = now_s
        self._mav().heartbeat_send(_MAV_TYPE_ONBOARD_CONTROLLER, _MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def execute(self, actions: Iterable[Action], now_s: float) -> None:
        """Send each action.

        Raises:
            InvalidInputError: a setpoint with NaN/inf (never sent).
        """
        for action in actions:
            if isinstance(action, SendSetpoint):
                self.send_setpoint(action.position_enu_m, action.yaw_enu_rad, now_s)
            elif isinstance(action, RequestMode):
                self.request_mode(action.mode)
            elif isinstance(action, RequestArm):
                self._command(_MAV_CMD_COMPONENT_ARM_DISARM, 1.0 if action.arm else 0.0)
            elif isinstance(action, RequestTakeoff):
                self._command(_MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, 0.0, math.nan, math.nan, math.nan, action.height_m)

    def send_setpoint(self, position_enu_m: tuple[float, float, float], yaw_enu_rad: float, now_s: float) -> None:
        """SET_POSITION_TARGET_LOCAL_NED, position + yaw (type_mask 2552).

        Raises:
            InvalidInputError: non-finite position or yaw; nothing is sent.
        """
        values = (*position_enu_m, yaw_enu_rad)
        if not all(math.isfinite(v) for v in values):
            msg = f"refusing to send a non-finite setpoint: position {position_enu_m}, yaw {yaw_enu_rad}"
            raise InvalidInputError(msg)
        n, e, d = (float(v) for v in enu_to_ned(position_enu_m))
        time_boot_ms = max(0, int((now_s - self._opened_s) * 1000.0)) & 0xFFFFFFFF
        self._mav().set_position_target_local_ned_send(
            time_boot_ms,
            self.target_system,
            self.target_component,
            _MAV_FRAME_LOCAL_NED,
            POSITION_YAW_TYPE_MASK,
            n, e, d,
            0.0, 0.0, 0.0,
            0.0, 0.0, 0.0,
            yaw_enu_to_ned(yaw_enu_rad),
            0.0,
        )  # fmt: skip

    def send_timesync(self, tc1_ns: int, ts1_ns: int) -> None:
        """TIMESYNC (#111): ``tc1 = 0`` asks the autopilot for its time; ``ts1`` is ours (ns)."""
        self._mav().timesync_send(tc1_ns, ts1_ns)

    def set_message_interval(self, msg_id: int, rate_hz: float) -> None:
        """MAV_CMD_SET_MESSAGE_INTERVAL: stream ``msg_id`` at ``rate_hz`` on this link (0: the autopilot's default)."""
        interval_us = 0.0 if rate_hz <= 0.0 else 1e6 / rate_hz
        self._command(_MAV_CMD_SET_MESSAGE_INTERVAL, float(msg_id), interval_us)

    def request_mode(self, mode: FlightMode) -> None:
        """MAV_CMD_DO_SET_MODE in the autopilot's encoding (confirmation comes from the heartbeat)."""
        armed = bool(self._st.base_mode & _MAV_MODE_FLAG_SAFETY_ARMED)
        p1, p2, p3 = set_mode_params(self._st.autopilot, mode, armed=armed)
        self._command(_MAV_CMD_DO_SET_MODE, p1, p2, p3)

    def _command(self, command: int, *params: float) -> None:
        p = [*params, *([0.0] * (7 - len(params)))]
        self._mav().command_long_send(self.target_system, self.target_component, command, 0, *p)

    def _require(self) -> object:
        if self._conn is None:
            msg = f"MAVLink connection '{self.url}' is not open"
            raise MavlinkLinkError(msg)
        return self._conn

    def _mav(self):  # type: ignore[no-untyped-def]
        return self._require().mav  # type: ignore[attr-defined]
