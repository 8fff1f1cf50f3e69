"""Conversions between ROS messages and the depth core's types (the only place they meet).

Images are converted with numpy directly (no cv_bridge): row padding (``step``)
and byte order are honoured, and unsupported encodings raise
:class:`DepthInputError` with the encoding in the message.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
from geometry_msgs.msg import Transform
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField
from std_msgs.msg import Header

from uav_autonomy.core.depth_config import EvaluatorConfig
from uav_autonomy.core.depth_errors import DepthInputError
from uav_autonomy.core.depth_estimator import DepthEstimate, EstimatorStats
from uav_autonomy.core.depth_metrics import DepthEvaluation, DepthStats
from uav_autonomy.core.depth_triangulate import ColoredPoints
from uav_autonomy.core.depth_types import CameraPose, PinholeCamera
from uav_common.pointcloud import FIELD_OFFSETS, POINT_STEP, pack_xyzrgb
from uav_common.rotations import matrix_from_quat
from uav_msgs.msg import DepthEstimatorStatus, DepthMetrics
from uav_msgs.msg import DepthStats as DepthStatsMsg

__all__ = [
    "CLOUD_FIELDS",
    "camera_from_info",
    "cloud_msg",
    "depth_image_msg",
    "estimator_status_msg",
    "image_to_depth_m",
    "image_to_instances",
    "image_to_rgb",
    "instance_classes_from_json",
    "metrics_msg",
    "pose_from_odometry",
    "pose_from_transform",
]

# The ground-truth cloud layout (docs/architecture.md, uav_common.pointcloud): x y z rgb float32, point_step 16.
CLOUD_FIELDS = [PointField(name=n, offset=o, datatype=PointField.FLOAT32, count=1) for n, o in FIELD_OFFSETS.items()]


def _pixels(msg: Image, dtype: npt.DTypeLike, channels: int) -> npt.NDArray[Any]:
    item = np.dtype(dtype).itemsize * channels
    if msg.height == 0 or msg.width == 0:
        msg_text = f"empty {msg.encoding} image ({msg.width}x{msg.height})"
        raise DepthInputError(msg_text)
    if msg.step < msg.width * item or len(msg.data) < msg.step * msg.height:
        msg_text = (
            f"{msg.encoding} image {msg.width}x{msg.height}: step {msg.step} and {len(msg.data)} bytes "
            f"are too small for {item} bytes per pixel"
        )
        raise DepthInputError(msg_text)
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    raw = np.frombuffer(msg.data, dtype=np.uint8, count=msg.step * msg.height).reshape(msg.height, msg.step)
    rows = raw[:, : msg.width * item]
    arr = np.ascontiguousarray(rows).view(dt).reshape(msg.height, msg.width, channels)
    return arr.astype(np.dtype(dtype).newbyteorder("="), copy=False)


def image_to_rgb(msg: Image) -> npt.NDArray[np.uint8]:
    """``rgb8``/``bgr8``/``rgba8``/``bgra8`` -> ``(H, W, 3)`` uint8 RGB (a copy)."""
    enc = msg.encoding.lower()
    if enc in ("rgb8", "bgr8"):
        px = _pixels(msg, np.uint8, 3)
    elif enc in ("rgba8", "bgra8"):
        px = _pixels(msg, np.uint8, 4)[:, :, :3]
    else:
        text = f"color image encoding {msg.encoding!r} is not supported (rgb8, bgr8, rgba8, bgra8)"
        raise DepthInputError(text)
    if enc.startswith("bgr"):
        px = px[:, :, ::-1]
    return np.ascontiguousarray(px, dtype=np.uint8)


def image_to_depth_m(msg: Image) -> npt.NDArray[np.float32]:
    """``32FC1`` (metres) or ``16UC1`` (millimetres, 0 = none) -> ``(H, W)`` float32 metres, NaN = none."""
    if msg.encoding == "32FC1":
        depth = _pixels(msg, np.float32, 1)[:, :, 0].astype(np.float32, copy=True)
        depth[~np.isfinite(depth)] = np.nan
        return depth
    if msg.encoding == "16UC1":
        mm = _pixels(msg, np.uint16, 1)[:, :, 0]
        depth = mm.astype(np.float32) / 1000.0
        depth[mm == 0] = np.nan
        return depth
    text = f"depth image encoding {msg.encoding!r} is not supported (32FC1 metres or 16UC1 millimetres)"
    raise DepthInputError(text)


def image_to_instances(msg: Image) -> npt.NDArray[np.uint16]:
    """``16UC1`` instance-id image -> ``(H, W)`` uint16."""
    if msg.encoding not in ("16UC1", "mono16"):
        text = f"instance image encoding {msg.encoding!r} is not supported (16UC1)"
        raise DepthInputError(text)
    return np.ascontiguousarray(_pixels(msg, np.uint16, 1)[:, :, 0])


def depth_image_msg(depth_m: npt.NDArray[np.float32], header: Header) -> Image:
    """``(H, W)`` float32 metres (NaN = none) -> ``32FC1`` Image."""
    data = np.ascontiguousarray(depth_m, dtype="<f4")
    h, w = data.shape
    return Image(header=header, height=h, width=w, encoding="32FC1", is_bigendian=0, step=4 * w, data=data.tobytes())


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


def cloud_msg(points: ColoredPoints, header: Header) -> PointCloud2:
    """Unorganised ``x y z rgb`` float32 cloud, point_step 16, finite points only (the ground-truth format)."""
    data = pack_xyzrgb(points.xyz_m, points.rgb)
    n = len(data) // POINT_STEP
    return PointCloud2(
        header=header,
        height=1,
        width=n,
        fields=CLOUD_FIELDS,
        is_bigendian=False,
        point_step=POINT_STEP,
        row_step=POINT_STEP * n,
        data=data,
        is_dense=True,
    )


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
