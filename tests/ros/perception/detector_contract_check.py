#!/usr/bin/env python3
# A rostest node: unittest assertions are how rosunit reports.
"""rostest node: a detector's vision_msgs/Detection2DArray reaches the tracker and the scorer, placed in map.

It plays the simulator and a detector: /clock, the forward camera's pose (tf_static map -> camera_forward_optical,
40 m up looking north, pitched 25 deg down), its camera_info and color images, a flat elevation layer on
/map_server/layers, odometry, the truth on /detections/ground_truth (three people with instance ids and
positions), and a detector on /test_detector/detections that sees the three people as boxes only (the third
every other frame), adds a box above the horizon (which cannot be placed), a NaN box and a box far outside the
image (which must be counted and discarded), and a dog (a COCO id that is no class of the range). Then the
run's status ends the run and the check reads the geolocator's placements and status, the tracker's tracks and
the scorer's final metrics and gallery.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
import unittest
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1])]
import numpy as np  # noqa: E402
import rospy  # noqa: E402
import rostest  # noqa: E402
from geometry_msgs.msg import Point, TransformStamped  # noqa: E402
from helpers.ros_collect import Collector  # noqa: E402 - after the path set-up
from nav_msgs.msg import Odometry  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402
from vision_msgs.msg import BoundingBox2D, Detection2D, Detection2DArray, ObjectHypothesisWithPose  # noqa: E402

from uav_common.rotations import quat_from_matrix  # noqa: E402
from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import (  # noqa: E402
    Detection,
    DetectionArray,
    GeolocatorStatus,
    GridLayers,
    RunMetrics,
    ScenarioStatus,
    TrackArray,
)

W, H, F = 640, 480, 320.0
CX, CY = (W - 1) / 2.0, (H - 1) / 2.0
OPTICAL = "camera_forward_optical"
EYE = np.array([0.0, 0.0, 40.0])
PITCH = math.radians(25.0)
FORWARD = np.array([0.0, math.cos(PITCH), -math.sin(PITCH)])
RIGHT = np.array([1.0, 0.0, 0.0])
R_MAP_OPTICAL = np.column_stack([RIGHT, np.cross(FORWARD, RIGHT), FORWARD])
PEOPLE = {101: (0.0, 60.0), 102: (-12.0, 50.0), 103: (15.0, 80.0)}
T0_S = 50.0
RATE_HZ = 10.0
N_FRAMES = 40


def project(p: np.ndarray) -> tuple[float, float]:
    c = R_MAP_OPTICAL.T @ (p - EYE)
    return (F * c[0] / c[2] + CX, F * c[1] / c[2] + CY)


def person_box(x: float, y: float) -> tuple[int, int, int, int]:
    """The inclusive pixel box of a 0.5 x 0.5 x 1.75 m person standing at (x, y, 0)."""
    pts = [project(np.array([x + dx, y + dy, z])) for dx in (-0.25, 0.25) for dy in (-0.25, 0.25) for z in (0.0, 1.75)]
    us, vs = [p[0] for p in pts], [p[1] for p in pts]
    return (round(min(us) + 0.5), round(min(vs) + 0.5), round(max(us) - 0.5), round(max(vs) - 0.5))


def stamp(k: int) -> rospy.Time:
    return rospy.Time.from_sec(T0_S + k / RATE_HZ)


def d2d(box: tuple[float, float, float, float], class_id: int, score: float, hdr: Header) -> Detection2D:
    """A Detection2D of centre and size ``box`` (pixels) with one hypothesis."""
    cu, cv, su, sv = box
    det = Detection2D(header=hdr, bbox=BoundingBox2D(size_x=su, size_y=sv))
    det.bbox.center.x, det.bbox.center.y = cu, cv
    det.results = [ObjectHypothesisWithPose(id=class_id, score=score)]
    return det


class TestDetectorContract(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("detector_contract_check")
        cls.collect = {
            "geo": Collector("/geolocator/detections", DetectionArray),
            "geo_status": Collector("/geolocator/status", GeolocatorStatus),
            "geo_depth": Collector("/geolocator_depth/detections", DetectionArray),
            "tracks": Collector("/scenario/tracks", TrackArray),
            "metrics": Collector("/scenario/metrics", RunMetrics),
            "gallery": Collector("/scenario/snapshot/gallery", Image),
        }
        cls.pub_clock = rospy.Publisher("/clock", Clock, queue_size=10)
        cls.pub_static = rospy.Publisher("/tf_static", TFMessage, queue_size=1, latch=True)
        cls.pub_layers = rospy.Publisher("/map_server/layers", GridLayers, queue_size=1, latch=True)
        cls.pub_info = rospy.Publisher("/cameras/forward/color/camera_info", CameraInfo, queue_size=50)
        cls.pub_color = rospy.Publisher("/cameras/forward/color/image_raw", Image, queue_size=50)
        cls.pub_depth = rospy.Publisher("/cameras/forward/depth/image_raw", Image, queue_size=50)
        cls.pub_odom = rospy.Publisher("/uav/ground_truth/odom", Odometry, queue_size=50)
        cls.pub_truth = rospy.Publisher("/detections/ground_truth", DetectionArray, queue_size=50)
        cls.pub_det = rospy.Publisher("/test_detector/detections", Detection2DArray, queue_size=50)
        cls.pub_status = rospy.Publisher("/scenario/status", ScenarioStatus, queue_size=10, latch=True)
        cls.now = T0_S - 1.0
        cls.clock_run = True
        threading.Thread(target=cls._clock_loop, daemon=True).start()
        tf = TransformStamped()
        tf.header.frame_id, tf.child_frame_id = "map", OPTICAL
        tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = EYE
        w, x, y, z = quat_from_matrix(R_MAP_OPTICAL)
        tf.transform.rotation.x, tf.transform.rotation.y, tf.transform.rotation.z, tf.transform.rotation.w = x, y, z, w
        cls.pub_static.publish(TFMessage([tf]))
        layers = GridLayers(resolution_m=1.0, origin_x_m=-150.0, origin_y_m=-150.0, width=300, height=300)
        layers.header.frame_id = "map"
        layers.names = ["elevation_m", "observed"]
        layers.data = np.concatenate([np.zeros(300 * 300), np.ones(300 * 300)]).astype(np.float32).tolist()
        cls.pub_layers.publish(layers)
        for pub, nodes in (
            (cls.pub_det, {"/geolocator", "/geolocator_depth"}),
            (cls.pub_info, {"/geolocator", "/geolocator_depth"}),
            (cls.pub_depth, {"/geolocator_depth"}),
            (cls.pub_layers, {"/geolocator"}),
            (cls.pub_truth, {"/scorer"}),
            (cls.pub_color, {"/scorer"}),
            (cls.pub_odom, {"/scorer"}),
            (cls.pub_status, {"/scorer", "/tracker"}),
        ):
            wait_until(
                lambda p=pub: {c.endpoint_id for c in p.impl.connections},
                lambda ids, n=nodes: n <= ids,
                timeout_s=60.0,
                describe=f"{sorted(nodes)} to subscribe to {pub.resolved_name}",
                clock=time.monotonic,
            )
        cls.boxes = {iid: person_box(*xy) for iid, xy in PEOPLE.items()}
        cls._status(T0_S, stop=False)
        cls.pub_info.publish(cls._camera_info(stamp(0)))
        time.sleep(1.0)
        cls._play()

    @classmethod
    def tearDownClass(cls) -> None:
        cls.clock_run = False

    @classmethod
    def _clock_loop(cls) -> None:
        while cls.clock_run and not rospy.is_shutdown():
            try:
                cls.pub_clock.publish(Clock(clock=rospy.Time.from_sec(cls.now)))
            except rospy.ROSException:
                return
            time.sleep(0.01)

    @classmethod
    def _status(cls, t: float, *, stop: bool) -> None:
        msg = ScenarioStatus(scenario="detector_contract", mission="loiter", phase="DONE" if stop else "LOITERING")
        msg.header.stamp = rospy.Time.from_sec(t)
        msg.sim_time_s = t - T0_S
        msg.complete_time_s = math.nan
        msg.stop, msg.stop_reason = stop, "time_limit" if stop else ""
        cls.pub_status.publish(msg)

    @classmethod
    def _camera_info(cls, t: rospy.Time) -> CameraInfo:
        info = CameraInfo(width=W, height=H, distortion_model="plumb_bob")
        info.header.stamp, info.header.frame_id = t, OPTICAL
        info.D = [0.0] * 5
        info.K = [F, 0.0, CX, 0.0, F, CY, 0.0, 0.0, 1.0]
        info.P = [F, 0.0, CX, 0.0, 0.0, F, CY, 0.0, 0.0, 0.0, 1.0, 0.0]
        return info

    @classmethod
    def _play(cls) -> None:
        # z-depth of the flat ground (z = 0) seen by the camera, NaN above the horizon
        u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
        rays = np.stack([(u - CX) / F, (v - CY) / F, np.ones_like(u)], axis=-1) @ R_MAP_OPTICAL.T
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = np.where(rays[..., 2] < 0, -EYE[2] / rays[..., 2], np.nan).astype(np.float32)
        rgb = np.full((H, W, 3), 110, np.uint8)
        for x0, y0, x1, y1 in cls.boxes.values():
            rgb[y0 : y1 + 1, x0 : x1 + 1] = (40, 40, 160)
        for k in range(N_FRAMES):
            t = stamp(k)
            cls.now = t.to_sec()
            hdr = Header(stamp=t, frame_id=OPTICAL)
            odom = Odometry(header=Header(stamp=t, frame_id="map"), child_frame_id="base_link")
            odom.pose.pose.position = Point(*EYE)
            odom.pose.pose.orientation.w = 1.0
            cls.pub_odom.publish(odom)
            cls.pub_info.publish(cls._camera_info(t))
            img = Image(header=hdr, height=H, width=W, encoding="rgb8", step=3 * W, data=rgb.tobytes())
            cls.pub_color.publish(img)
            if k % 5 != 4:  # every fifth frame's depth image never comes: that frame falls back (no surface)
                cls.pub_depth.publish(
                    Image(header=hdr, height=H, width=W, encoding="32FC1", step=4 * W, data=depth.tobytes())
                )
            truth = DetectionArray(header=hdr, camera="forward", source="ground_truth")
            dets = []
            for iid, (x, y) in PEOPLE.items():
                x0, y0, x1, y1 = cls.boxes[iid]
                truth.detections.append(
                    Detection(
                        instance_id=iid,
                        class_name="person",
                        score=1.0,
                        x_min=x0,
                        y_min=y0,
                        x_max=x1,
                        y_max=y1,
                        range_m=float(np.linalg.norm(np.array([x, y, 0.9]) - EYE)),
                        visible_fraction=1.0,
                        position=Point(x, y, 0.9),
                        position_covariance=[0.0] * 9,
                        position_source="ground_truth",
                    )
                )
                if iid == 103 and k % 2:
                    continue  # the detector misses the farthest person every other frame
                dets.append(d2d(((x0 + x1) / 2 + 0.3, (y0 + y1) / 2, x1 - x0 + 1, y1 - y0 + 1), 0, 0.9, hdr))
            dets.append(d2d((400.0, 20.0, 6.0, 14.0), 0, 0.7, hdr))  # above the horizon: cannot be placed
            dets.append(d2d((math.nan, 100.0, 6.0, 14.0), 0, 0.9, hdr))  # NaN: discarded
            dets.append(d2d((5000.0, 100.0, 6.0, 14.0), 0, 0.9, hdr))  # far outside the image: discarded
            dets.append(d2d((200.0, 300.0, 10.0, 8.0), 16, 0.9, hdr))  # a COCO dog: no class of the range
            cls.pub_truth.publish(truth)
            cls.pub_det.publish(Detection2DArray(header=hdr, detections=dets))
            time.sleep(1.0 / RATE_HZ)
            cls.now = t.to_sec() + 0.05
        end = stamp(N_FRAMES).to_sec()
        for k in range(40):  # the clock moves on past the scorer's hold
            cls.now = end + 0.1 * k
            if k == 5:
                cls._status(cls.now, stop=True)
            time.sleep(0.05)
        wait_until(
            cls.collect["metrics"].snapshot,
            lambda msgs: any('"final": true' in m.summary_json for m in msgs),
            timeout_s=60.0,
            describe="the scorer's final metrics",
            clock=time.monotonic,
        )
        time.sleep(0.5)

    def test_every_frame_is_placed_and_bad_boxes_are_counted_and_discarded(self) -> None:
        frames = self.collect["geo"].snapshot()
        self.assertEqual(len(frames), N_FRAMES)
        for frame in frames:
            self.assertEqual((frame.camera, frame.source, frame.header.frame_id), ("forward", "external", OPTICAL))
            discarded = dict(zip(frame.discarded_reasons, frame.discarded_counts, strict=True))
            self.assertEqual(discarded, {"nan_box": 1, "out_of_image": 1, "unknown_class": 1})
            people = [d for d in frame.detections if d.position_source != "unplaced:no_surface"]
            sky = [d for d in frame.detections if d.position_source == "unplaced:no_surface"]
            self.assertEqual(len(sky), 1)
            self.assertTrue(math.isnan(sky[0].position.x))
            for d in people:
                self.assertEqual((d.position_source, d.instance_id), ("elevation", 0))
                err = min(math.hypot(d.position.x - x, d.position.y - y) for x, y in PEOPLE.values())
                self.assertLess(err, 1.0, f"placed {d.position.x:.2f}, {d.position.y:.2f}")
                cov = np.array(d.position_covariance).reshape(3, 3)
                self.assertTrue(np.all(np.isfinite(cov)))
                self.assertGreater(cov[0, 0], 0.0)
        status = self.collect["geo_status"].snapshot()[-1]
        self.assertEqual(status.frames, N_FRAMES)
        self.assertEqual(
            dict(zip(status.unplaced_reasons, status.unplaced_counts, strict=True)), {"no_surface": N_FRAMES}
        )
        discarded = dict(zip(status.discarded_reasons, status.discarded_counts, strict=True))
        self.assertEqual(discarded, {"nan_box": N_FRAMES, "out_of_image": N_FRAMES, "unknown_class": N_FRAMES})
        self.assertEqual(dict(zip(status.placed_sources, status.placed_counts, strict=True)), {"elevation": 100})

    def test_a_geolocator_on_the_depth_image_places_by_depth_and_falls_back_without_it(self) -> None:
        frames = self.collect["geo_depth"].snapshot()
        self.assertEqual(len(frames), N_FRAMES)
        by_depth = 0
        for frame in frames:
            k = round((frame.header.stamp.to_sec() - T0_S) * RATE_HZ)
            people = [d for d in frame.detections if d.position_source in ("depth", "unplaced:no_surface_model")]
            sources = {d.position_source for d in people}
            if k % 5 == 4:  # no depth image for this stamp, and this geolocator has no other surface
                self.assertNotIn("depth", sources)
                continue
            for d in frame.detections:
                if d.position_source != "depth":
                    continue
                by_depth += 1
                err = min(math.hypot(d.position.x - x, d.position.y - y) for x, y in PEOPLE.values())
                self.assertLess(err, 0.6, f"placed by depth at {d.position.x:.2f}, {d.position.y:.2f}")
        self.assertGreaterEqual(by_depth, 60)

    def test_the_tracker_follows_the_placements_and_reports_what_it_could_not_use(self) -> None:
        frames = self.collect["tracks"].snapshot()
        self.assertGreaterEqual(len(frames), N_FRAMES - 2)
        last = frames[-1]
        self.assertEqual(last.detections_unplaced, N_FRAMES)  # the box above the horizon, every frame
        self.assertEqual(last.detections_received, 100 + N_FRAMES)  # the three people (less misses) and the sky box
        tracked = {t.track_id: (t.position.x, t.position.y) for f in frames[-4:] for t in f.tracks}
        for x, y in list(PEOPLE.values())[:2]:
            self.assertTrue(any(math.hypot(tx - x, ty - y) < 1.5 for tx, ty in tracked.values()), tracked)

    def test_the_scorer_scores_the_detector_against_the_truth(self) -> None:
        final = next(m for m in self.collect["metrics"].snapshot() if '"final": true' in m.summary_json)
        summary = json.loads(final.summary_json)
        det = summary["detection"]
        self.assertEqual(det["source"], "external")
        self.assertEqual((det["tp"], det["fn"], det["fp"]), (100, 20, N_FRAMES))
        geo = det["geolocation"]
        self.assertEqual(geo["discarded"], {"nan_box": N_FRAMES, "out_of_image": N_FRAMES, "unknown_class": N_FRAMES})
        self.assertEqual(geo["unplaced"], {"no_surface": N_FRAMES})
        self.assertLess(geo["error"]["median_m"], 1.0)
        coco = det["coco"]
        self.assertGreater(coco["AP50"], 0.5)
        self.assertLess(coco["AP50"], 1.0)  # the misses and the false box cost it
        self.assertIn("1-8 px", coco["by_context"]["pixel_size"])
        self.assertGreater(summary["tracking"]["hota"], 0.3)
        self.assertEqual(summary["tracking"]["inputs"]["detections_unplaced"], N_FRAMES)
        gallery = self.collect["gallery"].snapshot()
        self.assertEqual(len(gallery), 1)
        self.assertEqual(gallery[0].encoding, "rgb8")
        self.assertEqual(len(det["gallery"]), 2)  # one false box (worst view) and the missed person (worst view)


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "detector_contract", TestDetectorContract)
