#!/usr/bin/env python3
# A rostest node: unittest assertions are how rosunit reports.
"""rostest node: a synthetic camera flight in, depth images, clouds, metrics and status out.

It plays the sim bridge's part: /clock, tf map -> base_link -> camera_nadir_optical,
odometry, and per frame a color image, a ground-truth depth image and an instance
image of an exactly known scene (tests/unit/depth/synthetic_scene.py), all with the
same stamp. Then it checks what depth_estimator (poses from tf), a second
depth_estimator (poses from odometry) and depth_evaluator publish, and that bad
input is counted, not fatal.
"""

from __future__ import annotations

import json
import math
import os
import sys
import threading
import time
import unittest
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1]), str(HERE.parents[1] / "unit" / "perception")]
import numpy as np  # noqa: E402
import rospy  # noqa: E402
import rostest  # noqa: E402
from geometry_msgs.msg import TransformStamped  # noqa: E402
from helpers.ros_collect import Collector  # noqa: E402 - after the path set-up
from nav_msgs.msg import Odometry  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField  # noqa: E402
from synthetic_scene import default_scene, nadir_rotation  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from uav_common.rotations import quat_from_matrix  # noqa: E402
from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import DepthEstimatorStatus, DepthMetrics  # noqa: E402
from uav_perception.core.depth.types import CameraPose, PinholeCamera  # noqa: E402

CAM = PinholeCamera(320, 240, 160.0, 160.0, 159.5, 119.5)
OPTICAL = "camera_nadir_optical"
HEADING = 0.3
SPEED_MPS = 8.0
RATE_HZ = 10.0
N_FRAMES = 14
T0_S = 100.0
R_BASE_OPTICAL = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # nadir mount, FLU body
RUN_DIR = Path(os.environ.get("UAV_DEPTH_RUN_DIR", "/tmp/depth_rostest_run"))


def body_pose(k: int) -> CameraPose:
    fwd = np.array([math.cos(HEADING), math.sin(HEADING), 0.0])
    yaw = np.array([[math.cos(HEADING), -math.sin(HEADING), 0], [math.sin(HEADING), math.cos(HEADING), 0], [0, 0, 1]])
    pos = np.array([-6.0, -2.0, 50.0]) + fwd * SPEED_MPS * k / RATE_HZ
    return CameraPose(yaw, pos)


def stamp(k: int) -> rospy.Time:
    return rospy.Time.from_sec(T0_S + k / RATE_HZ)


def image_msg(arr: np.ndarray, encoding: str, t: rospy.Time) -> Image:
    msg = Image(height=arr.shape[0], width=arr.shape[1], encoding=encoding, is_bigendian=0)
    msg.header.stamp, msg.header.frame_id = t, OPTICAL
    data = np.ascontiguousarray(arr)
    msg.step = data.strides[0]
    msg.data = data.tobytes()
    return msg


def transform(parent: str, child: str, pose: CameraPose, t: rospy.Time) -> TransformStamped:
    tf = TransformStamped()
    tf.header.stamp, tf.header.frame_id, tf.child_frame_id = t, parent, child
    tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = pose.position_map_m
    w, x, y, z = quat_from_matrix(pose.rotation_map_optical)
    tf.transform.rotation.x, tf.transform.rotation.y, tf.transform.rotation.z, tf.transform.rotation.w = x, y, z, w
    return tf


class TestDepthNodes(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("depth_check")
        scene = default_scene(seed=0)
        cls.frames = []
        for k in [*range(N_FRAMES), N_FRAMES + 3]:
            cam_pose = body_pose(k).compose(R_BASE_OPTICAL, np.zeros(3))
            assert np.allclose(cam_pose.rotation_map_optical, nadir_rotation(HEADING))
            cls.frames.append(scene.render(CAM, cam_pose))
        cls.late_frame = cls.frames.pop()
        RUN_DIR.mkdir(parents=True, exist_ok=True)
        cls.collect = {
            "depth": Collector("/depth_estimator/depth/image_raw", Image, queue_size=50),
            "info": Collector("/depth_estimator/depth/camera_info", CameraInfo, queue_size=50),
            "points": Collector("/depth_estimator/points", PointCloud2, queue_size=50),
            "status": Collector("/depth_estimator/status", DepthEstimatorStatus, queue_size=50),
            "odom_depth": Collector("/depth_estimator_odom/depth/image_raw", Image, queue_size=50),
            "metrics": Collector("/depth_evaluator/metrics", DepthMetrics, queue_size=50),
        }
        cls.pub_clock = rospy.Publisher("/clock", Clock, queue_size=10)
        cls.pub_tf = rospy.Publisher("/tf", TFMessage, queue_size=100)
        cls.pub_static = rospy.Publisher("/tf_static", TFMessage, queue_size=10, latch=True)
        cls.pub_odom = rospy.Publisher("/uav/ground_truth/odom", Odometry, queue_size=100)
        base = "/cameras/nadir"
        cls.pub_color = rospy.Publisher(f"{base}/color/image_raw", Image, queue_size=10)
        cls.pub_info = rospy.Publisher(f"{base}/color/camera_info", CameraInfo, queue_size=10)
        cls.pub_depth = rospy.Publisher(f"{base}/depth/image_raw", Image, queue_size=10)
        cls.pub_inst = rospy.Publisher(f"{base}/instance/image_raw", Image, queue_size=10)
        cls.now = T0_S - 1.0
        cls.clock_run = True
        cls.clock_thread = threading.Thread(target=cls._clock_loop, daemon=True)
        cls.clock_thread.start()
        static = transform("base_link", OPTICAL, CameraPose(R_BASE_OPTICAL, np.zeros(3)), rospy.Time(0))
        cls.pub_static.publish(TFMessage([static]))
        for name in ("depth_estimator", "depth_estimator_odom", "depth_evaluator"):
            wait_until(
                lambda n=name: rospy.get_published_topics(),
                lambda topics, n=name: any(t.startswith(f"/{n}/") for t, _ in topics),
                timeout_s=30.0,
                describe=f"{name} to advertise",
                clock=time.monotonic,
            )
        # Every subscription connected before the first frame: a frame (or its transform) published into a
        # connection still being set up is lost, and the first frame must reach the estimators.
        for pub, nodes in (
            (cls.pub_tf, {"/depth_estimator"}),
            (cls.pub_odom, {"/depth_estimator_odom"}),
            (cls.pub_info, {"/depth_estimator", "/depth_estimator_odom"}),
            (cls.pub_color, {"/depth_estimator", "/depth_estimator_odom"}),
            (cls.pub_depth, {"/depth_evaluator"}),
            (cls.pub_inst, {"/depth_evaluator"}),
        ):
            wait_until(
                lambda p=pub: {c.endpoint_id for c in p.impl.connections},
                lambda ids, n=nodes: n <= ids,
                timeout_s=30.0,
                describe=f"{sorted(nodes)} to subscribe to {pub.resolved_name}",
                clock=time.monotonic,
            )
        # camera_info ahead of the first image: it arrives on its own connection, in no set order with the image.
        cls.pub_info.publish(cls._camera_info(stamp(0)))
        time.sleep(0.5)
        cls._play()

    @classmethod
    def tearDownClass(cls) -> None:
        cls.clock_run = False

    @classmethod
    def _clock_loop(cls) -> None:
        while cls.clock_run and not rospy.is_shutdown():
            try:
                cls.pub_clock.publish(Clock(clock=rospy.Time.from_sec(cls.now)))
            except rospy.ROSException:  # the node is shutting down
                return
            time.sleep(0.01)

    @classmethod
    def _camera_info(cls, t: rospy.Time) -> CameraInfo:
        info = CameraInfo(width=CAM.width_px, height=CAM.height_px, distortion_model="plumb_bob")
        info.header.stamp, info.header.frame_id = t, OPTICAL
        info.D = [0.0] * 5
        info.K = CAM.matrix.ravel().tolist()
        info.P = [CAM.fx_px, 0, CAM.cx_px, 0, 0, CAM.fy_px, CAM.cy_px, 0, 0, 0, 1, 0]
        return info

    @classmethod
    def _wait_for(cls, name: str, count: int, describe: str) -> None:
        """Until the collector ``name`` holds ``count`` messages (20 s)."""
        wait_until(
            lambda: len(cls.collect[name].snapshot()),
            lambda n: n >= count,
            timeout_s=20.0,
            describe=describe,
            clock=time.monotonic,
        )

    @classmethod
    def _play(cls) -> None:
        for k, (rgb, depth, inst) in enumerate(cls.frames):
            t = stamp(k)
            cls.now = t.to_sec()
            pose = body_pose(k)
            cls.pub_tf.publish(TFMessage([transform("map", "base_link", pose, t)]))
            odom = Odometry()
            odom.header.stamp, odom.header.frame_id, odom.child_frame_id = t, "map", "base_link"
            tf = transform("map", "base_link", pose, t).transform
            odom.pose.pose.position.x, odom.pose.pose.position.y, odom.pose.pose.position.z = pose.position_map_m
            odom.pose.pose.orientation = tf.rotation
            cls.pub_odom.publish(odom)
            time.sleep(0.02)
            cls.pub_info.publish(cls._camera_info(t))
            cls.pub_depth.publish(image_msg(depth.astype(np.float32), "32FC1", t))
            cls.pub_inst.publish(image_msg(inst.astype(np.uint16), "16UC1", t))
            cls.pub_color.publish(image_msg(rgb, "rgb8", t))
            if k == 0:
                # The first frame is processed on its own (a loaded machine could otherwise hand the worker the
                # first two frames at once, and the first would only be remembered): it has no history.
                cls._wait_for("status", 1, "the estimator's status for the first frame")
            time.sleep(1.0 / RATE_HZ)
            cls.now = t.to_sec() + 0.05
        cls.now = stamp(N_FRAMES).to_sec()
        cls._wait_for("metrics", 5, "5 depth metrics")
        time.sleep(1.0)

    def test_depth_images_are_32fc1_in_the_reference_camera(self) -> None:
        msgs = self.collect["depth"].snapshot()
        self.assertGreaterEqual(len(msgs), 5)
        stamps = {stamp(k).to_nsec(): k for k in range(N_FRAMES)}
        for msg in msgs:
            self.assertEqual(msg.encoding, "32FC1")
            self.assertEqual((msg.width, msg.height, msg.step), (320, 240, 320 * 4))
            self.assertEqual(msg.header.frame_id, OPTICAL)
            self.assertIn(msg.header.stamp.to_nsec(), stamps)
        # The estimate of the last frame, pixel by pixel against its ground truth.
        last = msgs[-1]
        est = np.frombuffer(last.data, dtype="<f4").reshape(240, 320)
        truth = self.frames[stamps[last.header.stamp.to_nsec()]][1]
        ok = np.isfinite(est) & np.isfinite(truth)
        self.assertGreater(ok.mean(), 0.6)
        self.assertGreater(np.mean(np.abs(est[ok] - truth[ok]) < 1.0), 0.9)
        infos = self.collect["info"].snapshot()
        self.assertTrue(any(i.header.stamp == last.header.stamp for i in infos))

    def test_cloud_has_exactly_the_ground_truth_layout(self) -> None:
        msgs = self.collect["points"].snapshot()
        self.assertGreaterEqual(len(msgs), 5)
        cloud = msgs[-1]
        layout = [(f.name, f.offset, f.datatype, f.count) for f in cloud.fields]
        self.assertEqual(layout, [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("rgb", 12, 7, 1)])
        self.assertEqual(PointField.FLOAT32, 7)
        self.assertEqual((cloud.height, cloud.point_step, cloud.is_bigendian), (1, 16, False))
        self.assertEqual(cloud.row_step, 16 * cloud.width)
        self.assertEqual(cloud.header.frame_id, OPTICAL)
        pts = np.frombuffer(cloud.data, dtype="<f4").reshape(-1, 4)
        self.assertEqual(len(pts), cloud.width)
        self.assertTrue(np.isfinite(pts[:, :3]).all())
        self.assertGreater(cloud.width, 0.5 * 320 * 240)
        # Points lie about 50 m below the camera (the roofs of the boxes are nearer).
        self.assertAlmostEqual(float(np.median(pts[:, 2])), 50.0, delta=5.0)
        # And the color is the color image's, packed 0x00RRGGBB.
        k = {stamp(i).to_nsec(): i for i in range(N_FRAMES)}[cloud.header.stamp.to_nsec()]
        rgb = self.frames[k][0]
        u = np.rint(pts[:, 0] / pts[:, 2] * CAM.fx_px + CAM.cx_px).astype(int)
        v = np.rint(pts[:, 1] / pts[:, 2] * CAM.fy_px + CAM.cy_px).astype(int)
        c = rgb[v, u].astype(np.uint32)
        packed = (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
        self.assertTrue(np.array_equal(pts[:, 3].view(np.uint32), packed))

    def test_odometry_poses_work_too(self) -> None:
        self.assertGreaterEqual(len(self.collect["odom_depth"].snapshot()), 3)

    def test_metrics_per_band_and_class(self) -> None:
        msgs = self.collect["metrics"].snapshot()
        self.assertGreaterEqual(len(msgs), 5)
        m = msgs[-1]
        self.assertEqual(m.camera, "nadir")
        self.assertLess(m.stamp_diff_s, 1e-3)
        self.assertEqual(m.n_pixels, 320 * 240)
        self.assertGreater(m.overall.coverage, 0.6)
        self.assertGreater(m.overall.within_abs, 0.9)
        self.assertGreater(m.overall.delta1, 0.95)
        self.assertLess(m.overall.abs_rel, 0.03)
        self.assertEqual([b.label for b in m.range_bands][:3], ["0-20m", "20-40m", "40-60m"])
        self.assertEqual(sum(b.n_evaluated for b in m.range_bands), m.overall.n_evaluated)
        classes = {c.label: c for c in m.classes}
        self.assertEqual(list(classes), ["terrain", "road", "building", "tree", "person", "vehicle"])
        self.assertGreater(classes["terrain"].n_evaluated, 0)
        self.assertGreater(classes["building"].n_evaluated, 0)
        self.assertEqual(classes["tree"].n_evaluated, 0)
        self.assertTrue(math.isnan(classes["tree"].coverage))
        lines = (RUN_DIR / "depth_metrics.jsonl").read_text().splitlines()
        self.assertGreaterEqual(len(lines), len(msgs))
        rec = json.loads(lines[-1])
        self.assertEqual(rec["camera"], "nadir")
        self.assertEqual({c["label"] for c in rec["classes"]} >= {"terrain", "building"}, True)

    def test_status_counts_and_bad_input_is_not_fatal(self) -> None:
        status = self.collect["status"].snapshot()[-1]
        skips = dict(zip(status.skip_reasons, status.skip_counts, strict=True))
        self.assertGreaterEqual(skips.get("no_history", 0), 1)
        self.assertGreaterEqual(status.estimates, 5)
        self.assertGreater(status.baseline_m, 2.0)
        self.assertTrue(status.refine_applied)
        self.assertLess(status.refine_rms_after_px, 0.5)
        before = len(self.collect["depth"].snapshot())
        # A color image whose size disagrees with camera_info, and one with no pose (tf never reaches it).
        t_bad = stamp(N_FRAMES + 1)
        self.__class__.now = t_bad.to_sec()
        self.pub_color.publish(image_msg(np.zeros((100, 100, 3), np.uint8), "rgb8", t_bad))
        t_far = rospy.Time.from_sec(T0_S + 500.0)
        self.pub_color.publish(image_msg(self.frames[0][0], "rgb8", t_far))
        self.pub_color.publish(image_msg(self.frames[0][0], "mono16", t_bad))

        def counts() -> dict[str, int]:
            s = self.collect["status"].snapshot()[-1]
            return dict(zip(s.skip_reasons, s.skip_counts, strict=True))

        wait_until(
            counts,
            lambda c: c.get("bad_input", 0) >= 2 and c.get("no_pose", 0) >= 1,
            timeout_s=15.0,
            describe="bad_input and no_pose counted",
            clock=time.monotonic,
        )
        # Still alive: a good frame after the bad ones is estimated.
        rgb = self.late_frame[0]
        t_good = stamp(N_FRAMES + 3)
        pose = body_pose(N_FRAMES + 3)
        self.__class__.now = t_good.to_sec()
        self.pub_tf.publish(TFMessage([transform("map", "base_link", pose, t_good)]))
        time.sleep(0.05)
        self.pub_color.publish(image_msg(rgb, "rgb8", t_good))
        wait_until(
            lambda: len(self.collect["depth"].snapshot()),
            lambda n: n > before,
            timeout_s=15.0,
            describe="a depth image after bad input",
            clock=time.monotonic,
        )


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "depth_nodes", TestDepthNodes)
