"""Conversions between ROS messages and the depth core's types (the only place they meet).

Images and clouds are converted by :mod:`uav_common.ros.arrays` (numpy, no cv_bridge; row
padding and byte order honoured); this module builds the depth core's camera, pose and
points from the rest, and the depth status and metrics messages.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import Transform
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, PointCloud2
from std_msgs.msg import Header

from uav_common.ros.arrays import cloud_msg
from uav_common.rotations import matrix_from_quat
from uav_msgs.msg import DepthEstimatorStatus, DepthMetrics
from uav_msgs.msg import DepthStats as DepthStatsMsg
from uav_perception.core.depth.config import EvaluatorConfig
from uav_perception.core.depth.estimator import DepthEstimate, EstimatorStats
from uav_perception.core.depth.metrics import DepthEvaluation, DepthStats
from uav_perception.core.depth.triangulate import ColoredPoints
from uav_perception.core.depth.types import CameraPose, PinholeCamera
from uav_perception.errors import DepthInputError

__all__ = [
    "camera_from_info",
    "colored_cloud_msg",
    "estimator_status_msg",
    "instance_classes_from_json",
    "metrics_msg",
    "pose_from_odometry",
    "pose_from_transform",
]


def camera_from_info(msg: CameraInfo) -> PinholeCamera:
    """Intrinsics of an undistorted camera.

    Raises:
        DepthInputError: zero size, a singular K, or non-zero distortion (not modelled).
    """
    if msg.width == 0 or msg.height == 0:
        text = f"camera_info of {msg.header.frame_id!r} has no image size"
        raise DepthInputError(text)
    if any(abs(d) > 1e-9 for d in msg.D):
        text = f"camera_info of {msg.header.frame_id!r} has distortion {list(msg.D)}; only undistorted images work"
        raise DepthInputError(text)
    return PinholeCamera.from_matrix(np.asarray(msg.K, dtype=np.float64).reshape(3, 3), msg.width, msg.height)


def pose_from_transform(tf: Transform) -> CameraPose:
    """``geometry_msgs/Transform`` (parent <- child) -> :class:`CameraPose` of the child in the parent."""
    q = tf.rotation
    t = tf.translation
    quat = np.array([q.w, q.x, q.y, q.z], dtype=np.float64)
    if not np.all(np.isfinite(quat)) or np.linalg.norm(quat) < 1e-9:
        return CameraPose(np.full((3, 3), np.nan), np.array([t.x, t.y, t.z], dtype=np.float64))
    return CameraPose(matrix_from_quat(quat), np.array([t.x, t.y, t.z], dtype=np.float64))


def pose_from_odometry(msg: Odometry) -> CameraPose:
    """The ``child_frame_id`` (base_link) pose in ``header.frame_id`` (map)."""
    p = msg.pose.pose.position
    q = msg.pose.pose.orientation
    quat = np.array([q.w, q.x, q.y, q.z], dtype=np.float64)
    pos = np.array([p.x, p.y, p.z], dtype=np.float64)
    if not np.all(np.isfinite(quat)) or np.linalg.norm(quat) < 1e-9:
        return CameraPose(np.full((3, 3), np.nan), pos)
    return CameraPose(matrix_from_quat(quat), pos)


def colored_cloud_msg(points: ColoredPoints, header: Header) -> PointCloud2:
    """Unorganised ``x y z rgb`` float32 cloud, point_step 16, finite points only (the ground-truth format)."""
    return cloud_msg(header, points.xyz_m, points.rgb)


def _stats_msg(stats: DepthStats, lo_m: float = math.nan, hi_m: float = math.nan) -> DepthStatsMsg:
    return DepthStatsMsg(
        label=stats.label,
        range_min_m=lo_m,
        range_max_m=hi_m,
        n_evaluated=stats.sums.n_evaluated,
        n_covered=stats.sums.n_covered,
        coverage=stats.coverage,
        within_abs=stats.within_abs,
        within_rel=stats.within_rel,
        delta1=stats.delta1,
        delta2=stats.delta2,
        delta3=stats.delta3,
        abs_rel=stats.abs_rel,
        rmse_m=stats.rmse_m,
        mae_m=stats.mae_m,
        bias_m=stats.bias_m,
        median_abs_err_m=stats.median_abs_err_m,
    )


def metrics_msg(
    evaluation: DepthEvaluation, header: Header, camera: str, config: EvaluatorConfig, stamp_diff_s: float
) -> DepthMetrics:
    """A per-frame :class:`DepthEvaluation` as ``uav_msgs/DepthMetrics``."""
    edges = config.range_bands_m
    bands = [_stats_msg(b, edges[i], edges[i + 1]) for i, b in enumerate(evaluation.range_bands)]
    return DepthMetrics(
        header=header,
        camera=camera,
        abs_tol_m=config.abs_tol_m,
        rel_tol=config.rel_tol,
        stamp_diff_s=stamp_diff_s,
        n_pixels=evaluation.n_pixels,
        n_spurious=evaluation.n_spurious,
        overall=_stats_msg(evaluation.overall),
        range_bands=bands,
        classes=[_stats_msg(c) for c in evaluation.classes],
    )


def estimator_status_msg(
    header: Header,
    *,
    camera: str,
    stats: EstimatorStats,
    extra_skips: Mapping[str, int],
    last: DepthEstimate | None,
    processing_time_s: float,
) -> DepthEstimatorStatus:
    """The estimator's counters and last estimate as ``uav_msgs/DepthEstimatorStatus``."""
    skips = {reason.value: count for reason, count in stats.skipped.items()}
    for name, count in extra_skips.items():
        skips[name] = skips.get(name, 0) + count
    rejections = {verdict.value: count for verdict, count in stats.pair_rejections.items()}
    msg = DepthEstimatorStatus(
        header=header,
        camera=camera,
        frames_in=stats.frames_in + sum(extra_skips.values()),
        estimates=stats.estimates,
        skip_reasons=sorted(skips),
        skip_counts=[skips[k] for k in sorted(skips)],
        pair_rejection_reasons=sorted(rejections),
        pair_rejection_counts=[rejections[k] for k in sorted(rejections)],
        processing_time_s=processing_time_s,
    )
    nan = math.nan
    if last is None:
        for name in ("baseline_m", "baseline_ratio", "rotation_deg", "axial_angle_deg", "depth_prior_m", "coverage"):
            setattr(msg, name, nan)
        msg.refine_rms_before_px = msg.refine_rms_after_px = msg.refine_correction_deg = nan
        msg.pose_jitter_m = nan
        return msg
    msg.last_partner_stamp.secs, msg.last_partner_stamp.nsecs = divmod(last.partner_stamp_ns, 10**9)
    msg.baseline_m = last.geometry.baseline_m
    msg.baseline_ratio = last.geometry.baseline_ratio
    msg.rotation_deg = last.geometry.rotation_deg
    msg.axial_angle_deg = last.geometry.axial_angle_deg
    msg.depth_prior_m = last.depth_prior_m
    msg.num_disparities = last.search.num_disparities
    msg.coverage = last.coverage
    refine = last.refine
    msg.refine_applied = bool(refine is not None and refine.applied)
    msg.refine_rms_before_px = refine.rms_before_px if refine is not None else nan
    msg.refine_rms_after_px = refine.rms_after_px if refine is not None else nan
    msg.refine_correction_deg = refine.correction_deg if refine is not None else nan
    msg.pose_smoothed = last.pose_smoothed
    msg.pose_jitter_m = last.pose_jitter_m
    return msg


def instance_classes_from_json(text: str) -> dict[int, str]:
    """Instance id -> class name from the world's object list (``objects.json``).

    Accepts a list of objects or ``{"objects": [...]}``; each object needs
    ``instance_id`` and ``class``.

    Raises:
        DepthInputError: not JSON, or an object without those keys.
    """
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        msg = f"object list is not JSON: {err}"
        raise DepthInputError(msg) from err
    objects: Sequence[Any] = data.get("objects", []) if isinstance(data, dict) else data
    if not isinstance(objects, list):
        msg = "object list must be a JSON list or an object with an 'objects' list"
        raise DepthInputError(msg)
    out: dict[int, str] = {}
    for i, obj in enumerate(objects):
        try:
            out[int(obj["instance_id"])] = str(obj["class"])
        except (KeyError, TypeError, ValueError) as err:
            msg = f"object #{i} of the object list lacks an integer 'instance_id' and a 'class': {obj!r:.80}"
            raise DepthInputError(msg) from err
    return out
