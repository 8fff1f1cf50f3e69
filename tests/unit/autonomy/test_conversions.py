"""Message conversions with the real generated message classes (no ROS master needed)."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("uav_msgs.msg", reason="needs the catkin devel space (scripts/in_env)")

from std_msgs.msg import Header

from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.errors import InvalidInputError
from uav_autonomy.ros.autonomy_conversions import (
    color_image_msg,
    float_image_msg,
    grid_layers_from_msg,
    grid_layers_msg,
    path_from_msg,
    path_msg,
    target_from_points,
    yaw_from_quaternion,
)


def test_grid_layers_round_trip_is_layer_major_row_major() -> None:
    spec = GridSpec(2.0, -10.0, 5.0, width=3, height=2)
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    b = -a
    msg = grid_layers_msg(spec, {"a": a, "b": b}, Header(frame_id="map"))
    assert list(msg.data[:6]) == [0, 1, 2, 3, 4, 5]
    assert list(msg.data[6:]) == [0, -1, -2, -3, -4, -5]
    spec2, layers = grid_layers_from_msg(msg)
    assert spec2 == spec
    np.testing.assert_array_equal(layers["b"], b)


def test_grid_layers_bad_length_and_duplicates_raise() -> None:
    msg = grid_layers_msg(GridSpec(1.0, 0.0, 0.0, 2, 2), {"a": np.zeros((2, 2), np.float32)}, Header())
    msg.data = msg.data[:3]
    with pytest.raises(InvalidInputError, match="expected 4"):
        grid_layers_from_msg(msg)
    msg.data = [0.0] * 8
    msg.names = ["a", "a"]
    with pytest.raises(InvalidInputError, match="duplicate"):
        grid_layers_from_msg(msg)


def test_images_are_north_up() -> None:
    layer = np.array([[0.0, 0.25], [1.0, np.nan]], dtype=np.float32)  # row 0 = south
    img = float_image_msg(layer, Header())
    pixels = np.frombuffer(img.data, dtype=np.float32).reshape(2, 2)
    assert pixels[0, 0] == 1.0  # top-left pixel is the north-west cell
    assert img.encoding == "32FC1"
    color = color_image_msg(layer, Header(), unit_range=True)
    rgb = np.frombuffer(color.data, dtype=np.uint8).reshape(2, 2, 3)
    assert (rgb[0, 1] == 0).all()  # NaN is black
    assert color.encoding == "rgb8"


def test_path_round_trip_and_yaw() -> None:
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 50.0], [0.0, 100.0, 50.0]])
    msg = path_msg(pts, Header(frame_id="map"))
    np.testing.assert_array_equal(path_from_msg(msg), pts)
    assert yaw_from_quaternion(msg.poses[1].pose.orientation) == pytest.approx(math.pi / 2)


def test_target_from_points() -> None:
    from geometry_msgs.msg import Point  # noqa: PLC0415

    assert target_from_points([]) is None
    assert target_from_points([Point(1.0, 2.0, 9.0)]).points_xy_m == ((1.0, 2.0),)
    with pytest.raises(InvalidInputError):
        target_from_points([Point(0, 0, 0), Point(1, 0, 0)])
