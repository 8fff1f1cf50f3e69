#!/usr/bin/env python3

"""rostest node: clouds into the real map server -> features, goal and a 3D path out; a new wall -> replan.

The scene, seen by a nadir camera 45 m above (30, 0): flat ground (z = 0) over x in [-10, 80), y in [-24, 24).
The goal selector only weighs the distance to the target (60, 0), so the goal is the map cell nearest to it;
the drone is at (0, 0, 20). Then a wall (x in [30, 34), y in [-24, 24), 0..54 m: higher than the planner's
ceiling allows to clear) appears on the way: the planner must notice it in the voxel map and replan around
its ends, keeping the clearance.
"""

from __future__ import annotations

import itertools
import math
import sys
import threading
import time
import unittest
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1])]

import numpy as np  # noqa: E402
import rosgraph  # noqa: E402
import rospy  # noqa: E402
import rostest  # noqa: E402
import tf2_ros  # noqa: E402
from geometry_msgs.msg import PointStamped, TransformStamped  # noqa: E402
from helpers.sim_clock import SimClock  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from nav_msgs.msg import Path as PathMsg  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from std_msgs.msg import String  # noqa: E402

from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import GridLayers, MapInsertStats  # noqa: E402

FRAME = "camera_test_optical"
CAM = (30.0, 0.0, 45.0)
SIM_START_S = 1000.0
CLEARANCE_M = 6.0
WALL = (30.0, 34.0, -24.0, 24.0, 54.0)  # x0, x1, y0, y1, top


def ground_points() -> np.ndarray:
    xs, ys = np.meshgrid(np.arange(-10.0, 80.0, 0.5) + 0.25, np.arange(-24.0, 24.0, 0.5) + 0.25, indexing="xy")
    return np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)


def wall_points() -> np.ndarray:
    x0, x1, y0, y1, top = WALL
    ys, zs = np.meshgrid(np.arange(y0, y1, 0.5) + 0.25, np.arange(0.0, top, 0.5) + 0.25, indexing="xy")
    west = np.stack([np.full(ys.size, x0 + 0.1), ys.ravel(), zs.ravel()], axis=1)
    xs, ys2 = np.meshgrid(np.arange(x0, x1, 0.5) + 0.25, np.arange(y0, y1, 0.5) + 0.25, indexing="xy")
    roof = np.stack([xs.ravel(), ys2.ravel(), np.full(xs.size, top - 0.1)], axis=1)
    return np.concatenate([west, roof])


def cloud_msg(p_map: np.ndarray, stamp: rospy.Time) -> PointCloud2:
    """Points in the optical frame of a nadir camera at CAM (x east, y south, z down), grey."""
    p = np.stack([p_map[:, 0] - CAM[0], -(p_map[:, 1] - CAM[1]), CAM[2] - p_map[:, 2]], axis=1).astype(np.float32)
    msg = PointCloud2()
    msg.header.stamp = stamp
    msg.header.frame_id = FRAME
    msg.height, msg.width = 1, len(p)
    msg.fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate("xyz")]
    msg.fields.append(PointField(name="rgb", offset=12, datatype=PointField.FLOAT32, count=1))
    msg.is_bigendian = False
    msg.point_step = 16
    msg.row_step = 16 * len(p)
    msg.is_dense = True
    packed = np.zeros(len(p), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    packed["x"], packed["y"], packed["z"] = p[:, 0], p[:, 1], p[:, 2]
    packed["rgb"] = (128 << 16) | (128 << 8) | 128
    msg.data = packed.tobytes()
    return msg


def path_points(msg: PathMsg) -> np.ndarray:
    return np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in msg.poses])


def wall_gap_m(path: np.ndarray) -> float:
    """Smallest distance between the path (after its first leg) and the wall's box."""
    x0, x1, y0, y1, top = WALL
    lo, hi = np.array([x0, y0, 0.0]), np.array([x1, y1, top])
    pts = np.concatenate([np.linspace(a, b, 400) for a, b in itertools.pairwise(path[1:])])
    gap = np.maximum(np.maximum(lo - pts, pts - hi), 0.0)
    return float(np.sqrt((gap**2).sum(axis=1)).min())


class MapChain(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("map_chain_check")
        cls.clock = SimClock(SIM_START_S)  # simulation time from SIM_START_S, 50 Hz
        wait_until(rospy.get_time, lambda t: t >= SIM_START_S, timeout_s=10.0, describe="/clock")
        tf = TransformStamped()
        tf.header.stamp = rospy.Time.from_sec(SIM_START_S - 10.0)
        tf.header.frame_id = "map"
        tf.child_frame_id = FRAME
        tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = CAM
        tf.transform.rotation.x = 1.0  # 180 deg about x: optical z down, y south
        cls.tf_static = tf2_ros.StaticTransformBroadcaster()
        cls.tf_static.sendTransform(tf)
        cls.lock = threading.Lock()
        cls.paths: list[PathMsg] = []
        cls.goals: list[PointStamped] = []
        cls.features: list[GridLayers] = []
        cls.stats: list[MapInsertStats] = []
        cls.status: list[str] = []
        rospy.Subscriber("/autonomy/path", PathMsg, cls._add(cls.paths), queue_size=10)
        rospy.Subscriber("/autonomy/goal", PointStamped, cls._add(cls.goals), queue_size=10)
        rospy.Subscriber("/autonomy/features", GridLayers, cls._add(cls.features), queue_size=2, buff_size=2**24)
        rospy.Subscriber("/map_server/insert_stats", MapInsertStats, cls._add(cls.stats), queue_size=20)
        rospy.Subscriber("/path_planner/status", String, lambda m: cls._add(cls.status)(m.data), queue_size=20)
        cls.pub_cloud = rospy.Publisher("/test/points", PointCloud2, queue_size=2)
        cls.pub_odom = rospy.Publisher("/uav/ground_truth/odom", Odometry, queue_size=1, latch=True)
        wait_until(cls.pub_cloud.get_num_connections, lambda n: n > 0, timeout_s=30.0, describe="map_server subscribed")
        # The chain must be listening before the first cloud: a map published before the planner subscribed
        # would reach it only at the next change (latch is off here, as in the scenario runs).
        master = rosgraph.Master(rospy.get_name())

        def planner_inputs() -> set[str]:
            _, subs, _ = master.getSystemState()
            return {topic for topic, nodes in subs if "/path_planner" in nodes}

        wait_until(
            planner_inputs,
            lambda t: {"/octomap_binary", "/map_server/layers", "/autonomy/goal"} <= t,
            timeout_s=30.0,
            describe="path_planner subscribed to the map and the goal",
        )
        odom = Odometry()
        odom.header.frame_id = "map"
        odom.header.stamp = rospy.Time.from_sec(SIM_START_S)
        odom.pose.pose.position.z = 20.0
        odom.pose.pose.orientation.w = 1.0
        cls.pub_odom.publish(odom)

    @classmethod
    def _add(cls, store: list) -> object:
        def cb(msg: object) -> None:
            with cls.lock:
                store.append(msg)

        return cb

    def insert(self, points: np.ndarray) -> None:
        n = len(self.stats)
        self.pub_cloud.publish(cloud_msg(points, rospy.Time.from_sec(self.clock.now_s)))
        stats = wait_until(lambda: self.stats[n:], lambda s: len(s) > 0, timeout_s=20.0, describe="insert_stats")
        self.assertTrue(stats[0].inserted, stats[0].drop_reason)

    def test_chain_plans_over_the_voxel_map_and_replans_around_a_new_wall(self) -> None:
        t0 = time.monotonic()
        self.insert(ground_points())
        feats = wait_until(lambda: list(self.features), lambda f: len(f) > 0, timeout_s=30.0, describe="features")
        self.assertIn("score", feats[-1].names)
        goal = wait_until(lambda: list(self.goals), lambda g: len(g) > 0, timeout_s=30.0, describe="a goal")[-1]
        self.assertLess(math.hypot(goal.point.x - 60.0, goal.point.y), 1.5, goal.point)
        # The planner may plan once before the ground's voxels reach it (over an empty voxel map, aiming at an
        # unknown height); it replans when they arrive. Wait for the path over the ground's voxels.
        wait_until(
            lambda: (list(self.status), list(self.paths)),
            lambda sp: len(sp[0]) > 0 and "over the voxel map" in sp[0][-1] and len(sp[1]) > 0
            and abs(path_points(sp[1][-1])[-1][2] - 14.0) < 1e-6,
            timeout_s=30.0, describe="a path over the voxel map of the ground",
        )  # fmt: skip
        p1 = path_points(self.paths[-1])
        np.testing.assert_allclose(p1[0], [0.0, 0.0, 20.0])
        # Aimed 10 m above the top of the ground voxels ([0, 1) m), raised to the lowest planner voxel (4 m,
        # centred on 2 + 4k) that keeps the 6 m clearance: the one centred at 14 m.
        np.testing.assert_allclose(p1[-1], [goal.point.x, goal.point.y, 14.0], atol=1e-6)
        self.assertLess(wall_gap_m(p1), 0.1, "the first path goes straight through where the wall will be")
        n_status = len(self.status)  # earlier "the map grew" replans (the ground arriving) do not count
        self.insert(wall_points())
        status = wait_until(
            lambda: list(self.status[n_status:]),
            lambda s: len(s) > 0 and "the map grew" in s[-1],
            timeout_s=30.0,
            describe="a path replanned around the wall",
        )[-1]
        self.assertIn("over the voxel map", status)
        time.sleep(0.5)  # the path is published just before its status
        p2 = path_points(self.paths[-1])
        self.assertGreater(len(p2), 2, p2)
        np.testing.assert_allclose(p2[-1], p1[-1], atol=1e-6)
        gap = wall_gap_m(p2)
        self.assertGreaterEqual(gap, CLEARANCE_M - 1.0, f"replanned path passes {gap:.1f} m from the wall: {p2}")
        rospy.loginfo(f"map_chain_check: {status}; first path {p1.tolist()}, replanned {p2.tolist()}, gap {gap:.1f} m")
        self.assertLess(time.monotonic() - t0, 80.0)


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "autonomy_map_chain", MapChain)
