from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from uav_common.geo import GeoPoint, LocalProjection

HOME = GeoPoint(47.397742, 8.545594, 488.0)


def test_one_degree_of_latitude_is_about_111_km() -> None:
    proj = LocalProjection(HOME)
    north, east, down = proj.to_ned(GeoPoint(HOME.lat_deg + 1.0, HOME.lon_deg, HOME.alt_amsl_m - 10.0))
    assert north == pytest.approx(111_195, rel=1e-3)
    assert abs(east) < 1e-6
    assert down == pytest.approx(10.0)


@given(st.floats(-2000, 2000), st.floats(-2000, 2000), st.floats(-500, 100))
def test_round_trip_submillimetre(north: float, east: float, down: float) -> None:
    proj = LocalProjection(HOME)
    back = proj.to_ned(proj.to_geo(north, east, down))
    assert math.dist(back, (north, east, down)) < 1e-3
