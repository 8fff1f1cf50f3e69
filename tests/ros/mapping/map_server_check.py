#!/usr/bin/env python3

"""rostest node: clouds and tf in -> map, layers, octomap outputs and services out; bad input survives.

The scene, seen by a nadir camera 20 m above the map origin: flat ground at z = 0.1 (grey) and a red
2 m x 2 m roof at z = 5.2 over x, y in [2, 4). With 0.5 m voxels the ground voxels' centres are at
z = 0.25 and the roof's at z = 5.25. The node runs with the backend given as ~backend.
"""

from __future__ import annotations

import math
import shutil
import sys
import tempfile
import time
import unittest
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1])]

import numpy as np  # noqa: E402
import rospy  # noqa: E402
import rostest  # noqa: E402
from geometry_msgs.msg import Point  # noqa: E402
from helpers.sim_clock import SimClock  # noqa: E402
from helpers.static_tf import nadir_camera_tf  # noqa: E402
from nav_msgs.msg import OccupancyGrid  # noqa: E402
from octomap_msgs.msg import Octomap  # noqa: E402
from octomap_msgs.srv import BoundingBoxQuery, GetOctomap  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from std_srvs.srv import Empty  # noqa: E402
from visualization_msgs.msg import MarkerArray  # noqa: E402

from uav_autonomy.core.octree_reader import decode_binary_octree, load_occupied_cells  # noqa: E402
from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import GridLayers, MapInsertStats  # noqa: E402
from uav_msgs.srv import ExportVoxels, GetGridLayers, MapFile  # noqa: E402

RES = 0.5
CAM_Z = 20.0
SIM_START_S = 1000.0
FRAME = "camera_test_optical"


def scene_points() -> tuple[np.ndarray, np.ndarray]:
    """Ground and roof points in the map frame (x, y every 0.1 m over [-5, 5)) and their colours."""
    xs, ys = np.meshgrid(np.arange(-5.0, 5.0, 0.1) + 0.05, np.arange(-5.0, 5.0, 0.1) + 0.05, indexing="xy")
    x, y = xs.ravel(), ys.ravel()
    roof = (x >= 2.0) & (x < 4.0) & (y >= 2.0) & (y < 4.0)
    z = np.where(roof, 5.2, 0.1)
    rgb = np.where(roof[:, None], np.array([220, 20, 20]), np.array([128, 128, 128])).astype(np.uint8)
    return np.stack([x, y, z], axis=1).astype(np.float32), rgb


def to_optical(p_map: np.ndarray) -> np.ndarray:
    """Map -> optical frame of a nadir camera at (0, 0, CAM_Z): x east, y south, z down."""
    return np.stack([p_map[:, 0], -p_map[:, 1], CAM_Z - p_map[:, 2]], axis=1).astype(np.float32)


def cloud_msg(p_optical: np.ndarray, rgb: np.ndarray, stamp: rospy.Time, frame: str = FRAME) -> PointCloud2:
    msg = PointCloud2()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.height, msg.width = 1, len(p_optical)
    msg.fields = [
        PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate("xyz")
    ] + [PointField(name="rgb", offset=12, datatype=PointField.FLOAT32, count=1)]
    msg.is_bigendian = False
    msg.point_step = 16
    msg.row_step = 16 * len(p_optical)
    msg.is_dense = True
    packed = np.zeros(len(p_optical), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    packed["x"], packed["y"], packed["z"] = p_optical[:, 0], p_optical[:, 1], p_optical[:, 2]
    rgb32 = rgb.astype(np.uint32)
    packed["rgb"] = (rgb32[:, 0] << 16) | (rgb32[:, 1] << 8) | rgb32[:, 2]
    msg.data = packed.tobytes()  # uav_common.pointcloud's layout, but NaN/inf allowed (bad-input tests)
    return msg


def layers_of(msg: GridLayers) -> dict[str, np.ndarray]:
    data = np.asarray(msg.data, dtype=np.float32).reshape(len(msg.names), msg.height, msg.width)
    return dict(zip(msg.names, data, strict=True))


def cell(msg: GridLayers, x: float, y: float) -> tuple[int, int]:
    row = math.floor((y - msg.origin_y_m) / msg.resolution_m)
    col = math.floor((x - msg.origin_x_m) / msg.resolution_m)
    return row, col


class MapServerCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("map_server_check")
        cls.backend = rospy.get_param("~backend")
        cls.tmp = Path(tempfile.mkdtemp(prefix="map_server_check_"))
        cls.clock = SimClock(SIM_START_S)  # simulation time from SIM_START_S, 50 Hz
        cls.tf_static = nadir_camera_tf(FRAME, CAM_Z, SIM_START_S)
        cls.stats: list[MapInsertStats] = []
        cls.layers: list[GridLayers] = []
        rospy.Subscriber("/map_server/insert_stats", MapInsertStats, cls.stats.append, queue_size=100)
        rospy.Subscriber("/map_server/layers", GridLayers, cls.layers.append, queue_size=10, buff_size=2**24)
        cls.pub_cloud = rospy.Publisher("/test/points", PointCloud2, queue_size=10)
        for srv in ("/map_server/get_layers", "/octomap_binary", "/map_server/reset", "/map_server/export_occupied"):
            rospy.wait_for_service(srv, timeout=30.0)
        wait_until(cls.pub_cloud.get_num_connections, lambda n: n > 0, timeout_s=10.0, describe="map_server subscribed")

    @classmethod
    def tearDownClass(cls) -> None:
        cls.clock.stop()
        shutil.rmtree(cls.tmp, ignore_errors=True)

    # ------------------------------------------------------------------------------------------ helpers

    def publish_scene(self, stamp_s: float) -> MapInsertStats:
        n_before = len(self.stats)
        p, rgb = scene_points()
        self.pub_cloud.publish(cloud_msg(to_optical(p), rgb, rospy.Time.from_sec(stamp_s)))
        wait_until(
            lambda: len(self.stats), lambda n: n > n_before, timeout_s=15.0, describe="insert_stats after a cloud"
        )
        st = self.stats[n_before]
        self.assertTrue(st.inserted, f"cloud dropped: {st.drop_reason}")
        return st

    def wait_layers(self, predicate: Any, what: str) -> GridLayers:
        return wait_until(
            lambda: self.layers[-1] if self.layers else None,
            lambda m: m is not None and predicate(m),
            timeout_s=15.0,
            describe=what,
        )

    def wait_message(self, topic: str, msg_type: Any, predicate: Any, what: str) -> Any:
        """The first message on ``topic`` satisfying ``predicate`` (latched ones included)."""
        got: list[Any] = []
        sub = rospy.Subscriber(topic, msg_type, got.append, queue_size=5, buff_size=2**24)
        try:
            return wait_until(
                lambda: next((m for m in reversed(got) if predicate(m)), None),
                lambda m: m is not None,
                timeout_s=15.0,
                describe=what,
            )
        finally:
            sub.unregister()

    def call(self, name: str, srv_type: Any, *args: Any) -> Any:
        return rospy.ServiceProxy(name, srv_type)(*args)

    def check_scene_layers(self, msg: GridLayers, stamp_s: float) -> None:
        layers = layers_of(msg)
        self.assertEqual(msg.header.frame_id, "map")
        self.assertAlmostEqual(msg.resolution_m, RES)
        self.assertEqual(list(msg.names), ["elevation_m", "last_seen_s", "observed"])
        roof = cell(msg, 3.1, 3.1)
        ground = cell(msg, -2.9, 1.1)
        self.assertEqual(layers["elevation_m"][roof], 5.25)
        self.assertEqual(layers["elevation_m"][ground], 0.25)
        self.assertEqual(layers["observed"][roof], 1.0)
        self.assertAlmostEqual(float(layers["last_seen_s"][ground]), stamp_s, delta=1e-3)
        # The layers cover the observed columns only: [-5, 5) x [-5, 5) at 0.5 m.
        self.assertEqual((msg.width, msg.height), (20, 20))
        self.assertEqual((msg.origin_x_m, msg.origin_y_m), (-5.0, -5.0))

    # ------------------------------------------------------------------------------------------ tests

    def test_1_insert_layers_and_octomap_outputs(self) -> None:
        stamp = SIM_START_S + 2.0
        st = self.publish_scene(stamp)
        self.assertEqual(st.backend, self.backend)
        self.assertEqual(st.mode, "full")
        self.assertEqual(st.points_in, 10000)
        self.assertEqual(st.hits, 400)  # one surface voxel per column
        self.assertGreater(st.misses, 10 * st.hits)
        self.assertGreater(st.total_ms, 0.0)
        msg = self.wait_layers(lambda m: m.width > 0, "layers after the first cloud")
        self.check_scene_layers(msg, stamp)
        # The service gives the same snapshot.
        snap = self.call("/map_server/get_layers", GetGridLayers).layers
        self.assertEqual(list(snap.data), list(msg.data))

        # octomap_binary: the same md5 as upstream octomap_msgs, a standard OcTree stream.
        self.assertEqual(Octomap._md5sum, "9a45536b45c5e409cd49f04bb2d9999f")
        binary = self.call("/octomap_binary", GetOctomap).map
        self.assertTrue(binary.binary)
        self.assertEqual(binary.id, "OcTree")
        self.assertAlmostEqual(binary.resolution, RES)
        leaves = decode_binary_octree(bytes(np.asarray(binary.data, dtype=np.int8).tobytes()), binary.resolution)
        occupied = leaves.occupied_indices()
        self.assertEqual(len(occupied), 400)  # 20 x 20 columns, one surface voxel each
        roof = occupied[(occupied[:, 0] >= 4) & (occupied[:, 0] < 8) & (occupied[:, 1] >= 4) & (occupied[:, 1] < 8)]
        self.assertEqual(len(roof), 16)
        self.assertTrue(np.all(roof[:, 2] == 10))  # z = 5.2 -> voxel 10
        self.assertTrue(np.all(np.delete(occupied, np.flatnonzero(np.isin(occupied[:, 2], [10])), axis=0)[:, 2] == 0))
        full = self.call("/octomap_full", GetOctomap).map
        self.assertFalse(full.binary)
        self.assertEqual(full.id, "ColorOcTree")
        self.assertGreater(len(full.data), len(binary.data))

        # Latched topics: markers (one CUBE_LIST per node size), the projected map, the binary map.
        markers = self.wait_message(
            "/occupied_cells_vis_array",
            MarkerArray,
            lambda m: sum(len(k.points) for k in m.markers) > 0,
            "markers of the first cloud",
        )
        self.assertEqual(sum(len(m.points) for m in markers.markers), 400)
        self.assertEqual({m.header.frame_id for m in markers.markers}, {"map"})
        grid = self.wait_message("/projected_map", OccupancyGrid, lambda m: m.info.width > 0, "projected_map")
        self.assertEqual((grid.info.width, grid.info.height), (20, 20))
        self.assertEqual(sorted(set(grid.data)), [100])  # every column has a surface voxel
        topic = self.wait_message("/octomap_binary", Octomap, lambda m: len(m.data) > 0, "octomap_binary topic")
        self.assertEqual(topic.id, "OcTree")
        centers = self.wait_message(
            "/octomap_point_cloud_centers", PointCloud2, lambda m: m.width > 0, "octomap_point_cloud_centers"
        )
        self.assertEqual(centers.width, 400)

    def test_2_bad_input_is_dropped_and_counted(self) -> None:
        stamp = rospy.Time.from_sec(SIM_START_S + 3.0)
        p, rgb = scene_points()
        n0 = len(self.stats)
        # NaN / inf points: inserted, counted.
        bad = to_optical(p).copy()
        bad[:100, 0] = np.nan
        bad[100:150, 2] = np.inf
        self.pub_cloud.publish(cloud_msg(bad, rgb, stamp))
        wait_until(lambda: len(self.stats), lambda n: n > n0, timeout_s=10.0, describe="stats of the NaN cloud")
        self.assertTrue(self.stats[n0].inserted)
        self.assertEqual(self.stats[n0].points_nonfinite, 150)
        # Empty cloud.
        empty = cloud_msg(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8), stamp)
        # Wrong layout: z missing.
        no_z = cloud_msg(to_optical(p), rgb, stamp)
        no_z.fields = [f for f in no_z.fields if f.name != "z"]
        # Wrong layout: data shorter than width * point_step.
        short = cloud_msg(to_optical(p), rgb, stamp)
        short.data = short.data[: len(short.data) // 2]
        # Absurd size (width beyond max_points; the data is not even there).
        huge = cloud_msg(to_optical(p[:10]), rgb[:10], stamp)
        huge.width = 10**7
        huge.row_step = 16 * huge.width
        # A frame tf does not know.
        nowhere = cloud_msg(to_optical(p), rgb, stamp, frame="nowhere")
        for m in (empty, no_z, short, huge, nowhere):
            self.pub_cloud.publish(m)
            time.sleep(0.05)
        wait_until(lambda: len(self.stats), lambda n: n >= n0 + 6, timeout_s=10.0, describe="stats of the bad clouds")
        reasons = [s.drop_reason for s in self.stats[n0 + 1 : n0 + 6]]
        self.assertEqual(reasons, ["empty", "bad_layout", "bad_layout", "too_large", "no_transform"])
        last = self.stats[n0 + 5]
        self.assertEqual(
            (
                last.clouds_dropped_empty,
                last.clouds_dropped_bad_layout,
                last.clouds_dropped_too_large,
                last.clouds_dropped_no_transform,
            ),
            (1, 2, 1, 1),
        )
        self.assertGreaterEqual(last.points_nonfinite_total, 150)
        # Still alive and mapping.
        st = self.publish_scene(SIM_START_S + 4.0)
        self.assertGreater(st.clouds_inserted, 1)

    def test_3_clear_bbx_save_reset_load_export(self) -> None:
        self.publish_scene(SIM_START_S + 5.0)
        before = self.call("/map_server/get_layers", GetGridLayers).layers
        # Save, reset (empty map and layers), load (the same layers again).
        path = str(self.tmp / ("map.ot" if self.backend == "octomap" else "map.vdb"))
        res = self.call("/map_server/save", MapFile, path)
        self.assertTrue(res.success, res.message)
        self.assertTrue(Path(path).stat().st_size > 1000)
        wrong = self.call("/map_server/save", MapFile, str(self.tmp / "map.xyz"))
        self.assertFalse(wrong.success)
        self.call("/map_server/reset", Empty)
        empty = self.call("/map_server/get_layers", GetGridLayers).layers
        self.assertEqual((empty.width, empty.height, len(empty.data)), (0, 0, 0))
        self.assertEqual(len(self.call("/octomap_binary", GetOctomap).map.data), 0)
        res = self.call("/map_server/load", MapFile, path)
        self.assertTrue(res.success, res.message)
        after = self.call("/map_server/get_layers", GetGridLayers).layers
        self.assertEqual(
            (after.width, after.height, after.origin_x_m), (before.width, before.height, before.origin_x_m)
        )
        np.testing.assert_array_equal(np.asarray(after.data), np.asarray(before.data))
        bad = self.call("/map_server/load", MapFile, str(self.tmp / "missing.ot"))
        self.assertFalse(bad.success)

        # Export for evaluation: the occupied voxels at 0.5 m and 1 m.
        out = self.tmp / "occupied.npy"
        res = self.call("/map_server/export_occupied", ExportVoxels, str(out), 0.0)
        self.assertTrue(res.success, res.message)
        self.assertEqual(res.count, 400)
        cells = load_occupied_cells(out)
        self.assertEqual(cells.resolution_m, RES)
        self.assertIn([6, 6, 10], cells.cells.tolist())  # roof voxel over (3.1, 3.1)
        coarse = self.call("/map_server/export_occupied", ExportVoxels, str(self.tmp / "occ1.npy"), 1.0)
        self.assertEqual((coarse.count, coarse.resolution_m), (100 + 0, 1.0))

        # clear_bbx over the roof: its voxels turn free; no occupied voxel is left in those columns.
        self.call("/map_server/clear_bbx", BoundingBoxQuery, Point(2.1, 2.1, -1.0), Point(3.9, 3.9, 10.0))
        layers = layers_of(self.call("/map_server/get_layers", GetGridLayers).layers)
        roof = cell(after, 3.1, 3.1)
        self.assertTrue(math.isnan(layers["elevation_m"][roof]))
        self.assertEqual(layers["observed"][roof], 1.0)
        self.assertEqual(layers["elevation_m"][cell(after, -2.9, 1.1)], 0.25)

    def test_4_what_moved_away_is_cleared(self) -> None:
        """OctoMap's probabilistic update clears a walker that left: the rays to the ground where it stood pass
        through its voxels (full insertion, as the lockstep scenarios' `insert_mode` can be; the default
        truncated mode clears the last `truncation_m` before each hit, docs/scenarios.md `moving_objects`)."""
        self.call("/map_server/reset", Empty)
        ground, rgb = scene_points()
        ground = ground.copy()
        ground[:, 2] = 0.1  # no roof: the ground only
        walker = (np.abs(ground[:, 0] + 2.75) < 0.5) & (np.abs(ground[:, 1] + 2.75) < 0.5)
        standing = ground.copy()
        standing[walker, 2] = 1.7  # a 1 m x 1 m column (a walker seen from above: head and shoulders at 1.7 m)
        out = self.tmp / "walker.npy"

        def occupied() -> set[tuple[int, int, int]]:
            res = self.call("/map_server/export_occupied", ExportVoxels, str(out), 0.0)
            self.assertTrue(res.success, res.message)
            return {tuple(c) for c in load_occupied_cells(out).cells.tolist()}

        def insert(points: np.ndarray, stamp_s: float) -> None:
            n_before = len(self.stats)
            self.pub_cloud.publish(cloud_msg(to_optical(points), rgb, rospy.Time.from_sec(stamp_s)))
            wait_until(lambda: len(self.stats), lambda n: n > n_before, timeout_s=15.0, describe="insert_stats")

        t = SIM_START_S + 10.0
        for k in range(3):  # it stands there for three frames
            insert(standing, t + 0.1 * k)
        head = (-6, -6, 3)  # the voxel [-3, -2.5) x [-3, -2.5) x [1.5, 2) of the walker's head
        self.assertIn(head, occupied())
        for k in range(3, 13):  # it walked away: ten frames see the ground where it stood
            insert(ground, t + 0.1 * k)
        now = occupied()
        self.assertNotIn(head, now, "the walker's voxels are still occupied after it left (a ghost)")
        self.assertIn((-6, -6, 0), now)  # the ground it stood on stays


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "map_server_check", MapServerCheck)
