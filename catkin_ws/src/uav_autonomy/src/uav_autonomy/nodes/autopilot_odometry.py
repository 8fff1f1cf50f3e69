"""autopilot_odometry: the autopilot's own state estimate as ROS odometry and tf (what a real vehicle flies on).

ROS interface:

Publishes:
    ``~odom_topic`` (nav_msgs/Odometry, default ``/uav/autopilot/odom``): ``odom -> base_link``, stamped with
    the autopilot's own time of the estimate mapped onto ROS time (``time_sync: timesync``: TIMESYNC, see
    :mod:`uav_autonomy.core.pose_estimate`; ``shared``: the SITL, whose clock is ROS time), with its
    covariances (the autopilot's, or the configured assumed accuracy when it gives none); twist in
    ``base_link``. Only new, finite estimates, in time order.
    ``/tf``: ``odom -> base_link`` for every estimate (also one that arrived after a newer one: tf keeps its
    samples sorted, the odometry topic does not go back in time); ``/tf_static``: ``map -> odom`` (identity: the
    autopilot's local frame is anchored at home by its GNSS fusion, so ``map`` and ``odom`` coincide; a
    SLAM or VIO front end would publish the correction here).
    ``~target`` (geometry_msgs/PointStamped, frame ``map``): the autopilot's own position target
    (POSITION_TARGET_LOCAL_NED: the hold point in HOLD, the streamed setpoint in OFFBOARD), stamped like
    the odometry; the scorer's ``autopilot_tracking`` measures the vehicle against it. Only finite targets.
    ``~status`` (uav_msgs/EstimateStatus) at ``status_rate_hz`` and on every change of state: OK, WAITING,
    STALE (no fresh estimate for ``stale_timeout_s``) or INVALID (NaN/inf or failed), with the reason, the
    time mapping in force and counters. Changes of state are also logged (warnings for STALE/INVALID).
MAVLink (``connection_url``; sysid/compid 1/192, heartbeat 1 Hz as an onboard component):
    reads ODOMETRY where the autopilot sends it (``source: auto``), else LOCAL_POSITION_NED with the latest
    ATTITUDE_QUATERNION; POSITION_TARGET_LOCAL_NED; TIMESYNC answers; HEARTBEAT. Sends TIMESYNC requests at
    ``timesync_rate_hz`` and asks for ODOMETRY at ``odometry_rate_hz`` (MAV_CMD_SET_MESSAGE_INTERVAL,
    repeated until acknowledged).
Parameters:
    ``~config`` (str, default: the project's ``config/autonomy.yaml``), section ``autopilot_odometry``;
    ``~overrides`` (dict); ``~connection_url`` (str, optional, wins); ``~odom_topic`` (str).
    Any other private parameter stops the node (exit code 2, docs/architecture.md).

Messages are read by a thread that waits on the socket, so an estimate is published as soon as it arrives
(no polling timer in between). Each wake-up drains the socket and publishes the estimates that were
waiting, in order: every one of them normally (the map server interpolates the tf between them, so a
gap costs accuracy while the vehicle turns), but when the node has fallen behind (a lockstep simulation
running many times faster than real time on a loaded machine) it skips those more than
``BACKLOG_STALE_TIMEOUTS`` stale timeouts behind the newest (counted as ``superseded``) instead of working
through a backlog.

Causal lockstep (docs/lockstep.md): a participant with a lookahead of 2 steps and no reader thread: its MAVLink link
is a lockstep client of the router; each step it reads the autopilot's messages up to the router's step marker,
publishes their estimates (every one: no backlog to shed), sends what is due, and ends with its own marker.
"""

from __future__ import annotations

import math
import threading
import time

import rospy
from geometry_msgs.msg import PointStamped, TransformStamped
from nav_msgs.msg import Odometry
from std_msgs.msg import Header

from uav_autonomy.core.pose_estimate import (
    AutopilotOdometryConfig,
    EstimateState,
    EstimateWatchdog,
    PoseEstimate,
    TimeSync,
    estimate_from_local_position,
    estimate_from_odometry,
    target_from_position_target,
)
from uav_autonomy.errors import InvalidInputError, UavAutonomyError
from uav_autonomy.mavlink.link import MavlinkLink
from uav_autonomy.ros.conversions import odometry_msg
from uav_autonomy.ros.params import AutopilotOdometryParams, mavlink_node_section
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import EstimateStatus

__all__ = ["AutopilotOdometryNode", "main"]

_ODOMETRY_ID = 331
_SET_MESSAGE_INTERVAL = 511
_INTERVAL_RETRY_S = 5.0
_LINK_TIMEOUT_S = 2.0
#: A read holding estimates this many stale timeouts older than its newest is a backlog: those are skipped.
BACKLOG_STALE_TIMEOUTS = 3.0
#: Steps between its inputs and when its estimates are consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 2


class AutopilotOdometryNode:
    def __init__(self, config: AutopilotOdometryConfig, odom_topic: str) -> None:
        self.cfg = config
        self.odom_topic = odom_topic
        self.sync = TimeSync(window=config.timesync_window)
        self.watchdog = EstimateWatchdog(config.stale_timeout_s, config.wall_floor_s)
        self.link = MavlinkLink(
            config.connection_url,
            source_system=config.source_system,
            source_component=config.source_component,
            target_system=config.target_system,
            target_component=config.target_component,
            reconnect_after_s=config.reconnect_after_s,
            wall_floor_s=config.wall_floor_s,
            on_message=self._on_message,
        )
        self._lock = threading.Lock()
        self._attitude: tuple[tuple[float, float, float, float], tuple[float, float, float]] | None = None
        self._pending: list[object] = []  # the ODOMETRY and LOCAL_POSITION_NED of this wake-up, in order
        self.superseded = 0
        self._last_odometry_s: float | None = None
        self._pending_ts1: dict[int, float] = {}
        self._last_timesync_s = -math.inf
        self._interval_acked = config.odometry_rate_hz <= 0.0
        self._last_interval_s = -math.inf
        self._last_stamp_s = -math.inf
        self._source = ""
        self._from_autopilot = False
        self._published = 0
        self._out_of_order = 0
        self._reported: tuple[str, str] = ("", "")
        self._stop = threading.Event()

    # ------------------------------------------------------------------ setup
    def start(self, ls: Participant) -> None:
        cfg = self.cfg
        self.ls = ls
        self.pub_odom = ls.publisher(self.odom_topic, Odometry, queue_size=50)
        self.pub_status = ls.publisher("~status", EstimateStatus, queue_size=10, latch=True)
        self.pub_target = ls.publisher("~target", PointStamped, queue_size=20)
        self.tf = ls.tf_broadcaster()
        self.tf_static = ls.tf_broadcaster(static=True)
        identity = TransformStamped()
        identity.header = Header(stamp=rospy.Time(0), frame_id=cfg.map_frame)
        identity.child_frame_id = cfg.odom_frame
        identity.transform.rotation.w = 1.0
        self.tf_static.sendTransform([identity])
        self.link.open(rospy.get_time(), time.monotonic())
        ls.timer(1.0 / cfg.status_rate_hz, self._on_status_timer, name="status")
        if ls.causal:
            self.link.start_lockstep(ls.settings.lookahead_steps, ls.settings.watchdog_s, should_stop=rospy.is_shutdown)
            ls.around_step(before=self.link.read_step, after=self.link.end_step)
            ls.on_step(self._step)
            return
        self._thread = threading.Thread(target=self._read_loop, name="autopilot_odometry-reader", daemon=True)
        self._thread.start()

    def _step(self, _step: int, now: float) -> None:
        """Causal lockstep: the step's messages were read (read_step); estimate them all, send what is due."""
        with self._lock:
            self._estimate_pending(now, now, shed=False)
            self._send_periodic(now)

    def shutdown(self) -> None:
        self._stop.set()
        if getattr(self, "_thread", None) is not None:
            self._thread.join(timeout=1.0)
        self.link.close()

    # ------------------------------------------------------------------ reading
    def _read_loop(self) -> None:
        while not self._stop.is_set() and not rospy.is_shutdown():
            try:
                self.link.wait_readable(0.05)
                now, wall = rospy.get_time(), time.monotonic()
                with self._lock:
                    # each message stamped with the clocks when it is read, not the poll's start: a poll on a
                    # loaded machine can outlast simulated seconds (the waypoint controller's poll does the same)
                    self.link.poll(now, wall, clock=_clocks)
                    now, wall = max(now, rospy.get_time()), time.monotonic()
                    self._estimate_pending(now, wall)
                    self._send_periodic(now)
            except UavAutonomyError as err:  # the socket could not be reopened: say so, keep trying
                rospy.logerr_throttle(10.0, f"autopilot_odometry: {err}")
                time.sleep(0.5)
            except rospy.ROSException:
                break  # shutting down

    def _send_periodic(self, now: float) -> None:
        cfg = self.cfg
        self.link.send_heartbeat_if_due(now)
        if cfg.timesync_rate_hz > 0.0 and now - self._last_timesync_s >= 1.0 / cfg.timesync_rate_hz:
            self._last_timesync_s = now
            ts1 = round(now * 1e9)
            self._pending_ts1 = {k: v for k, v in self._pending_ts1.items() if now - v <= self.sync.max_rtt_s}
            self._pending_ts1[ts1] = now
            self.link.send_timesync(0, ts1)
        if not self._interval_acked and now - self._last_interval_s >= _INTERVAL_RETRY_S:
            self._last_interval_s = now
            self.link.set_message_interval(_ODOMETRY_ID, cfg.odometry_rate_hz)

    def _on_message(self, msg: object, now: float, wall: float | None) -> None:
        mtype = msg.get_type()  # type: ignore[attr-defined]
        if now <= 0.0:
            return  # no clock yet (simulated time before the first /clock): nothing can be stamped
        if mtype == "TIMESYNC":
            tc1, ts1 = int(msg.tc1), int(msg.ts1)  # type: ignore[attr-defined]
            if tc1 != 0 and self._pending_ts1.pop(ts1, None) is not None:
                self.sync.on_timesync(ts1 * 1e-9, tc1 * 1e-9, now)
        elif mtype == "COMMAND_ACK":
            if int(msg.command) == _SET_MESSAGE_INTERVAL and int(msg.result) == 0:  # type: ignore[attr-defined]
                self._interval_acked = True
        elif mtype == "ATTITUDE_QUATERNION":
            m = msg
            q = (float(m.q1), float(m.q2), float(m.q3), float(m.q4))  # type: ignore[attr-defined]
            rates = (float(m.rollspeed), float(m.pitchspeed), float(m.yawspeed))  # type: ignore[attr-defined]
            self._attitude = (q, rates)
        elif mtype in ("ODOMETRY", "LOCAL_POSITION_NED"):
            self._pending.append(msg)
        elif mtype == "POSITION_TARGET_LOCAL_NED":
            self._on_position_target(msg, now)

    def _estimate_pending(self, now: float, wall: float | None, *, shed: bool = True) -> None:
        """The estimates this wake-up read (the socket is drained), in order, shedding a backlog (module doc)
        unless ``shed`` is false (the causal lockstep has none: every step's estimates are published)."""
        pending, self._pending = self._pending, []
        if now <= 0.0 or not pending:
            return
        newest = max(_stamp_s(m) for m in pending)
        backlog_s = BACKLOG_STALE_TIMEOUTS * self.cfg.stale_timeout_s if shed else math.inf
        for msg in pending:
            if newest - _stamp_s(msg) > backlog_s:
                self.superseded += 1
            elif msg.get_type() == "ODOMETRY":  # type: ignore[attr-defined]
                self._on_odometry(msg, now, wall)
            else:
                self._on_local_position(msg, now, wall)

    def _on_odometry(self, m: object, now: float, wall: float | None) -> None:
        if self.cfg.source == "local_position":
            return
        self._last_odometry_s = now
        try:
            est = estimate_from_odometry(
                int(m.time_usec),  # type: ignore[attr-defined]
                frame_id=int(m.frame_id),  # type: ignore[attr-defined]
                child_frame_id=int(m.child_frame_id),  # type: ignore[attr-defined]
                position_ned_m=(m.x, m.y, m.z),  # type: ignore[attr-defined]
                q_ned_frd_wxyz=tuple(m.q),  # type: ignore[attr-defined]
                velocity_child_mps=(m.vx, m.vy, m.vz),  # type: ignore[attr-defined]
                rates_frd_radps=(m.rollspeed, m.pitchspeed, m.yawspeed),  # type: ignore[attr-defined]
                pose_covariance_urt=tuple(m.pose_covariance),  # type: ignore[attr-defined]
                velocity_covariance_urt=tuple(m.velocity_covariance),  # type: ignore[attr-defined]
                quality=int(getattr(m, "quality", 0)),
                assumed=self.cfg.assumed_accuracy,
            )
        except InvalidInputError as err:
            self.watchdog.invalid(str(err))
            return
        self._publish(est, now, wall)

    def _on_local_position(self, m: object, now: float, wall: float | None) -> None:
        cfg = self.cfg
        if cfg.source == "odometry":
            return
        recent = self._last_odometry_s is not None and now - self._last_odometry_s <= cfg.odometry_fallback_s
        if cfg.source == "auto" and recent:
            return
        if self._attitude is None:
            return  # no ATTITUDE_QUATERNION yet: a position without an attitude cannot place the cameras
        q, rates = self._attitude
        try:
            est = estimate_from_local_position(
                int(m.time_boot_ms),  # type: ignore[attr-defined]
                (m.x, m.y, m.z),  # type: ignore[attr-defined]
                velocity_ned_mps=(m.vx, m.vy, m.vz),  # type: ignore[attr-defined]
                q_ned_frd_wxyz=q,
                rates_frd_radps=rates,
                assumed=cfg.assumed_accuracy,
            )
        except InvalidInputError as err:
            self.watchdog.invalid(str(err))
            return
        self._publish(est, now, wall)

    def _on_position_target(self, m: object, now: float) -> None:
        target = target_from_position_target(
            int(m.time_boot_ms),  # type: ignore[attr-defined]
            int(m.type_mask),  # type: ignore[attr-defined]
            (m.x, m.y, m.z),  # type: ignore[attr-defined]
        )
        if target is None:
            return
        t = target.t_autopilot_s
        stamp = t if self.cfg.time_sync == "shared" else self.sync.to_local(t)
        if not math.isfinite(stamp):
            return
        msg = PointStamped(header=Header(stamp=rospy.Time.from_sec(stamp), frame_id=self.cfg.map_frame))
        msg.point.x, msg.point.y, msg.point.z = target.position_enu_m
        self.pub_target.publish(msg)

    # ------------------------------------------------------------------ output
    def _publish(self, est: PoseEstimate, now: float, wall: float | None) -> None:
        cfg = self.cfg
        self.sync.on_arrival(est.t_autopilot_s, now)
        stamp = est.t_autopilot_s if cfg.time_sync == "shared" else self.sync.to_local(est.t_autopilot_s)
        if not math.isfinite(stamp):
            return
        if stamp == self._last_stamp_s:
            self._out_of_order += 1  # the same estimate again
            return
        in_order = stamp > self._last_stamp_s
        ros_stamp = rospy.Time.from_sec(stamp)
        if in_order:
            # The odometry topic never goes back in time; a reordered (older) estimate still goes to tf below,
            # which keeps its samples sorted: the map server interpolates between them.
            self._last_stamp_s = stamp
            self.watchdog.valid(stamp, now, wall)
            self._source = est.source
            self._from_autopilot = est.covariance_from_autopilot
            msg = odometry_msg(est, Header(stamp=ros_stamp, frame_id=cfg.odom_frame), cfg.base_frame)
            self.pub_odom.publish(msg)
        else:
            self._out_of_order += 1
        tf = TransformStamped()
        tf.header = Header(stamp=ros_stamp, frame_id=cfg.odom_frame)
        tf.child_frame_id = cfg.base_frame
        tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = est.position_enu_m
        w, x, y, z = est.q_enu_flu_wxyz
        r = tf.transform.rotation
        r.x, r.y, r.z, r.w = x, y, z, w
        self.tf.sendTransform(tf)
        self._published += 1

    def _on_status_timer(self, now: float) -> None:
        wall = now if self.ls.causal else time.monotonic()
        with self._lock:
            state, reason = self.watchdog.state(now, wall)
            tel = self.link.telemetry()
            status = EstimateStatus(
                header=Header(stamp=rospy.Time.from_sec(now), frame_id=self.cfg.odom_frame),
                state=state,
                reason=reason,
                source=self._source,
                time_sync="shared" if self.cfg.time_sync == "shared" else self.sync.method,
                time_offset_s=self.sync.offset_s,
                time_sync_rtt_s=self.sync.rtt_s,
                age_s=now - self._last_stamp_s if math.isfinite(self._last_stamp_s) else math.nan,
                covariance_from_autopilot=self._from_autopilot,
                link_ok=tel.heartbeat_s is not None and now - tel.heartbeat_s <= _LINK_TIMEOUT_S,
                published=self._published,
                invalid=self.watchdog.invalid_count,
                late=self.watchdog.late_count,
                out_of_order=self._out_of_order,
                superseded=self.superseded,
            )
        self.pub_status.publish(status)
        if (state, reason.split(" for ")[0]) != self._reported:
            self._report(state, reason)

    def _report(self, state: str, reason: str) -> None:
        self._reported = (state, reason.split(" for ", maxsplit=1)[0])
        text = f"autopilot_odometry: estimate {state}" + (f": {reason}" if reason else "")
        if state in (EstimateState.STALE, EstimateState.INVALID):
            rospy.logwarn(text + " (the autonomy must not fly on it)")
        else:
            timing = "the autopilot's clock (shared)" if self.cfg.time_sync == "shared" else f"by {self.sync.method}"
            rospy.loginfo(text + (f" ({self._source or 'no source yet'}, time {timing})"))


def _clocks() -> tuple[float, float]:
    """ROS time and the wall clock, read now (the link stamps each message it reads with them)."""
    return rospy.get_time(), time.monotonic()


def _stamp_s(msg: object) -> float:
    """The autopilot's time of an ODOMETRY (``time_usec``) or LOCAL_POSITION_NED (``time_boot_ms``)."""
    if hasattr(msg, "time_usec"):
        return float(msg.time_usec) * 1e-6
    return float(msg.time_boot_ms) * 1e-3  # type: ignore[attr-defined]


def main() -> None:
    run_participant("autopilot_odometry", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(UavAutonomyError,))


def _build(ls: Participant) -> None:
    params = node_params(AutopilotOdometryParams, "autopilot_odometry")
    config = mavlink_node_section(AutopilotOdometryConfig, "autopilot_odometry", params)
    node = AutopilotOdometryNode(config, params.odom_topic)
    node.start(ls)
    rospy.on_shutdown(node.shutdown)
    rospy.loginfo(
        f"autopilot_odometry: MAVLink on {config.connection_url}, {params.odom_topic} + tf "
        f"{config.map_frame} -> {config.odom_frame} -> {config.base_frame} (source {config.source})"
    )
