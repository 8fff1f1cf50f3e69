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
    "DepthImagePacker",
    "pack_depth_image",
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


def pack_depth_image(
    depth_m: npt.ArrayLike, colors_rgb_u8: npt.ArrayLike, k: npt.ArrayLike, stride: int = 1
) -> tuple[bytes, int]:
    """:meth:`DepthImagePacker.pack` with a throw-away packer (see there)."""
    return DepthImagePacker().pack(depth_m, colors_rgb_u8, k, stride)


class DepthImagePacker:
    """Back-projects z-depth images and packs their returns with their colors, in one pass.

    Gives the same bytes as :func:`pack_xyzrgb` of the back-projected pixels (row-major,
    every ``stride``-th row and column) whose depth is finite and positive, about ten times
    faster: no per-field copies, no boolean indexing of 3-D arrays, and the working buffers
    are kept between calls (fresh multi-megabyte arrays cost page faults).  A 640x480 frame
    takes ~4 ms.  Not thread-safe: one packer per publishing thread.
    """

    def __init__(self) -> None:
        self._buf = np.empty((0, 4), dtype=np.float32)
        self._picked = np.empty((0, 4), dtype=np.float32)

    def pack(
        self, depth_m: npt.ArrayLike, colors_rgb_u8: npt.ArrayLike, k: npt.ArrayLike, stride: int = 1
    ) -> tuple[bytes, int]:
        """Pack one frame.

        Args:
            depth_m: ``(H, W)`` z-depth along the optical axis, metres; NaN, inf or <= 0: no return.
            colors_rgb_u8: ``(H, W, 3)`` uint8 RGB of the same pixels.
            k: 3x3 intrinsic matrix (pixel centres at integer coordinates).
            stride: keep every ``stride``-th pixel in each direction.

        Returns:
            ``(data, n_points)``: ``n_points * 16`` bytes in the module's layout, optical frame.

        Raises:
            ValueError: shapes do not match, or ``stride < 1``.
        """
        if stride < 1:
            msg = f"stride must be >= 1, got {stride}"
            raise ValueError(msg)
        depth_full = np.asarray(depth_m, dtype=np.float32)
        color_full = np.asarray(colors_rgb_u8, dtype=np.uint8)
        if depth_full.ndim != 2 or color_full.shape != (*depth_full.shape, 3):
            msg = f"need an (H, W) depth and an (H, W, 3) color image, got {depth_full.shape} and {color_full.shape}"
            raise ValueError(msg)
        depth = depth_full[::stride, ::stride]
        color = color_full[::stride, ::stride]
        kk = np.asarray(k, dtype=np.float64)
        fx, fy, cx, cy = kk[0, 0], kk[1, 1], kk[0, 2], kk[1, 2]
        h, w = depth.shape
        if len(self._buf) != h * w:
            self._buf = np.empty((h * w, 4), dtype=np.float32)
            self._picked = np.empty((h * w, 4), dtype=np.float32)
        buf = self._buf.reshape(h, w, 4)
        x_n = ((np.arange(0, depth_full.shape[1], stride) - cx) / fx).astype(np.float32)
        y_n = ((np.arange(0, depth_full.shape[0], stride) - cy) / fy).astype(np.float32)
        with np.errstate(invalid="ignore"):  # inf * 0 on the centre row/column of a no-return pixel
            np.multiply(depth, x_n[None, :], out=buf[..., 0])
            np.multiply(depth, y_n[:, None], out=buf[..., 1])
        buf[..., 2] = depth
        rgb = buf.view(np.uint8).reshape(h, w, POINT_STEP)  # little endian 0x00RRGGBB: bytes B G R 0
        rgb[..., 12] = color[..., 2]
        rgb[..., 13] = color[..., 1]
        rgb[..., 14] = color[..., 0]
        rgb[..., 15] = 0
        ok = ((depth > 0) & (depth < np.inf)).reshape(-1)  # False for NaN
        n = int(np.count_nonzero(ok))
        picked = self._picked[:n]
        np.compress(ok, self._buf, axis=0, out=picked)
        return picked.tobytes(), n


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
