"""Scripted patterns: lawnmower and expanding square, hand-computed."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from uav_autonomy.core.patterns import expanding_square, follow_terrain, lawnmower, waypoint_list
from uav_autonomy.errors import InvalidInputError


def test_lawnmower_rectangle_tracks_alternate() -> None:
    rect = [(0.0, 0.0), (100.0, 0.0), (100.0, 40.0), (0.0, 40.0)]
    path = lawnmower(rect, spacing_m=10.0, altitude_m=30.0)
    expected = [
        (0, 5),
        (100, 5),
        (100, 15),
        (0, 15),
        (0, 25),
        (100, 25),
        (100, 35),
        (0, 35),
    ]
    np.testing.assert_allclose(path[:, :2], expected, atol=1e-9)
    np.testing.assert_allclose(path[:, 2], 30.0)


def test_lawnmower_spacing_is_never_exceeded_and_heading_respected() -> None:
    tri = [(0.0, 0.0), (60.0, 0.0), (0.0, 60.0)]
    path = lawnmower(tri, spacing_m=7.0, altitude_m=20.0, sweep_heading_rad=math.pi / 2)  # tracks run north
    xs = sorted(set(np.round(path[:, 0], 6)))
    assert max(np.diff(xs)) <= 7.0 + 1e-9
    assert xs[0] <= 3.5 + 1e-9
    assert xs[-1] >= 60.0 - 3.5 - 1e-9
    for x, y in path[:, :2]:
        assert y <= 60.0 - x + 1e-6  # every track end is on or inside the hypotenuse


def test_expanding_square_legs() -> None:
    path = expanding_square((0.0, 0.0), spacing_m=10.0, altitude_m=40.0, max_radius_m=15.0)
    np.testing.assert_allclose(path[:, :2], [(0, 0), (0, 10), (10, 10), (10, -10), (-10, -10)], atol=1e-9)
    assert (path[:, 2] == 40.0).all()
    bigger = expanding_square((5.0, 5.0), spacing_m=10.0, altitude_m=40.0, max_radius_m=100.0)
    legs = np.linalg.norm(np.diff(bigger[:, :2], axis=0), axis=1)
    np.testing.assert_allclose(legs[:6], [10, 10, 20, 20, 30, 30])


def test_pattern_input_errors() -> None:
    with pytest.raises(InvalidInputError, match="spacing_m"):
        lawnmower([(0, 0), (1, 0), (1, 1)], spacing_m=0.0, altitude_m=10.0)
    with pytest.raises(InvalidInputError, match="polygon"):
        lawnmower([(0, 0), (1, 0)], spacing_m=1.0, altitude_m=10.0)
    with pytest.raises(InvalidInputError, match="altitude_m"):
        expanding_square((0.0, 0.0), 10.0, math.nan, max_radius_m=50.0)
    with pytest.raises(InvalidInputError, match="finite"):
        waypoint_list([[0, 0, math.inf]])
    assert waypoint_list([[1, 2, 3]]).shape == (1, 3)


def _hill(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """An 80 m hill at (100, 0) on flat ground at 0 m, 60 m wide."""
    return 80.0 * np.exp(-(((np.asarray(x) - 100.0) ** 2 + np.asarray(y) ** 2) / (2 * 30.0**2)))


def test_follow_terrain_keeps_the_height_above_the_ground_everywhere() -> None:
    # A track straight over the hill at 30 m above home would go through it; following the terrain it clears
    # the ground by at least 40 m everywhere along the flown straight lines, and flies 40 m over flat ground.
    track = np.array([[-100.0, 0.0, 30.0], [300.0, 0.0, 30.0], [300.0, 60.0, 30.0], [-100.0, 60.0, 30.0]])
    flown = follow_terrain(track, _hill, 40.0, max_leg_m=25.0, sample_m=2.0)
    legs = np.linalg.norm(np.diff(flown[:, :2], axis=0), axis=1)
    assert legs.max() <= 25.0 + 1e-9
    for corner in track[:, :2]:  # the pattern's corners are kept
        assert np.min(np.linalg.norm(flown[:, :2] - corner, axis=1)) < 1e-9
    t = np.linspace(0.0, 1.0, 200)[:, None]
    dense = np.concatenate([a + (b - a) * t for a, b in itertools.pairwise(flown)])
    clearance = dense[:, 2] - _hill(dense[:, 0], dense[:, 1])
    assert clearance.min() >= 40.0 - 0.05
    assert flown[0, 2] == pytest.approx(40.0, abs=1e-3)  # the hill is 80 * exp(-22) m there
    assert flown[:, 2].max() > 80.0 + 40.0 - 1.0
    # one waypoint: straight above the ground
    np.testing.assert_allclose(follow_terrain([[100.0, 0.0, 0.0]], _hill, 10.0), [[100.0, 0.0, 90.0]])


def test_follow_terrain_errors() -> None:
    outside = lambda x, y: np.where(np.asarray(x) > 50.0, np.nan, 0.0)  # noqa: E731
    with pytest.raises(InvalidInputError, match="leaves the terrain model at"):
        follow_terrain([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0]], outside, 30.0)
    with pytest.raises(InvalidInputError, match="agl_m"):
        follow_terrain([[0.0, 0.0, 0.0]], _hill, 0.0)
