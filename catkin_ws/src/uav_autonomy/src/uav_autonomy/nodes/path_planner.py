"""path_planner: plans from the drone to the current goal, and replans when the goal moves or the map grows.

ROS interface:

Subscribes:
    ``/autonomy/goal`` (geometry_msgs/PointStamped): x, y used (z ignored); NaN/inf rejected.
    ``/map_server/layers`` (uav_msgs/GridLayers): its ``elevation_m`` layer is the DEM.
    ``octomap_binary`` (octomap_msgs/Octomap, binary OcTree, map frame): the voxel map, for
    ``algorithm: astar`` with ``voxel_source: octomap`` only (read from its serialized bytes).
    ``~odom_topic`` (nav_msgs/Odometry, default ``/uav/ground_truth/odom``): the start.
Publishes:
    ``/autonomy/path`` (nav_msgs/Path, map, latched): start, (climb, cruise, descend | A* waypoints), goal;
    a single pose at the drone's position means "stop here" (the path ahead is blocked and no other
    path was found).
    ``~status`` (std_msgs/String, latched): the last planning event, e.g. ``astar over the voxel map
    (the map grew: the path ahead is blocked 31 m ahead): 5 waypoints, 48.2 ms``.
    ``/autonomy/goal_unreachable`` (uav_msgs/UnreachableGoal): the goal it found no path to and why, so
    that the goal selector picks another one.
Parameters:
    ``~config`` (str, default: the project's ``config/autonomy.yaml``), section ``planner``;
    ``~overrides`` (dict, default {}); ``~odom_topic``. Any other private parameter stops the node (exit code 2).

Threads: callbacks only store their message and wake the planning thread, so a slow plan or a large
map never blocks them. The planning thread plans when the goal moves more than
``replan_distance_m`` (or the first pose arrives after a goal), and at most every
``map_check_period_s`` (ROS time) after a map update checks the rest of the current path against the new map:
if it now comes closer than ``clearance_m`` to known obstacles, it replans at once.

Causal lockstep (docs/lockstep.md): a participant with a lookahead of 2 steps; there is no planning thread:
the same planning step runs once a step, after the step's inputs, so what it plans is a function of the step.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import rospy
from geometry_msgs.msg import Point, PointStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from std_msgs.msg import Header, String

from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.core.planning import (
    ElevationMap,
    PlannerConfig,
    build_voxels,
    dem_conflict_m,
    path_conflict_m,
    plan,
    remaining_path,
)
from uav_autonomy.core.planning_voxels import (
    VoxelOccupancy,
    decode_octree,
    grid_from_occupancy,
    occupancy_from_leaves,
    plan_on_voxel_map,
)
from uav_autonomy.errors import InvalidInputError, PlanningError, UavAutonomyError
from uav_autonomy.ros.conversions import (
    NumpyGridLayers,
    OctomapBlob,
    grid_layers_from_msg,
    octomap_from_buffer,
    path_msg,
)
from uav_autonomy.ros.params import PlannerParams, autonomy_section
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import GridLayers, UnreachableGoal

PathArray = npt.NDArray[np.float64]
#: Steps between its inputs and when its path is consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 2


@dataclass
class _Inputs:
    """What the callbacks leave for the planning thread (guarded by the node's condition)."""

    dem: ElevationMap | None = None
    octomap: OctomapBlob | None = None
    octomap_version: int = 0
    map_version: int = 0
    start: tuple[float, float, float] | None = None
    goal: tuple[float, float] | None = None


class PathPlannerNode:
    def __init__(self, config: PlannerConfig, odom_topic: str) -> None:
        self.config = config
        self.odom_topic = odom_topic
        self._cond = threading.Condition()
        self._in = _Inputs()
        # Planning-thread state.
        self._path: PathArray | None = None
        self._planned_goal: tuple[float, float] | None = None
        self._checked_version = 0
        self._last_check_s = -math.inf
        self._occupancy: tuple[int, VoxelOccupancy] | None = None
        self._warned_no_octomap = False
        self._failed: tuple[tuple[float, float], int] | None = None
        self._path_source = ""
        self._stop = threading.Event()

    @property
    def uses_octomap(self) -> bool:
        return self.config.algorithm == "astar" and self.config.voxel_source == "octomap"

    def start(self, ls: Participant) -> None:
        self.ls = ls
        self.pub_path = ls.publisher("/autonomy/path", PathMsg, queue_size=1, latch=True)
        self.pub_status = ls.publisher("~status", String, queue_size=5, latch=True)
        self.pub_unreachable = ls.publisher("/autonomy/goal_unreachable", UnreachableGoal, queue_size=10)
        ls.subscribe("/map_server/layers", NumpyGridLayers, self.on_layers, queue_size=1, buff_size=2**26)
        ls.subscribe(self.odom_topic, Odometry, self.on_odom, queue_size=1)
        ls.subscribe("/autonomy/goal", PointStamped, self.on_goal, queue_size=1)
        if self.uses_octomap:
            ls.subscribe("octomap_binary", rospy.AnyMsg, self.on_octomap, queue_size=1, buff_size=2**28)
        if ls.causal:
            ls.on_step(lambda _step, _now: self._plan_step())
            return
        self._thread = threading.Thread(target=self._run, name="path_planner", daemon=True)
        self._thread.start()

    def shutdown(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()

    # ---------------------------------------------------------------- callbacks: store and wake
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
        with self._cond:
            self._in.dem = dem
            self._in.map_version += 1
            self._cond.notify()

    def on_octomap(self, msg: rospy.AnyMsg) -> None:
        try:
            blob = octomap_from_buffer(msg._buff)
            if not blob.binary or blob.tree_id != "OcTree":
                text = f"need a binary OcTree (octomap_binary), got binary={blob.binary} id={blob.tree_id!r}"
                raise InvalidInputError(text)
            if blob.frame_id not in ("map", "/map"):
                text = f"the voxel map is in frame '{blob.frame_id}', the planner plans in 'map'"
                raise InvalidInputError(text)
        except InvalidInputError as err:
            rospy.logerr_throttle(5.0, f"path_planner: ignoring voxel map: {err}")
            return
        with self._cond:
            self._in.octomap = blob
            self._in.octomap_version += 1
            self._in.map_version += 1
            self._cond.notify()

    def on_odom(self, msg: Odometry) -> None:
        p = msg.pose.pose.position
        if not all(math.isfinite(v) for v in (p.x, p.y, p.z)):
            rospy.logerr_throttle(5.0, "path_planner: ignoring non-finite odometry")
            return
        with self._cond:
            first = self._in.start is None
            self._in.start = (p.x, p.y, p.z)
            if first:
                self._cond.notify()

    def on_goal(self, msg: PointStamped) -> None:
        x, y = msg.point.x, msg.point.y
        if not (math.isfinite(x) and math.isfinite(y)):
            rospy.logerr_throttle(5.0, f"path_planner: ignoring non-finite goal ({x}, {y})")
            return
        with self._cond:
            self._in.goal = (x, y)
            self._cond.notify()

    # ---------------------------------------------------------------- planning thread
    def _snapshot(self) -> _Inputs:
        with self._cond:
            return _Inputs(**vars(self._in))

    def _run(self) -> None:
        while not (self._stop.is_set() or rospy.is_shutdown()):
            with self._cond:
                self._cond.wait(timeout=max(self.config.map_check_period_s, 0.05))
            self._plan_step()

    def _plan_step(self) -> None:
        try:
            self._step(self._snapshot())
        except Exception as err:
            rospy.logerr(f"path_planner: planning step failed: {type(err).__name__}: {err}")

    def _step(self, inputs: _Inputs) -> None:
        start, goal = inputs.start, inputs.goal
        if start is None or goal is None:
            return
        last = self._planned_goal
        if self._path is None or last is None or math.dist(last, goal) > self.config.replan_distance_m:
            if self._failed != (goal, inputs.map_version):  # retry a failed goal only on a new map
                self._plan(inputs, "new goal" if last is None else f"goal moved {math.dist(last, goal):.1f} m")
            return
        if inputs.map_version == self._checked_version:
            return
        if self.uses_octomap and inputs.octomap is not None and self._path_source == "DEM":
            self._plan(inputs, "the voxel map arrived")
            return
        now = rospy.get_time()  # simulated time in a run (and the step's in the causal lockstep)
        if now - self._last_check_s < self.config.map_check_period_s:
            return
        self._last_check_s = now
        self._checked_version = inputs.map_version
        if len(self._path) == 1:
            self._plan(inputs, "stopped: retrying on the new map", blocked=True)
            return
        hit = self._conflict(inputs, remaining_path(self._path, start))
        if hit is not None:
            self._plan(inputs, f"the map grew: the path ahead is blocked {hit:.0f} m ahead", blocked=True)

    def _skip_m(self) -> float:
        """Ignore this much of the path next to the drone: it is where it is (e.g. still climbing)."""
        c = self.config
        return c.clearance_m + math.hypot(c.voxel_xy_m, c.voxel_xy_m, c.voxel_z_m)

    def _occupancy_for(self, inputs: _Inputs) -> VoxelOccupancy | None:
        """The voxel map on the planner's lattice, decoded once per received map."""
        blob = inputs.octomap
        if blob is None:
            if not self._warned_no_octomap:
                self._warned_no_octomap = True
                rospy.logwarn("path_planner: no voxel map (octomap_binary) yet: planning over the DEM meanwhile")
            return None
        key = inputs.octomap_version
        if self._occupancy is not None and self._occupancy[0] == key:
            return self._occupancy[1]
        t0 = time.perf_counter()
        leaves = decode_octree(blob.data, blob.resolution_m)
        occ = occupancy_from_leaves(leaves, self.config)
        self._occupancy = (key, occ)
        rospy.loginfo_throttle(
            30.0,
            f"path_planner: voxel map {len(leaves.occupied)} leaves ({int(leaves.occupied.sum())} occupied) -> "
            f"{len(occ.occupied)} occupied planner cells in {(time.perf_counter() - t0) * 1e3:.0f} ms",
        )
        return occ

    def _dem_or_empty(self, inputs: _Inputs, goal: tuple[float, float]) -> ElevationMap:
        if inputs.dem is not None:
            return inputs.dem
        # Nothing mapped yet: one unknown cell; the planner uses unknown_elevation_m.
        return ElevationMap(GridSpec(1.0, goal[0] - 0.5, goal[1] - 0.5, 1, 1), np.full((1, 1), np.nan, np.float32))

    def _conflict(self, inputs: _Inputs, rest: PathArray) -> float | None:
        cfg = self.config
        start, goal = inputs.start, inputs.goal
        if start is None or goal is None:  # the caller checked
            return None
        if cfg.algorithm == "straight":
            return None if inputs.dem is None else dem_conflict_m(rest, inputs.dem, cfg.clearance_m, self._skip_m())
        occ = self._occupancy_for(inputs) if self.uses_octomap else None
        goal3 = (goal[0], goal[1], float(rest[-1, 2]))
        if occ is not None:
            grid = grid_from_occupancy(occ, start, goal3, cfg)
        else:
            grid = build_voxels(self._dem_or_empty(inputs, goal), start, goal3, cfg)
        return path_conflict_m(rest, grid, self._skip_m())

    def _plan(self, inputs: _Inputs, reason: str, *, blocked: bool = False) -> None:
        start, goal = inputs.start, inputs.goal
        if start is None or goal is None:  # the caller checked
            return
        t0 = time.perf_counter()
        try:
            occ = self._occupancy_for(inputs) if self.uses_octomap else None
            dem = self._dem_or_empty(inputs, goal)
            if occ is not None:
                path, _ = plan_on_voxel_map(start, goal, occ, self.config, dem=inputs.dem)
                source = "voxel map"
            else:
                path = plan(start, goal, dem, self.config)
                source = "DEM"
        except (PlanningError, InvalidInputError) as err:
            self._failed = (goal, inputs.map_version)
            text = f"no path to ({goal[0]:.1f}, {goal[1]:.1f}) ({reason}): {err}"
            if blocked:
                # Never keep flying a path into known obstacles: stop where the drone is.
                self._planned_goal = goal
                if self._path is None or len(self._path) != 1:
                    self._publish(np.asarray([start], dtype=np.float64))
                text += "; stopped where it is"
                rospy.logerr_throttle(5.0, f"path_planner: {text}")
            else:  # a new goal it cannot reach: keep the current path (the goal selector moves on)
                rospy.logwarn_throttle(5.0, f"path_planner: {text}")
            self.pub_status.publish(String(data=text))
            self.pub_unreachable.publish(
                UnreachableGoal(
                    header=Header(stamp=rospy.Time.now(), frame_id="map"),
                    goal=Point(x=goal[0], y=goal[1], z=math.nan),
                    reason=str(err),
                )
            )
            return
        ms = (time.perf_counter() - t0) * 1e3
        self._planned_goal = goal
        self._failed = None
        self._checked_version = inputs.map_version
        self._path_source = source
        self._publish(path)
        text = (
            f"{self.config.algorithm} over the {source} ({reason}): {len(path)} waypoints to "
            f"({goal[0]:.1f}, {goal[1]:.1f}), max z {path[:, 2].max():.1f} m, {ms:.1f} ms"
        )
        self.pub_status.publish(String(data=text))
        rospy.loginfo(f"path_planner: {text}")

    def _publish(self, path: PathArray) -> None:
        self._path = path
        self.pub_path.publish(path_msg(path, Header(stamp=rospy.Time.now(), frame_id="map")))


def main() -> None:
    run_participant("path_planner", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(UavAutonomyError,))


def _build(ls: Participant) -> None:
    params = node_params(PlannerParams, "path_planner")
    config = autonomy_section(PlannerConfig, "planner", params.config, params.overrides)
    node = PathPlannerNode(config, params.odom_topic)
    node.start(ls)
    rospy.on_shutdown(node.shutdown)
    source = f" over the {config.voxel_source}" if config.algorithm == "astar" else ""
    rospy.loginfo(f"path_planner: running ({config.algorithm}{source})")
