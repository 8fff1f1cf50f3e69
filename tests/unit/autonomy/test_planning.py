"""Planners: climb-cruise-descend profile, ridge clearance, no-fly zones, geofence."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.core.planning import ElevationMap, PlannerConfig, max_elevation_along_m, plan_astar, plan_straight
from uav_autonomy.errors import InvalidInputError, NoPathError
from uav_common.config import ConfigError, from_mapping

SPEC = GridSpec(2.0, -100.0, -100.0, width=300, height=100)  # x in [-100, 500), y in [-100, 100)


def _ridge_dem(height_m: float = 120.0, gap: bool = False) -> ElevationMap:
    """Flat 0 m ground with a north-south ridge at x in [190, 210) and an optional 20 m pass at y in [-20, 20)."""
    elev = np.zeros(SPEC.shape, dtype=np.float32)
    xs = SPEC.cell_centers_x_m()
    ys = SPEC.cell_centers_y_m()
    ridge = (xs >= 190.0) & (xs < 210.0)
    elev[:, ridge] = height_m
    if gap:
        elev[np.ix_((ys >= -20.0) & (ys < 20.0), ridge)] = 20.0
    return ElevationMap(SPEC, elev)


def _clearance_along(path: np.ndarray, dem: ElevationMap) -> float:
    """Minimum height above the DEM along the path (ignoring the first leg from the ground)."""
    worst = math.inf
    for a, b in itertools.pairwise(path[1:]):
        for t in np.linspace(0.0, 1.0, 400):
            p = a + t * (b - a)
            e = dem.at(p[0], p[1])
            if not math.isnan(e):
                worst = min(worst, p[2] - e)
    return worst


def test_straight_profile_flat_ground() -> None:
    dem = ElevationMap(SPEC, np.zeros(SPEC.shape, dtype=np.float32))
    path = plan_straight((0.0, 0.0, 0.0), (300.0, 0.0), dem, PlannerConfig())
    np.testing.assert_allclose(path, [[0, 0, 0], [0, 0, 50], [300, 0, 50]])  # goal 50 m up: no descent


def test_straight_climbs_over_the_ridge_and_descends_to_the_goal() -> None:
    dem = _ridge_dem(120.0)
    cfg = PlannerConfig(cruise_buffer_m=30.0, goal_height_m=50.0, max_altitude_m=300.0)
    path = plan_straight((0.0, 0.0, 10.0), (400.0, 10.0), dem, cfg)
    np.testing.assert_allclose(path, [[0, 0, 10], [0, 0, 150], [400, 10, 150], [400, 10, 50]])
    assert max_elevation_along_m(dem, (0.0, 0.0), (400.0, 10.0)) == 120.0
    assert _clearance_along(path, dem) >= 30.0 - 1e-6


def test_straight_unknown_elevation_and_bad_input() -> None:
    elev = np.full(SPEC.shape, np.nan, dtype=np.float32)
    dem = ElevationMap(SPEC, elev)
    path = plan_straight((0.0, 0.0, 0.0), (100.0, 0.0), dem, PlannerConfig(unknown_elevation_m=5.0))
    assert path[-1, 2] == pytest.approx(55.0)
    with pytest.raises(InvalidInputError, match="goal"):
        plan_straight((0.0, 0.0, 0.0), (math.nan, 0.0), dem, PlannerConfig())
    with pytest.raises(NoPathError, match="max_altitude_m"):
        plan_straight((0.0, 0.0, 0.0), (400.0, 0.0), _ridge_dem(120.0), PlannerConfig(max_altitude_m=150.0))


def test_astar_clears_the_ridge() -> None:
    dem = _ridge_dem(120.0)
    cfg = PlannerConfig(
        algorithm="astar",
        clearance_m=15.0,
        max_altitude_m=200.0,
        voxel_xy_m=10.0,
        voxel_z_m=5.0,
        unknown_space="occupied",  # the ridge ends with the map: do not let it fly around through unknown space
    )
    path = plan_astar((0.0, 0.0, 0.0), (400.0, 0.0), dem, cfg)
    assert path[0].tolist() == [0.0, 0.0, 0.0]
    assert path[-1][:2].tolist() == [400.0, 0.0]
    assert path[-1][2] == pytest.approx(50.0)
    assert _clearance_along(path, dem) >= 15.0 - 1e-6
    assert path[:, 2].max() >= 135.0


def test_astar_takes_the_pass_under_a_low_ceiling() -> None:
    dem = _ridge_dem(120.0, gap=True)
    cfg = PlannerConfig(
        algorithm="astar", clearance_m=15.0, max_altitude_m=80.0, goal_height_m=40.0, unknown_space="occupied"
    )
    path = plan_astar((0.0, 60.0, 0.0), (400.0, 60.0), dem, cfg)
    assert _clearance_along(path, dem) >= 15.0 - 1e-6
    assert path[:, 2].max() <= 80.0 + 1e-6
    # It must have crossed x = 200 inside the pass.
    crossings = []
    for a, b in itertools.pairwise(path):
        if (a[0] - 200.0) * (b[0] - 200.0) <= 0 and a[0] != b[0]:
            t = (200.0 - a[0]) / (b[0] - a[0])
            crossings.append(a[1] + t * (b[1] - a[1]))
    assert crossings
    assert all(-20.0 <= y <= 20.0 for y in crossings)
    with pytest.raises(NoPathError):
        plan_astar((0.0, 60.0, 0.0), (400.0, 60.0), _ridge_dem(120.0), cfg)


def test_astar_goes_around_through_unknown_space_when_it_counts_as_free() -> None:
    cfg = PlannerConfig(algorithm="astar", max_altitude_m=80.0, unknown_space="free", domain_margin_m=50.0)
    path = plan_astar((0.0, 0.0, 0.0), (400.0, 0.0), _ridge_dem(120.0), cfg)
    assert path[:, 2].max() <= 80.0 + 1e-6
    assert np.abs(path[:, 1]).max() >= 100.0  # around the end of the known ridge


def test_no_fly_zone_and_geofence() -> None:
    dem = ElevationMap(SPEC, np.zeros(SPEC.shape, dtype=np.float32))
    zone = ((140.0, -30.0), (160.0, -30.0), (160.0, 30.0), (140.0, 30.0))
    cfg = PlannerConfig(no_fly_zones_xy_m=(zone,), algorithm="astar", max_altitude_m=100.0)
    with pytest.raises(NoPathError, match="no-fly zone 0"):
        plan_straight((0.0, 0.0, 0.0), (300.0, 0.0), dem, cfg)
    path = plan_astar((0.0, 0.0, 0.0), (300.0, 0.0), dem, cfg)
    dense = np.concatenate([np.linspace(a, b, 200) for a, b in itertools.pairwise(path)])
    inside = (dense[:, 0] >= 140.0) & (dense[:, 0] <= 160.0) & (np.abs(dense[:, 1]) <= 30.0)
    assert not inside.any()
    fence = ((-50.0, -70.0), (350.0, -70.0), (350.0, 70.0), (-50.0, 70.0))
    fenced = PlannerConfig(geofence_xy_m=fence, no_fly_zones_xy_m=(zone,), algorithm="astar")
    path2 = plan_astar((0.0, 0.0, 0.0), (300.0, 0.0), dem, fenced)
    assert np.abs(path2[:, 1]).max() <= 70.0
    with pytest.raises(NoPathError, match="geofence"):
        plan_straight((0.0, 0.0, 0.0), (400.0, 0.0), dem, PlannerConfig(geofence_xy_m=fence))


def test_unknown_space_occupied_blocks_unknown_columns() -> None:
    elev = np.zeros(SPEC.shape, dtype=np.float32)
    xs = SPEC.cell_centers_x_m()
    elev[:, (xs >= 100.0) & (xs < 120.0)] = np.nan  # an unknown band across the whole map
    dem = ElevationMap(SPEC, elev)
    free_cfg = PlannerConfig(algorithm="astar", unknown_space="free", domain_margin_m=0.0)
    assert plan_astar((0.0, 0.0, 0.0), (300.0, 0.0), dem, free_cfg).shape[1] == 3
    with pytest.raises(NoPathError):
        plan_astar(
            (0.0, 0.0, 0.0),
            (300.0, 0.0),
            dem,
            PlannerConfig(algorithm="astar", unknown_space="occupied", domain_margin_m=0.0),
        )


def test_planner_config_validation() -> None:
    with pytest.raises(ConfigError, match="min_altitude_m"):
        from_mapping(PlannerConfig, {"min_altitude_m": 200.0, "max_altitude_m": 100.0}, source="t")
    with pytest.raises(ConfigError, match="polygon"):
        from_mapping(PlannerConfig, {"geofence_xy_m": [[0, 0], [1, 1]]}, source="t")
    with pytest.raises(ConfigError, match="algorithm"):
        from_mapping(PlannerConfig, {"algorithm": "rrt"}, source="t")


def test_remaining_path_starts_at_the_drone_and_keeps_what_is_ahead() -> None:
    from uav_autonomy.core.planning import remaining_path  # noqa: PLC0415

    path = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 50.0], [300.0, 0.0, 50.0], [300.0, 0.0, 20.0]])
    rest = remaining_path(path, (120.0, 3.0, 49.0))
    np.testing.assert_allclose(rest, [[120, 3, 49], [300, 0, 50], [300, 0, 20]])
    np.testing.assert_allclose(remaining_path(path, (0.0, 0.0, 10.0)), [[0, 0, 10], *path[1:]])  # climbing
    np.testing.assert_allclose(remaining_path(path[:1], (1.0, 2.0, 3.0)), [[1, 2, 3], [0, 0, 0]])


def test_dem_conflict_finds_a_new_tower_under_the_cruise() -> None:
    from uav_autonomy.core.planning import dem_conflict_m  # noqa: PLC0415

    dem = ElevationMap(SPEC, np.zeros(SPEC.shape, dtype=np.float32))
    cfg = PlannerConfig(max_altitude_m=300.0)
    path = plan_straight((0.0, 0.0, 10.0), (300.0, 0.0), dem, cfg)  # cruise at 50 m
    assert dem_conflict_m(path, dem, clearance_m=15.0, skip_m=20.0) is None
    assert dem_conflict_m(path, dem, clearance_m=15.0) == 0.0  # the start, 10 m up, is too low; hence skip_m
    elev = np.zeros(SPEC.shape, dtype=np.float32)
    elev[np.ix_((SPEC.cell_centers_y_m() > -10) & (SPEC.cell_centers_y_m() < 10),
                (SPEC.cell_centers_x_m() > 150) & (SPEC.cell_centers_x_m() < 160))] = 40.0  # fmt: skip
    tower = ElevationMap(SPEC, elev)
    hit = dem_conflict_m(path, tower, clearance_m=15.0, skip_m=20.0)
    assert hit is not None
    assert hit == pytest.approx(40.0 + 150.0, abs=1.0)  # 40 m climb, then 150 m along the cruise
    replanned = plan_straight((0.0, 0.0, 50.0), (300.0, 0.0), tower, cfg)
    assert dem_conflict_m(replanned, tower, clearance_m=15.0, skip_m=20.0) is None
    assert replanned[:, 2].max() == pytest.approx(90.0)
