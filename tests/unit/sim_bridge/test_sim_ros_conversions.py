"""ROS message conversions (genpy messages, no master)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.detections import GroundTruthDetection
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.vehicle_state import VehicleState
from uav_sim_bridge.core.world_config import ObjectClass
from uav_sim_bridge.errors import PointCloudLayoutError
from uav_sim_bridge.ros import conversions as conv
from uav_sim_bridge.ros.pointcloud2 import pointcloud2_to_xyzrgb, xyzrgb_to_pointcloud2


@pytest.mark.parametrize(
    ("array", "encoding"),
    [
        (np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3), "rgb8"),
        (np.array([[1.5, np.nan], [3.25, 1e4]], dtype=np.float32), "32FC1"),
        (np.array([[0, 65535], [7, 1234]], dtype=np.uint16), "16UC1"),
    ],
)
def test_image_round_trip(array: np.ndarray, encoding: str) -> None:
    msg = conv.numpy_to_image(array, encoding, conv.header(1.5, "camera_nadir_optical"))
    assert (msg.height, msg.width, msg.encoding, msg.is_bigendian) == (array.shape[0], array.shape[1], encoding, 0)
    assert msg.step == array.shape[1] * array.itemsize * (3 if array.ndim == 3 else 1)
    np.testing.assert_array_equal(conv.image_to_numpy(msg), array)
    assert msg.header.stamp.to_sec() == 1.5


@pytest.mark.parametrize(("sim_time_s", "secs", "nsecs"), [(8.1, 8, 100_000_000), (68.9, 68, 900_000_000), (0.0, 0, 0)])
def test_stamps_are_the_nearest_nanosecond(sim_time_s: float, secs: int, nsecs: int) -> None:
    # rospy.Time.from_sec truncates (8.1 -> 8.099999999): a bag's stamps then read one nanosecond early.
    t = conv.stamp(sim_time_s)
    assert (t.secs, t.nsecs) == (secs, nsecs)


def test_image_shape_must_fit_encoding() -> None:
    with pytest.raises(ValueError, match="does not fit"):
        conv.numpy_to_image(np.zeros((2, 2), np.uint8), "rgb8", Header())
    with pytest.raises(ValueError, match="unsupported"):
        conv.numpy_to_image(np.zeros((2, 2), np.uint8), "bgr8", Header())


def test_camera_info_and_odometry() -> None:
    cam = CameraModel.simple(640, 480, 90.0, name="nadir")
    info = conv.camera_info(cam, conv.header(2.0, cam.optical_frame_id))
    assert list(info.K) == pytest.approx([320.0, 0.0, 319.5, 0.0, 320.0, 239.5, 0.0, 0.0, 1.0])
    assert list(info.P)[:4] == pytest.approx([320.0, 0.0, 319.5, 0.0])
    assert (info.width, info.height) == (640, 480)
    state = VehicleState(3.0, RigidTransform.from_rpy([1.0, 2.0, 3.0], yaw_rad=math.pi / 2), np.array([4.0, 0.0, 0.5]))
    odom = conv.odometry(state, "map", "base_link")
    assert (odom.header.frame_id, odom.child_frame_id) == ("map", "base_link")
    q = odom.pose.pose.orientation
    assert (q.x, q.y) == pytest.approx((0.0, 0.0))
    assert (q.z, q.w) == pytest.approx((math.sqrt(0.5), math.sqrt(0.5)))
    assert odom.twist.twist.linear.x == 4.0  # body frame
    tf = conv.transform_stamped(3.0, "map", "base_link", state.t_map_base)
    assert tf.transform.translation.z == 3.0
    assert tf.child_frame_id == "base_link"


def test_detection_array() -> None:
    det = GroundTruthDetection(7, ObjectClass.PERSON, 1, 2, 3, 4, 55.5, 0.5, 12, (1.0, 2.0, 3.0))
    msg = conv.detection_array(conv.header(1.0, "camera_forward_optical"), "forward", [det])
    d = msg.detections[0]
    assert (msg.camera, msg.source) == ("forward", "ground_truth")
    assert (d.instance_id, d.class_name, d.x_min, d.y_max, d.score) == (7, "person", 1, 4, 1.0)
    assert d.range_m == pytest.approx(55.5)
    assert d.position.z == 3.0


def test_pointcloud2_round_trip_and_layout() -> None:
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(100, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (100, 3)).astype(np.uint8)
    msg = xyzrgb_to_pointcloud2(conv.header(1.0, "camera_nadir_optical"), xyz, rgb)
    assert (msg.height, msg.width, msg.point_step, msg.row_step, msg.is_dense) == (1, 100, 16, 1600, True)
    assert [(f.name, f.offset, f.datatype) for f in msg.fields] == [
        ("x", 0, PointField.FLOAT32), ("y", 4, PointField.FLOAT32), ("z", 8, PointField.FLOAT32),
        ("rgb", 12, PointField.FLOAT32),
    ]  # fmt: skip
    got_xyz, got_rgb = pointcloud2_to_xyzrgb(msg)
    np.testing.assert_array_equal(got_xyz, xyz)
    np.testing.assert_array_equal(got_rgb, rgb)


def test_pointcloud2_organised_with_row_padding() -> None:
    rec = np.zeros((2, 3), dtype={"names": ["x", "y", "z", "rgb"], "formats": ["<f4"] * 3 + ["<u4"], "itemsize": 20})
    rec["x"] = np.arange(6).reshape(2, 3)
    rec["rgb"] = 0x0000FF
    rows = [rec[r].tobytes() + b"\xee" * 4 for r in range(2)]  # 4 bytes of padding per row
    fields = [
        PointField(name=n, offset=o, datatype=PointField.FLOAT32, count=1)
        for n, o in zip("xyz", (0, 4, 8), strict=True)
    ]
    fields.append(PointField(name="rgb", offset=12, datatype=PointField.FLOAT32, count=1))
    msg = PointCloud2(height=2, width=3, fields=fields, point_step=20, row_step=64, data=b"".join(rows))
    xyz, rgb = pointcloud2_to_xyzrgb(msg)
    np.testing.assert_array_equal(xyz[:, 0], np.arange(6))
    assert (rgb == [0, 0, 255]).all()


@pytest.mark.parametrize(
    ("mutate", "match"),
    [
        (lambda m: setattr(m, "fields", m.fields[:3]), "lacks field"),
        (lambda m: setattr(m.fields[0], "datatype", PointField.FLOAT64), "FLOAT32"),
        (lambda m: setattr(m, "data", m.data[:-5]), "inconsistent"),
        (lambda m: setattr(m, "point_step", 0), "inconsistent"),
    ],
)
def test_pointcloud2_bad_layouts(mutate, match: str) -> None:
    msg = xyzrgb_to_pointcloud2(Header(), np.zeros((4, 3)), np.zeros((4, 3), np.uint8))
    mutate(msg)
    with pytest.raises(PointCloudLayoutError, match=match):
        pointcloud2_to_xyzrgb(msg)
