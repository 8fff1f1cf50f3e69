"""Scripted patterns: lawnmower and expanding square, hand-computed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_autonomy.core.patterns import expanding_square, lawnmower, waypoint_list
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
