"""path_planner: plans from the drone to the current goal over the known DEM.

ROS interface:

Subscribes:
    ``/autonomy/goal`` (geometry_msgs/PointStamped): x, y used (z ignored); NaN/inf rejected.
    ``/map_server/layers`` (uav_msgs/GridLayers): its ``elevation_m`` layer is the DEM.
    ``~odom_topic`` (nav_msgs/Odometry, default ``/uav/ground_truth/odom``): the start.
Publishes:
    ``/autonomy/path`` (nav_msgs/Path, map): start, (climb, cruise, descend | A* waypoints), goal.
Parameters:
    ``~config`` (str, default ``<repo>/config/autonomy.yaml``), section ``planner``;
    ``~overrides`` (dict, default {}).

Replans when the goal moves more than ``replan_distance_m`` (or when the first
pose arrives after a goal). On NoPathError it logs and publishes nothing, so the
controller keeps its last path.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import numpy as np
import rospy
from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from std_msgs.msg import Header

from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.core.planning import ElevationMap, PlannerConfig, plan
from uav_autonomy.errors import InvalidInputError, PlanningError
from uav_autonomy.ros.autonomy_conversions import grid_layers_from_msg, path_msg
from uav_autonomy.ros.autonomy_params import default_config_path, load_section
from uav_common.config import ConfigError
from uav_msgs.msg import GridLayers


class PathPlannerNode:
    def __init__(self, config: PlannerConfig) -> None:
        self.config = config
        self._lock = threading.Lock()
        self._dem: ElevationMap | None = None
        self._start: tuple[float, float, float] | None = None
        self._goal: tuple[float, float] | None = None
        self._planned_goal: tuple[float, float] | None = None

    def start(self) -> None:
        self.pub_path = rospy.Publisher("/autonomy/path", PathMsg, queue_size=1, latch=True)
        rospy.Subscriber("/map_server/layers", GridLayers, self.on_layers, queue_size=1, buff_size=2**26)
        rospy.Subscriber(rospy.get_param("~odom_topic", "/uav/ground_truth/odom"), Odometry, self.on_odom, queue_size=1)
        rospy.Subscriber("/autonomy/goal", PointStamped, self.on_goal, queue_size=1)

    def on_layers(self, msg: GridLayers) -> None:
        try:
            spec, layers = grid_layers_from_msg(msg)
            if "elevation_m" not in layers:
                text = f"no elevation_m layer (have {sorted(layers)})"
                raise InvalidInputError(text)
            dem = ElevationMap(spec, layers["elevation_m"])
        except InvalidInputError as err:
            rospy.logerr_throttle(5.0, f"path_planner: ignoring bad layers: {err}")
            return
        with self._lock:
            self._dem = dem

    def on_odom(self, msg: Odometry) -> None:
        p = msg.pose.pose.position
        if all(math.isfinite(v) for v in (p.x, p.y, p.z)):
            with self._lock:
                first = self._start is None
                self._start = (p.x, p.y, p.z)
            if first:
                self.replan()

    def on_goal(self, msg: PointStamped) -> None:
        x, y = msg.point.x, msg.point.y
        if not (math.isfinite(x) and math.isfinite(y)):
            rospy.logerr_throttle(5.0, f"path_planner: ignoring non-finite goal ({x}, {y})")
            return
        with self._lock:
            self._goal = (x, y)
            last = self._planned_goal
        if last is None or math.dist(last, (x, y)) > self.config.replan_distance_m:
            self.replan()

    def replan(self) -> None:
        with self._lock:
            start, goal, dem = self._start, self._goal, self._dem
        if start is None or goal is None:
            return
        if dem is None:  # nothing mapped yet: one unknown cell; the planner uses unknown_elevation_m
            dem = ElevationMap(GridSpec(1.0, goal[0] - 0.5, goal[1] - 0.5, 1, 1), np.full((1, 1), np.nan, np.float32))
        t0 = time.perf_counter()
        try:
            path = plan(start, goal, dem, self.config)
        except (PlanningError, InvalidInputError) as err:
            rospy.logwarn_throttle(5.0, f"path_planner: no path to ({goal[0]:.1f}, {goal[1]:.1f}): {err}")
            return
        ms = (time.perf_counter() - t0) * 1e3
        with self._lock:
            self._planned_goal = goal
        self.pub_path.publish(path_msg(path, Header(stamp=rospy.Time.now(), frame_id="map")))
        rospy.loginfo(
            f"path_planner: {self.config.algorithm} path with {len(path)} waypoints to "
            f"({goal[0]:.1f}, {goal[1]:.1f}), max z {path[:, 2].max():.1f} m, planned in {ms:.1f} ms"
        )


def main() -> None:
    rospy.init_node("path_planner")
    path = Path(rospy.get_param("~config", str(default_config_path())))
    try:
        config = load_section(PlannerConfig, path, "planner", rospy.get_param("~overrides", None))
    except ConfigError as err:
        rospy.logfatal(f"path_planner: {err}")
        raise SystemExit(1) from err
    PathPlannerNode(config).start()
    rospy.loginfo(f"path_planner: running ({config.algorithm})")
    rospy.spin()
