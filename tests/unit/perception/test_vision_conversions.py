"""The detector contract's messages: vendored vision_msgs are upstream's (md5), boxes survive the round trip
through Detection2DArray, the ground truth's boxes carry neither ids nor positions, the geolocator's output keeps
unplaced detections (NaN, with the reason) and the frame's discard counts."""

from __future__ import annotations

import math
from collections import Counter

import numpy as np
import pytest
from std_msgs.msg import Header
from vision_msgs.msg import BoundingBox2D, Detection2D, Detection2DArray, ObjectHypothesisWithPose

from uav_common.detection_classes import DetectionClasses
from uav_msgs.msg import GridLayers
from uav_perception.core.detection.boxes import RawDetection, screen
from uav_perception.core.detection.geolocation import Placement
from uav_perception.ros.vision import (
    detection2d_array_msg,
    elevation_from_layers,
    geolocated_array_msg,
    raw_detections_from_msg,
)
from uav_sim_bridge.core.detections import GroundTruthDetection
from uav_sim_bridge.core.world_config import ObjectClass
from uav_sim_bridge.ros.conversions import ground_truth_boxes

#: md5sums of ros-perception/vision_msgs noetic-devel 0.0.2, computed with genmsg from the upstream files
#: (Detection2DArray's also appears in other projects' generated code, e.g. iviz).
UPSTREAM_MD5 = {
    Detection2DArray: "402071f61477de256df9f1aa45e6e4c8",
    Detection2D: "9e11092151fa150724a255fbac727f3b",
    ObjectHypothesisWithPose: "fa1ab3bc7146f53921fa142d631d02db",
    BoundingBox2D: "9ab41e2a4c8627735e5091a9abd68b02",
}
CLASSES = DetectionClasses()


@pytest.mark.parametrize("cls", list(UPSTREAM_MD5), ids=lambda c: c._type)
def test_vendored_vision_msgs_are_upstreams(cls: type) -> None:
    assert cls._md5sum == UPSTREAM_MD5[cls]  # type: ignore[attr-defined]


def test_boxes_round_trip_through_detection2d_array() -> None:
    sent = [RawDetection(100.5, 50.0, 10.0, 20.0, ((0, 0.9),)), RawDetection(3.0, 4.0, 2.0, 2.0, ((7, 0.4), (2, 0.3)))]
    msg = detection2d_array_msg(Header(frame_id="camera_forward_optical"), sent)
    assert raw_detections_from_msg(msg) == sent
    assert all(d.header.frame_id == "camera_forward_optical" and d.source_img.data == b"" for d in msg.detections)


def test_the_ground_truths_boxes_are_box_only_and_exact() -> None:
    truth = [
        GroundTruthDetection(622, ObjectClass.PERSON, 300, 200, 304, 215, 80.0, 0.7, 50, (1.0, 2.0, 3.0)),
        GroundTruthDetection(700, ObjectClass.VEHICLE, 10, 20, 49, 39, 40.0, 1.0, 800, (5.0, 6.0, 0.7)),
    ]
    msg = ground_truth_boxes(Header(frame_id="camera_forward_optical"), truth, CLASSES)
    for d in msg.detections:
        (hyp,) = d.results
        pose = hyp.pose.pose
        assert (pose.position.x, pose.position.y, pose.position.z) == (0.0, 0.0, 0.0)  # no 3D position
    assert [h.id for d in msg.detections for h in d.results] == [0, 2]  # class ids, not instance ids
    kept, discarded = screen(raw_detections_from_msg(msg), CLASSES, width_px=640, height_px=480)
    assert not discarded
    assert [b.inclusive() for b in kept] == [(300, 200, 304, 215), (10, 20, 49, 39)]
    assert [b.class_name for b in kept] == ["person", "vehicle"]


def test_the_geolocated_array_keeps_unplaced_detections_and_counts_discards() -> None:
    raw = [RawDetection(100.0, 100.0, 10.0, 20.0, ((0, 0.9),)), RawDetection(300.0, 20.0, 4.0, 8.0, ((2, 0.6),))]
    kept, _ = screen(raw, CLASSES, width_px=640, height_px=480)
    placements = [
        Placement((10.0, 20.0, 0.5), (1.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.1), "terrain", 55.0, (100.0, 110.0)),
        Placement.unplaced("no_surface", (300.0, 24.0)),
    ]
    msg = geolocated_array_msg(
        Header(frame_id="camera_forward_optical"),
        camera="forward",
        source="stand_in",
        boxes=kept,
        placements=placements,
        discarded=Counter({"nan_box": 2, "out_of_image": 1, "bad_score": 0}),
    )
    first, second = msg.detections
    assert (first.position.x, first.position.y, first.position_source) == (10.0, 20.0, "terrain")
    assert list(first.position_covariance)[4] == 2.0
    assert first.instance_id == 0
    assert math.isnan(first.visible_fraction)
    assert math.isnan(second.position.x)
    assert second.position_source == "unplaced:no_surface"
    assert (second.x_min, second.y_min, second.x_max, second.y_max) == (299, 17, 302, 24)  # 4 x 8 pixels
    assert dict(zip(msg.discarded_reasons, msg.discarded_counts, strict=True)) == {"nan_box": 2, "out_of_image": 1}


def test_the_elevation_layer_is_read_from_grid_layers() -> None:
    elevation = np.array([[1.0, 2.0, np.nan], [4.0, 5.0, 6.0]], dtype=np.float32)
    observed = np.ones_like(elevation)
    msg = GridLayers(resolution_m=1.0, origin_x_m=-1.0, origin_y_m=-2.0, width=3, height=2)
    msg.names = ["observed", "elevation_m"]
    msg.data = list(np.concatenate([observed.ravel(), elevation.ravel()]))
    grid = elevation_from_layers(msg)
    assert grid is not None
    assert grid.interpolation == "nearest"
    assert grid.at(0.5, -0.5)[()] == 5.0  # column 1, row 1
    assert math.isnan(grid.at(1.5, -1.5)[()])  # unknown cell
    msg.data = msg.data[:-1]
    assert elevation_from_layers(msg) is None  # inconsistent sizes: not used
    msg.names = ["observed"]
    assert elevation_from_layers(msg) is None
