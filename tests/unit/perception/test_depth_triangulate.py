from __future__ import annotations

import math

import numpy as np
import pytest
from synthetic_scene import nadir_rotation, rotation_about

from uav_perception.core.depth.config import RectificationConfig
from uav_perception.core.depth.rectify import rectify_pair
from uav_perception.core.depth.triangulate import points_from_depth, reference_depth, reference_lookup
from uav_perception.core.depth.types import CameraPose, PinholeCamera
from uav_perception.errors import DepthInputError

CAM = PinholeCamera(160, 120, 80.0, 80.0, 79.5, 59.5)


def test_reference_depth_from_the_exact_disparity_of_a_plane() -> None:
    # A tilted partner: rectified and reference frames differ by a real rotation.
    ref = CameraPose(nadir_rotation(0.0), np.array([0.0, 0.0, 40.0]))
    partner = CameraPose(rotation_about([1, 1, 0], math.radians(4)) @ nadir_rotation(0.0), np.array([5.0, 1.0, 40.5]))
    rect = rectify_pair(CAM, ref, partner, RectificationConfig())
    # Exact disparity of the ground plane z = 0 at every rectified pixel.
    rays = rect.camera.pixel_rays().reshape(-1, 3).T
    r_map_rect = ref.rotation_map_optical @ rect.rot_rect_ref.T
    dirs = r_map_rect @ rays
    lam = -ref.position_map_m[2] / dirs[2]
    z_rect = lam  # rays have z = 1 in the rectified frame
    disp = (rect.camera.fx_px * rect.baseline_m / z_rect).reshape(rect.camera.shape).astype(np.float32)
    depth = reference_depth(disp, CAM, rect, min_depth_m=0.5, max_depth_m=400.0)
    # Ground truth: z-depth of the plane in the reference camera.
    ref_rays = CAM.pixel_rays().reshape(-1, 3) @ ref.rotation_map_optical.T
    gt = (-40.0 / ref_rays[:, 2]).reshape(CAM.shape)
    # Nearest-neighbour lookup: the error is the depth change over half a pixel at most.
    assert np.isfinite(depth).all()
    assert np.max(np.abs(depth - gt)) < 0.05


def test_reference_depth_filters_range_and_shape() -> None:
    ref = CameraPose(nadir_rotation(0.0), np.array([0.0, 0.0, 40.0]))
    partner = CameraPose(nadir_rotation(0.0), np.array([0.0, -4.0, 40.0]))
    rect = rectify_pair(CAM, ref, partner, RectificationConfig())
    disp = np.full(rect.camera.shape, 8.0, np.float32)  # 80 * 4 / 8 = 40 m everywhere
    disp[0, 0] = np.nan
    depth = reference_depth(disp, CAM, rect, min_depth_m=0.5, max_depth_m=400.0)
    assert np.nanmax(np.abs(depth - 40.0)) < 1e-4
    assert np.isnan(depth[0, 0])
    assert np.isnan(reference_depth(disp, CAM, rect, min_depth_m=0.5, max_depth_m=39.0)).all()
    lut = reference_lookup(CAM, rect)
    assert lut.map_x[5, 7] == pytest.approx(7.0)
    assert lut.map_y[5, 7] == pytest.approx(5.0)
    with pytest.raises(DepthInputError, match="rectified shape"):
        reference_depth(disp[1:], CAM, rect, min_depth_m=0.5, max_depth_m=400.0)


def test_points_from_depth_back_project_and_pack_color() -> None:
    depth = np.full(CAM.shape, np.nan, np.float32)
    depth[59, 79] = 10.0
    depth[0, 0] = 20.0
    depth[119, 159] = -1.0  # not a depth: dropped
    rgb = np.zeros((*CAM.shape, 3), np.uint8)
    rgb[0, 0] = (255, 16, 1)
    pts = points_from_depth(depth, rgb, CAM)
    assert pts.xyz_m.shape == (2, 3)
    assert pts.xyz_m.dtype == np.float32
    assert pts.xyz_m[0] == pytest.approx([20.0 * -79.5 / 80, 20.0 * -59.5 / 80, 20.0])
    assert pts.xyz_m[1] == pytest.approx([10.0 * -0.5 / 80, 10.0 * -0.5 / 80, 10.0])
    assert pts.rgb[0].tolist() == [255, 16, 1]
    assert pts.rgb.dtype == np.uint8
    strided = points_from_depth(np.full(CAM.shape, 5.0, np.float32), rgb, CAM, stride_px=4)
    assert len(strided.xyz_m) == 30 * 40
    with pytest.raises(DepthInputError, match="must both be"):
        points_from_depth(depth[1:], rgb, CAM)
