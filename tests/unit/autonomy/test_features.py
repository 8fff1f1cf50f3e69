"""Every feature on small hand-computed grids, plus exactness checks against scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from uav_autonomy.core.features import (
    FeatureConfig,
    FeatureEvaluator,
    MapLayers,
    Target,
    age_feature,
    distance_to_point_m,
    distance_to_polygon_m,
    frontier_boundary,
    frontier_feature,
    invert_scale,
)
from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.errors import InvalidInputError

NAN = math.nan


def test_age_decays_by_half_life_and_unseen_is_zero() -> None:
    last_seen = np.array([[10.0, NAN], [5.0, 0.0]], dtype=np.float32)
    out = age_feature(last_seen, now_s=10.0, half_life_s=5.0)
    np.testing.assert_allclose(out, [[1.0, 0.0], [0.5, 0.25]], rtol=1e-6)
    assert out.dtype == np.float32


def test_age_takes_the_freshest_voxel_of_each_column() -> None:
    # (H=1, W=2, D=3): column 0 has voxels seen at 0, 8, NaN; column 1 never.
    last_seen = np.array([[[0.0, 8.0, NAN], [NAN, NAN, NAN]]], dtype=np.float32)
    out = age_feature(last_seen, now_s=10.0, half_life_s=2.0)
    np.testing.assert_allclose(out, [[0.5, 0.0]], rtol=1e-6)


def test_age_seen_in_the_future_scores_one_and_bad_time_raises() -> None:
    out = age_feature(np.array([[12.0]], dtype=np.float32), now_s=10.0, half_life_s=5.0)
    assert out[0, 0] == pytest.approx(1.0)
    with pytest.raises(InvalidInputError, match="now_s"):
        age_feature(np.zeros((1, 1), np.float32), now_s=NAN, half_life_s=5.0)


def test_frontier_boundary_is_the_observed_ring_with_outside_unobserved() -> None:
    observed = np.zeros((5, 5), dtype=bool)
    observed[1:4, 1:4] = True
    boundary = frontier_boundary(observed)
    expected = observed.copy()
    expected[2, 2] = False
    np.testing.assert_array_equal(boundary, expected)
    full = np.ones((3, 3), dtype=bool)
    ring = frontier_boundary(full)
    assert not ring[1, 1]
    assert ring.sum() == 8  # the map edge is a frontier


def test_frontier_feature_hand_computed() -> None:
    observed = np.zeros((5, 5), dtype=bool)
    observed[1:4, 1:4] = True
    out = frontier_feature(observed, resolution_m=2.0, scale_m=None)
    # Distances in cells: boundary 0, centre 1, (0, 2) 1, corner (0, 0) sqrt 2 = max.
    assert out[1, 1] == pytest.approx(1.0)
    assert out[2, 2] == pytest.approx(1.0 - 1.0 / math.sqrt(2.0), abs=1e-5)
    assert out[0, 2] == pytest.approx(1.0 - 1.0 / math.sqrt(2.0), abs=1e-5)
    assert out[0, 0] == pytest.approx(0.0, abs=1e-6)
    scaled = frontier_feature(observed, resolution_m=2.0, scale_m=4.0)
    assert scaled[2, 2] == pytest.approx(0.5, abs=1e-5)
    assert scaled[0, 0] == pytest.approx(1.0 - 2.0 * math.sqrt(2.0) / 4.0, abs=1e-5)


def test_frontier_map_edge_scores_one_interior_less() -> None:
    out = frontier_feature(np.ones((5, 7), dtype=bool), resolution_m=1.0, scale_m=None)
    assert out[0, :].min() == pytest.approx(1.0)
    assert out[:, -1].min() == pytest.approx(1.0)
    assert out[2, 3] == pytest.approx(0.0, abs=1e-6)  # the centre is farthest (2 cells)
    assert out[1, 3] == pytest.approx(0.5, abs=1e-6)


def test_frontier_nothing_observed_is_all_unexplored() -> None:
    np.testing.assert_array_equal(frontier_feature(np.zeros((3, 4), bool), 1.0, None), np.ones((3, 4)))


def test_frontier_distance_is_exact_euclidean() -> None:
    rng = np.random.default_rng(3)
    observed = ndimage.binary_dilation(rng.random((60, 80)) < 0.02, iterations=6)
    boundary = frontier_boundary(observed)
    expected_d = ndimage.distance_transform_edt(~boundary) * 0.5
    out = frontier_feature(observed, resolution_m=0.5, scale_m=10.0)
    np.testing.assert_allclose(out, np.clip(1.0 - expected_d / 10.0, 0.0, 1.0), atol=1e-4)


def test_distance_to_point_and_inversion() -> None:
    spec = GridSpec(1.0, 0.0, 0.0, width=3, height=1)
    dist, dmax = distance_to_point_m(spec, 0.5, 0.5)
    np.testing.assert_allclose(dist, [[0.0, 1.0, 2.0]])
    assert dmax == pytest.approx(2.0)
    np.testing.assert_allclose(invert_scale(dist, None, dmax), [[1.0, 0.5, 0.0]])
    np.testing.assert_allclose(invert_scale(dist, 4.0), [[1.0, 0.75, 0.5]])


def _brute_polygon_distance(spec: GridSpec, poly: np.ndarray) -> np.ndarray:
    """Per-cell reference: point-in-polygon by ray casting, else min distance to edges."""
    out = np.zeros(spec.shape)
    n = len(poly)
    for r in range(spec.height):
        for c in range(spec.width):
            px, py = spec.cell_center_m(r, c)
            inside = False
            best = math.inf
            for i in range(n):
                (ax, ay), (bx, by) = poly[i], poly[(i + 1) % n]
                if (ay > py) != (by > py) and px < ax + (py - ay) * (bx - ax) / (by - ay):
                    inside = not inside
                ex, ey = bx - ax, by - ay
                t = max(0.0, min(1.0, ((px - ax) * ex + (py - ay) * ey) / (ex * ex + ey * ey)))
                best = min(best, math.hypot(px - ax - t * ex, py - ay - t * ey))
            out[r, c] = 0.0 if inside else best
    return out


def test_distance_to_polygon_hand_computed_and_against_reference() -> None:
    spec = GridSpec(1.0, 0.0, 0.0, width=4, height=4)
    square = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0], [0.0, 2.0]])
    d = distance_to_polygon_m(spec, square)
    assert d[0, 0] == 0.0
    assert d[1, 1] == 0.0
    assert d[0, 3] == pytest.approx(1.5)  # centre (3.5, 0.5)
    assert d[3, 3] == pytest.approx(math.hypot(1.5, 1.5))
    concave = np.array([[-3.0, -1.0], [6.0, -2.0], [2.0, 1.5], [7.0, 6.0], [-1.0, 5.0]])
    spec2 = GridSpec(0.7, -4.0, -3.0, width=17, height=14)
    np.testing.assert_allclose(
        distance_to_polygon_m(spec2, concave), _brute_polygon_distance(spec2, concave), atol=1e-4
    )


def test_distance_to_polygon_outside_the_grid() -> None:
    spec = GridSpec(1.0, 0.0, 0.0, width=2, height=1)
    far = np.array([[10.0, -1.0], [12.0, -1.0], [12.0, 1.0], [10.0, 1.0]])
    np.testing.assert_allclose(distance_to_polygon_m(spec, far), [[9.5, 8.5]], atol=1e-5)


def test_target_validation() -> None:
    with pytest.raises(InvalidInputError, match="polygon of >= 3"):
        Target(((0.0, 0.0), (1.0, 1.0)))
    with pytest.raises(InvalidInputError, match="finite"):
        Target(((NAN, 0.0),))


def _layers(spec: GridSpec) -> MapLayers:
    h, w = spec.shape
    observed = np.zeros(spec.shape, dtype=bool)
    observed[: h // 2, : w // 2] = True
    return MapLayers(
        spec=spec,
        elevation_m=np.where(observed, 3.0, NAN).astype(np.float32),
        last_seen_s=np.where(observed, 90.0, NAN).astype(np.float32),
        observed=observed,
    )


def test_evaluator_produces_every_layer_in_range() -> None:
    spec = GridSpec(2.0, -20.0, -10.0, width=20, height=10)
    ev = FeatureEvaluator(FeatureConfig(age_half_life_s=10.0))
    maps = ev.evaluate(_layers(spec), now_s=100.0, drone_xy_m=(0.0, 0.0), target=Target(((10.0, 5.0),)))
    assert set(maps.layers) == {"elevation_m", "age", "frontier", "target", "drone", "origin"}
    for name, layer in maps.scored().items():
        assert layer.shape == spec.shape, name
        assert layer.dtype == np.float32, name
        assert float(layer.min()) >= 0.0, name
        assert float(layer.max()) <= 1.0, name
    assert maps.layers["age"][0, 0] == pytest.approx(0.5)
    assert maps.layers["age"][9, 19] == 0.0
    row, col = spec.cell_of(10.0, 5.0) or (-1, -1)
    assert maps.layers["target"][row, col] == pytest.approx(maps.layers["target"].max())
    assert np.isnan(maps.layers["elevation_m"][9, 19])


def test_evaluator_target_layer_follows_a_moving_target_and_grid_growth() -> None:
    spec = GridSpec(1.0, 0.0, 0.0, width=10, height=10)
    ev = FeatureEvaluator(FeatureConfig())
    a = ev.evaluate(_layers(spec), now_s=0.0, drone_xy_m=None, target=Target(((0.5, 0.5),)))
    b = ev.evaluate(_layers(spec), now_s=0.0, drone_xy_m=None, target=Target(((9.5, 9.5),)))
    assert a.layers["target"][0, 0] == pytest.approx(1.0)
    assert b.layers["target"][9, 9] == pytest.approx(1.0)
    assert b.layers["target"][0, 0] == pytest.approx(0.0)
    np.testing.assert_array_equal(b.layers["drone"], 0.0)  # no pose yet
    grown = GridSpec(1.0, -5.0, 0.0, width=15, height=10)
    c = ev.evaluate(_layers(grown), now_s=0.0, drone_xy_m=(0.0, 0.0), target=Target(((9.5, 9.5),)))
    assert c.layers["target"].shape == (10, 15)
    assert c.layers["target"][9, 14] == pytest.approx(1.0)


def test_evaluator_rejects_bad_input_without_side_effects() -> None:
    spec = GridSpec(1.0, 0.0, 0.0, width=4, height=3)
    with pytest.raises(InvalidInputError, match="shape"):
        MapLayers(spec, np.zeros((3, 4), np.float32), np.zeros((4, 3), np.float32), np.zeros((3, 4), bool))
    with pytest.raises(InvalidInputError, match="at least one cell"):
        GridSpec(1.0, 0.0, 0.0, width=0, height=3)
    ev = FeatureEvaluator(FeatureConfig())
    with pytest.raises(InvalidInputError, match="drone position"):
        ev.evaluate(_layers(spec), now_s=0.0, drone_xy_m=(NAN, 0.0), target=None)
