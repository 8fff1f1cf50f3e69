"""degraded_detector: a TEST INSTRUMENT, NOT A DETECTOR. The ground truth's boxes, made worse, seeded.

It lets the detector contract be exercised end to end with boxes only (geolocation, tracking, the search
and rescue confirmation, the scorer) before a learned detector is in the loop. It never looks at an
image: it reads the ground truth's box-only ``vision_msgs/Detection2DArray`` (no instance ids, no 3D
positions), misses objects (small ones more often), jitters the boxes, confuses classes now and then,
adds false boxes and gives scores that mean nothing about the image
(``uav_perception.core.detection.degrade``). Its numbers are not a detector's numbers.

ROS interface:

Subscribes:
    ``~input`` (vision_msgs/Detection2DArray; "" = ``/detections/<camera>/ground_truth``).
    ``~camera_info`` (sensor_msgs/CameraInfo; "" = ``/cameras/<camera>/color/camera_info``): the image size.
Publishes:
    ``~detections`` (vision_msgs/Detection2DArray): one message per input frame, same header, box-only
    (class id from ``config/detection_classes.yaml``, score; pose unset).
Parameters (``uav_perception.ros.params.DegradedDetectorParams``):
    ``~camera`` (``forward``), ``~input``, ``~camera_info``, ``~classes`` (class map, ""),
    ``~degrade`` (dict: ``DegradeConfig`` keys: ``seed``, ``miss_rate_small``, ``miss_rate_large``,
    ``jitter_px``, ``jitter_rel``, ``confusion_rate``, ``false_positives_per_frame``, ...).
"""

from __future__ import annotations

import threading

import rospy
from sensor_msgs.msg import CameraInfo
from vision_msgs.msg import Detection2DArray

from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_perception.core.detection.boxes import screen
from uav_perception.core.detection.degrade import degrade, frame_rng
from uav_perception.errors import PerceptionError
from uav_perception.ros.params import DegradedDetectorParams, detection_classes
from uav_perception.ros.vision import detection2d_array_msg, raw_detections_from_msg

#: Steps between a frame's boxes and when its degraded boxes are consumed, in the causal lockstep
#: (docs/lockstep.md); the camera info of a frame is dispatched before its boxes (declared first).
LOOKAHEAD_STEPS = 2


class DegradedDetectorNode:
    def __init__(self, params: DegradedDetectorParams) -> None:
        self.p = params
        self.classes = detection_classes(params.classes)
        self.class_ids = {name: self.classes.id_of(name) for name in self.classes.names}
        self.size: tuple[int, int] | None = None
        self.lock = threading.Lock()
        self.frames = 0

    def start(self, ls: Participant) -> None:
        cam = self.p.camera
        self.pub = ls.publisher("~detections", Detection2DArray, queue_size=50)
        ls.subscribe(self.p.camera_info or f"/cameras/{cam}/color/camera_info", CameraInfo, self.on_info, queue_size=5)
        topic = self.p.input or f"/detections/{cam}/ground_truth"
        ls.subscribe(topic, Detection2DArray, self.on_truth, queue_size=100)
        rospy.loginfo(f"degraded_detector (a test instrument, not a detector): {topic} -> {self.pub.resolved_name}")

    def on_info(self, msg: CameraInfo) -> None:
        if msg.width > 0 and msg.height > 0:
            with self.lock:
                self.size = (int(msg.width), int(msg.height))

    def on_truth(self, msg: Detection2DArray) -> None:
        with self.lock:
            size = self.size
        if size is None:
            rospy.logwarn_throttle(5.0, "degraded_detector: no camera_info yet; frame passed on empty")
            self.pub.publish(detection2d_array_msg(msg.header, []))
            return
        truth, _ = screen(raw_detections_from_msg(msg), self.classes, width_px=size[0], height_px=size[1])
        rng = frame_rng(self.p.degrade.seed, msg.header.stamp.to_nsec(), msg.header.frame_id)
        out = degrade(truth, width_px=size[0], height_px=size[1], class_ids=self.class_ids, cfg=self.p.degrade, rng=rng)
        self.pub.publish(detection2d_array_msg(msg.header, out))
        self.frames += 1


def main() -> None:
    run_participant("degraded_detector", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(PerceptionError,))


def _build(ls: Participant) -> None:
    DegradedDetectorNode(node_params(DegradedDetectorParams, "degraded_detector")).start(ls)
