"""Dense matching of a rectified pair with OpenCV SGBM, and the disparity filters.

Disparities here are *true* rectified disparities ``x_left - x_right`` in pixels
(float32, NaN = rejected). SGBM itself searches ``[0, num_disparities)`` on a
partner image whose principal point was shifted by ``shift_px``, so the searched
true window is ``[shift_px, shift_px + num_disparities)``.

Filters, in order:

1. SGBM's uniqueness ratio (a confidence test on the cost curve).
2. Left-right consistency: the right-to-left match must land back within
   ``lr_max_diff_px`` (a second SGBM pass on mirrored images), or SGBM's internal
   ``disp12MaxDiff`` check.
3. Disparities on the edge of the search window (clipped, not measured).
4. Speckles: connected regions smaller than ``speckle_window_px``.
5. Texture: pixels whose reference neighbourhood has a grey-level standard
   deviation below ``min_texture_std``.
6. Coverage: the pixel and its match must both lie inside the warped images.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from uav_perception.core.depth.config import DepthPriorConfig, FilterConfig, LrCheck, MatchingConfig, SgbmMode
from uav_perception.core.depth.types import BoolImage, FloatImage
from uav_perception.errors import DepthInputError

__all__ = ["DisparitySearch", "disparity_search", "left_right_consistent", "match_rectified", "texture_mask"]

_SGBM_MODES = {
    SgbmMode.SGBM: cv2.STEREO_SGBM_MODE_SGBM,
    SgbmMode.HH: cv2.STEREO_SGBM_MODE_HH,
    SgbmMode.SGBM_3WAY: cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    SgbmMode.HH4: cv2.STEREO_SGBM_MODE_HH4,
}


@dataclass(frozen=True)
class DisparitySearch:
    """The true-disparity window ``[shift_px, shift_px + num_disparities)`` searched by SGBM."""

    shift_px: int
    num_disparities: int

    @property
    def max_px(self) -> int:
        """One past the largest searchable true disparity."""
        return self.shift_px + self.num_disparities


def disparity_search(
    *,
    focal_px: float,
    baseline_m: float,
    depth_prior_m: float,
    prior: DepthPriorConfig,
    matching: MatchingConfig,
    min_depth_m: float,
) -> DisparitySearch:
    """Search window covering depths from ``near_factor`` to ``far_factor`` times the prior.

    The window is widened to a multiple of 16 (SGBM's requirement), at least
    ``min_num_disparities``; when it would exceed ``max_num_disparities`` the near
    end is cut (the closest depths become unmeasurable, never the ground).
    """
    near_m = max(min_depth_m, prior.near_factor * depth_prior_m)
    far_m = prior.far_factor * depth_prior_m
    d_low = focal_px * baseline_m / far_m
    d_high = focal_px * baseline_m / near_m
    shift = max(0, math.floor(d_low) - 2)
    span = math.ceil(d_high) + 2 - shift
    num = 16 * math.ceil(span / 16)
    num = min(max(num, matching.min_num_disparities), matching.max_num_disparities)
    return DisparitySearch(shift_px=shift, num_disparities=num)


def _make_sgbm(num_disparities: int, matching: MatchingConfig, disp12_max_diff: int) -> cv2.StereoSGBM:
    area = matching.block_size_px * matching.block_size_px
    return cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=num_disparities,
        blockSize=matching.block_size_px,
        P1=matching.p1_factor * area,
        P2=matching.p2_factor * area,
        disp12MaxDiff=disp12_max_diff,
        preFilterCap=matching.pre_filter_cap,
        uniquenessRatio=matching.uniqueness_ratio_pct,
        speckleWindowSize=0,
        speckleRange=0,
        mode=_SGBM_MODES[matching.mode],
    )


def texture_mask(gray: npt.NDArray[np.uint8], window_px: int, min_std: float) -> BoolImage:
    """Pixels whose ``window_px`` neighbourhood has a grey-level std of at least ``min_std``."""
    img = gray.astype(np.float32)
    mean = cv2.boxFilter(img, -1, (window_px, window_px), borderType=cv2.BORDER_REFLECT)
    mean_sq = cv2.boxFilter(img * img, -1, (window_px, window_px), borderType=cv2.BORDER_REFLECT)
    var = np.maximum(mean_sq - mean * mean, 0.0)
    return np.asarray(var >= min_std * min_std)


def left_right_consistent(disp_left: FloatImage, disp_right: FloatImage, max_diff_px: float) -> BoolImage:
    """Left pixels whose right match maps back within ``max_diff_px``.

    Args:
        disp_left: ``(H, W)`` left disparities (NaN = none); left ``x`` matches right ``x - d``.
        disp_right: ``(H, W)`` right disparities; right ``x`` matches left ``x + d``.
        max_diff_px: tolerance.
    """
    h, w = disp_left.shape
    cols = np.arange(w, dtype=np.float32)[None, :]
    finite = np.isfinite(disp_left)
    xr = np.rint(cols - np.where(finite, disp_left, 0.0)).astype(np.int64)
    inside = finite & (xr >= 0) & (xr < w)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    back = disp_right[rows, np.clip(xr, 0, w - 1)]
    with np.errstate(invalid="ignore"):
        return np.asarray(inside & (np.abs(back - disp_left) <= max_diff_px))


def _pad_left(image: npt.NDArray[np.uint8], pad: int) -> npt.NDArray[np.uint8]:
    return np.asarray(cv2.copyMakeBorder(image, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=(0.0,)), dtype=np.uint8)


def _to_float(raw_any: npt.NDArray[np.generic]) -> FloatImage:
    raw = np.asarray(raw_any, dtype=np.int16)
    disp = raw.astype(np.float32) / 16.0
    disp[raw < 0] = np.nan
    return disp


def match_rectified(
    left_gray: npt.NDArray[np.uint8],
    right_gray: npt.NDArray[np.uint8],
    *,
    left_valid: BoolImage,
    right_valid: BoolImage,
    search: DisparitySearch,
    matching: MatchingConfig,
    filtering: FilterConfig,
) -> FloatImage:
    """Filtered true disparity of the left (reference) rectified image.

    Args:
        left_gray, right_gray: ``(H, W)`` uint8 rectified images (right shifted by ``search.shift_px``).
        left_valid, right_valid: ``(H, W)`` pixels inside each warped image.
        search: disparity window.
        matching: SGBM parameters.
        filtering: filter parameters.

    Returns:
        ``(H, W)`` float32 true disparity in pixels, NaN where rejected.

    Raises:
        DepthInputError: images of different shapes or types.
    """
    shape = left_gray.shape
    if left_gray.dtype != np.uint8 or right_gray.dtype != np.uint8 or left_gray.ndim != 2:
        msg = f"rectified images must be 2-D uint8, got {left_gray.dtype}{shape} and {right_gray.dtype}"
        raise DepthInputError(msg)
    if right_gray.shape != shape or left_valid.shape != shape or right_valid.shape != shape:
        msg = f"rectified images and masks must share a shape, got {shape}, {right_gray.shape}"
        raise DepthInputError(msg)
    internal = filtering.lr_check is LrCheck.INTERNAL
    sgbm = _make_sgbm(search.num_disparities, matching, math.ceil(filtering.lr_max_diff_px) if internal else -1)
    # SGBM leaves the first num_disparities columns unmatched (their window would leave
    # the image); pad them away so edge pixels whose match is inside still get one.
    pad = search.num_disparities
    raw_left = sgbm.compute(_pad_left(left_gray, pad), _pad_left(right_gray, pad))[:, pad:]
    disp = _to_float(raw_left)
    if filtering.lr_check is LrCheck.FULL:
        mirrored_right = _pad_left(np.ascontiguousarray(right_gray[:, ::-1]), pad)
        mirrored_left = _pad_left(np.ascontiguousarray(left_gray[:, ::-1]), pad)
        raw_right = sgbm.compute(mirrored_right, mirrored_left)[:, pad:]
        disp_right = _to_float(np.ascontiguousarray(raw_right[:, ::-1]))
        disp[~left_right_consistent(disp, disp_right, filtering.lr_max_diff_px)] = np.nan
    # Values on the window edge are clipped by the search, not measured.
    with np.errstate(invalid="ignore"):
        disp[(disp < 0.5) | (disp > search.num_disparities - 1.5)] = np.nan
    if filtering.speckle_window_px > 0:
        fixed = np.where(np.isfinite(disp), np.rint(disp * 16.0), -16).astype(np.int16)
        cv2.filterSpeckles(fixed, -16, filtering.speckle_window_px, filtering.speckle_range_px * 16.0)
        disp[fixed < 0] = np.nan
    if filtering.min_texture_std > 0:
        disp[~texture_mask(left_gray, filtering.texture_window_px, filtering.min_texture_std)] = np.nan
    # The left pixel and its right match must both see the inside of the original images.
    h, w = shape
    cols = np.arange(w, dtype=np.float32)[None, :]
    finite = np.isfinite(disp)
    xr = np.rint(cols - np.where(finite, disp, 0.0)).astype(np.int64)
    rows = np.broadcast_to(np.arange(h)[:, None], shape)
    match_ok = (xr >= 0) & (xr < w) & right_valid[rows, np.clip(xr, 0, w - 1)]
    disp[~(left_valid & match_ok)] = np.nan
    return (disp + np.float32(search.shift_px)).astype(np.float32)
