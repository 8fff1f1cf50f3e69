"""Feature maps for MCDM goal selection, computed from the map server's 2D layers.

Every array is a layer on one :class:`~uav_autonomy.core.grid_geometry.GridSpec`,
shape ``(height, width)``, ``float32``, indexed ``[row, col]`` (row 0 south). All
features except ``elevation_m`` are scaled to ``[0, 1]`` with 1 the most desirable:

``elevation_m``
    Known surface height, metres ENU (NaN where unknown); used by the planner.
``age``
    ``2 ** (-(now_s - last_seen_s) / half_life_s)``: 1 for a cell seen just now,
    0.5 one half-life later, 0 for a cell never seen. For 3D ``last_seen_s``
    (``(height, width, depth)``) the maximum along each column is taken.
``frontier``
    Boundary cells of the observed region (observed cells with an unobserved
    4-neighbour; outside the grid counts as unobserved, so the observed map edge
    is a boundary), then the Euclidean distance ``d`` to the nearest boundary cell,
    inverted and scaled: ``1 - d / scale``. Boundary cells score 1.
``target``
    Inverted, scaled distance to the target point, or to the nearest point of the
    target polygon (0 inside it). All 0 when no target is set.
``drone``
    Inverted, scaled distance to the drone's current position.
``origin``
    Inverted, scaled distance to home (``home_xy_m``).

Scaling: with ``*_scale_m`` set, ``p = max(0, 1 - d / scale_m)``; with it None the
distance is normalised by its maximum over the grid, ``p = 1 - d / max(d)``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Final

import cv2
import numpy as np
import numpy.typing as npt

from uav_autonomy.core.grid_geometry import FloatGrid, GridSpec
from uav_autonomy.errors import InvalidInputError

__all__ = [
    "ELEVATION",
    "SCORED_FEATURES",
    "FeatureConfig",
    "FeatureEvaluator",
    "FeatureMaps",
    "MapLayers",
    "Target",
    "age_feature",
    "distance_to_point_m",
    "distance_to_polygon_m",
    "frontier_boundary",
    "frontier_feature",
    "invert_scale",
]

ELEVATION: Final = "elevation_m"
SCORED_FEATURES: Final = ("age", "frontier", "target", "drone", "origin")
"""Features in ``[0, 1]`` that take part in the score, in publishing order."""

_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


@dataclass(frozen=True)
class FeatureConfig:
    """Settings of the feature evaluator (section ``features`` of ``config/autonomy.yaml``)."""

    age_half_life_s: float = 60.0
    frontier_scale_m: float | None = None
    distance_scale_m: float | None = None
    home_xy_m: tuple[float, float] = (0.0, 0.0)
    rate_hz: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.rate_hz) and self.rate_hz > 0.0):
            msg = f"rate_hz must be > 0, got {self.rate_hz}"
            raise ValueError(msg)
        if not (math.isfinite(self.age_half_life_s) and self.age_half_life_s > 0.0):
            msg = f"age_half_life_s must be > 0, got {self.age_half_life_s}"
            raise ValueError(msg)
        for name in ("frontier_scale_m", "distance_scale_m"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value > 0.0):
                msg = f"{name} must be > 0 or null (normalise by the grid maximum), got {value}"
                raise ValueError(msg)
        if not all(math.isfinite(v) for v in self.home_xy_m):
            msg = f"home_xy_m must be finite, got {self.home_xy_m}"
            raise ValueError(msg)


@dataclass(frozen=True)
class Target:
    """A search target in ``map`` (ENU): one point, or a polygon of at least 3 vertices.

    ``points_xy_m`` is a tuple of ``(x_m, y_m)``; polygons may be given in either
    winding order and are closed implicitly.
    """

    points_xy_m: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        n = len(self.points_xy_m)
        if n in {0, 2}:
            msg = f"a target is one point or a polygon of >= 3 points, got {n} points"
            raise InvalidInputError(msg)
        for x, y in self.points_xy_m:
            if not (math.isfinite(x) and math.isfinite(y)):
                msg = f"target points must be finite, got ({x}, {y})"
                raise InvalidInputError(msg)

    @property
    def is_point(self) -> bool:
        return len(self.points_xy_m) == 1

    def as_array(self) -> npt.NDArray[np.float64]:
        """``(N, 2)`` float64 vertices, metres ENU."""
        return np.asarray(self.points_xy_m, dtype=np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class MapLayers:
    """The map server's 2D layers on one grid (``/map_server/layers``).

    Attributes:
        spec: the grid.
        elevation_m: ``(H, W)`` float32, known surface height in metres ENU, NaN unknown.
        last_seen_s: ``(H, W)`` or ``(H, W, D)`` float32, time a cell (voxel) was last
            observed, seconds of simulation time; NaN never.
        observed: ``(H, W)`` bool, the cell has been observed.
    """

    spec: GridSpec
    elevation_m: FloatGrid
    last_seen_s: npt.NDArray[np.float32]
    observed: npt.NDArray[np.bool_]

    def __post_init__(self) -> None:
        self.spec.check_layer(ELEVATION, self.elevation_m)
        self.spec.check_layer("last_seen_s", self.last_seen_s)
        self.spec.check_layer("observed", self.observed)
        if self.last_seen_s.ndim not in (2, 3):
            msg = f"last_seen_s must be 2D (H, W) or 3D (H, W, D), got shape {self.last_seen_s.shape}"
            raise InvalidInputError(msg)


@dataclass(frozen=True)
class FeatureMaps:
    """Computed features: ``layers`` maps a name (``elevation_m`` or one of
    :data:`SCORED_FEATURES`) to an ``(H, W)`` float32 array on ``spec``."""

    spec: GridSpec
    layers: Mapping[str, FloatGrid] = field(default_factory=dict)

    def scored(self) -> dict[str, FloatGrid]:
        """Only the features in ``[0, 1]`` (everything but elevation)."""
        return {k: v for k, v in self.layers.items() if k in SCORED_FEATURES}


def age_feature(last_seen_s: npt.NDArray[np.float32], now_s: float, half_life_s: float) -> FloatGrid:
    """Exponential decay of the last-observed time; max along each column for 3D input.

    Args:
        last_seen_s: ``(H, W)`` or ``(H, W, D)`` seconds; NaN = never observed.
        now_s: current (simulation) time, seconds.
        half_life_s: time for the feature to halve, seconds.

    Returns:
        ``(H, W)`` float32 in ``[0, 1]``; 1 seen at ``now_s`` (or later), 0 never seen.
    """
    if not (math.isfinite(now_s) and math.isfinite(half_life_s) and half_life_s > 0.0):
        msg = f"age_feature needs finite now_s and half_life_s > 0, got now_s={now_s}, half_life_s={half_life_s}"
        raise InvalidInputError(msg)
    seen = np.asarray(last_seen_s, dtype=np.float32)
    if seen.ndim == 3:
        # Decay is monotonic in time, so the max of the decay is the decay of the max.
        seen = np.fmax.reduce(seen, axis=2) if seen.shape[2] else np.full(seen.shape[:2], np.nan, np.float32)
    k = math.log(2.0) / half_life_s
    # exp(k * (t - now)) in float32 with the exp in OpenCV (SIMD). Subtracting the
    # float32-rounded now first is exact for nearby times (Sterbenz); the rounding
    # residual is added back as a float64 scalar.
    ref = np.float32(now_s)
    arg = seen - ref
    arg *= np.float32(k)
    arg += np.float32(k * (float(ref) - now_s))
    np.minimum(arg, np.float32(0.0), out=arg)  # seen "in the future" (clock skew) scores 1
    np.exp(arg, out=arg)
    cv2.patchNaNs(arg, 0.0)  # never seen (NaN) scores 0
    return arg


def frontier_boundary(observed: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """Observed cells with an unobserved 4-neighbour; outside the grid is unobserved.

    Args:
        observed: ``(H, W)`` bool.

    Returns:
        ``(H, W)`` bool mask of boundary cells.
    """
    obs_u8 = np.ascontiguousarray(observed, dtype=np.uint8)
    interior = cv2.erode(obs_u8, _CROSS, borderType=cv2.BORDER_CONSTANT, borderValue=(0.0,))
    return np.asarray(obs_u8 > interior)


def invert_scale(distance_m: FloatGrid, scale_m: float | None, max_distance_m: float | None = None) -> FloatGrid:
    """``1 - d / scale`` clipped to ``[0, 1]``; ``scale`` defaults to the maximum distance.

    Args:
        distance_m: ``(H, W)`` float32 metres, >= 0.
        scale_m: distance that maps to 0; None normalises by the maximum.
        max_distance_m: the maximum of ``distance_m`` if the caller knows it already.
    """
    if scale_m is None:
        scale_m = float(distance_m.max()) if max_distance_m is None else max_distance_m
    if scale_m <= 0.0:
        return np.ones_like(distance_m, dtype=np.float32)
    out = distance_m * np.float32(-1.0 / scale_m)
    out += np.float32(1.0)
    np.maximum(out, np.float32(0.0), out=out)
    return out


def frontier_feature(observed: npt.NDArray[np.bool_], resolution_m: float, scale_m: float | None) -> FloatGrid:
    """Inverted, scaled Euclidean distance to the frontier of the observed region.

    Args:
        observed: ``(H, W)`` bool.
        resolution_m: cell size, metres.
        scale_m: distance mapped to 0 (None: the grid's maximum).

    Returns:
        ``(H, W)`` float32 in ``[0, 1]``: 1 on the boundary, less inside and outside.
        With nothing observed yet every cell is unexplored and scores 1.
    """
    boundary = frontier_boundary(observed)
    if not boundary.any():
        return np.ones(observed.shape, dtype=np.float32)
    # OpenCV: distance from each non-zero pixel to the nearest zero pixel; the
    # "precise" mask is the exact Euclidean transform (Felzenszwalb-Huttenlocher).
    src = np.logical_not(boundary).view(np.uint8)
    dist = np.asarray(cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_PRECISE), dtype=np.float32)
    max_m = float(cv2.minMaxLoc(dist)[1]) * resolution_m
    scale = max_m if scale_m is None else scale_m
    if scale <= 0.0:
        return np.ones(observed.shape, dtype=np.float32)
    dist *= np.float32(-resolution_m / scale)  # in place: 1 - d * res / scale
    dist += np.float32(1.0)
    if scale_m is not None:
        np.maximum(dist, np.float32(0.0), out=dist)
    return dist


def distance_to_point_m(spec: GridSpec, x_m: float, y_m: float) -> tuple[FloatGrid, float]:
    """Distance from every cell centre to a point.

    Returns:
        ``(H, W)`` float32 metres, and the maximum distance (at a grid corner).
    """
    dx2 = ((spec.cell_centers_x_m() - x_m) ** 2).astype(np.float32)
    dy2 = ((spec.cell_centers_y_m() - y_m) ** 2).astype(np.float32)
    dist = dy2[:, None] + dx2[None, :]
    np.sqrt(dist, out=dist)
    return dist, float(math.sqrt(float(dx2.max()) + float(dy2.max())))


def distance_to_polygon_m(spec: GridSpec, polygon_xy_m: npt.ArrayLike) -> FloatGrid:
    """Distance from every cell centre to the nearest point of a polygon (0 inside).

    Exact for any simple polygon, also when it lies partly or wholly outside the
    grid. Cost is one vectorised pass over the grid per edge.

    Args:
        spec: the grid.
        polygon_xy_m: ``(N, 2)`` vertices, metres ENU, N >= 3.

    Returns:
        ``(H, W)`` float32 metres.
    """
    poly = np.asarray(polygon_xy_m, dtype=np.float64).reshape(-1, 2)
    if poly.shape[0] < 3 or not np.isfinite(poly).all():
        msg = f"polygon needs >= 3 finite vertices, got {poly.tolist()}"
        raise InvalidInputError(msg)
    px = spec.cell_centers_x_m()[None, :]
    py = spec.cell_centers_y_m()[:, None]
    best_sq = np.full(spec.shape, np.inf, dtype=np.float64)
    inside = np.zeros(spec.shape, dtype=bool)
    for i in range(poly.shape[0]):
        ax, ay = poly[i]
        bx, by = poly[(i + 1) % poly.shape[0]]
        ex, ey = bx - ax, by - ay
        length_sq = ex * ex + ey * ey
        if length_sq > 0.0:
            t = ((px - ax) * ex + (py - ay) * ey) / length_sq
            np.clip(t, 0.0, 1.0, out=t)
        else:
            t = np.zeros(spec.shape)
        d_sq = (px - (ax + t * ex)) ** 2 + (py - (ay + t * ey)) ** 2
        np.minimum(best_sq, d_sq, out=best_sq)
        # Crossing number: edges straddling the horizontal line through the cell.
        if ay != by:
            straddles = (ay > py) != (by > py)  # (H, 1)
            x_cross = ax + (py - ay) * ex / (by - ay)  # (H, 1)
            inside ^= straddles & (px < x_cross)
    best_sq[inside] = 0.0
    return np.sqrt(best_sq).astype(np.float32)


class FeatureEvaluator:
    """Computes :class:`FeatureMaps` from :class:`MapLayers`; caches the static layers.

    The target-distance and origin-distance layers depend only on the grid and the
    target, so they are recomputed only when either changes. The evaluator holds
    no clock: time is passed to :meth:`evaluate`.
    """

    def __init__(self, config: FeatureConfig) -> None:
        self.config = config
        self._target_cache: tuple[GridSpec, Target | None, FloatGrid] | None = None
        self._origin_cache: tuple[GridSpec, FloatGrid] | None = None

    def evaluate(
        self,
        layers: MapLayers,
        *,
        now_s: float,
        drone_xy_m: tuple[float, float] | None,
        target: Target | None,
    ) -> FeatureMaps:
        """All features on ``layers.spec``.

        Args:
            layers: the map server's layers.
            now_s: current simulation time, seconds.
            drone_xy_m: drone position (ENU metres); None before the first pose,
                in which case the drone feature is 0 everywhere.
            target: the target, or None (target feature 0 everywhere).

        Raises:
            InvalidInputError: non-finite time or drone position.
        """
        if drone_xy_m is not None and not all(math.isfinite(v) for v in drone_xy_m):
            msg = f"drone position must be finite, got {drone_xy_m}"
            raise InvalidInputError(msg)
        spec = layers.spec
        cfg = self.config
        out: dict[str, FloatGrid] = {ELEVATION: np.asarray(layers.elevation_m, dtype=np.float32)}
        out["age"] = age_feature(layers.last_seen_s, now_s, cfg.age_half_life_s)
        out["frontier"] = frontier_feature(layers.observed, spec.resolution_m, cfg.frontier_scale_m)
        out["target"] = self._target_layer(spec, target)
        if drone_xy_m is None:
            out["drone"] = np.zeros(spec.shape, dtype=np.float32)
        else:
            dist, dmax = distance_to_point_m(spec, drone_xy_m[0], drone_xy_m[1])
            out["drone"] = invert_scale(dist, cfg.distance_scale_m, dmax)
        out["origin"] = self._origin_layer(spec)
        return FeatureMaps(spec=spec, layers=out)

    def _target_layer(self, spec: GridSpec, target: Target | None) -> FloatGrid:
        cached = self._target_cache
        if cached is not None and cached[0] == spec and cached[1] == target:
            return cached[2]
        if target is None:
            layer = np.zeros(spec.shape, dtype=np.float32)
        elif target.is_point:
            x, y = target.points_xy_m[0]
            dist, dmax = distance_to_point_m(spec, x, y)
            layer = invert_scale(dist, self.config.distance_scale_m, dmax)
        else:
            layer = invert_scale(distance_to_polygon_m(spec, target.as_array()), self.config.distance_scale_m)
        layer.flags.writeable = False
        self._target_cache = (spec, target, layer)
        return layer

    def _origin_layer(self, spec: GridSpec) -> FloatGrid:
        cached = self._origin_cache
        if cached is not None and cached[0] == spec:
            return cached[1]
        hx, hy = self.config.home_xy_m
        dist, dmax = distance_to_point_m(spec, hx, hy)
        layer = invert_scale(dist, self.config.distance_scale_m, dmax)
        layer.flags.writeable = False
        self._origin_cache = (spec, layer)
        return layer
