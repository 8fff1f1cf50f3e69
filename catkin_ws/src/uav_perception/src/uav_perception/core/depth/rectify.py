"""Two-view rectification from a relative pose, for arbitrary camera motion.

The rectified frame (Fusiello, Trucco and Verri's construction) has its x axis
exactly along the baseline, from the reference camera to the partner, and its z
axis as close as possible to the mean optical axis. Both views are rotated into
it about their own centres, so the reference becomes the *left* image and the
partner the *right* one, and every scene point lies on the same row in both,
with disparity ``d = x_left - x_right = f * B / z_rect > 0``.

Unlike ``cv2.stereoRectify`` this never switches to vertical stereo: a baseline
along the image y axis (a nadir camera flying forward) simply gives a rectified
image rotated by 90 degrees. The rectified grid is the bounding box of the
reference image, so no reference pixel is lost.

The partner image can be warped with a principal point shifted right by
``right_shift_px``: disparities then start at that shift, and SGBM, which
cannot match the first ``minDisparity + numDisparities`` columns, loses fewer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from uav_perception.core.depth.config import RectificationConfig
from uav_perception.core.depth.types import BoolImage, CameraPose, FloatArray, FloatImage, PinholeCamera
from uav_perception.errors import DepthGeometryError

__all__ = ["Rectification", "coverage_mask", "rectification_rotation", "rectify_pair", "warp_to_rectified"]

_MIN_BASELINE_M = 1e-6


@dataclass(frozen=True, eq=False)
class Rectification:
    """A rectified stereo geometry for a (reference, partner) pair.

    Attributes:
        camera: intrinsics and size of the rectified reference (left) camera.
        rot_rect_ref: ``(3, 3)``, maps reference optical vectors into the rectified frame.
        rot_rect_partner: ``(3, 3)``, the same for the partner.
        baseline_m: distance from the reference to the partner centre (along rectified +x).
        right_shift_px: the partner's rectified principal point is ``cx + right_shift_px``.
        homography_ref: ``(3, 3)``, reference pixels to rectified pixels.
        homography_partner: ``(3, 3)``, partner pixels to (shifted) rectified pixels.
    """

    camera: PinholeCamera
    rot_rect_ref: FloatArray
    rot_rect_partner: FloatArray
    baseline_m: float
    right_shift_px: int
    homography_ref: FloatArray
    homography_partner: FloatArray

    def depth_rect_m(self, disparity_px: FloatImage) -> FloatImage:
        """Rectified z-depth ``f * B / d`` of a true disparity image (NaN stays NaN)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = (self.camera.fx_px * self.baseline_m) / disparity_px.astype(np.float64)
        depth[~(disparity_px > 0)] = np.nan
        return depth.astype(np.float32)


def rectification_rotation(ref: CameraPose, partner: CameraPose) -> FloatArray:
    """``R_map_rect``: columns are the rectified x, y, z axes in ``map``.

    Raises:
        DepthGeometryError: the baseline is zero or parallel to the mean optical axis.
    """
    base = partner.position_map_m - ref.position_map_m
    length = float(np.linalg.norm(base))
    if not math.isfinite(length) or length < _MIN_BASELINE_M:
        msg = f"cannot rectify: baseline {length:.3g} m is degenerate"
        raise DepthGeometryError(msg)
    x_axis = base / length
    mean_z = ref.optical_axis_map + partner.optical_axis_map
    z_axis = mean_z - (mean_z @ x_axis) * x_axis
    z_norm = float(np.linalg.norm(z_axis))
    if z_norm < 1e-6:
        msg = "cannot rectify: the baseline is parallel to the optical axis (pure forward motion)"
        raise DepthGeometryError(msg)
    z_axis = z_axis / z_norm
    y_axis = np.cross(z_axis, x_axis)
    return np.stack([x_axis, y_axis, z_axis], axis=1)


def _project(rot: FloatArray, camera: PinholeCamera, u: FloatArray, v: FloatArray) -> tuple[FloatArray, FloatArray]:
    rays = np.stack([(u - camera.cx_px) / camera.fx_px, (v - camera.cy_px) / camera.fy_px, np.ones_like(u)])
    p = rot @ rays
    if np.any(p[2] <= 1e-6):
        msg = "cannot rectify: part of the reference image would lie behind the rectified camera"
        raise DepthGeometryError(msg)
    return p[0] / p[2], p[1] / p[2]


def rectify_pair(
    camera: PinholeCamera,
    ref: CameraPose,
    partner: CameraPose,
    config: RectificationConfig,
    right_shift_px: int = 0,
) -> Rectification:
    """Rectified geometry whose grid covers the whole reference image.

    Args:
        camera: intrinsics shared by both views.
        ref: reference (left) camera pose.
        partner: partner (right) camera pose.
        config: rectified focal scale and area cap.
        right_shift_px: shift of the partner's rectified principal point (>= 0).

    Raises:
        DepthGeometryError: degenerate baseline or a rotation so large that the
            reference image does not fit in front of the rectified camera.
    """
    r_map_rect = rectification_rotation(ref, partner)
    rot_rect_ref = r_map_rect.T @ ref.rotation_map_optical
    rot_rect_partner = r_map_rect.T @ partner.rotation_map_optical
    w, h = camera.width_px, camera.height_px
    # The homography maps the image rectangle to a convex quadrilateral (all corners
    # in front), so the corners bound it.
    cu = np.array([-0.5, w - 0.5, w - 0.5, -0.5])
    cv = np.array([-0.5, -0.5, h - 0.5, h - 0.5])
    xn, yn = _project(rot_rect_ref, camera, cu, cv)
    focal = config.scale * math.sqrt(camera.fx_px * camera.fy_px)
    span_x = float(xn.max() - xn.min())
    span_y = float(yn.max() - yn.min())
    area_cap = config.max_area_ratio * (config.scale * w) * (config.scale * h)
    area = focal * focal * span_x * span_y
    if area > area_cap:
        focal *= math.sqrt(area_cap / area)
    width = max(16, math.ceil(focal * span_x))
    height = max(16, math.ceil(focal * span_y))
    cx = -focal * float(xn.min()) - 0.5
    cy = -focal * float(yn.min()) - 0.5
    rect_cam = PinholeCamera(width, height, focal, focal, cx, cy)
    k_inv = np.linalg.inv(camera.matrix)
    k_rect = rect_cam.matrix
    k_right = k_rect.copy()
    k_right[0, 2] += right_shift_px
    return Rectification(
        camera=rect_cam,
        rot_rect_ref=rot_rect_ref,
        rot_rect_partner=rot_rect_partner,
        baseline_m=float(np.linalg.norm(partner.position_map_m - ref.position_map_m)),
        right_shift_px=int(right_shift_px),
        homography_ref=k_rect @ rot_rect_ref @ k_inv,
        homography_partner=k_right @ rot_rect_partner @ k_inv,
    )


def warp_to_rectified(
    image: npt.NDArray[np.uint8],
    homography: FloatArray,
    rect_camera: PinholeCamera,
    *,
    interpolation: int = cv2.INTER_LINEAR,
) -> npt.NDArray[np.uint8]:
    """Warp ``image`` (any channels) onto the rectified grid; outside pixels are 0."""
    out = cv2.warpPerspective(
        image,
        homography,
        (rect_camera.width_px, rect_camera.height_px),
        flags=interpolation,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=(0.0, 0.0, 0.0, 0.0),
    )
    return np.asarray(out, dtype=np.uint8)


def coverage_mask(
    source: PinholeCamera, homography: FloatArray, rect_camera: PinholeCamera, erode_px: int = 0
) -> BoolImage:
    """Rectified pixels that see the inside of the source image (eroded by ``erode_px``)."""
    ones = np.full(source.shape, 255, dtype=np.uint8)
    mask = warp_to_rectified(ones, homography, rect_camera, interpolation=cv2.INTER_NEAREST)
    if erode_px > 0:
        kernel = np.ones((2 * erode_px + 1, 2 * erode_px + 1), dtype=np.uint8)
        mask = np.asarray(cv2.erode(mask, kernel), dtype=np.uint8)
    return np.asarray(mask > 0)
