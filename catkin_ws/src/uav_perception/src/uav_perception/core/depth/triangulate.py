"""From rectified disparity to depth in the reference camera, and to a colored cloud.

The depth image is resampled into the *original* reference image so it can be
compared pixel by pixel with the ground-truth depth of the same camera and time.
Reference pixel ``(u, v)`` sees the rectified pixel ``H_ref (u, v)`` along the
same ray (both frames share the optical centre), so its z-depth is

    z_ref(u, v) = z_rect(H_ref (u, v)) / (R_rect_ref K^-1 [u, v, 1])_z

where ``z_rect = f B / d``. The lookup is nearest-neighbour: interpolating
across an occlusion edge would invent depths between foreground and background.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from uav_perception.core.depth.rectify import Rectification
from uav_perception.core.depth.types import FloatImage, PinholeCamera, RgbImage
from uav_perception.errors import DepthInputError

__all__ = ["ColoredPoints", "points_from_depth", "reference_depth", "reference_lookup"]


@dataclass(frozen=True, eq=False)
class ReferenceLookup:
    """Per-reference-pixel rectified coordinates and ray z factor.

    Attributes:
        map_x, map_y: ``(H, W)`` float32 rectified coordinates of each reference pixel.
        ray_z: ``(H, W)`` float32 ``(R_rect_ref K^-1 [u, v, 1])_z``.
    """

    map_x: FloatImage
    map_y: FloatImage
    ray_z: FloatImage


def reference_lookup(camera: PinholeCamera, rect: Rectification) -> ReferenceLookup:
    """Where each reference pixel lands in the rectified grid."""
    rays = camera.pixel_rays().reshape(-1, 3).T
    p = rect.rot_rect_ref @ rays
    xr = rect.camera.fx_px * p[0] / p[2] + rect.camera.cx_px
    yr = rect.camera.fy_px * p[1] / p[2] + rect.camera.cy_px
    shape = camera.shape
    return ReferenceLookup(
        map_x=xr.reshape(shape).astype(np.float32),
        map_y=yr.reshape(shape).astype(np.float32),
        ray_z=p[2].reshape(shape).astype(np.float32),
    )


def reference_depth(
    disparity_px: FloatImage,
    camera: PinholeCamera,
    rect: Rectification,
    *,
    min_depth_m: float,
    max_depth_m: float,
    lookup: ReferenceLookup | None = None,
) -> FloatImage:
    """Z-depth in the reference camera (``camera.shape``, float32, NaN = none) from rectified disparity.

    Raises:
        DepthInputError: the disparity image does not have the rectified shape.
    """
    if disparity_px.shape != rect.camera.shape:
        msg = f"disparity shape {disparity_px.shape} != rectified shape {rect.camera.shape}"
        raise DepthInputError(msg)
    lut = lookup if lookup is not None else reference_lookup(camera, rect)
    depth_rect = rect.depth_rect_m(disparity_px)
    sampled = cv2.remap(
        depth_rect,
        lut.map_x,
        lut.map_y,
        interpolation=cv2.INTER_NEAREST,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=(float("nan"),),
    )
    depth = np.asarray(sampled, dtype=np.float32) / lut.ray_z
    with np.errstate(invalid="ignore"):
        depth[~((depth >= min_depth_m) & (depth <= max_depth_m))] = np.nan
    return np.asarray(depth, dtype=np.float32)


@dataclass(frozen=True, eq=False)
class ColoredPoints:
    """An unorganised colored cloud in the camera optical frame.

    Attributes:
        xyz_m: ``(N, 3)`` float32 finite points, metres, optical frame.
        rgb: ``(N, 3)`` uint8 colors; :func:`uav_common.pointcloud.pack_xyzrgb` packs
            both into the project's cloud layout.
    """

    xyz_m: npt.NDArray[np.float32]
    rgb: npt.NDArray[np.uint8]


def points_from_depth(depth_m: FloatImage, rgb: RgbImage, camera: PinholeCamera, stride_px: int = 1) -> ColoredPoints:
    """Back-project every ``stride_px``-th valid pixel of a z-depth image.

    Raises:
        DepthInputError: depth or color do not match the camera.
    """
    if depth_m.shape != camera.shape or rgb.shape[:2] != camera.shape:
        msg = f"depth {depth_m.shape} and color {rgb.shape} must both be {camera.shape}"
        raise DepthInputError(msg)
    depth = depth_m[::stride_px, ::stride_px]
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[v, u].astype(np.float64)
    u_px = u * stride_px
    v_px = v * stride_px
    xyz = np.stack(
        [(u_px - camera.cx_px) / camera.fx_px * z, (v_px - camera.cy_px) / camera.fy_px * z, z], axis=1
    ).astype(np.float32)
    return ColoredPoints(xyz_m=xyz, rgb=np.ascontiguousarray(rgb[v_px, u_px], dtype=np.uint8))
