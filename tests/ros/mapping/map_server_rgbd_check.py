#!/usr/bin/env python3

"""rostest node: the map server's rgbd input (depth + color images + camera info in, map out).

The scene of map_server_check.py (flat grey ground at z = 0.1, a red 2 m x 2 m roof at z = 5.2 over
x, y in [2, 4)) rendered analytically into a 160 x 160 z-depth image of a nadir camera 20 m above the map
origin (fx = fy = 80, so the image covers [-20, 20) m of ground), with a corner of no-return pixels.
"""

from __future__ import annotations

import math
import sys
import unittest
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1])]

import numpy as np  # noqa: E402
import rospy  # noqa: E402
import rostest  # noqa: E402
from helpers.sim_clock import SimClock  # noqa: E402
from helpers.static_tf import nadir_camera_tf  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # noqa: E402

from uav_common.pointcloud import unpack_xyzrgb  # noqa: E402
from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import GridLayers, MapInsertStats  # noqa: E402
from uav_msgs.srv import GetGridLayers  # noqa: E402

CAM_Z = 20.0
SIM_START_S = 1000.0
FRAME = "camera_test_optical"
W = H = 160
F = 80.0
C = (W - 1) / 2.0
RED = (220, 20, 20)
GREY = (128, 128, 128)


def render() -> tuple[np.ndarray, np.ndarray]:
    """(z-depth float32 (H, W) with NaN where nothing was hit, rgb uint8 (H, W, 3))."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    xn, yn = (u - C) / F, (v - C) / F  # optical frame: x east, y south
    depth = np.full((H, W), CAM_Z - 0.1)
    roof_depth = CAM_Z - 5.2
    x_roof, y_roof = roof_depth * xn, -roof_depth * yn
    roof = (x_roof >= 2.0) & (x_roof < 4.0) & (y_roof >= 2.0) & (y_roof < 4.0)
    depth[roof] = roof_depth
    depth[:10, :10] = np.nan  # no return
    rgb = np.where(roof[..., None], np.array(RED), np.array(GREY)).astype(np.uint8)
    return depth.astype(np.float32), rgb


def image(data: np.ndarray, encoding: str, stamp: rospy.Time) -> Image:
    msg = Image()
    msg.header.stamp = stamp
    msg.header.frame_id = FRAME
    msg.height, msg.width = data.shape[:2]
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = data.strides[0]
    msg.data = np.ascontiguousarray(data).tobytes()
    return msg


def info(stamp: rospy.Time, fx: float = F, size: tuple[int, int] = (W, H)) -> CameraInfo:
    msg = CameraInfo()
    msg.header.stamp = stamp
    msg.header.frame_id = FRAME
    msg.width, msg.height = size
    msg.K = [fx, 0.0, C, 0.0, fx, C, 0.0, 0.0, 1.0]
    return msg


class MapServerRgbdCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("map_server_rgbd_check")
        cls.clock = SimClock(SIM_START_S)  # simulation time from SIM_START_S, 50 Hz
        cls.tf_static = nadir_camera_tf(FRAME, CAM_Z, SIM_START_S)
        cls.stats: list[MapInsertStats] = []
        rospy.Subscriber("/map_server/insert_stats", MapInsertStats, cls.stats.append, queue_size=100)
        cls.pub_depth = rospy.Publisher("/test/depth", Image, queue_size=10)
        cls.pub_color = rospy.Publisher("/test/color", Image, queue_size=10)
        cls.pub_info = rospy.Publisher("/test/depth_info", CameraInfo, queue_size=10)
        rospy.wait_for_service("/map_server/get_layers", timeout=30.0)
        for pub in (cls.pub_depth, cls.pub_color, cls.pub_info):
            wait_until(pub.get_num_connections, lambda n: n > 0, timeout_s=10.0, describe=f"{pub.name} subscribed")

    @classmethod
    def tearDownClass(cls) -> None:
        cls.clock.stop()

    def send(self, depth: Image, color: Image, cam: CameraInfo) -> MapInsertStats:
        n_before = len(self.stats)
        self.pub_color.publish(color)
        self.pub_info.publish(cam)
        self.pub_depth.publish(depth)
        wait_until(lambda: len(self.stats), lambda n: n > n_before, timeout_s=15.0, describe="insert_stats")
        return self.stats[n_before]

    def layers(self) -> tuple[GridLayers, dict[str, np.ndarray]]:
        msg = rospy.ServiceProxy("/map_server/get_layers", GetGridLayers)().layers
        data = np.asarray(msg.data, dtype=np.float32).reshape(len(msg.names), msg.height, msg.width)
        return msg, dict(zip(msg.names, data, strict=True))

    def value(self, msg: GridLayers, layer: np.ndarray, x: float, y: float) -> float:
        row = math.floor((y - msg.origin_y_m) / msg.resolution_m)
        col = math.floor((x - msg.origin_x_m) / msg.resolution_m)
        return float(layer[row, col])

    def test_1_depth_and_color_build_the_coloured_map(self) -> None:
        depth, rgb = render()
        stamp = rospy.Time.from_sec(SIM_START_S + 1.0)
        st = self.send(image(depth, "32FC1", stamp), image(rgb, "rgb8", stamp), info(stamp))
        self.assertTrue(st.inserted, st.drop_reason)
        self.assertEqual(st.points_in, W * H - 100)  # every pixel with a return, none of the NaN corner
        self.assertEqual(st.points_nonfinite, 0)
        self.assertGreater(st.hits, 1000)
        msg, layers = self.layers()
        self.assertEqual(self.value(msg, layers["elevation_m"], 3.1, 3.1), 5.25)  # roof
        self.assertEqual(self.value(msg, layers["elevation_m"], -12.9, 7.1), 0.25)  # ground
        self.assertAlmostEqual(self.value(msg, layers["last_seen_s"], -12.9, 7.1), SIM_START_S + 1.0, delta=1e-3)
        # the colours: voxel centres of the roof are red, the ground's grey
        got: list[PointCloud2] = []
        sub = rospy.Subscriber("/octomap_point_cloud_centers", PointCloud2, got.append, queue_size=2, buff_size=2**24)
        try:
            wait_until(lambda: len(got), lambda n: n > 0, timeout_s=15.0, describe="octomap_point_cloud_centers")
        finally:
            sub.unregister()
        xyz, colors = unpack_xyzrgb(bytes(got[-1].data))
        roof = (xyz[:, 2] > 5.0) & (xyz[:, 2] < 5.5)
        self.assertEqual(int(roof.sum()), 16)  # 2 m x 2 m at 0.5 m
        self.assertTrue(np.all(np.abs(colors[roof].astype(int) - RED) <= 1), colors[roof][:4])
        ground = xyz[:, 2] < 0.5
        self.assertTrue(np.all(np.abs(colors[ground].astype(int) - GREY) <= 1))

    def test_2_millimetre_depth_and_bgr_color_give_the_same_map(self) -> None:
        depth, rgb = render()
        mm = np.nan_to_num(np.round(depth * 1000.0), nan=0.0).astype(np.uint16)  # 0 = no return
        stamp = rospy.Time.from_sec(SIM_START_S + 2.0)
        st = self.send(image(mm, "16UC1", stamp), image(rgb[..., ::-1].copy(), "bgr8", stamp), info(stamp))
        self.assertTrue(st.inserted, st.drop_reason)
        self.assertEqual(st.points_in, W * H - 100)
        msg, layers = self.layers()
        self.assertEqual(self.value(msg, layers["elevation_m"], 3.1, 3.1), 5.25)
        self.assertAlmostEqual(self.value(msg, layers["last_seen_s"], 3.1, 3.1), SIM_START_S + 2.0, delta=1e-3)

    def test_3_malformed_frames_are_dropped_with_a_reason(self) -> None:
        depth, rgb = render()
        t = SIM_START_S + 3.0
        nan = np.full_like(depth, np.nan)
        cases = [  # (what, depth image, color image, camera info, expected drop reason)
            ("color size", (depth, "32FC1"), (rgb[:80], "rgb8"), {}, "bad_layout"),
            ("depth encoding", (rgb[..., 0], "8UC1"), (rgb, "rgb8"), {}, "bad_layout"),
            ("color encoding", (depth, "32FC1"), (rgb, "yuv422"), {}, "bad_layout"),
            ("zero focal length", (depth, "32FC1"), (rgb, "rgb8"), {"fx": 0.0}, "bad_layout"),
            ("info size", (depth, "32FC1"), (rgb, "rgb8"), {"size": (80, 80)}, "bad_layout"),
            ("no returns", (nan, "32FC1"), (rgb, "rgb8"), {}, "empty"),
        ]
        for k, (what, d, c, cam, reason) in enumerate(cases):
            s = rospy.Time.from_sec(t + 0.1 * k)
            st = self.send(image(*d, s), image(*c, s), info(s, **cam))
            self.assertFalse(st.inserted, what)
            self.assertEqual(st.drop_reason, reason, what)
        # and the node still maps a good frame afterwards
        stamp = rospy.Time.from_sec(t + 1.0)
        st = self.send(image(depth, "32FC1", stamp), image(rgb, "rgb8", stamp), info(stamp))
        self.assertTrue(st.inserted, st.drop_reason)
        self.assertEqual(st.clouds_dropped_bad_layout, 5)
        self.assertEqual(st.clouds_dropped_empty, 1)

    def test_4_an_incomplete_frame_is_dropped_and_counted(self) -> None:
        """A frame whose colour image never arrives must not vanish: once a newer frame is complete, the
        synchroniser gives it up and the map server reports it as unsynchronized."""
        depth, rgb = render()
        lost = rospy.Time.from_sec(SIM_START_S + 5.0)
        n_before = len(self.stats)
        self.pub_info.publish(info(lost))
        self.pub_depth.publish(image(depth, "32FC1", lost))
        rospy.sleep(0.5)  # the parts reach the synchroniser before the next frame's
        stamp = rospy.Time.from_sec(SIM_START_S + 5.1)
        self.pub_color.publish(image(rgb, "rgb8", stamp))
        self.pub_info.publish(info(stamp))
        self.pub_depth.publish(image(depth, "32FC1", stamp))
        wait_until(lambda: len(self.stats), lambda n: n >= n_before + 2, timeout_s=15.0, describe="two insert_stats")
        by_stamp = {st.header.stamp: st for st in self.stats[n_before:]}
        self.assertTrue(by_stamp[stamp].inserted, by_stamp[stamp].drop_reason)
        self.assertFalse(by_stamp[lost].inserted)
        self.assertEqual(by_stamp[lost].drop_reason, "unsynchronized")
        self.assertEqual(self.stats[-1].clouds_dropped_unsynchronized, 1)


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "map_server_rgbd_check", MapServerRgbdCheck)
