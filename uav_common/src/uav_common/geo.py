"""WGS-84 geodetic <-> local NED tangent plane around a home position.

Uses the azimuthal equidistant projection that PX4's ``map_projection`` uses, so
positions round-trip to well under a millimetre within the 1 km² worlds we fly,
and agree with what PX4 reports in ``LOCAL_POSITION_NED``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["EARTH_RADIUS_M", "GeoPoint", "LocalProjection"]

EARTH_RADIUS_M = 6_371_000.0


@dataclass(frozen=True)
class GeoPoint:
    """A WGS-84 position; ``alt_amsl_m`` is height above mean sea level."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float


@dataclass(frozen=True)
class LocalProjection:
    """Local NED tangent plane anchored at ``origin`` (usually home)."""

    origin: GeoPoint

    def to_ned(self, point: GeoPoint) -> tuple[float, float, float]:
        """Geodetic point -> ``(north_m, east_m, down_m)`` relative to the origin."""
        lat0 = math.radians(self.origin.lat_deg)
        lon0 = math.radians(self.origin.lon_deg)
        lat = math.radians(point.lat_deg)
        lon = math.radians(point.lon_deg)
        cos_d_lon = math.cos(lon - lon0)
        arg = math.sin(lat0) * math.sin(lat) + math.cos(lat0) * math.cos(lat) * cos_d_lon
        arg = max(-1.0, min(1.0, arg))
        c = math.acos(arg)
        k = 1.0 if abs(c) < 1e-12 else c / math.sin(c)
        north = k * (math.cos(lat0) * math.sin(lat) - math.sin(lat0) * math.cos(lat) * cos_d_lon) * EARTH_RADIUS_M
        east = k * math.cos(lat) * math.sin(lon - lon0) * EARTH_RADIUS_M
        down = self.origin.alt_amsl_m - point.alt_amsl_m
        return north, east, down

    def to_geo(self, north_m: float, east_m: float, down_m: float) -> GeoPoint:
        """Local ``(north, east, down)`` -> geodetic point."""
        lat0 = math.radians(self.origin.lat_deg)
        lon0 = math.radians(self.origin.lon_deg)
        x = north_m / EARTH_RADIUS_M
        y = east_m / EARTH_RADIUS_M
        c = math.hypot(x, y)
        if c < 1e-15:
            lat, lon = lat0, lon0
        else:
            sin_c, cos_c = math.sin(c), math.cos(c)
            lat = math.asin(cos_c * math.sin(lat0) + (x * sin_c * math.cos(lat0)) / c)
            lon = lon0 + math.atan2(y * sin_c, c * math.cos(lat0) * cos_c - x * math.sin(lat0) * sin_c)
        return GeoPoint(math.degrees(lat), math.degrees(lon), self.origin.alt_amsl_m - down_m)
