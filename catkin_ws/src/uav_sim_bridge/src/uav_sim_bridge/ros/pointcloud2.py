"""``sensor_msgs/PointCloud2`` <-> numpy for the project's ``x y z rgb`` layout.

The byte layout itself is :mod:`uav_common.pointcloud`; this module only wraps it
in (or reads it from) a ROS message.  Used by the sim bridge for ground-truth
clouds and by the depth estimator for its own, so both are interchangeable.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
from sensor_msgs.msg import PointCloud2, PointField

from uav_common.pointcloud import FIELD_OFFSETS, POINT_STEP, DepthImagePacker, pack_xyzrgb, unpack_xyzrgb
from uav_sim_bridge.errors import PointCloudLayoutError

__all__ = ["depth_image_to_pointcloud2", "pointcloud2_to_xyzrgb", "xyzrgb_fields", "xyzrgb_to_pointcloud2"]


def xyzrgb_fields() -> list[PointField]:
    """Fresh ``PointField`` s of the x y z rgb layout (messages must not share mutable field objects)."""
    return [PointField(name=n, offset=o, datatype=PointField.FLOAT32, count=1) for n, o in FIELD_OFFSETS.items()]


def xyzrgb_to_pointcloud2(header: Any, points_xyz: npt.ArrayLike, colors_rgb_u8: npt.ArrayLike) -> PointCloud2:
    """An unorganised cloud (``height = 1``) of finite points in ``header.frame_id``.

    Raises:
        ValueError: shapes differ or a point is not finite.
    """
    data = pack_xyzrgb(points_xyz, colors_rgb_u8)
    return _cloud(header, data, len(data) // POINT_STEP)


def depth_image_to_pointcloud2(
    packer: DepthImagePacker,
    header: Any,
    depth_m: npt.ArrayLike,
    colors_rgb_u8: npt.ArrayLike,
    k: npt.ArrayLike,
    *,
    stride: int = 1,
) -> PointCloud2:
    """The unorganised cloud of a z-depth image's returns (see :class:`uav_common.pointcloud.DepthImagePacker`)."""
    data, n = packer.pack(depth_m, colors_rgb_u8, k, stride)
    return _cloud(header, data, n)


def _cloud(header: Any, data: bytes, n: int) -> PointCloud2:
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


def pointcloud2_to_xyzrgb(msg: PointCloud2) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """``(xyz (N, 3) float32, rgb (N, 3) uint8)`` of a cloud with float32 ``x y z rgb`` fields.

    Other fields are ignored; organised clouds are flattened (row padding honoured).

    Raises:
        PointCloudLayoutError: missing or non-float32 x/y/z/rgb fields, or inconsistent sizes.
    """
    offsets: dict[str, int] = {}
    for f in msg.fields:
        if f.name in ("x", "y", "z", "rgb"):
            if f.datatype not in (PointField.FLOAT32, PointField.UINT32) or f.count != 1:
                msg_ = f"PointCloud2 field {f.name!r} must be one FLOAT32, got datatype {f.datatype} count {f.count}"
                raise PointCloudLayoutError(msg_)
            offsets[f.name] = int(f.offset)
    missing = sorted({"x", "y", "z", "rgb"} - set(offsets))
    if missing:
        msg_ = f"PointCloud2 lacks field(s) {', '.join(missing)} (fields: {[f.name for f in msg.fields]})"
        raise PointCloudLayoutError(msg_)
    width, height, step, row = int(msg.width), int(msg.height), int(msg.point_step), int(msg.row_step)
    data = bytes(msg.data)
    if step <= 0 or row < width * step or len(data) < row * height:
        msg_ = f"PointCloud2 sizes inconsistent: {width}x{height}, point_step {step}, row_step {row}, {len(data)} bytes"
        raise PointCloudLayoutError(msg_)
    if row != width * step:
        data = b"".join(data[r * row : r * row + width * step] for r in range(height))
    else:
        data = data[: row * height]
    try:
        return unpack_xyzrgb(data, step, offsets, big_endian=bool(msg.is_bigendian))
    except ValueError as err:
        raise PointCloudLayoutError(str(err)) from err
