from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_common.config import ConfigError, from_mapping
from uav_sim_bridge.core.camera import CameraConfig, CameraModel, MountConfig, depth_to_points, look_at
from uav_sim_bridge.core.transforms import RigidTransform


@settings(max_examples=60, deadline=None)
@given(
    width=st.integers(16, 1280),
    height=st.integers(16, 960),
    hfov=st.floats(20.0, 150.0),
    u=st.floats(0.0, 1.0),
    v=st.floats(0.0, 1.0),
    depth=st.floats(0.3, 3000.0),
)
def test_project_unproject_round_trip(
    *, width: int, height: int, hfov: float, u: float, v: float, depth: float
) -> None:
    cam = CameraModel.simple(width, height, hfov)
    uv = np.array([[u * (width - 1), v * (height - 1)]])
    pts = cam.unproject(uv, [depth])
    uv2, z = cam.project(pts)
    np.testing.assert_allclose(uv2, uv, atol=1e-6 * max(width, height))
    np.testing.assert_allclose(z, [depth], rtol=1e-12)
    assert cam.in_image(uv2).all()


def test_explicit_intrinsics_and_centre() -> None:
    cam = CameraModel.from_config("c", CameraConfig(width=640, height=480, fx=500.0, fy=510.0, cx=300.0, cy=200.0))
    np.testing.assert_allclose(cam.k, [[500, 0, 300], [0, 510, 200], [0, 0, 1]])
    uv, _ = cam.project([[0.0, 0.0, 7.0]])
    np.testing.assert_allclose(uv, [[300.0, 200.0]])
    hfov = CameraModel.simple(640, 480, 90.0)
    assert hfov.fx == pytest.approx(320.0)
    assert (hfov.cx, hfov.cy) == (319.5, 239.5)
    assert math.degrees(hfov.hfov_rad) == pytest.approx(90.0)


def test_points_behind_camera_do_not_project() -> None:
    cam = CameraModel.simple(64, 48, 90.0)
    uv, _ = cam.project([[0.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
    assert np.isnan(uv).all()
    assert not cam.in_image(uv).any()


def test_depth_to_points_matches_unproject() -> None:
    cam = CameraModel.simple(40, 30, 70.0)
    rng = np.random.default_rng(0)
    depth = rng.uniform(1, 50, (30, 40)).astype(np.float32)
    depth[3, 4] = np.nan
    depth[5, 6] = 0.0
    pts = depth_to_points(depth, cam.k)
    assert pts.shape == (30, 40, 3)
    assert np.isnan(pts[3, 4]).all()
    assert np.isnan(pts[5, 6]).all()
    rows, cols = np.mgrid[0:30, 0:40]
    ok = np.isfinite(depth) & (depth > 0)
    ref = cam.unproject(np.stack([cols[ok], rows[ok]], 1), depth[ok])
    np.testing.assert_allclose(pts[ok], ref, rtol=1e-5)
    with pytest.raises(ValueError, match="2-D"):
        depth_to_points(np.zeros(5), cam.k)


def test_mounts_follow_rep103() -> None:
    nadir = CameraModel.from_config("nadir", CameraConfig(hfov_deg=90, mount=MountConfig(rpy_deg=(0, 90, 0))))
    t = nadir.optical_pose(RigidTransform.from_rpy([0, 0, 50.0], yaw_rad=0.0))
    np.testing.assert_allclose(t.rotation[:, 2], [0, 0, -1], atol=1e-12)  # optical z looks down
    np.testing.assert_allclose(t.rotation[:, 0], [0, -1, 0], atol=1e-12)  # image x = vehicle right (south)
    fwd = CameraModel.from_config("forward", CameraConfig(hfov_deg=90, mount=MountConfig(rpy_deg=(0, 25, 0))))
    z_axis = fwd.optical_pose(RigidTransform.from_rpy([0, 0, 0], yaw_rad=math.pi / 2)).rotation[:, 2]
    # vehicle facing north, camera pitched 25 degrees down
    np.testing.assert_allclose(z_axis, [0, math.cos(math.radians(25)), -math.sin(math.radians(25))], atol=1e-12)
    assert nadir.frame_id == "camera_nadir"
    assert nadir.optical_frame_id == "camera_nadir_optical"


def test_look_at_nadir_has_north_up() -> None:
    t = look_at([10, 20, 50], [10, 20, 0])
    cam = CameraModel.simple(64, 48, 90)
    north = t.inverse().apply([10, 30, 0])
    uv, _ = cam.project(north[None])
    assert uv[0, 1] < cam.cy  # north appears above the centre
    with pytest.raises(ValueError, match="coincide"):
        look_at([0, 0, 0], [0, 0, 0])


def test_with_size_keeps_field_of_view() -> None:
    cam = CameraModel.simple(640, 480, 90.0)
    half = cam.with_size(320, 240)
    assert half.hfov_rad == pytest.approx(cam.hfov_rad)
    assert (half.cx, half.cy) == pytest.approx((159.5, 119.5))


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"hfov_deg": 90, "fx": 300, "fy": 300}, "not both"),
        ({}, "give hfov_deg"),
        ({"hfov_deg": 200}, "hfov_deg"),
        ({"hfov_deg": 90, "rate_hz": 0}, "rate_hz"),
        ({"hfov_deg": 90, "near_m": 5, "far_m": 1}, "near_m"),
        ({"hfov_deg": 90, "mount": {"xyz": [0, 0, 0]}}, "unknown key"),
        ({"hfov_deg": 90, "width": 0}, "width"),
    ],
)
def test_bad_camera_config_is_a_clear_error(data: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        from_mapping(CameraConfig, data, source="test")


def test_frustum_planes_contain_image_points() -> None:
    cam = CameraModel.simple(64, 48, 80.0)
    planes = cam.frustum_planes_optical()
    inside = cam.unproject([[0, 0], [63, 47], [32, 24]], [10, 10, 10])
    outside = cam.unproject([[-20, 24], [32, 90], [32, 24], [0, 0]], [10, 10, cam.far_m + 1.0, 0.4])  # far, near
    assert (inside @ planes[:, :3].T + planes[:, 3] >= -1e-9).all()
    assert ((outside @ planes[:, :3].T + planes[:, 3]) < 0).any(axis=1).all()
