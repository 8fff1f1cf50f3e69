from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.paths import REPO
from synthetic_scene import nadir_rotation, rotation_about

from uav_common.config import ConfigError, from_mapping, load_config
from uav_perception.core.depth.config import DepthConfig, EvaluatorConfig, LrCheck, PairingConfig, SgbmMode
from uav_perception.core.depth.types import CameraPose, PinholeCamera, check_rgb_image
from uav_perception.errors import DepthGeometryError, DepthInputError


def test_project_config_loads_strictly_and_matches_the_defaults() -> None:
    cfg = load_config(DepthConfig, REPO / "config" / "depth.yaml")
    assert cfg == DepthConfig()
    assert cfg.estimator.matching.mode is SgbmMode.SGBM_3WAY
    assert cfg.estimator.filtering.lr_check is LrCheck.INTERNAL
    assert math.isinf(cfg.evaluator.range_bands_m[-1])


def test_unknown_and_invalid_keys_are_rejected() -> None:
    with pytest.raises(ConfigError, match="unknown key"):
        from_mapping(DepthConfig, {"estimator": {"pairing": {"max_baseline": 3}}}, source="t")
    with pytest.raises(ConfigError, match="min_baseline_m <= max_baseline_m"):
        from_mapping(PairingConfig, {"min_baseline_m": 5.0, "max_baseline_m": 1.0}, source="t")
    with pytest.raises(ConfigError, match="range_bands_m"):
        from_mapping(EvaluatorConfig, {"range_bands_m": [0, 50, 20]}, source="t")
    with pytest.raises(ConfigError, match="block_size_px"):
        from_mapping(DepthConfig, {"estimator": {"matching": {"block_size_px": 4}}}, source="t")


def test_camera_from_matrix_and_validation() -> None:
    cam = PinholeCamera.from_matrix([[320.0, 0, 319.5], [0, 321.0, 239.5], [0, 0, 1]], 640, 480)
    assert (cam.fx_px, cam.fy_px, cam.cx_px, cam.cy_px) == (320.0, 321.0, 319.5, 239.5)
    rays = cam.pixel_rays()
    assert rays.shape == (480, 640, 3)
    assert rays[239, 319] == pytest.approx([-0.5 / 320, -0.5 / 321, 1.0])
    with pytest.raises(DepthInputError, match="positive focal"):
        PinholeCamera(640, 480, 0.0, 320.0, 320, 240)
    with pytest.raises(DepthInputError, match=r"\[\[fx,0,cx\]"):
        PinholeCamera.from_matrix([[320.0, 1.0, 319.5], [0, 321.0, 239.5], [0, 0, 1]], 640, 480)


def test_check_rgb_image_rejects_wrong_size_and_type() -> None:
    cam = PinholeCamera(64, 48, 32.0, 32.0, 31.5, 23.5)
    check_rgb_image(np.zeros((48, 64, 3), np.uint8), cam)
    with pytest.raises(DepthInputError, match="64x48"):
        check_rgb_image(np.zeros((48, 63, 3), np.uint8), cam)
    with pytest.raises(DepthInputError, match="uint8"):
        check_rgb_image(np.zeros((48, 64, 3), np.float32), cam)


def test_pose_validity_and_relative_pose() -> None:
    a = CameraPose(nadir_rotation(0.2), np.array([1.0, 2.0, 50.0]))
    b = CameraPose(rotation_about([0, 0, 1], 0.1) @ nadir_rotation(0.2), np.array([4.0, 2.0, 51.0]))
    assert a.is_valid
    assert b.is_valid
    rot, trans = a.relative_to(b)
    # A point seen by a, mapped into b, equals the same map point seen from b.
    p_map = np.array([3.0, -7.0, 2.0])
    p_a = a.rotation_map_optical.T @ (p_map - a.position_map_m)
    p_b = b.rotation_map_optical.T @ (p_map - b.position_map_m)
    assert rot @ p_a + trans == pytest.approx(p_b)
    assert not CameraPose(np.full((3, 3), np.nan), np.zeros(3)).is_valid
    assert not CameraPose(2.0 * np.eye(3), np.zeros(3)).is_valid
    assert not CameraPose(np.eye(3), np.array([0.0, np.inf, 0.0])).is_valid
    with pytest.raises(DepthGeometryError, match="3x3"):
        CameraPose(np.eye(2), np.zeros(3))
