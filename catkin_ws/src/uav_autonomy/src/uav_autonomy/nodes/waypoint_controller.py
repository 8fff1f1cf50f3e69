"""waypoint_controller: flies the autopilot over MAVLink (PX4 OFFBOARD / ArduPilot GUIDED).

ROS interface:

Subscribes:
    ``/autonomy/path`` (nav_msgs/Path, map ENU): followed in AUTONOMOUS.
    ``~pose_topic`` (nav_msgs/Odometry, when the parameter is set): the pose the rest of the autonomy plans on.
    If it goes stale (no fresh message for ``pose_timeout_s``) or carries NaN/inf, the controller stops
    commanding at once (asks the autopilot to hold, goes IDLE, says why) and refuses to fly until it is fit.
    ``~manual_setpoint`` (geometry_msgs/PoseStamped, map ENU): operator override; switches to
    MANUAL at once (taking off first on the ground); NaN/inf rejected.
Publishes:
    ``/uav/controller/state`` (uav_msgs/ControllerState) at ``state_rate_hz`` and on every event.
    ``/uav/battery`` (sensor_msgs/BatteryState) from BATTERY_STATUS / SYS_STATUS, 1 Hz.
    ``/uav/controller/odom`` (nav_msgs/Odometry, map -> base_link) the autopilot's own estimate
    (LOCAL_POSITION_NED + ATTITUDE) at up to ``odom_rate_hz``: the pose source of the planner and
    the evaluator when no simulator bridge publishes ground truth (a real vehicle, or the e2e tests).
Services:
    ``~set_state`` (uav_msgs/SetControllerState): IDLE TAKEOFF AUTONOMOUS SCRIPTED MANUAL HOLD RTL LAND.
Parameters:
    ``~config`` (str, default: the project's ``config/autonomy.yaml``), section ``controller``;
    ``~overrides`` (dict, default {}); ``~connection_url`` (str, optional): wins over both;
    ``~pose_topic`` (str, default "": not watched).
    Any other private parameter stops the node (exit code 2, docs/architecture.md).

MAVLink: connects with ``connection_url`` (pymavlink syntax), sysid/compid 1/191,
heartbeat 1 Hz as an onboard controller, position setpoints from a ROS-time timer
at ``setpoint_rate_hz``. The decision logic is :class:`uav_autonomy.core.controller.WaypointController`.

One step per ROS time: when simulated time advances in lockstep steps longer than the timer period
(0.1 s steps, 20 Hz timer), rospy fires the timer several times back to back at the same time; only
the first steps the controller. Otherwise whether the autopilot's answer to a command sent by the
first callback (e.g. the OFFBOARD confirmation) arrived before the second one would depend on
process scheduling, and two lockstep runs could diverge by a step.

Causal lockstep (docs/lockstep.md): a participant with a lookahead of 2 steps, on both sides: its MAVLink link is
a lockstep client of the router (it reads the autopilot's messages of step k up to the router's step marker, and
ends its own with a marker), its ROS inputs are counted, and its timer fires once a step.
"""

from __future__ import annotations

import math
import threading
import time

import rospy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from sensor_msgs.msg import BatteryState
from std_msgs.msg import Header

from uav_autonomy.core.controller import (
    ControllerConfig,
    ControllerState,
    ControllerStatus,
    PoseCheck,
    WaypointController,
)
from uav_autonomy.core.patterns import expanding_square, lawnmower, waypoint_list
from uav_autonomy.core.pose_estimate import EstimateState, EstimateWatchdog
from uav_autonomy.errors import InvalidInputError, InvalidTransitionError, UavAutonomyError
from uav_autonomy.mavlink.link import MavlinkLink
from uav_autonomy.ros.conversions import (
    battery_msg,
    controller_state_msg,
    odometry_msg,
    path_from_msg,
    points_from_msgs,
    yaw_from_quaternion,
)
from uav_autonomy.ros.params import ControllerParams, mavlink_node_section
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import ControllerState as ControllerStateMsg
from uav_msgs.srv import SetControllerState, SetControllerStateResponse

#: Steps between its inputs and when its outputs (MAVLink setpoints included) are consumed (docs/lockstep.md).
LOOKAHEAD_STEPS = 2


def scripted_waypoints(req: object, default_altitude_m: float) -> list[tuple[float, float, float]]:
    """Build the SCRIPTED pattern of a SetControllerState request.

    Raises:
        InvalidInputError: unknown pattern or bad pattern parameters.
    """
    pattern = str(req.pattern).strip().lower()  # type: ignore[attr-defined]
    pts = points_from_msgs(req.points)  # type: ignore[attr-defined]
    altitude = float(req.altitude_m) if req.altitude_m > 0.0 else default_altitude_m  # type: ignore[attr-defined]
    if pattern in ("", "waypoints"):
        arr = waypoint_list(pts)
    elif pattern == "lawnmower":
        arr = lawnmower([(x, y) for x, y, _ in pts], float(req.spacing_m), altitude)  # type: ignore[attr-defined]
    elif pattern == "expanding_square":
        if not pts:
            text = "expanding_square needs the datum as points[0]"
            raise InvalidInputError(text)
        arr = expanding_square(
            (pts[0][0], pts[0][1]),
            float(req.spacing_m),  # type: ignore[attr-defined]
            altitude,
            max_radius_m=float(req.max_radius_m),  # type: ignore[attr-defined]
        )
    else:
        text = f"unknown pattern '{pattern}'; use waypoints, lawnmower or expanding_square"
        raise InvalidInputError(text)
    return [(float(a), float(b), float(c)) for a, b, c in arr]


def _clocks() -> tuple[float, float]:
    """ROS time and the wall clock, read now (the link stamps each message it reads with them)."""
    return rospy.get_time(), time.monotonic()


class WaypointControllerNode:
    def __init__(self, config: ControllerConfig, pose_topic: str = "") -> None:
        self.config = config
        self.core = WaypointController(config)
        self.pose_topic = pose_topic
        self.pose_watchdog = EstimateWatchdog(config.pose_timeout_s, config.wall_floor_s) if pose_topic else None
        self.link = MavlinkLink(
            config.connection_url,
            source_system=config.source_system,
            source_component=config.source_component,
            target_system=config.target_system,
            target_component=config.target_component,
            reconnect_after_s=config.reconnect_after_s,
            wall_floor_s=config.wall_floor_s,
        )
        self._lock = threading.Lock()
        self._last_state_pub_s = -math.inf
        self._last_battery_pub_s = -math.inf
        self._last_odom_pub_s = -math.inf
        self._last_odom_stamp_s: float | None = None
        self._last_status: ControllerStatus | None = None
        self._last_step_s: float | None = None

    def start(self, ls: Participant) -> None:
        self.ls = ls
        self.link.open(rospy.get_time(), time.monotonic())
        self.pub_state = ls.publisher("/uav/controller/state", ControllerStateMsg, queue_size=10)
        self.pub_battery = ls.publisher("/uav/battery", BatteryState, queue_size=50)  # scored and recorded: no drops
        self.pub_odom = ls.publisher("/uav/controller/odom", Odometry, queue_size=5)
        ls.subscribe("/autonomy/path", PathMsg, self.on_path, queue_size=1)
        ls.subscribe("~manual_setpoint", PoseStamped, self.on_manual, queue_size=1)
        if self.pose_topic:
            ls.subscribe(self.pose_topic, Odometry, self.on_pose, queue_size=10)
        ls.service("~set_state", SetControllerState, self.on_set_state)
        if ls.causal:
            # The MAVLink side of the lockstep: HELLO now (registered before the first step), then each step's
            # messages up to the router's marker before the step's inputs, and our marker after our setpoints.
            self.link.start_lockstep(ls.settings.lookahead_steps, ls.settings.watchdog_s, should_stop=rospy.is_shutdown)
            ls.around_step(before=self.link.read_step, after=self.link.end_step)
        ls.timer(1.0 / self.config.setpoint_rate_hz, self.on_timer, name="setpoints")

    def shutdown(self) -> None:
        self.link.close()

    # -------------------------------------------------------------- callbacks
    def _wall(self) -> float:
        """The wall clock under the timeouts' floors; in the causal lockstep simulated time (floors are 0)."""
        return self.ls.now_s() if self.ls.causal else time.monotonic()

    def on_timer(self, now: float) -> None:
        if now == self._last_step_s:  # a catch-up callback at the same simulated time (see module docstring)
            return
        with self._lock:
            now_wall = self._wall()  # the wall floor under every timeout (see core.controller)
            if not self.ls.causal:  # causal: the step's messages were read before its inputs (read_step)
                self.link.poll(now, now_wall, clock=_clocks)
                # What the poll read is as of its end, and on a loaded machine a poll can outlast simulated seconds
                # (the process descheduled, or a burst of telemetry): step and stamp the state at that time, or a
                # mode change read then is published as if seen when the callback started.
                now, now_wall = max(now, rospy.get_time()), time.monotonic()
            self._last_step_s = now
            telemetry = self.link.telemetry()
            actions = self.core.step(now, telemetry, now_wall, self._pose_check(now, now_wall))
            try:
                self.link.execute(actions, now)
            except InvalidInputError as err:  # the core never emits these; the shell double-checks
                rospy.logerr(f"waypoint_controller: {err}")
            self.link.send_heartbeat_if_due(now)
            events = self.core.pop_events()
            texts = self.link.pop_status_texts()
            status = self.core.status()
        for text in texts:
            rospy.loginfo(f"waypoint_controller: autopilot says: {text}")
        for event in events:
            rospy.loginfo(f"waypoint_controller: [{status.state.value}] {event}")
        if events or status != self._last_status or now - self._last_state_pub_s >= 1.0 / self.config.state_rate_hz:
            self._publish_state(now)
            self._last_status = status
        self._publish_odometry(now)
        battery = self.link.battery()
        if battery.stamp_s is not None and now - self._last_battery_pub_s >= 1.0:
            self._last_battery_pub_s = now
            self.pub_battery.publish(
                battery_msg(
                    Header(stamp=rospy.Time.from_sec(now), frame_id="base_link"),
                    voltage_v=battery.voltage_v,
                    current_a=battery.current_a,
                    remaining_frac=battery.remaining_frac,
                    consumed_mah=battery.consumed_mah,
                    capacity_mah=self.config.battery_capacity_mah,
                )
            )

    def on_pose(self, msg: Odometry) -> None:
        """The watched pose: finite and fresh, or the reason it is not (judged on arrival, both clocks)."""
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        values = (p.x, p.y, p.z, q.x, q.y, q.z, q.w)
        with self._lock:
            assert self.pose_watchdog is not None
            if all(math.isfinite(v) for v in values):
                self.pose_watchdog.valid(msg.header.stamp.to_sec(), rospy.get_time(), self._wall())
            else:
                self.pose_watchdog.invalid(f"a message with NaN/inf at {msg.header.stamp.to_sec():.2f} s")

    def _pose_check(self, now: float, now_wall: float) -> PoseCheck | None:
        if self.pose_watchdog is None:
            return None
        state, reason = self.pose_watchdog.state(now, now_wall)
        return PoseCheck(state == EstimateState.OK, reason, f"pose estimate on {self.pose_topic}")

    def _publish_odometry(self, now: float) -> None:
        rate = self.config.odom_rate_hz
        if rate <= 0.0 or now - self._last_odom_pub_s < 1.0 / rate:
            return
        with self._lock:
            odom = self.link.odometry()
        if odom is None or odom.stamp_s == self._last_odom_stamp_s:
            return  # nothing new: never re-publish an old estimate with a new stamp
        self._last_odom_pub_s = now
        self._last_odom_stamp_s = odom.stamp_s
        self.pub_odom.publish(odometry_msg(odom, Header(stamp=rospy.Time.from_sec(odom.stamp_s), frame_id="map")))

    def _publish_state(self, now: float) -> None:
        self._last_state_pub_s = now
        header = Header(stamp=rospy.Time.from_sec(now), frame_id="map")
        self.pub_state.publish(controller_state_msg(self.core.status(), header))

    def on_path(self, msg: PathMsg) -> None:
        try:
            with self._lock:
                self.core.set_path(path_from_msg(msg))
        except InvalidInputError as err:
            rospy.logerr_throttle(5.0, f"waypoint_controller: ignoring path: {err}")

    def on_manual(self, msg: PoseStamped) -> None:
        p = msg.pose.position
        q = msg.pose.orientation
        yaw = yaw_from_quaternion(q) if (q.x, q.y, q.z, q.w) != (0.0, 0.0, 0.0, 0.0) else None
        try:
            with self._lock:
                self.core.set_manual_setpoint((p.x, p.y, p.z), yaw, rospy.get_time())
        except UavAutonomyError as err:
            rospy.logerr(f"waypoint_controller: manual setpoint rejected: {err}")

    def on_set_state(self, req: object) -> SetControllerStateResponse:
        name = str(req.state).strip().upper()  # type: ignore[attr-defined]
        try:
            target = ControllerState[name]
        except KeyError:
            known = " ".join(s.value for s in ControllerState)
            return SetControllerStateResponse(False, f"unknown state '{name}'; known: {known}", self.core.state.value)
        try:
            kwargs: dict[str, object] = {}
            if target is ControllerState.SCRIPTED:
                kwargs["waypoints_enu_m"] = scripted_waypoints(req, self.config.scripted_altitude_m)
            elif target is ControllerState.HOLD and req.points:  # type: ignore[attr-defined]
                kwargs["stare_at_enu_m"] = points_from_msgs(req.points)[0]  # type: ignore[attr-defined]
            with self._lock:
                entered = self.core.request(target, rospy.get_time(), **kwargs)  # type: ignore[arg-type]
        except (InvalidInputError, InvalidTransitionError) as err:
            return SetControllerStateResponse(False, str(err), self.core.state.value)
        self._publish_state(rospy.get_time())
        return SetControllerStateResponse(True, self.core.status().last_event, entered.value)


def main() -> None:
    run_participant("waypoint_controller", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(UavAutonomyError,))


def _build(ls: Participant) -> None:
    params = node_params(ControllerParams, "waypoint_controller")
    config = mavlink_node_section(ControllerConfig, "controller", params)
    node = WaypointControllerNode(config, params.pose_topic)
    node.start(ls)
    rospy.on_shutdown(node.shutdown)
    watched = f", stops commanding when the pose on {params.pose_topic} is stale or NaN" if params.pose_topic else ""
    rospy.loginfo(f"waypoint_controller: MAVLink on {config.connection_url}{watched}")
