"""detector: an ONNX object detector on a camera image, publishing the detector contract.

Runs any ONNX detector of the documented format (docs/detector.md; YOLOv8/YOLO11 exports and the range's own
``uav-train-detector`` models) with onnxruntime on the CPU, one intra-op thread by default, and publishes
``vision_msgs/Detection2DArray`` exactly as the ground truth's box-only detector and the stand-in do, so the
geolocator, the tracker, the search-and-rescue confirmation and the scorer consume it unchanged.

ROS interface:

Subscribes:
    ``~image`` (sensor_msgs/Image rgb8/bgr8; "" = ``/cameras/<camera>/color/image_raw``): newest frame only
    (a frame that arrives while the model runs replaces the waiting one); in the causal lockstep every frame,
    each in the step that delivers it (docs/lockstep.md: a participant with a lookahead of 2 steps).
Publishes:
    ``~detections`` (vision_msgs/Detection2DArray): one message per processed frame, the image's header,
    box-only (class id, score in [0, 1]; pose unset).
Parameters (``uav_perception.ros.params.DetectorParams``):
    ``~model`` (the ONNX file; "" = the shipped ``models/uav_detector.onnx``), ``~camera`` (``forward``),
    ``~image``, ``~classes`` (class map, ""), ``~threads`` (1), ``~decode`` (dict: ``score_threshold`` 0.05,
    ``iou_threshold`` 0.5, ``max_detections`` 100, ``margin_px`` 2).

A missing, corrupt or wrong-format model stops the node with exit code 3 and a message naming the file and
what was expected; candidates with NaN or out-of-image boxes are counted (logged every 10 s and at exit) and
discarded.
"""

from __future__ import annotations

import threading
import time
from collections import Counter

import rospy
from sensor_msgs.msg import Image
from vision_msgs.msg import Detection2DArray

from uav_common.ros.arrays import image_to_rgb
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_perception.errors import ModelFormatError, PerceptionError
from uav_perception.ros.params import DetectorParams, detection_classes
from uav_perception.ros.vision import detection2d_array_msg
from uav_perception.shell.models import resolve_model
from uav_perception.shell.onnx_detector import OnnxDetector

#: Steps between a frame and when its detections are consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 2


class DetectorNode:
    def __init__(self, params: DetectorParams) -> None:
        self.p = params
        classes = detection_classes(params.classes)
        self.model_path = str(resolve_model(params.model))
        self.model = OnnxDetector(self.model_path, threads=params.threads, cfg=params.decode)
        names = self.model.class_names
        if names is None:
            self.class_ids = list(range(self.model.num_classes))
        else:
            unknown = [n for n in names if n not in classes.names]
            if unknown:
                msg = (
                    f"{self.model_path}: metadata uav_classes names {unknown}, not classes of the range "
                    f"({', '.join(classes.names)}; config/detection_classes.yaml)"
                )
                raise ModelFormatError(msg)
            self.class_ids = [classes.id_of(n) for n in names]
        self.lock = threading.Condition()
        self.pending: Image | None = None
        self.frames = 0
        self.dropped = 0
        self.discarded: Counter[str] = Counter()
        self.infer_s = 0.0

    def start(self, ls: Participant) -> None:
        topic = self.p.image or f"/cameras/{self.p.camera}/color/image_raw"
        self.pub = ls.publisher("~detections", Detection2DArray, queue_size=10)
        every_frame = ls.causal
        ls.subscribe(topic, Image, self.detect if every_frame else self.on_image, queue_size=1, buff_size=2**24)
        spec = self.model.spec
        size = "dynamic" if spec.input_hw is None else f"{spec.input_hw[1]}x{spec.input_hw[0]}"
        rospy.loginfo(
            f"detector: {self.model_path} (input {size}, {self.model.num_classes} classes -> ids {self.class_ids}, "
            f"{self.p.threads} thread(s)): {topic} -> {self.pub.resolved_name}"
        )
        rospy.on_shutdown(self.report)
        if not every_frame:
            worker = threading.Thread(target=self.loop, daemon=True)
            worker.start()
        ls.timer(10.0, lambda _now: self.report(), name="report")

    def on_image(self, msg: Image) -> None:
        with self.lock:
            if self.pending is not None:
                self.dropped += 1
            self.pending = msg
            self.lock.notify()

    def loop(self) -> None:
        while not rospy.is_shutdown():
            with self.lock:
                while self.pending is None and not rospy.is_shutdown():
                    self.lock.wait(0.5)
                msg, self.pending = self.pending, None
            if msg is not None:
                self.detect(msg)

    def detect(self, msg: Image) -> None:
        """Detect on one frame and publish its boxes (a frame that cannot be decoded is skipped and said)."""
        try:
            image = image_to_rgb(msg)
        except ValueError as err:
            rospy.logwarn_throttle(5.0, f"detector: frame skipped: {err}")
            return
        t0 = time.perf_counter()
        dets, discarded = self.model.detect(image, self.class_ids)
        self.infer_s += time.perf_counter() - t0
        self.discarded.update(discarded)
        self.frames += 1
        self.pub.publish(detection2d_array_msg(msg.header, dets))

    def report(self) -> None:
        if self.frames:
            counts = ", ".join(f"{k} {v}" for k, v in sorted(self.discarded.items())) or "none"
            rospy.loginfo(
                f"detector: {self.frames} frames, {1e3 * self.infer_s / self.frames:.1f} ms each, "
                f"{self.dropped} skipped while busy; discarded candidates: {counts}"
            )


def main() -> None:
    run_participant("detector", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(PerceptionError,))


def _build(ls: Participant) -> None:
    DetectorNode(node_params(DetectorParams, "detector")).start(ls)
