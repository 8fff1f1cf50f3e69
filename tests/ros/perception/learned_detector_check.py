#!/usr/bin/env python3
# A rostest node: unittest assertions are how rosunit reports.
"""rostest node: the learned detector (``detector``, an ONNX model) on camera images reaches the tracker and scorer.

The scene is detector_contract_check's (the forward camera 40 m up, three people on flat ground). The model is
hand-made (tests/helpers/onnx_models.py): whatever the image, its candidates are the three people's boxes (score
0.9), a NaN box, a box far outside the image and a box of score 0.01, so every box the node publishes is known.
The node is started by this check (after the model is written) and stopped at the end.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
import unittest
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1]), str(HERE.parents[2]), str(HERE)]
import detector_contract_check as scene  # noqa: E402 - after the path set-up
import numpy as np  # noqa: E402
import rospy  # noqa: E402
import rostest  # noqa: E402
from helpers.onnx_models import constant_detector  # noqa: E402
from helpers.ros_collect import Collector  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402
from std_msgs.msg import Header  # noqa: E402
from vision_msgs.msg import Detection2DArray  # noqa: E402

from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import Detection, DetectionArray, GeolocatorStatus, RunMetrics, TrackArray  # noqa: E402

N_FRAMES = 30


def start_detector(model: Path, name: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        ["rosrun", "uav_perception", "detector", f"__name:={name}", f"_model:={model}", "_camera:=forward"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=os.environ.copy(),
        start_new_session=True,
    )


class TestLearnedDetector(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("learned_detector_check")
        cls.tmp = Path(tempfile.mkdtemp(prefix="learned_detector_"))
        cls.collect = {
            "det": Collector("/detector/detections", Detection2DArray),
            "geo": Collector("/geolocator/detections", DetectionArray),
            "geo_status": Collector("/geolocator/status", GeolocatorStatus),
            "tracks": Collector("/scenario/tracks", TrackArray),
            "metrics": Collector("/scenario/metrics", RunMetrics),
        }
        base = scene.TestDetectorContract
        # the contract check's scene: its clock, static tf, elevation layer, camera_info and status messages
        from geometry_msgs.msg import TransformStamped  # noqa: PLC0415
        from nav_msgs.msg import Odometry  # noqa: PLC0415
        from rosgraph_msgs.msg import Clock  # noqa: PLC0415
        from sensor_msgs.msg import CameraInfo  # noqa: PLC0415
        from tf2_msgs.msg import TFMessage  # noqa: PLC0415

        from uav_common.rotations import quat_from_matrix  # noqa: PLC0415
        from uav_msgs.msg import GridLayers, ScenarioStatus  # noqa: PLC0415

        cls.pub_clock = rospy.Publisher("/clock", Clock, queue_size=10)
        cls.pub_static = rospy.Publisher("/tf_static", TFMessage, queue_size=1, latch=True)
        cls.pub_layers = rospy.Publisher("/map_server/layers", GridLayers, queue_size=1, latch=True)
        cls.pub_info = rospy.Publisher("/cameras/forward/color/camera_info", CameraInfo, queue_size=50)
        cls.pub_color = rospy.Publisher("/cameras/forward/color/image_raw", Image, queue_size=50)
        cls.pub_odom = rospy.Publisher("/uav/ground_truth/odom", Odometry, queue_size=50)
        cls.pub_truth = rospy.Publisher("/detections/ground_truth", DetectionArray, queue_size=50)
        cls.pub_status = rospy.Publisher("/scenario/status", ScenarioStatus, queue_size=10, latch=True)
        cls.now = scene.T0_S - 1.0
        cls.clock_run = True
        import threading  # noqa: PLC0415

        threading.Thread(target=base._clock_loop.__func__, args=(cls,), daemon=True).start()  # type: ignore[attr-defined]
        tf = TransformStamped()
        tf.header.frame_id, tf.child_frame_id = "map", scene.OPTICAL
        tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = scene.EYE
        w, x, y, z = quat_from_matrix(scene.R_MAP_OPTICAL)
        tf.transform.rotation.x, tf.transform.rotation.y, tf.transform.rotation.z, tf.transform.rotation.w = x, y, z, w
        cls.pub_static.publish(TFMessage([tf]))
        layers = GridLayers(resolution_m=1.0, origin_x_m=-150.0, origin_y_m=-150.0, width=300, height=300)
        layers.header.frame_id = "map"
        layers.names = ["elevation_m", "observed"]
        layers.data = np.concatenate([np.zeros(300 * 300), np.ones(300 * 300)]).astype(np.float32).tolist()
        cls.pub_layers.publish(layers)

        cls.boxes = {iid: scene.person_box(*xy) for iid, xy in scene.PEOPLE.items()}
        rows = [
            [x0 + (x1 - x0 + 1) / 2, y0 + (y1 - y0 + 1) / 2, x1 - x0 + 1, y1 - y0 + 1, 0.9, 0.0]
            for x0, y0, x1, y1 in cls.boxes.values()
        ]
        rows += [[math.nan, 100, 6, 14, 0.9, 0], [5000, 100, 6, 14, 0.9, 0], [300, 300, 10, 10, 0.01, 0.0]]
        cls.model = constant_detector(cls.tmp / "people.onnx", rows)
        cls.proc = start_detector(cls.model, "detector")
        for pub, nodes in (
            (cls.pub_color, {"/detector", "/scorer"}),
            (cls.pub_info, {"/geolocator"}),
            (cls.pub_layers, {"/geolocator"}),
            (cls.pub_truth, {"/scorer"}),
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
        wait_until(
            rospy.get_published_topics,
            lambda topics: any(t == "/detector/detections" for t, _ in topics),
            timeout_s=60.0,
            describe="the detector to advertise /detector/detections",
            clock=time.monotonic,
        )
        time.sleep(1.0)  # the geolocator's subscription to the detector settles
        base._status.__func__(cls, scene.T0_S, stop=False)  # type: ignore[attr-defined]
        cls.pub_info.publish(base._camera_info.__func__(cls, scene.stamp(0)))  # type: ignore[attr-defined]
        time.sleep(0.5)
        cls._play()

    @classmethod
    def tearDownClass(cls) -> None:
        cls.clock_run = False
        if cls.proc.poll() is None:
            os.killpg(cls.proc.pid, 2)
            try:
                cls.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(cls.proc.pid, 9)

    @classmethod
    def _play(cls) -> None:
        from geometry_msgs.msg import Point  # noqa: PLC0415
        from nav_msgs.msg import Odometry  # noqa: PLC0415

        rgb = np.full((scene.H, scene.W, 3), 110, np.uint8)
        for x0, y0, x1, y1 in cls.boxes.values():
            rgb[y0 : y1 + 1, x0 : x1 + 1] = (40, 40, 160)
        for k in range(N_FRAMES):
            t = scene.stamp(k)
            cls.now = t.to_sec()
            hdr = Header(stamp=t, frame_id=scene.OPTICAL)
            odom = Odometry(header=Header(stamp=t, frame_id="map"), child_frame_id="base_link")
            odom.pose.pose.position = Point(*scene.EYE)
            odom.pose.pose.orientation.w = 1.0
            cls.pub_odom.publish(odom)
            cls.pub_info.publish(scene.TestDetectorContract._camera_info.__func__(cls, t))  # type: ignore[attr-defined]
            truth = DetectionArray(header=hdr, camera="forward", source="ground_truth")
            for iid, (x, y) in scene.PEOPLE.items():
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
                        range_m=float(np.linalg.norm(np.array([x, y, 0.9]) - scene.EYE)),
                        visible_fraction=1.0,
                        position=Point(x, y, 0.9),
                        position_covariance=[0.0] * 9,
                        position_source="ground_truth",
                    )
                )
            cls.pub_truth.publish(truth)
            cls.pub_color.publish(
                Image(header=hdr, height=scene.H, width=scene.W, encoding="rgb8", step=3 * scene.W, data=rgb.tobytes())
            )
            # one frame at a time: the node keeps only the newest frame while it works
            wait_until(
                cls.collect["det"].snapshot,
                lambda msgs, t=t: any(m.header.stamp == t for m in msgs),
                timeout_s=20.0,
                describe=f"the detector's output for frame {k}",
                clock=time.monotonic,
            )
            time.sleep(0.05)
            cls.now = t.to_sec() + 0.05
        end = scene.stamp(N_FRAMES).to_sec()
        for k in range(40):
            cls.now = end + 0.1 * k
            if k == 5:
                scene.TestDetectorContract._status.__func__(cls, cls.now, stop=True)  # type: ignore[attr-defined]
            time.sleep(0.05)
        wait_until(
            cls.collect["metrics"].snapshot,
            lambda msgs: any('"final": true' in m.summary_json for m in msgs),
            timeout_s=60.0,
            describe="the scorer's final metrics",
            clock=time.monotonic,
        )
        time.sleep(0.5)

    def test_the_detector_publishes_the_contract_for_every_image(self) -> None:
        frames = self.collect["det"].snapshot()
        self.assertEqual(len(frames), N_FRAMES)
        expected = sorted(
            ((x0 + x1) / 2, (y0 + y1) / 2, x1 - x0 + 1, y1 - y0 + 1) for x0, y0, x1, y1 in self.boxes.values()
        )
        for k, frame in enumerate(frames):
            self.assertEqual((frame.header.stamp, frame.header.frame_id), (scene.stamp(k), scene.OPTICAL))
            got = sorted((d.bbox.center.x, d.bbox.center.y, d.bbox.size_x, d.bbox.size_y) for d in frame.detections)
            self.assertEqual(len(got), 3)  # the NaN, out-of-image and low-score candidates are not passed on
            for g, e in zip(got, expected, strict=True):
                np.testing.assert_allclose(g, e, atol=1e-3)
            for d in frame.detections:
                self.assertEqual([(h.id, round(h.score, 3)) for h in d.results], [(0, 0.9)])

    def test_the_geolocator_places_the_detectors_boxes(self) -> None:
        frames = self.collect["geo"].snapshot()
        self.assertEqual(len(frames), N_FRAMES)
        for frame in frames:
            self.assertEqual(frame.source, "learned")
            self.assertEqual(len(frame.detections), 3)
            for d in frame.detections:
                self.assertEqual(d.position_source, "elevation")
                err = min(math.hypot(d.position.x - x, d.position.y - y) for x, y in scene.PEOPLE.values())
                self.assertLess(err, 1.0)
        status = self.collect["geo_status"].snapshot()[-1]
        self.assertEqual(status.frames, N_FRAMES)
        self.assertEqual(list(status.discarded_counts), [])  # the node discarded the bad candidates itself

    def test_the_tracker_and_scorer_take_the_learned_detections(self) -> None:
        tracks = self.collect["tracks"].snapshot()
        tracked = {t.track_id: (t.position.x, t.position.y) for f in tracks[-4:] for t in f.tracks}
        for x, y in scene.PEOPLE.values():
            self.assertTrue(any(math.hypot(tx - x, ty - y) < 1.5 for tx, ty in tracked.values()), tracked)
        final = next(m for m in self.collect["metrics"].snapshot() if '"final": true' in m.summary_json)
        det = json.loads(final.summary_json)["detection"]
        self.assertEqual(det["source"], "learned")
        self.assertEqual((det["tp"], det["fn"], det["fp"]), (3 * N_FRAMES, 0, 0))
        self.assertGreater(det["coco"]["AP50"], 0.99)

    def test_a_missing_corrupt_or_wrong_shape_model_stops_the_node_with_code_3_naming_the_file(self) -> None:
        corrupt = self.tmp / "corrupt.onnx"
        corrupt.write_bytes(b"not a model" * 50)
        wrong = constant_detector(self.tmp / "classifier.onnx", [[1, 2, 3, 4, 5, 6]], output_shape=[1, 6])
        cases = [
            (self.tmp / "missing.onnx", "no such model file"),
            (corrupt, "not a loadable ONNX model"),
            (wrong, "expected one input float32 [1, 3, H, W]"),
        ]
        for k, (path, expected) in enumerate(cases):
            proc = start_detector(path, f"bad_detector_{k}")
            out, _ = proc.communicate(timeout=60)
            self.assertEqual(proc.returncode, 3, out)
            self.assertIn(str(path), out)
            self.assertIn(expected, out)


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "learned_detector", TestLearnedDetector)
