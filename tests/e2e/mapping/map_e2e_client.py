"""ROS side of the map server e2e test, run as its own process (one rospy node per process and master).

    python map_e2e_client.py fly   OUT_DIR  # render nadir frames of the default world, publish clock + tf +
                                            # clouds, check layers, export, accuracy against ground truth
    python map_e2e_client.py check OUT_DIR  # after a restart with resume:=true: the map must be the one before

Prints one JSON object (the results) on its last line; exits non-zero on a failed check.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import PointCloud2, PointField

from uav_autonomy.core.octree_reader import load_occupied_cells
from uav_common.pointcloud import pack_xyzrgb
from uav_common.waiting import wait_until
from uav_msgs.msg import GridLayers, MapInsertStats
from uav_msgs.srv import ExportVoxels, GetGridLayers
from uav_sim_bridge.core.camera import CameraModel, depth_to_points, look_at
from uav_sim_bridge.core.world_config import load_world_config
from uav_sim_bridge.render import Renderer
from uav_sim_bridge.shell.world_store import load_or_generate

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # tests/: run as a script, not by pytest
from helpers.paths import REPO

WORLD = REPO / "config" / "worlds" / "default.yaml"
FRAME = "camera_nadir_optical"
AGL_M = 50.0
START_S = 100.0
# A pass over the valley floor east of home, then back along a parallel line: overlapping nadir frames.
PATH_XY = [(60.0 + 25.0 * i, 40.0) for i in range(5)] + [(160.0 - 25.0 * i, 110.0) for i in range(4)]


class SimClock:
    """Publishes /clock at 50 Hz, simulated time running at the wall-clock pace from start_s."""

    def __init__(self, start_s: float) -> None:
        self.start_s = start_s
        self.t0 = time.monotonic()
        self.pub = rospy.Publisher("/clock", Clock, queue_size=1)
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def now_s(self) -> float:
        return round(self.start_s + time.monotonic() - self.t0, 3)

    def _loop(self) -> None:
        while not rospy.is_shutdown():
            try:
                self.pub.publish(Clock(clock=rospy.Time.from_sec(self.now_s())))
            except rospy.ROSException:  # shutting down
                return
            time.sleep(0.02)


def layers_arrays(msg: GridLayers) -> dict[str, np.ndarray]:
    data = np.asarray(msg.data, dtype=np.float32).reshape(len(msg.names), msg.height, msg.width)
    out = dict(zip(msg.names, data, strict=True))
    out["grid"] = np.array([msg.resolution_m, msg.origin_x_m, msg.origin_y_m, msg.width, msg.height])
    return out


def cloud_msg(points: np.ndarray, rgb: np.ndarray, stamp: rospy.Time) -> PointCloud2:
    msg = PointCloud2()
    msg.header.stamp = stamp
    msg.header.frame_id = FRAME
    msg.height, msg.width = 1, len(points)
    msg.fields = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate("xyz")]
    msg.fields.append(PointField(name="rgb", offset=12, datatype=PointField.FLOAT32, count=1))
    msg.is_bigendian, msg.point_step, msg.row_step, msg.is_dense = False, 16, 16 * len(points), True
    msg.data = pack_xyzrgb(points, rgb)
    return msg


def fly(out: Path) -> dict[str, Any]:
    world = load_or_generate(load_world_config(WORLD), Path(sys.argv[3]))
    renderer = Renderer(world)
    cam = CameraModel.simple(640, 480, 90.0, name="nadir")
    clock = SimClock(START_S)
    tf_pub = tf2_ros.TransformBroadcaster()
    stats: list[MapInsertStats] = []
    layers: list[GridLayers] = []
    rospy.Subscriber("/map_server/insert_stats", MapInsertStats, stats.append, queue_size=50)
    rospy.Subscriber("/map_server/layers", GridLayers, layers.append, queue_size=5, buff_size=2**26)
    pub = rospy.Publisher("/cameras/nadir/points", PointCloud2, queue_size=5)
    wait_until(pub.get_num_connections, lambda n: n > 0, timeout_s=20.0, describe="map_server subscribed")
    stamps = []
    for x, y in PATH_XY:
        ground = float(world.height_at(np.array([x]), np.array([y]))[0])
        t_map_optical = look_at([x, y, ground + AGL_M], [x, y, ground])
        frame = renderer.render(cam, t_map_optical)
        pts = depth_to_points(frame.depth_m, cam.k).reshape(-1, 3)
        ok = np.all(np.isfinite(pts), axis=1)
        stamp_s = clock.now_s()
        stamp = rospy.Time.from_sec(stamp_s)
        tf = TransformStamped()
        tf.header.stamp = stamp
        tf.header.frame_id = "map"
        tf.child_frame_id = FRAME
        tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = t_map_optical.translation_m
        q = tf.transform.rotation
        q.w, q.x, q.y, q.z = t_map_optical.quat_wxyz
        tf_pub.sendTransform(tf)
        n_before = len(stats)
        pub.publish(cloud_msg(pts[ok], frame.color_rgb.reshape(-1, 3)[ok], stamp))
        wait_until(lambda: len(stats), lambda n, k=n_before: n > k, timeout_s=20.0, describe="insert_stats")
        assert stats[-1].inserted, stats[-1].drop_reason
        stamps.append(stamp_s)
    last = wait_until(
        lambda: layers[-1] if layers else None,
        lambda m: m is not None and abs(float(np.nanmax(layers_arrays(m)["last_seen_s"])) - stamps[-1]) < 1e-3,
        timeout_s=20.0,
        describe="layers with the last frame",
    )
    snap = rospy.ServiceProxy("/map_server/get_layers", GetGridLayers)().layers
    arrays = layers_arrays(snap)
    np.testing.assert_array_equal(np.asarray(snap.data), np.asarray(last.data))
    np.savez(out / "layers_before.npz", **arrays)

    export = rospy.ServiceProxy("/map_server/export_occupied", ExportVoxels)
    res = export(str(out / "occupied_05.npy"), 0.0)
    assert res.success, res.message
    res1 = export(str(out / "occupied_1m.npy"), 1.0)
    assert res1.success, res1.message
    # Accuracy at 1 m against the world's observable-surface voxels, in the columns the map observed.
    est = load_occupied_cells(out / "occupied_1m.npy").cells
    truth = world.surface_voxels(1.0)
    columns = {(int(i), int(j)) for i, j in est[:, :2]}
    truth_seen = truth[[(int(i), int(j)) in columns for i, j in truth[:, :2]]]
    e = {tuple(r) for r in est.tolist()}
    g = {tuple(r) for r in truth_seen.tolist()}
    common = len(e & g)
    elevation = arrays["elevation_m"]
    observed = arrays["observed"] > 0
    return {
        "frames": len(stamps),
        "inserted": int(stats[-1].clouds_inserted),
        "median_total_ms": float(np.median([s.total_ms for s in stats if s.inserted])),
        "occupied_05": int(res.count),
        "occupied_1m": int(res1.count),
        "precision_1m": common / len(e),
        "recall_1m_observed_columns": common / len(g),
        "iou_1m_observed_columns": common / len(e | g),
        "observed_area_m2": float(observed.sum()) * snap.resolution_m**2,
        "elevation_known_fraction": float(np.isfinite(elevation[observed]).mean()),
        "last_stamp_s": stamps[-1],
        "elevation_range_m": [float(np.nanmin(elevation)), float(np.nanmax(elevation))],
    }


def check(out: Path) -> dict[str, Any]:
    # The node registers its services one after the other with the master; wait for each one used.
    for service in ("/map_server/get_layers", "/map_server/export_occupied"):
        rospy.wait_for_service(service, timeout=30.0)
    snap = rospy.ServiceProxy("/map_server/get_layers", GetGridLayers)().layers
    now = layers_arrays(snap)
    before = np.load(out / "layers_before.npz")
    for name in ("grid", "elevation_m", "last_seen_s", "observed"):
        np.testing.assert_array_equal(now[name], before[name], err_msg=f"layer {name} differs after resume")
    res = rospy.ServiceProxy("/map_server/export_occupied", ExportVoxels)(str(out / "occupied_05_resumed.npy"), 0.0)
    assert res.success, res.message
    a = load_occupied_cells(out / "occupied_05.npy").cells
    b = load_occupied_cells(out / "occupied_05_resumed.npy").cells
    np.testing.assert_array_equal(a, b)
    return {"resumed_occupied_05": int(res.count), "layers_identical": True}


def main() -> int:
    mode, out = sys.argv[1], Path(sys.argv[2])
    rospy.init_node(f"map_e2e_{mode}", disable_signals=True)
    result = fly(out) if mode == "fly" else check(out)
    print(json.dumps(result), flush=True)
    rospy.signal_shutdown("done")
    return 0 if all(not (isinstance(v, float) and math.isnan(v)) for v in result.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
