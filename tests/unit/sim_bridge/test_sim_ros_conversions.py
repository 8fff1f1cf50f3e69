"""The bridge's ROS message conversions (genpy messages, no master); images and clouds: tests/unit/uav_common."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.detections import GroundTruthDetection
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.vehicle_state import VehicleState
from uav_sim_bridge.core.world_config import ObjectClass
from uav_sim_bridge.ros import conversions as conv


@pytest.mark.parametrize(("sim_time_s", "secs", "nsecs"), [(8.1, 8, 100_000_000), (68.9, 68, 900_000_000), (0.0, 0, 0)])
def test_stamps_are_the_nearest_nanosecond(sim_time_s: float, secs: int, nsecs: int) -> None:
    # rospy.Time.from_sec truncates (8.1 -> 8.099999999): a bag's stamps then read one nanosecond early.
    t = conv.stamp(sim_time_s)
    assert (t.secs, t.nsecs) == (secs, nsecs)


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
