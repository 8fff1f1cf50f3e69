"""Messages -> scoring records, for rospy messages and rosbags messages alike.

The two libraries give messages with the same field names; only time differs
(rospy ``stamp.secs/nsecs``, rosbags ``stamp.sec/nanosec``). These functions
read fields by name and import no ROS module at import time, so the offline report
(rosbags) runs where ROS is not installed. They are the only place messages meet
scoring records.
"""

from __future__ import annotations

import math
import zlib
from typing import Any

import numpy as np

from uav_common.ros.arrays import MessageLayoutError, image_to_array, image_to_rgb
from uav_scenarios.core.scoring.cameras import CameraFrameSample, noise_level
from uav_scenarios.core.scoring.trails import ObjectStateRecord
from uav_scenarios.core.scoring.types import (
    BatterySample,
    CollisionEvent,
    ControllerSample,
    DepthMetricsSample,
    Detection,
    DetectionFrame,
    EstimateStatusSample,
    FaultSample,
    GoalSample,
    GridSnapshot,
    PathSample,
    PoseSample,
    TargetSample,
    Track,
    TrackFrame,
)
from uav_scenarios.errors import ScoringError

__all__ = [
    "battery_from_msg",
    "camera_frame_from_msg",
    "collision_from_msg",
    "controller_from_msg",
    "depth_metrics_from_msg",
    "detections_from_msg",
    "estimate_status_from_msg",
    "goal_from_msg",
    "grid_from_msg",
    "image_from_msg",
    "object_states_from_msg",
    "pose_from_odometry",
    "stamp_s",
    "target_from_msg",
    "tracks_from_msg",
]


def stamp_s(stamp: Any) -> float:
    """A ROS time (rospy or rosbags) as float seconds."""
    if hasattr(stamp, "secs"):
        return float(stamp.secs) + float(stamp.nsecs) * 1e-9
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


def _xyz(p: Any) -> tuple[float, float, float]:
    return (float(p.x), float(p.y), float(p.z))


def pose_from_odometry(msg: Any) -> PoseSample:
    """``nav_msgs/Odometry`` -> pose (yaw from the orientation quaternion, ENU)."""
    q = msg.pose.pose.orientation
    yaw = math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
    quat = (float(q.x), float(q.y), float(q.z), float(q.w))
    return PoseSample(stamp_s(msg.header.stamp), _xyz(msg.pose.pose.position), yaw, quat)


def battery_from_msg(msg: Any) -> BatterySample:
    """``sensor_msgs/BatteryState`` -> battery sample.

    ``percentage`` is 0..1 in ROS; consumed mAh is ``capacity - charge`` (Ah) when both
    are known. ROS reports discharge current as negative; the record keeps it positive.
    """
    pct = float(msg.percentage)
    capacity = float(msg.capacity)
    charge = float(msg.charge)
    consumed = (
        (capacity - charge) * 1000.0 if math.isfinite(capacity) and math.isfinite(charge) and capacity > 0 else math.nan
    )
    return BatterySample(
        t_s=stamp_s(msg.header.stamp),
        voltage_v=float(msg.voltage),
        remaining_pct=100.0 * pct if math.isfinite(pct) else math.nan,
        consumed_mah=consumed,
        current_a=abs(float(msg.current)),
    )


def grid_from_msg(msg: Any) -> GridSnapshot:
    """``uav_msgs/GridLayers`` -> named ``(H, W)`` float arrays (row 0 = south).

    Raises:
        ScoringError: ``data`` does not hold ``len(names) * height * width`` values.
    """
    h, w = int(msg.height), int(msg.width)
    names = list(msg.names)
    data = np.asarray(msg.data, dtype=np.float32)
    if data.size != len(names) * h * w:
        msg_ = f"GridLayers has {data.size} values for {len(names)} layers of {h}x{w}"
        raise ScoringError(msg_)
    cube = data.reshape(len(names), h, w).astype(np.float64) if names else np.zeros((0, h, w))
    return GridSnapshot(
        t_s=stamp_s(msg.header.stamp),
        resolution_m=float(msg.resolution_m),
        origin_x_m=float(msg.origin_x_m),
        origin_y_m=float(msg.origin_y_m),
        layers={name: cube[k] for k, name in enumerate(names)},
    )


def detections_from_msg(msg: Any) -> DetectionFrame:
    """``uav_msgs/DetectionArray`` -> detection frame (bags recorded before the covariance, position source
    and discard counters existed read as unknown / none)."""
    reasons = [str(r) for r in getattr(msg, "discarded_reasons", ())]
    counts = [int(c) for c in getattr(msg, "discarded_counts", ())]
    return DetectionFrame(
        t_s=stamp_s(msg.header.stamp),
        camera=str(msg.camera),
        source=str(msg.source),
        detections=tuple(
            Detection(
                instance_id=int(d.instance_id),
                class_name=str(d.class_name),
                score=float(d.score),
                bbox_px=(int(d.x_min), int(d.y_min), int(d.x_max), int(d.y_max)),
                range_m=float(d.range_m),
                visible_fraction=float(d.visible_fraction),
                position_m=_xyz(d.position),
                position_cov_m2=tuple(float(c) for c in getattr(d, "position_covariance", ())),
                position_source=str(getattr(d, "position_source", "")),
            )
            for d in msg.detections
        ),
        discarded=tuple(zip(reasons, counts, strict=False)),
    )


def tracks_from_msg(msg: Any) -> TrackFrame:
    """``uav_msgs/TrackArray`` -> track frame."""
    return TrackFrame(
        t_s=stamp_s(msg.header.stamp),
        camera=str(msg.camera),
        tracks=tuple(
            Track(int(t.track_id), str(t.class_name), _xyz(t.position), _xyz(t.velocity), int(t.hits))
            for t in msg.tracks
        ),
        detections_received=int(getattr(msg, "detections_received", 0)),
        detections_unplaced=int(getattr(msg, "detections_unplaced", 0)),
        detections_below_threshold=int(getattr(msg, "detections_below_threshold", 0)),
    )


def collision_from_msg(msg: Any) -> CollisionEvent:
    """``uav_msgs/Collision`` -> collision event."""
    return CollisionEvent(
        t_s=stamp_s(msg.header.stamp),
        instance_id=int(msg.instance_id),
        class_name=str(msg.class_name),
        position_m=_xyz(msg.position),
        speed_mps=float(msg.speed_mps),
    )


def goal_from_msg(msg: Any) -> GoalSample:
    """``uav_msgs/GoalReason`` or ``geometry_msgs/PointStamped`` -> goal sample."""
    if hasattr(msg, "goal"):
        return GoalSample(stamp_s(msg.header.stamp), _xyz(msg.goal), str(msg.reason))
    return GoalSample(stamp_s(msg.header.stamp), _xyz(msg.point), "")


def camera_frame_from_msg(msg: Any, camera: str) -> CameraFrameSample:
    """A colour ``sensor_msgs/Image`` of a watched camera -> its stamp, pixel digest (CRC-32) and noise level."""
    rgb = image_to_rgb(msg)
    return CameraFrameSample(stamp_s(msg.header.stamp), camera, zlib.crc32(rgb.tobytes()), noise_level(rgb))


def fault_from_msg(msg: Any) -> FaultSample:
    """``uav_msgs/FaultEvent`` -> fault sample."""
    return FaultSample(
        t_s=stamp_s(msg.header.stamp),
        index=int(msg.index),
        at_s=float(msg.at_s),
        unit=str(msg.unit),
        failure_type=str(msg.type),
        instance=int(msg.instance),
        clear=bool(msg.clear),
        result=str(msg.result),
        detail=str(msg.detail),
        answered_s=float(msg.answered_s),
    )


def target_from_msg(msg: Any) -> TargetSample:
    """``geometry_msgs/PointStamped`` (the autopilot's position target, map ENU) -> target sample."""
    return TargetSample(t_s=stamp_s(msg.header.stamp), position_m=(msg.point.x, msg.point.y, msg.point.z))


def path_from_msg(msg: Any) -> PathSample:
    """``nav_msgs/Path`` -> path sample (map ENU points)."""
    return PathSample(
        t_s=stamp_s(msg.header.stamp),
        points_m=tuple((p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in msg.poses),
    )


def controller_from_msg(msg: Any, t_s: float | None = None) -> ControllerSample:
    """``uav_msgs/ControllerState`` -> controller sample (``t_s`` if the header stamp is zero)."""
    stamp = stamp_s(msg.header.stamp)
    return ControllerSample(
        t_s=stamp if stamp > 0 or t_s is None else t_s,
        state=str(msg.state),
        autopilot_mode=str(msg.autopilot_mode),
        armed=bool(msg.armed),
        in_air=bool(msg.in_air),
        last_event=str(getattr(msg, "last_event", "")),
    )


def estimate_status_from_msg(msg: Any) -> EstimateStatusSample:
    """``uav_msgs/EstimateStatus`` -> estimate status sample."""
    return EstimateStatusSample(
        t_s=stamp_s(msg.header.stamp),
        state=str(msg.state),
        reason=str(msg.reason),
        source=str(msg.source),
        time_sync=str(msg.time_sync),
        time_offset_s=float(msg.time_offset_s),
        published=int(msg.published),
        invalid=int(msg.invalid),
        late=int(msg.late),
        out_of_order=int(msg.out_of_order),
        covariance_from_autopilot=bool(msg.covariance_from_autopilot),
    )


_DEPTH_STATS = (
    "coverage",
    "within_abs",
    "within_rel",
    "delta1",
    "delta2",
    "delta3",
    "abs_rel",
    "rmse_m",
    "mae_m",
    "bias_m",
    "median_abs_err_m",
)


def _depth_stats(stats: Any) -> dict[str, float]:
    out = {name: float(getattr(stats, name)) for name in _DEPTH_STATS if hasattr(stats, name)}
    for name in ("n_evaluated", "n_covered"):
        if hasattr(stats, name):
            out[name] = float(getattr(stats, name))
    return out


def depth_metrics_from_msg(msg: Any) -> DepthMetricsSample:
    """``uav_msgs/DepthMetrics`` (the depth evaluator's per-frame accuracy) -> depth sample.

    ``overall`` gives the frame's values; ``range_bands`` and ``classes`` its breakdowns
    (bands or classes with no evaluated pixel are left out).
    """
    t = stamp_s(msg.header.stamp)
    values = _depth_stats(msg.overall)
    breakdown: dict[str, dict[str, dict[str, float]]] = {}
    for context, items in (("range", msg.range_bands), ("class", msg.classes)):
        per = {str(s.label): _depth_stats(s) for s in items if int(getattr(s, "n_evaluated", 1)) > 0}
        if per:
            breakdown[context] = per
    return DepthMetricsSample(t, values, breakdown, str(getattr(msg, "camera", "")))


def image_from_msg(msg: Any) -> np.ndarray[Any, Any]:
    """``sensor_msgs/Image`` -> numpy array: colour images as RGB, others as stored (``uav_common.ros.arrays``).

    Raises:
        ScoringError: an encoding the project does not use, or a malformed image.
    """
    try:
        if str(msg.encoding).lower() in ("rgb8", "bgr8", "rgba8", "bgra8"):
            return image_to_rgb(msg)
        return image_to_array(msg)
    except MessageLayoutError as err:
        raise ScoringError(str(err)) from err


def object_states_from_msg(msg: Any) -> ObjectStateRecord:
    """``uav_msgs/ObjectStateArray`` -> rows ``(instance_id, x, y, z, yaw, length, width, height)``."""
    rows = []
    moving = []
    for o in msg.objects:
        q = o.pose.orientation
        yaw = math.atan2(
            2.0 * (float(q.w) * float(q.z) + float(q.x) * float(q.y)), 1.0 - 2.0 * (float(q.y) ** 2 + float(q.z) ** 2)
        )
        p = o.pose.position
        rows.append(
            (
                float(o.instance_id),
                float(p.x),
                float(p.y),
                float(p.z),
                yaw,
                float(o.size.x),
                float(o.size.y),
                float(o.size.z),
            )
        )
        moving.append(bool(o.moving))
    return ObjectStateRecord(
        stamp_s(msg.header.stamp),
        np.array(rows, dtype=np.float64).reshape(-1, 8),
        np.array(moving, dtype=bool),
        tuple(str(o.name) for o in msg.objects),
        tuple(str(o.class_name) for o in msg.objects),
    )
