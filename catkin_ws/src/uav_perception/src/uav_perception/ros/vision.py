"""The detector contract's messages <-> the detection core (the only place they meet).

``vision_msgs/Detection2DArray`` in and out (any detector), ``uav_msgs/DetectionArray`` out (the
geolocator's placed detections), ``uav_msgs/GridLayers`` -> :class:`HeightGrid`. Readers go by field
name, so rospy and rosbags messages both work.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import Header
from vision_msgs.msg import BoundingBox2D, Detection2D, Detection2DArray, ObjectHypothesisWithPose

from uav_msgs.msg import Detection, DetectionArray, GeolocatorStatus
from uav_perception.core.detection.boxes import Box, RawDetection
from uav_perception.core.detection.geolocation import Placement
from uav_perception.core.detection.heightfield import HeightGrid

__all__ = [
    "detection2d_array_msg",
    "elevation_from_layers",
    "geolocated_array_msg",
    "raw_detections_from_msg",
    "status_msg",
]

_NAN3 = (math.nan, math.nan, math.nan)


def raw_detections_from_msg(msg: Any) -> list[RawDetection]:
    """``vision_msgs/Detection2DArray`` -> one :class:`RawDetection` per ``Detection2D`` (unchecked)."""
    out = []
    for det in msg.detections:
        box = det.bbox
        out.append(
            RawDetection(
                float(box.center.x),
                float(box.center.y),
                float(box.size_x),
                float(box.size_y),
                tuple((int(h.id), float(h.score)) for h in det.results),
            )
        )
    return out


def detection2d_array_msg(header: Header, detections: Iterable[RawDetection]) -> Detection2DArray:
    """Box-only ``Detection2DArray``: every ``Detection2D`` has the array's header, its box, its hypotheses
    (id, score; the pose is left unset: zeros) and no source image."""
    out = Detection2DArray(header=header)
    for d in detections:
        det = Detection2D(header=header)
        det.bbox = BoundingBox2D()
        det.bbox.center.x = d.center_u
        det.bbox.center.y = d.center_v
        det.bbox.center.theta = 0.0
        det.bbox.size_x = d.size_u
        det.bbox.size_y = d.size_v
        det.results = [ObjectHypothesisWithPose(id=class_id, score=score) for class_id, score in d.hypotheses]
        out.detections.append(det)
    return out


def geolocated_array_msg(
    header: Header,
    *,
    camera: str,
    source: str,
    boxes: Sequence[Box],
    placements: Sequence[Placement],
    discarded: Mapping[str, int],
) -> DetectionArray:
    """The geolocator's output: every kept box with its placement (NaN position and ``unplaced:<reason>``
    when it has none) and this frame's discarded counts by reason."""
    out = DetectionArray(header=header, camera=camera, source=source)
    for box, place in zip(boxes, placements, strict=True):
        x_min, y_min, x_max, y_max = box.inclusive()
        pos = place.position_m if place.placed else _NAN3
        out.detections.append(
            Detection(
                instance_id=0,
                class_name=box.class_name,
                score=box.score,
                x_min=x_min,
                y_min=y_min,
                x_max=x_max,
                y_max=y_max,
                range_m=place.range_m,
                visible_fraction=math.nan,
                position=Point(x=pos[0], y=pos[1], z=pos[2]),
                position_covariance=list(place.covariance_m2),
                position_source=place.source if place.placed else f"unplaced:{place.reason}",
            )
        )
    reasons = [r for r, n in discarded.items() if n]
    out.discarded_reasons = reasons
    out.discarded_counts = [int(discarded[r]) for r in reasons]
    return out


def elevation_from_layers(msg: Any, layer: str = "elevation_m") -> HeightGrid | None:
    """The ``elevation_m`` layer of a ``uav_msgs/GridLayers`` as a ``nearest`` :class:`HeightGrid`;
    ``None`` if the message has no such layer, no cells, or inconsistent sizes."""
    names = list(msg.names)
    h, w = int(msg.height), int(msg.width)
    if layer not in names or h == 0 or w == 0:
        return None
    data = np.asarray(msg.data, dtype=np.float32)
    if data.size != len(names) * h * w:
        return None
    k = names.index(layer)
    grid = data[k * h * w : (k + 1) * h * w].reshape(h, w).astype(np.float64)
    if not np.isfinite(grid).any():
        return None
    return HeightGrid(
        grid, float(msg.origin_x_m), float(msg.origin_y_m), float(msg.resolution_m), "nearest", "elevation"
    )


def _pairs(counts: Mapping[str, int]) -> tuple[list[str], list[int]]:
    keys = [k for k, v in counts.items() if v]
    return keys, [int(counts[k]) for k in keys]


def status_msg(
    header: Header,
    *,
    camera: str,
    detector: str,
    frames: int,
    frames_other_camera: int,
    received: int,
    discarded: Mapping[str, int],
    placed: Mapping[str, int],
    unplaced: Mapping[str, int],
    processing_ms: float,
) -> GeolocatorStatus:
    """The geolocator's running totals."""
    msg = GeolocatorStatus(
        header=header,
        camera=camera,
        detector=detector,
        frames=frames,
        frames_other_camera=frames_other_camera,
        detections_received=received,
        processing_ms=processing_ms,
    )
    msg.discarded_reasons, msg.discarded_counts = _pairs(discarded)
    msg.placed_sources, msg.placed_counts = _pairs(placed)
    msg.unplaced_reasons, msg.unplaced_counts = _pairs(unplaced)
    return msg
