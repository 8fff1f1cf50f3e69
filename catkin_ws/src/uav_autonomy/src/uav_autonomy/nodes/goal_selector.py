"""goal_selector: MCDM goal selection S = sum_k w_k p_k with hysteresis.

ROS interface:

Subscribes:
    ``/autonomy/features`` (uav_msgs/GridLayers from feature_evaluator).
    ``~odom_topic`` (nav_msgs/Odometry, default ``/uav/ground_truth/odom``): for "goal reached".
    ``/autonomy/target_point`` (geometry_msgs/PointStamped): moves the target to this point at
    once (e.g. a detected person); NaN/inf points are rejected.
    ``/autonomy/goal_unreachable`` (uav_msgs/UnreachableGoal from path_planner): no path to that goal;
    the cells within ``unreachable_radius_m`` of it are excluded for ``unreachable_retry_s`` (ROS time)
    and, if it is the current goal, another goal is chosen at once.
Publishes:
    ``/autonomy/goal`` (geometry_msgs/PointStamped, map): goal cell centre; z = known elevation (NaN unknown).
    ``/autonomy/goal_reason`` (uav_msgs/GoalReason): score, weights, values and contributions at the goal.
    ``/autonomy/weights`` (uav_msgs/FeatureWeights, latched), ``/autonomy/target`` (uav_msgs/SearchTarget, latched).
Services:
    ``~set_weights`` (uav_msgs/SetWeights), ``~set_target`` (uav_msgs/SetTarget).
Parameters:
    ``~config`` (str, default: the project's ``config/autonomy.yaml``), section ``goal_selector``;
    ``~overrides`` (dict, default {}); ``~odom_topic``. Any other private parameter stops the node (exit code 2).

A decision is made on every features message (new observations) and every
``1 / reevaluate_rate_hz`` seconds (ROS time); the goal and reason are published each time.

Causal lockstep (docs/lockstep.md): a participant with a lookahead of 2 steps.
"""

from __future__ import annotations

import math
import threading

import numpy as np
import rospy
from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Odometry
from std_msgs.msg import Header

from uav_autonomy.core.features import ELEVATION, SCORED_FEATURES, FeatureMaps, Target
from uav_autonomy.core.mcdm import GoalSelector, GoalSelectorConfig
from uav_autonomy.errors import InvalidInputError, UavAutonomyError
from uav_autonomy.ros.conversions import (
    NumpyGridLayers,
    goal_msgs,
    grid_layers_from_msg,
    search_target_msg,
    target_from_points,
    weights_msg,
)
from uav_autonomy.ros.params import GoalSelectorParams, autonomy_section
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import FeatureWeights, GoalReason, GridLayers, SearchTarget, UnreachableGoal
from uav_msgs.srv import SetTarget, SetTargetResponse, SetWeights, SetWeightsResponse

#: Steps between its inputs and when its goal is consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 2


class GoalSelectorNode:
    def __init__(self, config: GoalSelectorConfig, odom_topic: str) -> None:
        self.config = config
        self.odom_topic = odom_topic
        self.core = GoalSelector(config)
        self._lock = threading.Lock()
        self._features: FeatureMaps | None = None
        self._features_stamp = 0.0
        self._frame_id = "map"
        self._drone_xy: tuple[float, float] | None = None
        self._target = Target(config.target_xy_m) if config.target_xy_m else None
        self._target_changed_s: float | None = None

    def start(self, ls: Participant) -> None:
        self.pub_goal = ls.publisher("/autonomy/goal", PointStamped, queue_size=1)
        # Every goal is scored and recorded: a queue of 1 per connection dropped one of a burst for a subscriber
        # that was slower to take it (the recorder), so the bag and the live scorer disagreed.
        self.pub_reason = ls.publisher("/autonomy/goal_reason", GoalReason, queue_size=50)
        self.pub_weights = ls.publisher("/autonomy/weights", FeatureWeights, queue_size=1, latch=True)
        self.pub_target = ls.publisher("/autonomy/target", SearchTarget, queue_size=1, latch=True)
        self._publish_weights()
        self._publish_target("config")
        ls.subscribe("/autonomy/features", NumpyGridLayers, self.on_features, queue_size=1, buff_size=2**26)
        ls.subscribe(self.odom_topic, Odometry, self.on_odom, queue_size=1)
        ls.subscribe("/autonomy/target_point", PointStamped, self.on_target_point, queue_size=10)
        ls.subscribe("/autonomy/goal_unreachable", UnreachableGoal, self.on_unreachable, queue_size=10)
        ls.service("~set_weights", SetWeights, self.on_set_weights)
        ls.service("~set_target", SetTarget, self.on_set_target)
        ls.timer(1.0 / self.config.reevaluate_rate_hz, lambda _now: self.decide(), name="reevaluate")

    def _header(self) -> Header:
        return Header(stamp=rospy.Time.now(), frame_id=self._frame_id)

    def _publish_weights(self) -> None:
        self.pub_weights.publish(weights_msg(self.core.weights, self._header()))

    def _publish_target(self, source: str) -> None:
        self.pub_target.publish(search_target_msg(self._target, self._header(), source))

    # -------------------------------------------------------------- callbacks
    def on_features(self, msg: GridLayers) -> None:
        try:
            spec, layers = grid_layers_from_msg(msg)
        except InvalidInputError as err:
            rospy.logerr_throttle(5.0, f"goal_selector: ignoring bad features: {err}")
            return
        keep: dict[str, np.typing.NDArray[np.float32]] = {
            n: layers[n] for n in (ELEVATION, *SCORED_FEATURES) if n in layers
        }
        with self._lock:
            self._features = FeatureMaps(spec, keep)
            self._features_stamp = msg.header.stamp.to_sec()
            self._frame_id = msg.header.frame_id or "map"
        self.decide()

    def on_odom(self, msg: Odometry) -> None:
        x, y = msg.pose.pose.position.x, msg.pose.pose.position.y
        if math.isfinite(x) and math.isfinite(y):
            with self._lock:
                self._drone_xy = (x, y)

    def on_target_point(self, msg: PointStamped) -> None:
        try:
            target = Target(((float(msg.point.x), float(msg.point.y)),))
        except InvalidInputError as err:
            rospy.logerr(f"goal_selector: ignoring target point: {err}")
            return
        self._set_target(target, "topic")

    def on_unreachable(self, msg: UnreachableGoal) -> None:
        xy = (float(msg.goal.x), float(msg.goal.y))
        try:
            with self._lock:
                self.core.mark_unreachable(xy, rospy.get_time())
        except InvalidInputError as err:
            rospy.logerr_throttle(5.0, f"goal_selector: ignoring unreachable goal: {err}")
            return
        rospy.loginfo(
            f"goal_selector: ({xy[0]:.1f}, {xy[1]:.1f}) is unreachable ({msg.reason}); excluding "
            f"{self.config.unreachable_radius_m:g} m around it for {self.config.unreachable_retry_s:g} s"
        )
        self.decide()

    def on_set_target(self, req: object) -> SetTargetResponse:
        try:
            target = target_from_points(req.points)  # type: ignore[attr-defined]
        except InvalidInputError as err:
            return SetTargetResponse(success=False, message=str(err))
        self._set_target(target, "service")
        return SetTargetResponse(success=True, message=f"target set: {target}")

    def on_set_weights(self, req: object) -> SetWeightsResponse:
        names, values = list(req.features), list(req.weights)  # type: ignore[attr-defined]
        if len(names) != len(values):
            return SetWeightsResponse(success=False, message=f"{len(names)} names but {len(values)} weights")
        try:
            with self._lock:
                self.core.set_weights(dict(zip(names, values, strict=True)))
        except InvalidInputError as err:
            return SetWeightsResponse(success=False, message=str(err))
        self._publish_weights()
        self.decide()
        return SetWeightsResponse(success=True, message=f"weights: {self.core.weights}")

    def _set_target(self, target: Target | None, source: str) -> None:
        with self._lock:
            if target == self._target:
                return
            self._target = target
            self._target_changed_s = rospy.get_time()
        self._publish_target(source)

    # ---------------------------------------------------------------- work
    def decide(self) -> None:
        with self._lock:
            features = self._features
            if features is None:
                return
            changed = self._target_changed_s
            if changed is not None and self._features_stamp >= changed:
                # The features now include the moved target: decide afresh.
                self.core.target_moved()
                self._target_changed_s = None
            try:
                decision = self.core.select(features, drone_xy_m=self._drone_xy, now_s=rospy.get_time())
            except InvalidInputError as err:
                rospy.logerr_throttle(5.0, f"goal_selector: no goal: {err}")
                return
        goal, reason = goal_msgs(decision, self._header())
        self.pub_goal.publish(goal)
        self.pub_reason.publish(reason)
        if decision.changed:
            parts = ", ".join(f"{k}={v:.2f}" for k, v in decision.contributions.items() if v)
            rospy.loginfo(
                f"goal_selector: goal ({decision.goal_xy_m[0]:.1f}, {decision.goal_xy_m[1]:.1f}) "
                f"S={decision.score:.3f} [{parts}] {decision.reason.value}"
            )


def main() -> None:
    run_participant("goal_selector", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(UavAutonomyError,))


def _build(ls: Participant) -> None:
    params = node_params(GoalSelectorParams, "goal_selector")
    config = autonomy_section(GoalSelectorConfig, "goal_selector", params.config, params.overrides)
    GoalSelectorNode(config, params.odom_topic).start(ls)
    rospy.loginfo("goal_selector: running")
