"""Message conversions with the real generated message classes (no ROS master needed)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from std_msgs.msg import Header

from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.errors import InvalidInputError
from uav_autonomy.ros.conversions import (
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


def _mavlink_frame(name: str, *fields: float) -> object:
    """A decoded MAVLink 2 message from the autopilot (1/1), as the link would receive it."""
    from pymavlink.dialects.v20 import common as mavlink2  # noqa: PLC0415

    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    packed = getattr(mav, f"{name}_encode")(*fields).pack(mav)
    return mav.decode(bytearray(packed))


def test_odometry_from_autopilot_telemetry_is_enu_flu() -> None:
    from uav_autonomy.mavlink.link import MavlinkLink  # noqa: PLC0415
    from uav_autonomy.ros.conversions import odometry_msg  # noqa: PLC0415

    link = MavlinkLink("udpin:127.0.0.1:0", source_system=1, source_component=191, target_system=1,
                       target_component=1, reconnect_after_s=5.0)  # fmt: skip
    assert link.odometry() is None
    # NED (10 N, 5 E, 20 up), flying north at 2 m/s while heading east (NED yaw +90 deg), yawing right.
    link._handle(_mavlink_frame("local_position_ned", 1000, 10.0, 5.0, -20.0, 2.0, 0.0, 0.0), 3.0)
    link._handle(_mavlink_frame("attitude", 1000, 0.0, 0.0, math.pi / 2, 0.0, 0.0, 0.3), 3.0)
    odom = link.odometry()
    assert odom is not None
    assert odom.stamp_s == 3.0
    np.testing.assert_allclose(odom.position_enu_m, (5.0, 10.0, 20.0), atol=1e-9)
    # Heading east is ENU yaw 0: identity attitude.
    np.testing.assert_allclose(np.abs(odom.q_enu_flu_wxyz), (1.0, 0.0, 0.0, 0.0), atol=1e-6)  # float32 on the wire
    # North is the body's left: +y in FLU. Yawing right (FRD +z) is FLU -z.
    np.testing.assert_allclose(odom.velocity_flu_mps, (0.0, 2.0, 0.0), atol=1e-6)
    np.testing.assert_allclose(odom.angular_flu_radps, (0.0, 0.0, -0.3), atol=1e-9)
    msg = odometry_msg(odom, Header(frame_id="map"))
    assert (msg.header.frame_id, msg.child_frame_id) == ("map", "base_link")
    assert (msg.pose.pose.position.x, msg.pose.pose.position.y, msg.pose.pose.position.z) == (5.0, 10.0, 20.0)
    assert abs(msg.pose.pose.orientation.w) == pytest.approx(1.0)
    assert msg.twist.twist.linear.y == pytest.approx(2.0)


def test_link_stamps_arrivals_on_both_clocks_and_reconnects_only_after_the_wall_floor() -> None:
    from uav_autonomy.mavlink.link import MavlinkLink  # noqa: PLC0415

    link = MavlinkLink("udpin:127.0.0.1:0", source_system=1, source_component=191, target_system=1,
                       target_component=1, reconnect_after_s=5.0, wall_floor_s=0.5)  # fmt: skip
    link.open(0.0, 100.0)
    try:
        link._handle(_mavlink_frame("heartbeat", 2, 12, 0, 0, 4, 3), 1.0, 100.1)
        link._handle(_mavlink_frame("local_position_ned", 1000, 10.0, 5.0, -20.0, 0.0, 0.0, 0.0), 1.0, 100.1)
        t = link.telemetry()
        assert (t.heartbeat_s, t.heartbeat_wall_s, t.position_s, t.position_wall_s) == (1.0, 100.1, 1.0, 100.1)
        link.poll(20.0, 100.3)  # 19 simulated s of silence, but 0.2 wall s: a simulation running ahead
        assert link.reconnects == 0
        assert link.telemetry().heartbeat_s == 1.0
        link.poll(20.0, 100.7)  # and now 0.6 wall s as well: the link is silent, reopen it
        assert link.reconnects == 1
        assert link.telemetry().heartbeat_s is None
    finally:
        link.close()


def test_a_poll_stamps_each_message_with_the_clock_when_it_is_read() -> None:
    """A poll on a loaded machine can last simulated seconds: with a clock, a message read late in it is stamped
    then (the controller's mode change was once published 4.6 s before it was read)."""
    import socket  # noqa: PLC0415

    from uav_autonomy.mavlink.link import MavlinkLink  # noqa: PLC0415

    link = MavlinkLink("udpin:127.0.0.1:0", source_system=1, source_component=191, target_system=1,
                       target_component=1, reconnect_after_s=5.0)  # fmt: skip
    link.open(0.0, 100.0)
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        port = link._require().port.getsockname()[1]  # type: ignore[attr-defined]
        frames = [_mavlink_frame("heartbeat", 2, 12, 0, 0, 4, 3),
                  _mavlink_frame("local_position_ned", 1000, 10.0, 5.0, -20.0, 0.0, 0.0, 0.0)]  # fmt: skip
        for frame in frames:
            out.sendto(bytes(frame.get_msgbuf()), ("127.0.0.1", port))  # type: ignore[attr-defined]
        link.wait_readable(2.0)
        readings = iter([(7.0, 101.0), (9.5, 101.2)])
        link.poll(5.0, 100.5, clock=lambda: next(readings))
        t = link.telemetry()
        assert (t.heartbeat_s, t.heartbeat_wall_s) == (7.0, 101.0)
        assert (t.position_s, t.position_wall_s) == (9.5, 101.2)
    finally:
        out.close()
        link.close()


def test_octomap_read_from_its_serialized_bytes() -> None:
    import io  # noqa: PLC0415

    from octomap_msgs.msg import Octomap  # noqa: PLC0415

    from uav_autonomy.ros.conversions import octomap_from_buffer  # noqa: PLC0415

    msg = Octomap()
    msg.header.frame_id = "map"
    msg.header.stamp.secs, msg.header.stamp.nsecs = 12, 500_000_000
    msg.binary = True
    msg.id = "OcTree"
    msg.resolution = 0.5
    payload = bytes([0x00, 0xC0, 0x03, 0x00, 0xFF, 0x7F, 0x80])
    msg.data = [b - 256 if b > 127 else b for b in payload]  # int8[]
    buf = io.BytesIO()
    msg.serialize(buf)
    blob = octomap_from_buffer(buf.getvalue())
    assert (blob.frame_id, blob.binary, blob.tree_id, blob.resolution_m) == ("map", True, "OcTree", 0.5)
    assert blob.stamp_s == pytest.approx(12.5)
    assert blob.data == payload
    with pytest.raises(InvalidInputError, match="truncated"):
        octomap_from_buffer(buf.getvalue()[:-1])
    with pytest.raises(InvalidInputError, match="after its data"):
        octomap_from_buffer(buf.getvalue() + b"\x00")
