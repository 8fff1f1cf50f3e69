"""Geolocation against known geometry: boxes of people projected by an exact pinhole camera onto flat ground,
a slope and a building's roof, placed on a depth image, the map server's elevation layer and a terrain model,
and the fallbacks between them; the stated uncertainty checked by Monte Carlo."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
import pytest

from uav_perception.core.depth.types import CameraPose, PinholeCamera
from uav_perception.core.detection.boxes import Box
from uav_perception.core.detection.geolocation import GeolocationConfig, Placement, Surfaces, contact_point, place
from uav_perception.core.detection.heightfield import HeightGrid, first_hit
from uav_perception.errors import DetectionInputError

CAM = PinholeCamera(640, 480, 320.0, 320.0, 319.5, 239.5)  # 90 deg horizontal field of view
CFG = GeolocationConfig()
FloatArray = npt.NDArray[np.float64]


def camera_pose(position: tuple[float, float, float], yaw_deg: float = 90.0, pitch_deg: float = 25.0) -> CameraPose:
    """Optical frame of a camera at ``position`` looking along ``yaw_deg`` (ENU: 0 = east, 90 = north), pitched
    down by ``pitch_deg``: columns are the optical x (right), y (down), z (forward) axes in map."""
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    forward = np.array([math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), -math.sin(pitch)])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.cross(forward, right)
    return CameraPose(np.column_stack([right, down, forward]), np.array(position, dtype=np.float64))


def project(pose: CameraPose, points: FloatArray) -> FloatArray:
    pc = (np.asarray(points, dtype=np.float64) - pose.position_map_m) @ pose.rotation_map_optical
    return np.stack([CAM.fx_px * pc[:, 0] / pc[:, 2] + CAM.cx_px, CAM.fy_px * pc[:, 1] / pc[:, 2] + CAM.cy_px], axis=1)


def object_box(pose: CameraPose, foot: tuple[float, float, float], size: tuple[float, float, float]) -> Box:
    """The image box of an upright cuboid (length along x, width along y, height) standing centred on ``foot``."""
    lx, ly, h = size
    corners = np.array(
        [
            (foot[0] + sx * lx / 2, foot[1] + sy * ly / 2, foot[2] + sz * h)
            for sx in (-1, 1)
            for sy in (-1, 1)
            for sz in (0, 1)
        ]
    )
    uv = project(pose, corners)
    return Box("person", 0, 0.9, uv[:, 0].min(), uv[:, 1].min(), uv[:, 0].max(), uv[:, 1].max())


def person_box(pose: CameraPose, foot: tuple[float, float, float]) -> Box:
    return object_box(pose, foot, (0.5, 0.5, 1.75))


def grid(
    fn: object, res: float, half: float = 300.0, interpolation: str = "bilinear", name: str = "terrain"
) -> HeightGrid:
    n = round(2 * half / res)
    centres = -half + (np.arange(n) + 0.5) * res
    x, y = np.meshgrid(centres, centres)
    return HeightGrid(np.asarray(fn(x, y), dtype=np.float64), -half, -half, res, interpolation, name)  # type: ignore[operator]


FLAT = grid(lambda x, y: 0.0 * x, 2.0)


def horizontal_error(placement: Placement, truth: tuple[float, float, float]) -> float:
    return math.hypot(placement.position_m[0] - truth[0], placement.position_m[1] - truth[1])


def inside_2sigma(placement: Placement, truth: tuple[float, float, float]) -> bool:
    cov = np.array(placement.covariance_m2).reshape(3, 3)[:2, :2]
    err = np.array([placement.position_m[0] - truth[0], placement.position_m[1] - truth[1]])
    return float(err @ np.linalg.solve(cov, err)) <= 5.991


@pytest.mark.parametrize("foot", [(0.0, 30.0, 0.0), (-12.0, 55.0, 0.0), (20.0, 80.0, 0.0), (5.0, 100.0, 0.0)])
def test_flat_ground_standing_people_are_placed_at_their_feet(foot: tuple[float, float, float]) -> None:
    pose = camera_pose((0.0, 0.0, 40.0))
    p = place(person_box(pose, foot), CAM, pose, Surfaces(terrain=FLAT), CFG, footprint_radius_m=0.2)
    assert p.source == "terrain"
    assert horizontal_error(p, foot) < 0.35
    assert p.position_m[2] == pytest.approx(0.0, abs=0.05)
    assert p.range_m == pytest.approx(math.dist((0.0, 0.0, 40.0), p.position_m))
    assert inside_2sigma(p, foot)


def test_the_contact_point_is_the_bottom_centre_in_an_oblique_view_and_towards_the_nadir_seen_from_above() -> None:
    oblique = camera_pose((0.0, 0.0, 40.0))
    box = person_box(oblique, (8.0, 60.0, 0.0))
    u, v = contact_point(box, CAM, oblique)
    # the bottom edge, within a fraction of a pixel of its centre (verticals lean towards the nadir's image)
    assert u == pytest.approx(box.center[0], abs=0.5)
    assert v == pytest.approx(box.v1, abs=1e-6)
    nadir = camera_pose((0.0, 0.0, 50.0), pitch_deg=90.0)
    box = person_box(nadir, (8.0, -5.0, 0.0))
    u, v = contact_point(box, CAM, nadir)
    # from above, the head images farther from the image of the nadir (the principal point) than the feet
    to_centre = np.array([CAM.cx_px - box.center[0], CAM.cy_px - box.center[1]])
    assert np.dot(np.array([u, v]) - np.array(box.center), to_centre) > 0
    p = place(box, CAM, nadir, Surfaces(terrain=FLAT), CFG, footprint_radius_m=0.2)
    assert horizontal_error(p, (8.0, -5.0, 0.0)) < 0.3
    right_below = person_box(nadir, (0.0, 0.0, 0.0))  # straight down: head and feet image to one point
    assert contact_point(right_below, CAM, nadir) == pytest.approx(right_below.center, abs=0.05)


def test_a_lying_person_is_placed_within_half_a_body_length() -> None:
    pose = camera_pose((0.0, 0.0, 35.0))
    centre = (3.0, 60.0, 0.0)
    box = object_box(pose, centre, (0.5, 1.8, 0.3))  # lying along the line of sight, the hardest case
    p = place(box, CAM, pose, Surfaces(terrain=FLAT), CFG, footprint_radius_m=0.2)
    assert horizontal_error(p, centre) < 0.9
    assert inside_2sigma(p, centre)


def test_a_slope_needs_the_terrain_model() -> None:
    slope = grid(lambda x, y: 0.12 * y + 0.05 * x, 2.0)  # ~7 deg up to the north
    pose = camera_pose((0.0, 0.0, 40.0))
    for x, y in ((0.0, 50.0), (-15.0, 75.0), (10.0, 95.0)):
        foot = (x, y, 0.12 * y + 0.05 * x)
        box = person_box(pose, foot)
        on_slope = place(box, CAM, pose, Surfaces(terrain=slope), CFG, footprint_radius_m=0.2)
        assert on_slope.source == "terrain"
        assert horizontal_error(on_slope, foot) < 0.35
        assert on_slope.position_m[2] == pytest.approx(foot[2], abs=0.1)
        # the same box placed on a flat world lands tens of metres short of the uphill person
        assert horizontal_error(place(box, CAM, pose, Surfaces(terrain=FLAT), CFG), foot) > 0.25 * (y - 20)


BUILDING = ((-10.0, 60.0), (10.0, 80.0))  # footprint corners (x, y); roof at 8 m


def roof_height(x: FloatArray, y: FloatArray) -> FloatArray:
    (x0, y0), (x1, y1) = BUILDING
    return np.where((x >= x0) & (x <= x1) & (y >= y0) & (y <= y1), 8.0, 0.0)


def roof_depth_image(pose: CameraPose) -> npt.NDArray[np.float32]:
    """Exact z-depth of flat ground with the building (a box), every pixel, by slab intersection."""
    u, v = np.meshgrid(np.arange(CAM.width_px, dtype=np.float64), np.arange(CAM.height_px, dtype=np.float64))
    rays_opt = np.stack([(u - CAM.cx_px) / CAM.fx_px, (v - CAM.cy_px) / CAM.fy_px, np.ones_like(u)], axis=-1)
    d = rays_opt @ pose.rotation_map_optical.T  # map directions with optical z = 1 (so t is the z-depth)
    o = pose.position_map_m
    with np.errstate(divide="ignore", invalid="ignore"):
        t_ground = np.where(d[..., 2] < 0, -o[2] / d[..., 2], np.inf)
        lo = np.array([BUILDING[0][0], BUILDING[0][1], 0.0])
        hi = np.array([BUILDING[1][0], BUILDING[1][1], 8.0])
        t1 = (lo - o) / d
        t2 = (hi - o) / d
        t_near = np.nanmax(np.minimum(t1, t2), axis=-1)
        t_far = np.nanmin(np.maximum(t1, t2), axis=-1)
    t_box = np.where((t_near <= t_far) & (t_far > 0), t_near, np.inf)
    depth = np.minimum(t_ground, t_box)
    return np.where(np.isfinite(depth), depth, np.nan).astype(np.float32)


def test_a_person_on_a_roof_is_placed_on_the_roof_by_depth_and_elevation_not_by_the_terrain() -> None:
    pose = camera_pose((0.0, 0.0, 40.0))
    foot = (3.0, 70.0, 8.0)
    box = person_box(pose, foot)
    elevation = grid(roof_height, 0.5, half=150.0, interpolation="nearest", name="elevation")
    by_depth = place(box, CAM, pose, Surfaces(depth_m=roof_depth_image(pose), elevation=elevation, terrain=FLAT), CFG)
    by_elevation = place(box, CAM, pose, Surfaces(elevation=elevation, terrain=FLAT), CFG)
    by_terrain = place(box, CAM, pose, Surfaces(terrain=FLAT), CFG)
    assert (by_depth.source, by_elevation.source, by_terrain.source) == ("depth", "elevation", "terrain")
    for p in (by_depth, by_elevation):
        assert horizontal_error(p, foot) < 0.5
        assert p.position_m[2] == pytest.approx(8.0, abs=0.3)
    # The bare terrain has no building: the ray goes on to the ground far behind the person.
    assert horizontal_error(by_terrain, foot) > 10.0
    assert by_terrain.position_m[2] == pytest.approx(0.0, abs=0.05)


def test_fallbacks_depth_then_elevation_then_terrain() -> None:
    pose = camera_pose((0.0, 0.0, 40.0))
    foot = (-6.0, 50.0, 0.0)
    box = person_box(pose, foot)
    no_return = np.full((CAM.height_px, CAM.width_px), np.nan, dtype=np.float32)  # sky, or beyond the sensor
    # the elevation layer knows only a strip far from the person: the terrain model fills the rest
    partial = grid(lambda x, y: np.where(y < 20.0, 0.0, np.nan), 0.5, half=150.0, interpolation="nearest", name="e")
    known = grid(lambda x, y: 0.0 * x, 0.5, half=150.0, interpolation="nearest", name="e")
    assert place(box, CAM, pose, Surfaces(depth_m=no_return, elevation=known, terrain=FLAT), CFG).source == "elevation"
    assert place(box, CAM, pose, Surfaces(depth_m=no_return, elevation=partial, terrain=FLAT), CFG).source == "terrain"
    alone = place(box, CAM, pose, Surfaces(elevation=partial), CFG)  # no terrain model to fill the gap
    assert (alone.placed, alone.reason) == (False, "no_surface")
    assert all(math.isnan(v) for v in alone.position_m)


def test_boxes_that_cannot_be_placed_say_why() -> None:
    pose = camera_pose((0.0, 0.0, 40.0))
    box = person_box(pose, (0.0, 60.0, 0.0))
    assert place(box, None, pose, Surfaces(terrain=FLAT), CFG).reason == "no_camera_info"
    assert place(box, CAM, None, Surfaces(terrain=FLAT), CFG).reason == "no_pose"
    broken = CameraPose(np.full((3, 3), np.nan), np.zeros(3))
    assert place(box, CAM, broken, Surfaces(terrain=FLAT), CFG).reason == "no_pose"
    assert place(box, CAM, pose, Surfaces(), CFG).reason == "no_surface_model"
    sky = Box("person", 0, 0.9, 300.0, 10.0, 310.0, 30.0)  # 20 deg above the horizon: the ray meets nothing
    assert place(sky, CAM, pose, Surfaces(terrain=FLAT), CFG).reason == "no_surface"
    with pytest.raises(DetectionInputError, match="depth image is"):
        place(box, CAM, pose, Surfaces(depth_m=np.zeros((10, 10), np.float32)), CFG)


def test_first_hit_refines_a_roof_edge_and_never_hits_unknown_cells() -> None:
    elevation = grid(roof_height, 0.5, half=150.0, interpolation="nearest", name="elevation")
    o = np.array([0.0, 40.0, 4.0])
    d = np.array([0.0, 1.0, 0.0])  # level, towards the building's south wall at y = 60, below the roof
    hit = first_hit(o, d, [elevation], step_m=0.25, max_range_m=200.0)
    assert hit is not None
    assert hit.t_m == pytest.approx(20.0, abs=0.01)
    unknown = grid(lambda x, y: np.full_like(x, np.nan), 0.5, half=150.0, interpolation="nearest")
    assert first_hit(o, np.array([0.0, 0.6, -0.8]), [unknown], step_m=0.25, max_range_m=200.0) is None


def test_the_stated_uncertainty_is_calibrated() -> None:
    """Monte Carlo: contact pixels off by N(0, sigma_px) and a terrain model off by N(0, sigma_h); the placements
    should fall inside their own 95 % ellipse about 95 % of the time."""
    rng = np.random.default_rng(7)
    cfg = GeolocationConfig(pixel_sigma_px=1.5, pixel_sigma_rel=0.0, attitude_sigma_deg=0.0, terrain_sigma_m=0.8)
    pose = camera_pose((0.0, 0.0, 45.0))
    inside = []
    for _ in range(300):
        foot = (float(rng.uniform(-30, 30)), float(rng.uniform(30, 110)), 0.0)
        box = person_box(pose, foot)
        du, dv = rng.normal(0.0, cfg.pixel_sigma_px, 2)
        noisy = Box("person", 0, 0.9, box.u0 + du, box.v0 + dv, box.u1 + du, box.v1 + dv)
        dem = HeightGrid(FLAT.heights_m + rng.normal(0.0, cfg.terrain_sigma_m), -300.0, -300.0, 2.0, "bilinear")
        p = place(noisy, CAM, pose, Surfaces(terrain=dem), cfg)
        inside.append(inside_2sigma(p, foot))
    share = float(np.mean(inside))
    assert 0.88 <= share <= 0.99, share


def _first_hit_every_sample(o: np.ndarray, d: np.ndarray, grids: list[HeightGrid], step_m: float) -> float | None:
    """The first hit as first_hit finds it, marching from min_range (0.5 m) with no shortcut: the reference."""
    low = min(g.min_height_m for g in grids)
    t_end = 400.0 if d[2] >= 0 else min(400.0, (o[2] - low) / -d[2] + step_m)
    t = np.arange(0.5, t_end + step_m, step_m)
    pts = o[None, :] + t[:, None] * d[None, :]
    h = np.full(len(t), np.nan)
    for g in reversed(grids):  # the first grid that knows a point wins
        known = g.at(pts[:, 0], pts[:, 1])
        h = np.where(np.isfinite(known), known, h)
    hits = np.flatnonzero(pts[:, 2] <= h)
    if hits.size == 0 or hits[0] == 0:
        return None
    return float(t[hits[0]])


def test_the_march_skips_only_samples_above_every_surface() -> None:
    """first_hit starts where the ray comes down to the highest surface: the hit is the one a march over every
    sample finds (to the bisection's millimetre), over random rays and terrains."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        heights = rng.uniform(0.0, 40.0, (24, 24))
        heights[rng.random((24, 24)) < 0.1] = np.nan
        grid = HeightGrid(heights, -120.0, -120.0, 10.0, name="terrain")
        o = np.array([rng.uniform(-80, 80), rng.uniform(-80, 80), rng.uniform(5.0, 120.0)])
        d = np.array([rng.normal(), rng.normal(), rng.uniform(-1.0, 0.2)])
        d /= np.linalg.norm(d)
        hit = first_hit(o, d, [grid], step_m=0.5, max_range_m=400.0, min_range_m=0.5)
        ref = _first_hit_every_sample(o, d, [grid], 0.5)
        if ref is None:
            assert hit is None
        else:
            assert hit is not None
            assert ref - 0.5 <= hit.t_m <= ref + 1e-9


@pytest.mark.parametrize("interpolation", ["nearest", "bilinear"])
def test_one_point_lookups_equal_the_vectorised_ones(interpolation: str) -> None:
    """The bisection's one-point lookup gives exactly what the march's vectorised lookup gives (inside, at the
    edges, outside, over unknown cells), so refining a hit does not move it."""
    rng = np.random.default_rng(5)
    heights = rng.uniform(-5.0, 30.0, (17, 23))
    heights[rng.random(heights.shape) < 0.15] = np.nan
    grid = HeightGrid(heights, -40.0, 12.5, 2.5, interpolation=interpolation, name="g")  # type: ignore[arg-type]
    x = np.concatenate([rng.uniform(-50.0, 30.0, 500), [-40.0, -40.0 + 23 * 2.5, 0.0]])
    y = np.concatenate([rng.uniform(0.0, 70.0, 500), [12.5, 12.5 + 17 * 2.5, 12.5 + 17 * 2.5 + 1e-9]])
    expected = grid.at(x, y, 0.75)
    got = np.array([grid.at_point(float(a), float(b), 0.75) for a, b in zip(x, y, strict=True)])
    np.testing.assert_array_equal(got, expected)
