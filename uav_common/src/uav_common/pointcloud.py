"""The project's point-cloud byte layout, packed and unpacked with numpy only (no ROS).

Every colored cloud in the project (ground-truth ``/cameras/<cam>/points`` and the
depth estimator's ``/depth_estimator/points``) uses the PCL ``PointXYZRGB`` layout:

=====  ======  ========  =====================================================
field  offset  datatype  meaning
=====  ======  ========  =====================================================
x      0       FLOAT32   metres in the header's frame
y      4       FLOAT32
z      8       FLOAT32
rgb    12      FLOAT32   uint32 ``0x00RRGGBB`` whose bits are stored as float32
=====  ======  ========  =====================================================

``point_step`` is 16 bytes, little endian, unorganised (``height = 1``), finite points
only.  The ROS adapter that wraps these bytes into ``sensor_msgs/PointCloud2`` is
:mod:`uav_sim_bridge.ros.pointcloud2`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

__all__ = [
    "FIELD_OFFSETS",
    "POINT_STEP",
    "XYZRGB_DTYPE",
    "pack_rgb",
    "pack_xyzrgb",
    "unpack_rgb",
    "unpack_xyzrgb",
]

POINT_STEP = 16
FIELD_OFFSETS: Mapping[str, int] = {"x": 0, "y": 4, "z": 8, "rgb": 12}
XYZRGB_DTYPE = np.dtype(
    {"names": ["x", "y", "z", "rgb"], "formats": ["<f4", "<f4", "<f4", "<u4"], "offsets": [0, 4, 8, 12], "itemsize": 16}
)


def pack_rgb(colors_rgb_u8: npt.ArrayLike) -> npt.NDArray[np.uint32]:
    """``(N, 3)`` uint8 RGB -> ``(N,)`` uint32 ``0x00RRGGBB``."""
    c = np.asarray(colors_rgb_u8)
    if c.ndim != 2 or c.shape[1] != 3:
        msg = f"colors must have shape (N, 3), got {c.shape}"
        raise ValueError(msg)
    c = c.astype(np.uint32)
    return np.asarray((c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2], dtype=np.uint32)


def unpack_rgb(rgb_u32: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """``(N,)`` uint32 ``0x00RRGGBB`` -> ``(N, 3)`` uint8 RGB."""
    v = np.asarray(rgb_u32, dtype=np.uint32)
    return np.asarray(np.stack([(v >> 16) & 0xFF, (v >> 8) & 0xFF, v & 0xFF], axis=1), dtype=np.uint8)


def pack_xyzrgb(points_xyz: npt.ArrayLike, colors_rgb_u8: npt.ArrayLike) -> bytes:
    """Pack ``(N, 3)`` points (metres) and ``(N, 3)`` uint8 colors into ``N * 16`` bytes.

    Raises:
        ValueError: shapes do not match, or a coordinate is not finite.
    """
    pts = np.asarray(points_xyz, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3:
        msg = f"points must have shape (N, 3), got {pts.shape}"
        raise ValueError(msg)
    rgb = pack_rgb(colors_rgb_u8)
    if len(rgb) != len(pts):
        msg = f"{len(pts)} points but {len(rgb)} colors"
        raise ValueError(msg)
    if not np.all(np.isfinite(pts)):
        msg = "points must be finite (drop NaN/inf before packing)"
        raise ValueError(msg)
    out = np.empty(len(pts), dtype=XYZRGB_DTYPE)
    out["x"], out["y"], out["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    out["rgb"] = rgb
    return out.tobytes()


def unpack_xyzrgb(
    buf: bytes | bytearray | memoryview,
    point_step: int = POINT_STEP,
    field_offsets: Mapping[str, int] = FIELD_OFFSETS,
    *,
    big_endian: bool = False,
) -> tuple[npt.NDArray[np.float32], npt.NDArray[np.uint8]]:
    """Unpack a cloud whose x, y, z, rgb fields are float32 at ``field_offsets``.

    Extra fields (any other bytes inside ``point_step``) are ignored, so clouds with
    padding or more fields unpack too.

    Returns:
        ``(xyz, rgb)``: ``(N, 3)`` float32 points and ``(N, 3)`` uint8 colors.

    Raises:
        ValueError: missing field, fields that do not fit in ``point_step``, or a
            buffer that is not a whole number of points.
    """
    missing = [f for f in ("x", "y", "z", "rgb") if f not in field_offsets]
    if missing:
        msg = f"cloud lacks field(s) {', '.join(missing)}"
        raise ValueError(msg)
    if point_step <= 0 or any(not 0 <= field_offsets[f] <= point_step - 4 for f in ("x", "y", "z", "rgb")):
        msg = f"field offsets {dict(field_offsets)} do not fit in point_step {point_step}"
        raise ValueError(msg)
    nbytes = len(memoryview(buf).cast("B"))
    if nbytes % point_step:
        msg = f"buffer of {nbytes} bytes is not a multiple of point_step {point_step}"
        raise ValueError(msg)
    order = ">" if big_endian else "<"
    dtype = np.dtype(
        {
            "names": ["x", "y", "z", "rgb"],
            "formats": [order + "f4", order + "f4", order + "f4", order + "u4"],
            "offsets": [field_offsets["x"], field_offsets["y"], field_offsets["z"], field_offsets["rgb"]],
            "itemsize": point_step,
        }
    )
    rec = np.frombuffer(buf, dtype=dtype)
    xyz = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float32)
    return xyz, unpack_rgb(rec["rgb"])
