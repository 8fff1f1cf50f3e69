"""Uploaded geofences (MAVLink mission type 1): inclusion/exclusion polygons and circles, and the breach test.

The fence is uploaded, downloaded and cleared with the mission protocol (``mission_type`` FENCE), as
PX4 and ArduPilot store it and as MAVSDK's Geofence and MissionRaw plugins and QGC send it:

* ``NAV_FENCE_POLYGON_VERTEX_INCLUSION`` / ``_EXCLUSION`` (5001/5002): one item per vertex, ``param1`` =
  the polygon's vertex count (the same on each of its vertices, at least 3), ``x``/``y`` the vertex;
* ``NAV_FENCE_CIRCLE_INCLUSION`` / ``_EXCLUSION`` (5003/5004): ``param1`` = radius (m), ``x``/``y`` the centre.

The vehicle breaches the fence when it is outside any inclusion zone or inside any exclusion zone
(the fence's altitude limits are the parameters', not the items'). Positions are LOCAL_NED metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from sitl.core.mission import GLOBAL_FRAMES, RELATIVE_FRAMES, MissionItem
from sitl.core.protocol import MavCmd, MavMissionResult
from uav_common.geo import GeoPoint, LocalProjection

__all__ = ["FENCE_COMMANDS", "Fence", "FenceStore", "validate_fence_item"]

FENCE_COMMANDS = frozenset(
    {
        MavCmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION,
        MavCmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
        MavCmd.NAV_FENCE_CIRCLE_INCLUSION,
        MavCmd.NAV_FENCE_CIRCLE_EXCLUSION,
    }
)
_POLYGON = frozenset({MavCmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION, MavCmd.NAV_FENCE_POLYGON_VERTEX_EXCLUSION})
_INCLUSION = frozenset({MavCmd.NAV_FENCE_POLYGON_VERTEX_INCLUSION, MavCmd.NAV_FENCE_CIRCLE_INCLUSION})
MAX_FENCE_ITEMS = 500

Point2 = tuple[float, float]


def validate_fence_item(item: MissionItem) -> MavMissionResult:  # noqa: PLR0911 - one return per check
    """``ACCEPTED`` or why one fence item is refused."""
    if item.command not in FENCE_COMMANDS:
        return MavMissionResult.UNSUPPORTED
    if item.frame not in GLOBAL_FRAMES and item.frame not in RELATIVE_FRAMES:
        return MavMissionResult.UNSUPPORTED_FRAME
    if not math.isfinite(item.param1):
        return MavMissionResult.INVALID_PARAM1
    if item.command in _POLYGON:
        if item.param1 < 3 or item.param1 != int(item.param1):
            return MavMissionResult.INVALID_PARAM1
    elif item.param1 <= 0.0:
        return MavMissionResult.INVALID_PARAM1
    if not -900_000_000 <= item.x <= 900_000_000:
        return MavMissionResult.INVALID_PARAM5_X
    if not -1_800_000_000 <= item.y <= 1_800_000_000:
        return MavMissionResult.INVALID_PARAM6_Y
    return MavMissionResult.ACCEPTED


@dataclass(frozen=True)
class _Polygon:
    inclusion: bool
    vertices: tuple[Point2, ...]

    def contains(self, n: float, e: float) -> bool:
        """Even-odd ray casting."""
        inside = False
        verts = self.vertices
        j = len(verts) - 1
        for i, (ni, ei) in enumerate(verts):
            nj, ej = verts[j]
            if (ei > e) != (ej > e):
                cross_n = ni + (e - ei) * (nj - ni) / (ej - ei)
                if n < cross_n:
                    inside = not inside
            j = i
        return inside


@dataclass(frozen=True)
class _Circle:
    inclusion: bool
    centre: Point2
    radius_m: float

    def contains(self, n: float, e: float) -> bool:
        return math.hypot(n - self.centre[0], e - self.centre[1]) <= self.radius_m


@dataclass(frozen=True)
class Fence:
    """The uploaded zones in LOCAL_NED."""

    polygons: tuple[_Polygon, ...] = ()
    circles: tuple[_Circle, ...] = ()

    @property
    def empty(self) -> bool:
        return not self.polygons and not self.circles

    def breach(self, n: float, e: float) -> str | None:
        """``None`` inside the allowed area, else what is breached (for STATUSTEXT)."""
        zones: tuple[_Polygon | _Circle, ...] = (*self.polygons, *self.circles)
        for i, zone in enumerate(zones):
            kind = "polygon" if isinstance(zone, _Polygon) else "circle"
            inside = zone.contains(n, e)
            if zone.inclusion and not inside:
                return f"outside inclusion {kind} {i + 1}"
            if not zone.inclusion and inside:
                return f"inside exclusion {kind} {i + 1}"
        return None


def _build(items: tuple[MissionItem, ...], projection: LocalProjection) -> Fence | MavMissionResult:
    polygons: list[_Polygon] = []
    circles: list[_Circle] = []
    alt = projection.origin.alt_amsl_m
    i = 0
    while i < len(items):
        item = items[i]
        n, e, _ = projection.to_ned(GeoPoint(item.x * 1e-7, item.y * 1e-7, alt))
        if item.command in _POLYGON:
            count = int(item.param1)
            group = items[i : i + count]
            if len(group) < count or any(g.command != item.command or int(g.param1) != count for g in group):
                return MavMissionResult.INVALID_PARAM1
            verts = tuple(projection.to_ned(GeoPoint(g.x * 1e-7, g.y * 1e-7, alt))[:2] for g in group)
            polygons.append(_Polygon(item.command in _INCLUSION, verts))
            i += count
            continue
        circles.append(_Circle(item.command in _INCLUSION, (n, e), item.param1))
        i += 1
    return Fence(tuple(polygons), tuple(circles))


class FenceStore:
    """The uploaded fence (mission type 1): items as uploaded, and the zones they describe."""

    def __init__(self, projection: LocalProjection) -> None:
        self._projection = projection
        self._items: tuple[MissionItem, ...] = ()
        self.fence = Fence()
        self.mission_id = 0

    @property
    def items(self) -> tuple[MissionItem, ...]:
        return self._items

    def __len__(self) -> int:
        return len(self._items)

    def check(self, items: tuple[MissionItem, ...]) -> MavMissionResult:
        """Whether a complete upload describes valid zones (polygons with their vertex counts)."""
        built = _build(items, self._projection)
        return built if isinstance(built, MavMissionResult) else MavMissionResult.ACCEPTED

    def replace(self, items: tuple[MissionItem, ...]) -> None:
        items = tuple(replace(it, seq=i, current=0) for i, it in enumerate(items))
        built = _build(items, self._projection)
        if isinstance(built, MavMissionResult):  # check() refused it first; never store half a fence
            return
        self._items = items
        self.fence = built
        self.mission_id = (self.mission_id + 1) & 0xFFFFFFFF

    def clear(self) -> None:
        self.replace(())
