"""``uav_common.ros.arrays``: the one Image/PointCloud2 <-> numpy module (real genpy messages, no master)."""

from __future__ import annotations

import io
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from sensor_msgs.msg import Image, PointCloud2, PointField
from std_msgs.msg import Header

from uav_common.pointcloud import DepthImagePacker
from uav_common.ros.arrays import (
    MessageLayoutError,
    cloud_msg,
    cloud_to_xyzrgb,
    depth_cloud_msg,
    image_msg,
    image_to_array,
    image_to_depth_m,
    image_to_ids,
    image_to_rgb,
)


def roundtrip(msg: Any) -> Any:
    """Serialise and parse again, as a subscriber receives it."""
    buf = io.BytesIO()
    msg.serialize(buf)
    out = type(msg)()
    out.deserialize(buf.getvalue())
    return out


@pytest.mark.parametrize(
    ("array", "encoding"),
    [
        (np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3), "rgb8"),
        (np.arange(2 * 3 * 4, dtype=np.uint8).reshape(2, 3, 4), "bgra8"),
        (np.array([[1.5, np.nan], [3.25, 1e4]], dtype=np.float32), "32FC1"),
        (np.array([[0, 65535], [7, 1234]], dtype=np.uint16), "16UC1"),
        (np.array([[0, 255], [7, 12]], dtype=np.uint8), "mono8"),
    ],
)
def test_every_encoding_round_trips_through_a_serialised_message(array: np.ndarray, encoding: str) -> None:
    msg = roundtrip(image_msg(array, encoding, Header(frame_id="cam")))
    assert (msg.height, msg.width, msg.encoding, msg.is_bigendian) == (array.shape[0], array.shape[1], encoding, 0)
    assert msg.step == array.shape[1] * array.itemsize * (array.shape[2] if array.ndim == 3 else 1)
    np.testing.assert_array_equal(image_to_array(msg), array)


def test_row_padding_byte_order_and_colour_orders() -> None:
    rgb = np.arange(2 * 3 * 3, dtype=np.uint8).reshape(2, 3, 3)
    padded = np.zeros((2, 12), np.uint8)
    padded[:, :9] = rgb.reshape(2, 9)
    assert np.array_equal(image_to_rgb(Image(height=2, width=3, encoding="rgb8", step=12, data=padded.tobytes())), rgb)
    bgr = Image(height=2, width=3, encoding="bgr8", step=9, data=rgb[:, :, ::-1].tobytes())
    assert np.array_equal(image_to_rgb(bgr), rgb)
    rgba = np.concatenate([rgb, np.full((2, 3, 1), 9, np.uint8)], axis=2)
    assert np.array_equal(image_to_rgb(Image(height=2, width=3, encoding="rgba8", step=12, data=rgba.tobytes())), rgb)
    depth = np.array([[1.5, np.nan], [np.inf, 4.0]], np.float32)
    big_endian = Image(height=2, width=2, encoding="32FC1", is_bigendian=1, step=8, data=depth.astype(">f4").tobytes())
    out = image_to_depth_m(big_endian)
    assert (out[0, 0], out[1, 1]) == (1.5, 4.0)
    assert np.isnan(out[0, 1])
    assert np.isnan(out[1, 0])  # inf is no return too


def test_depth_in_millimetres_and_id_images() -> None:
    mm = Image(height=1, width=2, encoding="16UC1", step=4, data=np.array([[0, 2500]], "<u2").tobytes())
    depth = image_to_depth_m(mm)
    assert np.isnan(depth[0, 0])
    assert depth[0, 1] == pytest.approx(2.5)
    ids = Image(height=1, width=2, encoding="16UC1", step=4, data=np.array([[7, 65535]], "<u2").tobytes())
    assert image_to_ids(ids).tolist() == [[7, 65535]]


@pytest.mark.parametrize(
    ("call", "msg", "match"),
    [
        (image_to_rgb, Image(height=1, width=1, encoding="mono8", step=1, data=b"\x00"), "mono8"),
        (image_to_rgb, Image(height=2, width=3, encoding="rgb8", step=9, data=b"\x00" * 10), "too small"),
        (image_to_depth_m, Image(height=0, width=0, encoding="32FC1"), "empty"),
        (image_to_depth_m, Image(height=1, width=1, encoding="rgb8", step=3, data=b"\x00" * 3), "32FC1"),
        (image_to_ids, Image(height=1, width=1, encoding="32FC1", step=4, data=b"\x00" * 4), "16UC1"),
        (image_to_array, Image(height=1, width=1, encoding="yuv422", step=2, data=b"\x00" * 2), "not supported"),
    ],
)
def test_malformed_images_are_refused_with_the_reason(call: Any, msg: Image, match: str) -> None:
    with pytest.raises(MessageLayoutError, match=match):
        call(msg)


def test_an_array_that_does_not_fit_its_encoding_is_refused() -> None:
    with pytest.raises(MessageLayoutError, match="does not fit"):
        image_msg(np.zeros((2, 2), np.uint8), "rgb8", Header())
    with pytest.raises(MessageLayoutError, match="not supported"):
        image_msg(np.zeros((2, 2), np.uint8), "bayer_rggb8", Header())


def test_rosbags_style_messages_decode_too() -> None:
    """The offline report reads bags with rosbags: same field names, plain Python objects, numpy data."""
    arr = np.arange(6, dtype=np.uint16).reshape(2, 3)
    msg = SimpleNamespace(
        height=2, width=3, step=6, encoding="16UC1", is_bigendian=0, data=np.frombuffer(arr.tobytes(), np.uint8)
    )
    assert image_to_ids(msg).tolist() == arr.tolist()


def test_cloud_round_trip_and_layout() -> None:
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(100, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (100, 3)).astype(np.uint8)
    msg = roundtrip(cloud_msg(Header(frame_id="camera_nadir_optical"), xyz, rgb))
    assert (msg.height, msg.width, msg.point_step, msg.row_step, msg.is_dense) == (1, 100, 16, 1600, True)
    assert [(f.name, f.offset, f.datatype, f.count) for f in msg.fields] == [
        ("x", 0, PointField.FLOAT32, 1), ("y", 4, PointField.FLOAT32, 1), ("z", 8, PointField.FLOAT32, 1),
        ("rgb", 12, PointField.FLOAT32, 1),
    ]  # fmt: skip
    got_xyz, got_rgb = cloud_to_xyzrgb(msg)
    np.testing.assert_array_equal(got_xyz, xyz)
    np.testing.assert_array_equal(got_rgb, rgb)


def test_clouds_never_share_their_field_objects() -> None:
    """A module-level field list once shared between messages: editing one message's fields changed the next."""
    a = cloud_msg(Header(), np.zeros((1, 3)), np.zeros((1, 3), np.uint8))
    b = cloud_msg(Header(), np.zeros((1, 3)), np.zeros((1, 3), np.uint8))
    assert a.fields == b.fields
    assert all(fa is not fb for fa, fb in zip(a.fields, b.fields, strict=True))
    a.fields[0].name = "changed"
    assert b.fields[0].name == "x"


def test_depth_image_cloud_holds_the_returns_in_the_optical_frame() -> None:
    depth = np.full((3, 4), np.nan, np.float32)
    depth[1, 2] = 10.0
    rgb = np.full((3, 4, 3), 7, np.uint8)
    k = np.array([[2.0, 0.0, 1.5], [0.0, 2.0, 1.0], [0.0, 0.0, 1.0]])
    msg = depth_cloud_msg(DepthImagePacker(), Header(frame_id="camera_nadir_optical"), depth, rgb, k)
    xyz, colors = cloud_to_xyzrgb(msg)
    assert xyz.tolist() == [pytest.approx([2.5, 0.0, 10.0])]
    assert colors.tolist() == [[7, 7, 7]]


def test_organised_cloud_with_row_padding() -> None:
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
    xyz, rgb = cloud_to_xyzrgb(msg)
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
def test_bad_cloud_layouts_are_refused(mutate: Any, match: str) -> None:
    msg = cloud_msg(Header(), np.zeros((4, 3)), np.zeros((4, 3), np.uint8))
    mutate(msg)
    with pytest.raises(MessageLayoutError, match=match):
        cloud_to_xyzrgb(msg)
