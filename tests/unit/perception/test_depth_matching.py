from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from uav_perception.core.depth.config import DepthPriorConfig, FilterConfig, LrCheck, MatchingConfig
from uav_perception.core.depth.matching import (
    DisparitySearch,
    disparity_search,
    left_right_consistent,
    match_rectified,
    texture_mask,
)
from uav_perception.errors import DepthInputError


def textured(h: int, w: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur((rng.random((h, w)) * 255).astype(np.float32), (0, 0), 1.2)
    return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def shifted_pair(d_px: float, shift_px: int, h: int = 120, w: int = 200) -> tuple[np.ndarray, np.ndarray]:
    """A fronto-parallel plane at true disparity ``d_px``, right image principal point shifted by ``shift_px``."""
    base = textured(h, w + 200)
    m_left = np.float32([[1, 0, 100], [0, 1, 0]])
    m_right = np.float32([[1, 0, 100 + d_px - shift_px], [0, 1, 0]])
    left = cv2.warpAffine(base, m_left, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)
    right = cv2.warpAffine(base, m_right, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP)
    return left, right


@pytest.mark.parametrize("lr", [LrCheck.FULL, LrCheck.INTERNAL, LrCheck.OFF])
def test_constant_disparity_is_recovered_subpixel(lr: LrCheck) -> None:
    d_true, shift = 37.25, 20
    left, right = shifted_pair(d_true, shift)
    ones = np.ones(left.shape, bool)
    disp = match_rectified(
        left,
        right,
        left_valid=ones,
        right_valid=ones,
        search=DisparitySearch(shift, 48),
        matching=MatchingConfig(),
        filtering=FilterConfig(lr_check=lr),
    )
    valid = np.isfinite(disp)
    # Columns whose match falls off the right image (x < d - shift) cannot be matched.
    assert not valid[:, :15].any()
    assert valid[:, 40:-10].mean() > 0.95
    assert np.median(disp[valid]) == pytest.approx(d_true, abs=0.15)
    assert np.mean(np.abs(disp[valid] - d_true) < 0.5) > 0.97


def test_lr_check_and_masks_reject_bad_pixels() -> None:
    left, right = shifted_pair(30.0, 16)
    ones = np.ones(left.shape, bool)
    right_valid = ones.copy()
    right_valid[:, 100:] = False  # pretend the right image ends at column 100
    disp = match_rectified(
        left, right, left_valid=ones, right_valid=right_valid, search=DisparitySearch(16, 32),
        matching=MatchingConfig(), filtering=FilterConfig(),
    )  # fmt: skip
    # Left x matches right x - 14 (in the shifted image): columns >= 114 have no valid match.
    assert not np.isfinite(disp[:, 115:]).any()
    assert np.isfinite(disp[:, 30:110]).mean() > 0.9
    # A textureless left image gives nothing.
    flat = np.full_like(left, 128)
    none = match_rectified(
        flat, flat, left_valid=ones, right_valid=ones, search=DisparitySearch(0, 32),
        matching=MatchingConfig(), filtering=FilterConfig(),
    )  # fmt: skip
    assert not np.isfinite(none).any()


def test_mismatched_inputs_raise() -> None:
    a = np.zeros((10, 20), np.uint8)
    ok = np.ones((10, 20), bool)
    kw = {"search": DisparitySearch(0, 16), "matching": MatchingConfig(), "filtering": FilterConfig()}
    with pytest.raises(DepthInputError, match="share a shape"):
        match_rectified(a, np.zeros((10, 21), np.uint8), left_valid=ok, right_valid=ok, **kw)
    with pytest.raises(DepthInputError, match="uint8"):
        match_rectified(a.astype(np.float32), a, left_valid=ok, right_valid=ok, **kw)


def test_left_right_consistency() -> None:
    left = np.array([[np.nan, 1.0, 2.0, 2.0, 1.0]], np.float32)
    right = np.array([[2.0, 2.0, 1.0, 5.0, np.nan]], np.float32)
    # x=1 (d=1) -> right x=0 has 2: inconsistent; x=2 (d=2) -> right x=0 has 2: ok;
    # x=3 (d=2) -> right x=1 has 2: ok; x=4 (d=1) -> right x=3 has 5: inconsistent.
    ok = left_right_consistent(left, right, 0.5)
    assert ok.tolist() == [[False, False, True, True, False]]


def test_texture_mask() -> None:
    img = np.full((20, 40), 100, np.uint8)
    img[:, 20:] = textured(20, 20)
    mask = texture_mask(img, 5, 2.0)
    assert not mask[:, :15].any()
    assert mask[:, 25:].all()


def test_disparity_search_window() -> None:
    prior = DepthPriorConfig(near_factor=0.25, far_factor=2.5)
    s = disparity_search(
        focal_px=320.0, baseline_m=7.5, depth_prior_m=50.0, prior=prior, matching=MatchingConfig(), min_depth_m=0.5
    )
    # f B / z: 19.2 px at 125 m, 192 px at 12.5 m.
    assert s.shift_px <= 19.2
    assert s.max_px >= 192
    assert s.num_disparities % 16 == 0
    capped = disparity_search(
        focal_px=320.0, baseline_m=7.5, depth_prior_m=50.0, prior=prior,
        matching=MatchingConfig(max_num_disparities=64), min_depth_m=0.5,
    )  # fmt: skip
    assert capped.num_disparities == 64
    assert capped.shift_px == s.shift_px  # the far end (the ground) is kept, the near end is cut
    assert math.isclose(capped.max_px, s.shift_px + 64)
