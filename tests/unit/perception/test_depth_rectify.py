from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from synthetic_scene import nadir_rotation, rotation_about

from uav_perception.core.depth.config import RectificationConfig
from uav_perception.core.depth.rectify import coverage_mask, rectify_pair, warp_to_rectified
from uav_perception.core.depth.types import CameraPose, PinholeCamera
from uav_perception.errors import DepthGeometryError

CAM = PinholeCamera(640, 480, 320.0, 320.0, 319.5, 239.5)


def project(h: np.ndarray, pix: np.ndarray) -> np.ndarray:
    p = np.hstack([pix, np.ones((len(pix), 1))]) @ h.T
    return p[:, :2] / p[:, 2:]


def pixels_of(pose: CameraPose, pts_map: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pc = (pts_map - pose.position_map_m) @ pose.rotation_map_optical
    uv = np.stack([CAM.fx_px * pc[:, 0] / pc[:, 2] + CAM.cx_px, CAM.fy_px * pc[:, 1] / pc[:, 2] + CAM.cy_px], 1)
    return uv, pc[:, 2]


@settings(max_examples=60, deadline=None)
@given(
    heading=st.floats(-math.pi, math.pi),
    move_dir=st.floats(-math.pi, math.pi),
    climb=st.floats(-0.3, 0.3),
    baseline=st.floats(1.0, 15.0),
    tilt_axis=st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(0.1, 1)),
    tilt_deg=st.floats(0.0, 10.0),
    shift=st.integers(0, 40),
)
def test_rectified_rows_align_and_disparity_is_f_b_over_z(
    *,
    heading: float,
    move_dir: float,
    climb: float,
    baseline: float,
    tilt_axis: tuple[float, float, float],
    tilt_deg: float,
    shift: int,
) -> None:
    ref = CameraPose(nadir_rotation(heading), np.array([0.0, 0.0, 60.0]))
    direction = np.array([math.cos(move_dir), math.sin(move_dir), climb])
    direction /= np.linalg.norm(direction)
    partner = CameraPose(
        rotation_about(tilt_axis, math.radians(tilt_deg)) @ nadir_rotation(heading),
        ref.position_map_m + baseline * direction,
    )
    rect = rectify_pair(CAM, ref, partner, RectificationConfig(), right_shift_px=shift)
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(-25, 25, 200), rng.uniform(-25, 25, 200), rng.uniform(-5, 30, 200)])
    uv_ref, _ = pixels_of(ref, pts)
    uv_par, _ = pixels_of(partner, pts)
    left = project(rect.homography_ref, uv_ref)
    right = project(rect.homography_partner, uv_par)
    # Same row in both rectified images (the epipolar constraint made horizontal) ...
    assert np.max(np.abs(left[:, 1] - right[:, 1])) < 1e-6
    # ... and disparity = f B / z in the rectified frame (shifted by the right principal point offset).
    r_map_rect = ref.rotation_map_optical @ rect.rot_rect_ref.T
    z_rect = (pts - ref.position_map_m) @ r_map_rect[:, 2]
    disparity = left[:, 0] - (right[:, 0] - shift)
    assert disparity == pytest.approx(rect.camera.fx_px * baseline / z_rect, rel=1e-7, abs=1e-7)
    assert np.all(disparity > 0)
    # The rectified x axis points from the reference towards the partner.
    assert r_map_rect[:, 0] == pytest.approx(direction, abs=1e-9)


def test_the_grid_covers_the_reference_image_and_respects_the_area_cap() -> None:
    ref = CameraPose(nadir_rotation(0.3), np.array([0.0, 0.0, 50.0]))
    # Flying "forward" moves along optical -y: the rectified image is the reference turned by 90 deg.
    partner = CameraPose(nadir_rotation(0.3), np.array([-8 * math.cos(0.3), -8 * math.sin(0.3), 50.0]))
    rect = rectify_pair(CAM, ref, partner, RectificationConfig())
    assert (rect.camera.width_px, rect.camera.height_px) in {(480, 640), (481, 641)}
    corners = np.array([[-0.5, -0.5], [639.5, -0.5], [639.5, 479.5], [-0.5, 479.5]])
    mapped = project(rect.homography_ref, corners)
    assert mapped.min() >= -0.5 - 1e-6
    assert mapped[:, 0].max() <= rect.camera.width_px - 0.5 + 1e-6
    # A diagonal flight turns it by 45 deg: the box is larger, and the cap shrinks the focal length.
    diag = CameraPose(nadir_rotation(0.3), ref.position_map_m + rotation_about([0, 0, 1], 0.3 + 0.785) @ [-8, 0, 0])
    capped = rectify_pair(CAM, ref, diag, RectificationConfig(max_area_ratio=1.2))
    assert capped.camera.width_px * capped.camera.height_px <= 1.2 * 640 * 480 * 1.01
    assert capped.camera.fx_px < 320.0
    half = rectify_pair(CAM, ref, partner, RectificationConfig(scale=0.5))
    assert half.camera.fx_px == pytest.approx(160.0)


def test_warp_and_coverage_mask() -> None:
    ref = CameraPose(nadir_rotation(0.0), np.array([0.0, 0.0, 50.0]))
    partner = CameraPose(nadir_rotation(0.0), np.array([0.0, -6.0, 50.0]))  # moving right in the image
    rect = rectify_pair(CAM, ref, partner, RectificationConfig())
    assert rect.rot_rect_ref == pytest.approx(np.eye(3), abs=1e-12)  # already rectified: identity
    img = np.arange(480 * 640, dtype=np.uint32).reshape(480, 640).astype(np.uint8)
    out = warp_to_rectified(img, rect.homography_ref, rect.camera)
    assert np.array_equal(out[:480, :640], img)
    mask = coverage_mask(CAM, rect.homography_ref, rect.camera, erode_px=3)
    assert mask[240, 320]
    assert mask.mean() > 0.95


def test_degenerate_geometry_raises() -> None:
    ref = CameraPose(nadir_rotation(0.0), np.array([0.0, 0.0, 50.0]))
    with pytest.raises(DepthGeometryError, match="baseline"):
        rectify_pair(CAM, ref, CameraPose(nadir_rotation(0.0), ref.position_map_m.copy()), RectificationConfig())
    with pytest.raises(DepthGeometryError, match="forward motion"):
        rectify_pair(CAM, ref, CameraPose(nadir_rotation(0.0), np.array([0.0, 0.0, 40.0])), RectificationConfig())
    with pytest.raises(DepthGeometryError, match="behind"):
        rectify_pair(CAM, ref, CameraPose(nadir_rotation(0.0), np.array([3.0, 0.0, 46.0])), RectificationConfig())
