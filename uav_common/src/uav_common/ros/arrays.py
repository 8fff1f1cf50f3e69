"""``sensor_msgs/Image`` and ``sensor_msgs/PointCloud2`` <-> numpy: the project's one conversion module.

The decoders read messages by field name (``height``, ``width``, ``step``, ``encoding``,
``is_bigendian``, ``data``; ``fields``, ``point_step``, ``row_step``), so they take rospy
messages and rosbags messages alike: the offline report decodes bags with them where ROS
is not installed. The encoders build rospy messages; they import ``sensor_msgs`` when
called, so importing this module needs no ROS.

Images: ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``, ``mono8``, ``mono16``, ``16UC1`` and
``32FC1``, either byte order, row padding honoured. Encoded images are little endian and
unpadded. Clouds: the project's ``x y z rgb`` float32 layout (:mod:`uav_common.pointcloud`);
every encoded cloud gets its own ``PointField`` objects (messages never share them).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_common.errors import UavCommonError
from uav_common.pointcloud import FIELD_OFFSETS, POINT_STEP, DepthImagePacker, pack_xyzrgb, unpack_xyzrgb

__all__ = [
    "ENCODINGS",
    "MessageLayoutError",
    "cloud_msg",
    "cloud_to_xyzrgb",
    "depth_cloud_msg",
    "image_msg",
    "image_to_array",
    "image_to_depth_m",
    "image_to_ids",
    "image_to_rgb",
    "xyzrgb_fields",
]

#: encoding -> (numpy dtype, channels) of every image encoding the project reads and writes.
ENCODINGS: Mapping[str, tuple[npt.DTypeLike, int]] = {
    "rgb8": (np.uint8, 3),
    "bgr8": (np.uint8, 3),
    "rgba8": (np.uint8, 4),
    "bgra8": (np.uint8, 4),
    "mono8": (np.uint8, 1),
    "mono16": (np.uint16, 1),
    "16UC1": (np.uint16, 1),
    "32FC1": (np.float32, 1),
}

# PointField datatypes (sensor_msgs/PointField constants), so decoding needs no ROS import.
_FLOAT32 = 7
_UINT32 = 6


class MessageLayoutError(UavCommonError, ValueError):
    """An image or cloud message that does not have the layout it claims (or one the project uses)."""


def _layout(msg: Any) -> tuple[npt.DTypeLike, int]:
    encoding = str(msg.encoding)
    if encoding not in ENCODINGS:
        text = f"image encoding {encoding!r} is not supported; use one of {', '.join(ENCODINGS)}"
        raise MessageLayoutError(text)
    return ENCODINGS[encoding]


def image_to_array(msg: Any) -> npt.NDArray[Any]:
    """The pixels as stored: ``(H, W)`` for one channel, ``(H, W, C)`` otherwise; native byte order, a copy.

    Raises:
        MessageLayoutError: an unknown encoding, an empty image, or a ``step``/``data`` too small for its size.
    """
    dtype, channels = _layout(msg)
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    item = np.dtype(dtype).itemsize * channels
    data = bytes(msg.data) if not isinstance(msg.data, bytes | bytearray | memoryview) else msg.data
    if h == 0 or w == 0:
        text = f"empty {msg.encoding} image ({w}x{h})"
        raise MessageLayoutError(text)
    if step < w * item or len(data) < step * h:
        text = (
            f"{msg.encoding} image {w}x{h}: step {step} and {len(data)} bytes are too small for {item} bytes per pixel"
        )
        raise MessageLayoutError(text)
    big = bool(getattr(msg, "is_bigendian", 0))
    stored = np.dtype(dtype).newbyteorder(">" if big else "<")
    rows = np.frombuffer(data, dtype=np.uint8, count=step * h).reshape(h, step)[:, : w * item]
    px = np.ascontiguousarray(rows).view(stored)
    shape = (h, w, channels) if channels > 1 else (h, w)
    return np.array(px.reshape(shape), dtype=np.dtype(dtype).newbyteorder("="))


def image_to_rgb(msg: Any) -> npt.NDArray[np.uint8]:
    """A colour image (``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``) as ``(H, W, 3)`` uint8 RGB.

    Raises:
        MessageLayoutError: not a colour encoding, or a malformed image.
    """
    encoding = str(msg.encoding).lower()
    if encoding not in ("rgb8", "bgr8", "rgba8", "bgra8"):
        text = f"color image encoding {msg.encoding!r} is not supported (rgb8, bgr8, rgba8, bgra8)"
        raise MessageLayoutError(text)
    px = image_to_array(msg)[:, :, :3]
    if encoding.startswith("bgr"):
        px = px[:, :, ::-1]
    return np.ascontiguousarray(px, dtype=np.uint8)


def image_to_depth_m(msg: Any) -> npt.NDArray[np.float32]:
    """``32FC1`` (metres) or ``16UC1`` (millimetres, 0 = none) as ``(H, W)`` float32 metres, NaN = no return.

    Raises:
        MessageLayoutError: another encoding, or a malformed image.
    """
    if msg.encoding == "32FC1":
        depth = image_to_array(msg).astype(np.float32, copy=False)
        depth[~np.isfinite(depth)] = np.nan
        return depth
    if msg.encoding == "16UC1":
        mm = image_to_array(msg)
        depth = mm.astype(np.float32) / 1000.0
        depth[mm == 0] = np.nan
        return depth
    text = f"depth image encoding {msg.encoding!r} is not supported (32FC1 metres or 16UC1 millimetres)"
    raise MessageLayoutError(text)


def image_to_ids(msg: Any) -> npt.NDArray[np.uint16]:
    """A ``16UC1``/``mono16`` id image (instances, classes) as ``(H, W)`` uint16.

    Raises:
        MessageLayoutError: another encoding, or a malformed image.
    """
    if msg.encoding not in ("16UC1", "mono16"):
        text = f"id image encoding {msg.encoding!r} is not supported (16UC1)"
        raise MessageLayoutError(text)
    return np.ascontiguousarray(image_to_array(msg), dtype=np.uint16)


def image_msg(array: npt.ArrayLike, encoding: str, header: Any) -> Any:
    """An ``(H, W[, C])`` array as a little-endian, unpadded ``sensor_msgs/Image`` of ``encoding``.

    Raises:
        MessageLayoutError: an unknown encoding, or an array whose shape does not fit it.
    """
    from sensor_msgs.msg import Image  # noqa: PLC0415 - decoding above needs no ROS

    if encoding not in ENCODINGS:
        text = f"image encoding {encoding!r} is not supported; use one of {', '.join(ENCODINGS)}"
        raise MessageLayoutError(text)
    dtype, channels = ENCODINGS[encoding]
    arr = np.ascontiguousarray(array, dtype=np.dtype(dtype).newbyteorder("<"))
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] != channels) or (arr.ndim == 2 and channels != 1):
        text = f"array of shape {arr.shape} does not fit encoding {encoding} ({channels} channel(s))"
        raise MessageLayoutError(text)
    h, w = arr.shape[:2]
    return Image(
        header=header,
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=w * channels * arr.dtype.itemsize,
        data=arr.tobytes(),
    )


def xyzrgb_fields() -> list[Any]:
    """Fresh ``PointField`` objects of the ``x y z rgb`` layout."""
    from sensor_msgs.msg import PointField  # noqa: PLC0415

    return [PointField(name=n, offset=o, datatype=_FLOAT32, count=1) for n, o in FIELD_OFFSETS.items()]


def _cloud(header: Any, data: bytes, n: int) -> Any:
    from sensor_msgs.msg import PointCloud2  # noqa: PLC0415

    return PointCloud2(
        header=header,
        height=1,
        width=n,
        fields=xyzrgb_fields(),
        is_bigendian=False,
        point_step=POINT_STEP,
        row_step=POINT_STEP * n,
        data=data,
        is_dense=True,
    )


def cloud_msg(header: Any, points_xyz: npt.ArrayLike, colors_rgb_u8: npt.ArrayLike) -> Any:
    """An unorganised ``PointCloud2`` (``height = 1``) of finite coloured points in ``header.frame_id``.

    Raises:
        ValueError: the shapes differ or a point is not finite.
    """
    data = pack_xyzrgb(points_xyz, colors_rgb_u8)
    return _cloud(header, data, len(data) // POINT_STEP)


def depth_cloud_msg(
    packer: DepthImagePacker,
    header: Any,
    depth_m: npt.ArrayLike,
    colors_rgb_u8: npt.ArrayLike,
    k: npt.ArrayLike,
    *,
    stride: int = 1,
) -> Any:
    """The unorganised cloud of a z-depth image's returns (see :class:`uav_common.pointcloud.DepthImagePacker`)."""
    data, n = packer.pack(depth_m, colors_rgb_u8, k, stride)
    return _cloud(header, data, n)


def cloud_to_xyzrgb(msg: Any) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """``(xyz (N, 3) float32, rgb (N, 3) uint8)`` of a cloud with float32 ``x y z`` and ``rgb`` fields.

    Other fields are ignored; organised clouds are flattened (row padding honoured).

    Raises:
        MessageLayoutError: missing or non-float32 x/y/z/rgb fields, or inconsistent sizes.
    """
    offsets: dict[str, int] = {}
    for f in msg.fields:
        if f.name in ("x", "y", "z", "rgb"):
            if f.datatype not in (_FLOAT32, _UINT32) or f.count != 1:
                text = f"PointCloud2 field {f.name!r} must be one FLOAT32, got datatype {f.datatype} count {f.count}"
                raise MessageLayoutError(text)
            offsets[f.name] = int(f.offset)
    missing = sorted({"x", "y", "z", "rgb"} - set(offsets))
    if missing:
        text = f"PointCloud2 lacks field(s) {', '.join(missing)} (fields: {[f.name for f in msg.fields]})"
        raise MessageLayoutError(text)
    width, height, step, row = int(msg.width), int(msg.height), int(msg.point_step), int(msg.row_step)
    data = bytes(msg.data)
    if step <= 0 or row < width * step or len(data) < row * height:
        text = f"PointCloud2 sizes inconsistent: {width}x{height}, point_step {step}, row_step {row}, {len(data)} bytes"
        raise MessageLayoutError(text)
    if row != width * step:
        data = b"".join(data[r * row : r * row + width * step] for r in range(height))
    else:
        data = data[: row * height]
    try:
        return unpack_xyzrgb(data, step, offsets, big_endian=bool(msg.is_bigendian))
    except ValueError as err:
        raise MessageLayoutError(str(err)) from err
