#!/usr/bin/env python3

"""rostest node: layers in -> features, goal, reason and path out; services and moving targets."""

from __future__ import annotations

import math
import sys
import time
import unittest
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1])]

import numpy as np  # noqa: E402
import rospy  # noqa: E402
import rostest  # noqa: E402
from geometry_msgs.msg import Point, PointStamped  # noqa: E402
from helpers.sim_clock import SimClock  # noqa: E402
from nav_msgs.msg import MapMetaData, Odometry  # noqa: E402
from nav_msgs.msg import Path as PathMsg  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from uav_autonomy.core.features import frontier_feature  # noqa: E402
from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import FeatureWeights, GoalReason, GridLayers, SearchTarget, UnreachableGoal  # noqa: E402
from uav_msgs.srv import SetTarget, SetWeights  # noqa: E402

RES, OX, OY, W, H = 5.0, -200.0, -150.0, 80, 60
MAST_CELL = (40, 20)  # (row, col): x in [-100, -95), y in [50, 55); 190 m + 40 m goal height > the 200 m ceiling


def make_layers(stamp_s: float) -> tuple[GridLayers, dict[str, np.ndarray]]:
    """A 400 x 300 m map: the middle observed, a 120 m ridge at x in [50, 60), a 190 m mast at MAST_CELL."""
    xs = OX + (np.arange(W) + 0.5) * RES
    ys = OY + (np.arange(H) + 0.5) * RES
    observed = np.zeros((H, W), dtype=bool)
    observed[10:50, 15:70] = True
    elev = np.where(observed, 0.0, np.nan).astype(np.float32)
    elev[:, (xs >= 50.0) & (xs < 60.0)] = np.where(observed[:, (xs >= 50.0) & (xs < 60.0)], 120.0, np.nan)
    elev[MAST_CELL] = 190.0
    seen = np.where(observed, stamp_s - 30.0, np.nan).astype(np.float32)
    layers = {"elevation_m": elev, "last_seen_s": seen, "observed": observed.astype(np.float32)}
    msg = GridLayers()
    msg.header.frame_id = "map"
    msg.header.stamp = rospy.Time.from_sec(stamp_s)
    msg.resolution_m, msg.origin_x_m, msg.origin_y_m, msg.width, msg.height = RES, OX, OY, W, H
    msg.names = list(layers)
    msg.data = np.stack(list(layers.values())).ravel().tolist()
    del ys
    return msg, layers


class Pipeline(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("pipeline_check")
        # Simulation time starts at 1000 s (last_seen_s is float32 in GridLayers: sim seconds, not epoch).
        cls.clock = SimClock(1000.0, step_s=0.01)
        wait_until(rospy.get_time, lambda t: t >= 1000.0, timeout_s=10.0, describe="/clock")
        cls.last: dict[str, object] = {}
        cls.reasons: list[GoalReason] = []  # every goal decision: several can come between two polls
        for topic, mtype in [
            ("/autonomy/features", GridLayers),
            ("/autonomy/goal", PointStamped),
            ("/autonomy/goal_reason", GoalReason),
            ("/autonomy/path", PathMsg),
            ("/autonomy/weights", FeatureWeights),
            ("/autonomy/target", SearchTarget),
            ("/autonomy/feature_images/score/image_color", Image),
            ("/autonomy/feature_images/frontier/image", Image),
            ("/autonomy/feature_images/info", MapMetaData),
            ("/autonomy/goal_unreachable", UnreachableGoal),
        ]:
            rospy.Subscriber(topic, mtype, lambda m, t=topic: cls.last.__setitem__(t, m))
        rospy.Subscriber("/autonomy/goal_reason", GoalReason, cls.reasons.append, queue_size=100)
        cls.pub_layers = rospy.Publisher("/map_server/layers", GridLayers, queue_size=1, latch=True)
        cls.pub_odom = rospy.Publisher("/uav/ground_truth/odom", Odometry, queue_size=1)
        cls.pub_target = rospy.Publisher("/autonomy/target_point", PointStamped, queue_size=1)
        rospy.wait_for_service("/goal_selector/set_weights", timeout=30.0)
        cls.set_weights = rospy.ServiceProxy("/goal_selector/set_weights", SetWeights)
        cls.set_target = rospy.ServiceProxy("/goal_selector/set_target", SetTarget)
        cls.timer = rospy.Timer(rospy.Duration(0.1), cls._odom)
        wait_until(cls.pub_target.get_num_connections, lambda n: n >= 1, timeout_s=10.0, describe="target subscriber")

    @classmethod
    def _odom(cls, _e: object) -> None:
        odom = Odometry()
        odom.header.frame_id = "map"
        odom.pose.pose.position.x, odom.pose.pose.position.y, odom.pose.pose.position.z = -100.0, 0.0, 0.0
        odom.pose.pose.orientation.w = 1.0
        cls.pub_odom.publish(odom)

    def wait_msg(self, topic: str, pred, timeout_s: float = 10.0):  # type: ignore[no-untyped-def]
        return wait_until(lambda: self.last.get(topic), lambda m: m is not None and pred(m), timeout_s=timeout_s,
                          describe=topic)  # fmt: skip

    def goal_cell_of(self, x: float, y: float) -> tuple[float, float]:
        return (OX + (math.floor((x - OX) / RES) + 0.5) * RES, OY + (math.floor((y - OY) / RES) + 0.5) * RES)

    def test_pipeline(self) -> None:
        now = rospy.get_time()
        msg, layers = make_layers(now)
        self.pub_layers.publish(msg)

        # Features: every layer, on the same grid, in range, frontier exactly as the core computes it.
        feats = self.wait_msg("/autonomy/features", lambda m: m.width == W)
        names = list(feats.names)
        self.assertEqual(names, ["elevation_m", "age", "frontier", "target", "drone", "origin", "score"])
        cube = np.asarray(feats.data, dtype=np.float32).reshape(len(names), H, W)
        for k, name in enumerate(names[1:6], start=1):
            self.assertGreaterEqual(float(cube[k].min()), 0.0, name)
            self.assertLessEqual(float(cube[k].max()), 1.0, name)
        np.testing.assert_allclose(cube[2], frontier_feature(layers["observed"] > 0.5, RES, None), atol=1e-6)
        age = cube[1][20, 30]
        self.assertAlmostEqual(float(age), 2 ** (-30.0 / 60.0), delta=0.05)  # seen ~30 s ago, half-life 60 s
        self.assertEqual(float(cube[1][0, 0]), 0.0)  # never seen
        np.testing.assert_allclose(cube[6], cube[2] + cube[3] + 0.5 * cube[4], atol=1e-5)  # score, weights latched

        # Goal and reason: the argmax of the score; contributions add up.
        reason = self.wait_msg("/autonomy/goal_reason", lambda m: True)
        score = cube[6]
        row, col = np.unravel_index(int(np.argmax(score)), score.shape)
        self.assertAlmostEqual(reason.score, float(score[row, col]), delta=1e-4)
        self.assertAlmostEqual(reason.score, sum(reason.contributions), delta=1e-4)
        self.assertEqual(list(reason.features), ["age", "frontier", "target", "drone", "origin"])

        # Weights service: target only -> the goal is the target's cell; a bad request changes nothing.
        self.assertFalse(self.set_weights(["frontier", "speed"], [1.0, 1.0]).success)
        self.assertFalse(self.set_weights(["frontier"], [math.nan]).success)
        resp = self.set_weights(["target"], [1.0])
        self.assertTrue(resp.success, resp.message)
        self.wait_msg("/autonomy/weights", lambda m: list(m.weights) == [0.0, 0.0, 1.0, 0.0, 0.0])
        resp = self.set_target([Point(101.0, 51.0, 0.0)])
        self.assertTrue(resp.success, resp.message)
        expected = self.goal_cell_of(101.0, 51.0)
        goal = self.wait_msg("/autonomy/goal", lambda m: (m.point.x, m.point.y) == expected)
        # the target topic and the goal topic are separate: the target's message may come after the goal's
        self.wait_msg("/autonomy/target", lambda m: m.source == "service")
        self.assertFalse(self.set_target([Point(0, 0, 0), Point(1, 1, 0)]).success)

        # Moving target on the topic (a detected person): the goal follows at once.
        t0 = time.monotonic()
        self.pub_target.publish(PointStamped(point=Point(-151.0, -101.0, 0.0)))
        expected = self.goal_cell_of(-151.0, -101.0)
        self.wait_msg("/autonomy/goal", lambda m: (m.point.x, m.point.y) == expected, timeout_s=5.0)
        self.assertLess(time.monotonic() - t0, 3.0)
        bad = PointStamped(point=Point(math.nan, 0.0, 0.0))
        self.pub_target.publish(bad)

        # Path over the ridge to a goal beyond it: climb, cruise >= ridge + 30 m buffer, descend to 40 m.
        self.assertTrue(self.set_target([Point(151.0, 1.0, 0.0)]).success)
        expected = self.goal_cell_of(151.0, 1.0)
        goal = self.wait_msg("/autonomy/goal", lambda m: (m.point.x, m.point.y) == expected)
        path = self.wait_msg("/autonomy/path", lambda m: (m.poses[-1].pose.position.x, m.poses[-1].pose.position.y)
                             == expected)  # fmt: skip
        pts = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in path.poses])
        np.testing.assert_allclose(pts[0], [-100.0, 0.0, 0.0])
        self.assertGreaterEqual(pts[:, 2].max(), 150.0 - 1e-6)
        self.assertAlmostEqual(pts[-1, 2], 40.0, delta=1e-6)  # unknown elevation there: 0 + 40
        self.assertEqual(goal.header.frame_id, "map")

        # A goal the planner cannot reach (the mast is above its ceiling): it says so, and the goal selector
        # moves on to the best cell at least unreachable_radius_m (20 m) away instead of holding it forever.
        mast_xy = (OX + (MAST_CELL[1] + 0.5) * RES, OY + (MAST_CELL[0] + 0.5) * RES)
        seen = len(self.reasons)
        self.assertTrue(self.set_target([Point(mast_xy[0], mast_xy[1], 0.0)]).success)
        bad = self.wait_msg("/autonomy/goal_unreachable", lambda m: (m.goal.x, m.goal.y) == mast_xy)
        self.assertIn("max_altitude_m 200.0", bad.reason)
        # The decision is one message among the periodic re-evaluations (hysteresis_kept) that follow it.
        reason = wait_until(
            lambda: [m for m in self.reasons[seen:] if m.reason == "goal_unreachable"],
            bool,
            timeout_s=10.0,
            describe="a goal_reason 'goal_unreachable'",
        )[0]
        moved = (reason.goal.x, reason.goal.y)
        self.assertGreater(math.dist(moved, mast_xy), 20.0)
        self.assertLess(math.dist(moved, mast_xy), 20.0 + 2 * RES)  # the nearest cells to the target left
        path = self.wait_msg("/autonomy/path", lambda m: (m.poses[-1].pose.position.x, m.poses[-1].pose.position.y)
                             == moved)  # fmt: skip
        self.assertLessEqual(max(p.pose.position.z for p in path.poses), 200.0)

        # Images: north-up, right size and encodings; info carries resolution and origin.
        img = self.wait_msg("/autonomy/feature_images/score/image_color", lambda m: True)
        self.assertEqual((img.height, img.width, img.encoding), (H, W, "rgb8"))
        raw = self.wait_msg("/autonomy/feature_images/frontier/image", lambda m: True)
        frontier_img = np.frombuffer(raw.data, dtype=np.float32).reshape(H, W)
        np.testing.assert_allclose(frontier_img[::-1], cube[2], atol=1e-6)
        info = self.wait_msg("/autonomy/feature_images/info", lambda m: True)
        self.assertEqual((info.resolution, info.origin.position.x, info.origin.position.y), (RES, OX, OY))

        # Grid growth and broken input: a bad message is ignored, a bigger grid is followed.
        broken = GridLayers(resolution_m=RES, width=W, height=H, names=["elevation_m"], data=[0.0] * 5)
        self.pub_layers.publish(broken)
        bigger, _ = make_layers(rospy.get_time())
        bigger.width, bigger.origin_x_m = W + 20, OX - 100.0
        cube_b = np.zeros((3, H, W + 20), dtype=np.float32)
        cube_b[:, :, 20:] = np.asarray(bigger.data, dtype=np.float32).reshape(3, H, W)
        cube_b[0, :, :20] = np.nan
        cube_b[1, :, :20] = np.nan
        bigger.data = cube_b.ravel().tolist()
        self.pub_layers.publish(bigger)
        self.wait_msg("/autonomy/features", lambda m: m.width == W + 20)


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "autonomy_pipeline", Pipeline)
