"""The ROS adapters of the depth component, with real genpy messages and no master."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from geometry_msgs.msg import Transform
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from uav_common.ros.arrays import cloud_msg
from uav_perception.core.depth.config import EvaluatorConfig
from uav_perception.core.depth.estimator import EstimatorStats, SkipReason
from uav_perception.core.depth.metrics import evaluate_depth
from uav_perception.core.depth.pairing import PairVerdict
from uav_perception.core.depth.triangulate import points_from_depth
from uav_perception.core.depth.types import PinholeCamera
from uav_perception.errors import DepthInputError
from uav_perception.ros.conversions import (
    camera_from_info,
    colored_cloud_msg,
    estimator_status_msg,
    instance_classes_from_json,
    metrics_msg,
    pose_from_odometry,
    pose_from_transform,
)
from uav_perception.shell.runlog import DepthRunLog, json_safe


def roundtrip(msg: Any) -> Any:
    buf = io.BytesIO()
    msg.serialize(buf)
    out = type(msg)()
    out.deserialize(buf.getvalue())
    return out


def test_camera_info_and_poses() -> None:
    info = CameraInfo(width=640, height=480, K=[320, 0, 319.5, 0, 320, 239.5, 0, 0, 1], D=[0, 0, 0, 0, 0])
    assert camera_from_info(info) == PinholeCamera(640, 480, 320.0, 320.0, 319.5, 239.5)
    with pytest.raises(DepthInputError, match="distortion"):
        camera_from_info(CameraInfo(width=640, height=480, K=info.K, D=[0.1, 0, 0, 0, 0]))
    with pytest.raises(DepthInputError, match="no image size"):
        camera_from_info(CameraInfo(K=info.K))
    tf = Transform()
    tf.translation.x, tf.translation.z = 2.0, 30.0
    s = math.sin(math.pi / 4)
    tf.rotation.z, tf.rotation.w = s, s  # 90 deg about z
    pose = pose_from_transform(tf)
    assert pose.position_map_m.tolist() == [2.0, 0.0, 30.0]
    assert pose.rotation_map_optical @ np.array([1.0, 0, 0]) == pytest.approx([0, 1, 0])
    tf.rotation.w = float("nan")
    assert not pose_from_transform(tf).is_valid
    odom = Odometry()
    odom.pose.pose.orientation.w = 1.0
    odom.pose.pose.position.z = 12.0
    assert pose_from_odometry(odom).position_map_m[2] == 12.0


def test_cloud_message_layout() -> None:
    cam = PinholeCamera(4, 3, 2.0, 2.0, 1.5, 1.0)
    depth = np.full((3, 4), np.nan, np.float32)
    depth[1, 2] = 10.0
    rgb = np.full((3, 4, 3), 7, np.uint8)
    msg = roundtrip(colored_cloud_msg(points_from_depth(depth, rgb, cam), Header(frame_id="camera_nadir_optical")))
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ("x", 0, 7, 1),
        ("y", 4, 7, 1),
        ("z", 8, 7, 1),
        ("rgb", 12, 7, 1),
    ]
    assert (msg.height, msg.width, msg.point_step, msg.row_step, msg.is_dense) == (1, 1, 16, 16, True)
    rec = np.frombuffer(msg.data, "<f4")
    assert rec[:3].tolist() == pytest.approx([2.5, 0.0, 10.0])
    assert rec[3:].view("<u4")[0] == 0x070707
    # Byte for byte what the sim bridge publishes as its ground-truth cloud for the same points.
    xyz, colors = np.array([[2.5, 0.0, 10.0]], np.float32), np.array([[7, 7, 7]], np.uint8)
    truth = cloud_msg(Header(frame_id="camera_nadir_optical"), xyz, colors)
    for key in ("height", "width", "fields", "is_bigendian", "point_step", "row_step", "data", "is_dense"):
        assert getattr(msg, key) == getattr(truth, key), key


def test_metrics_and_status_messages() -> None:
    cfg = EvaluatorConfig(range_bands_m=(0.0, 20.0, math.inf), classes=("terrain", "tree"))
    gt = np.full((2, 2), 10.0, np.float32)
    est = np.array([[10.2, np.nan], [11.5, 10.0]], np.float32)
    ev = evaluate_depth(est, gt, cfg, np.array([[0, 0], [0, 0]], np.int16))
    msg = roundtrip(metrics_msg(ev, Header(frame_id="cam"), "nadir", cfg, 0.0))
    assert msg.overall.coverage == pytest.approx(0.75)
    assert msg.overall.within_abs == pytest.approx(2 / 3)
    assert [(b.label, b.range_min_m, b.range_max_m) for b in msg.range_bands] == [
        ("0-20m", 0.0, 20.0),
        (">=20m", 20.0, math.inf),
    ]
    assert math.isnan(msg.range_bands[1].coverage)
    assert [c.label for c in msg.classes] == ["terrain", "tree"]
    assert math.isnan(msg.overall.range_min_m)
    stats = EstimatorStats()
    stats.frames_in, stats.estimates = 5, 2
    stats.skipped[SkipReason.NO_HISTORY] = 1
    stats.skipped[SkipReason.BUSY] = 2
    stats.pair_rejections[PairVerdict.AXIAL_MOTION] = 4
    st = roundtrip(
        estimator_status_msg(
            Header(), camera="nadir", stats=stats, extra_skips={"no_pose": 3}, last=None, processing_time_s=0.1
        )
    )
    assert dict(zip(st.skip_reasons, st.skip_counts, strict=True)) == {"busy": 2, "no_history": 1, "no_pose": 3}
    assert dict(zip(st.pair_rejection_reasons, st.pair_rejection_counts, strict=True)) == {"axial_motion": 4}
    assert st.frames_in == 8
    assert math.isnan(st.baseline_m)


def test_object_list_and_run_log(tmp_path: Path) -> None:
    text = '{"objects": [{"instance_id": 1, "class": "terrain", "name": "t"}, {"instance_id": 9, "class": "tree"}]}'
    assert instance_classes_from_json(text) == {1: "terrain", 9: "tree"}
    assert instance_classes_from_json('[{"instance_id": 3, "class": "road"}]') == {3: "road"}
    with pytest.raises(DepthInputError, match="object #0"):
        instance_classes_from_json('[{"id": 3}]')
    with pytest.raises(DepthInputError, match="not JSON"):
        instance_classes_from_json("{")
    assert json_safe({"a": [math.nan, 1.0, math.inf]}) == {"a": [None, 1.0, None]}
    cfg = EvaluatorConfig()
    log = DepthRunLog(tmp_path / "run", "nadir", cfg)
    gt = np.full((3, 3), 30.0, np.float32)
    for k in range(3):
        log.add(float(k), 0.0, evaluate_depth(gt + 0.5 * k, gt, cfg))
    summary = log.write_summary({"dropped_no_truth": 0})
    log.close()
    lines = (tmp_path / "run" / "depth_metrics.jsonl").read_text().splitlines()
    assert len(lines) == 3

    data = json.loads(summary.read_text())
    assert data["frames"] == 3
    assert data["aggregate"]["overall"]["mae_m"] == pytest.approx(0.5)
    assert data["dropped_no_truth"] == 0
    # a frame evaluated while the node shuts down (after the close) is still logged and summarised
    log.add(3.0, 0.0, evaluate_depth(gt, gt, cfg))
    assert len((tmp_path / "run" / "depth_metrics.jsonl").read_text().splitlines()) == 4
    data = json.loads(summary.read_text())
    assert data["frames"] == 4
    assert data["dropped_no_truth"] == 0
