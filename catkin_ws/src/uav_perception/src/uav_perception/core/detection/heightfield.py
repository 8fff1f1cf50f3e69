"""Height fields in ``map`` and where a ray first meets them (pure numpy).

A :class:`HeightGrid` is a regular grid of heights (metres, ``map`` z) over the x-y plane, laid out
as the map server's ``uav_msgs/GridLayers``: row 0 is the southern-most row, column 0 the
western-most, and cell ``(r, c)`` covers ``[x0 + c res, x0 + (c+1) res) x [y0 + r res, y0 + (r+1) res)``.
NaN is "unknown". Two kinds are read differently:

* ``nearest``: the map server's ``elevation_m`` layer, the highest occupied voxel of each column:
  the cell's value holds over the whole cell (a roof edge stays sharp);
* ``bilinear``: a terrain model (DEM) sampled at cell centres, interpolated between them (the
  terrain is continuous; a DEM's cells are samples, not columns).

:func:`first_hit` marches a ray through a stack of grids, the first grid with a known height at a
point deciding (the live elevation layer over the prior terrain model, say), and refines the first
crossing by bisection.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from uav_perception.errors import DetectionInputError

__all__ = ["HeightGrid", "RayHit", "first_hit"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class HeightGrid:
    """Heights on a regular x-y grid (row 0 = south); NaN = unknown."""

    heights_m: FloatArray
    origin_x_m: float
    origin_y_m: float
    resolution_m: float
    interpolation: Literal["nearest", "bilinear"] = "nearest"
    #: What the grid is, for reports (``elevation``, ``terrain``...).
    name: str = "grid"

    def __post_init__(self) -> None:
        h = np.asarray(self.heights_m, dtype=np.float64)
        if h.ndim != 2 or h.shape[0] < 1 or h.shape[1] < 1:
            msg = f"{self.name}: heights must be a non-empty 2D grid, got shape {h.shape}"
            raise DetectionInputError(msg)
        if not (math.isfinite(self.resolution_m) and self.resolution_m > 0):
            msg = f"{self.name}: resolution_m must be finite and > 0, got {self.resolution_m}"
            raise DetectionInputError(msg)
        if not (math.isfinite(self.origin_x_m) and math.isfinite(self.origin_y_m)):
            msg = f"{self.name}: origin must be finite, got ({self.origin_x_m}, {self.origin_y_m})"
            raise DetectionInputError(msg)
        if self.interpolation == "bilinear" and min(h.shape) < 2:
            msg = f"{self.name}: a bilinear grid needs at least 2x2 samples, got {h.shape}"
            raise DetectionInputError(msg)
        object.__setattr__(self, "heights_m", h)
        finite = h[np.isfinite(h)]
        object.__setattr__(self, "_min_m", float(finite.min()) if finite.size else math.nan)
        object.__setattr__(self, "_max_m", float(finite.max()) if finite.size else math.nan)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.heights_m.shape[0]), int(self.heights_m.shape[1]))

    @property
    def min_height_m(self) -> float:
        """Lowest known height (NaN if none is known)."""
        return float(self._min_m)  # type: ignore[attr-defined]

    @property
    def max_height_m(self) -> float:
        return float(self._max_m)  # type: ignore[attr-defined]

    def at(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike, offset_m: float = 0.0) -> FloatArray:
        """Heights at points ``(x, y)`` (vectorised); NaN outside the grid or where unknown."""
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        rows, cols = self.shape
        fx = (x - self.origin_x_m) / self.resolution_m
        fy = (y - self.origin_y_m) / self.resolution_m
        if self.interpolation == "nearest":
            c = np.floor(fx)
            r = np.floor(fy)
            inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
            ci = np.where(inside, c, 0).astype(np.int64)
            ri = np.where(inside, r, 0).astype(np.int64)
            out = np.where(inside, self.heights_m[ri, ci], np.nan)
            return np.asarray(out + offset_m, dtype=np.float64)
        # bilinear between cell centres (sample k at (k + 0.5) res); the outer half cell is clamped
        sx = np.clip(fx - 0.5, 0.0, cols - 1.0)
        sy = np.clip(fy - 0.5, 0.0, rows - 1.0)
        inside = (fx >= 0) & (fx <= cols) & (fy >= 0) & (fy <= rows)
        c0 = np.minimum(np.floor(sx), cols - 2).astype(np.int64)
        r0 = np.minimum(np.floor(sy), rows - 2).astype(np.int64)
        tx = sx - c0
        ty = sy - r0
        h = self.heights_m
        top = h[r0, c0] * (1 - tx) + h[r0, c0 + 1] * tx
        bottom = h[r0 + 1, c0] * (1 - tx) + h[r0 + 1, c0 + 1] * tx
        out = np.where(inside, top * (1 - ty) + bottom * ty, np.nan)
        return np.asarray(out + offset_m, dtype=np.float64)

    def at_point(self, x_m: float, y_m: float, offset_m: float = 0.0) -> float:
        """:meth:`at` for one point, in plain floats (the same arithmetic, so the same value; a bisection asks
        one point at a time, where numpy's per-call cost is most of the time)."""
        rows, cols = self.shape
        fx = (x_m - self.origin_x_m) / self.resolution_m
        fy = (y_m - self.origin_y_m) / self.resolution_m
        h = self.heights_m
        if self.interpolation == "nearest":
            c = math.floor(fx)
            r = math.floor(fy)
            if not (0 <= c < cols and 0 <= r < rows):
                return math.nan
            return float(h[r, c]) + offset_m
        if not (0.0 <= fx <= cols and 0.0 <= fy <= rows):
            return math.nan
        sx = min(max(fx - 0.5, 0.0), cols - 1.0)
        sy = min(max(fy - 0.5, 0.0), rows - 1.0)
        c0 = min(math.floor(sx), cols - 2)
        r0 = min(math.floor(sy), rows - 2)
        tx = sx - c0
        ty = sy - r0
        top = float(h[r0, c0]) * (1 - tx) + float(h[r0, c0 + 1]) * tx
        bottom = float(h[r0 + 1, c0]) * (1 - tx) + float(h[r0 + 1, c0 + 1]) * tx
        return (top * (1 - ty) + bottom * ty) + offset_m


@dataclass(frozen=True)
class RayHit:
    """Where a ray first meets the stack: distance along the (unit) ray, the point, and which grid."""

    t_m: float
    point_m: tuple[float, float, float]
    grid: int


def _stack_heights(
    grids: Sequence[HeightGrid], x: FloatArray, y: FloatArray, offset_m: float
) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    heights = np.full(x.shape, np.nan)
    which = np.full(x.shape, -1, dtype=np.int64)
    for k, grid in enumerate(grids):
        todo = np.isnan(heights)
        if not todo.any():
            break
        h = grid.at(x[todo], y[todo], offset_m)
        idx = np.flatnonzero(todo)
        known = np.isfinite(h)
        heights[idx[known]] = h[known]
        which[idx[known]] = k
    return heights, which


def _stack_height_at(grids: Sequence[HeightGrid], x_m: float, y_m: float, offset_m: float) -> tuple[float, int]:
    """:func:`_stack_heights` for one point: (height, grid index), NaN and -1 where no grid knows it."""
    for k, grid in enumerate(grids):
        h = grid.at_point(x_m, y_m, offset_m)
        if math.isfinite(h):
            return h, k
    return math.nan, -1


def first_hit(
    origin_m: npt.ArrayLike,
    direction: npt.ArrayLike,
    grids: Sequence[HeightGrid],
    *,
    step_m: float,
    max_range_m: float,
    min_range_m: float = 0.5,
    offset_m: float = 0.0,
) -> RayHit | None:
    """The first point along ``origin + t direction`` (``t`` in ``[min_range_m, max_range_m]``) at or
    below the stack's surface, or ``None``.

    Each sample's height is the first grid's that knows it; samples no grid knows never hit. The first
    sample at or below the surface is refined by bisection against the sample before it (to 1 mm). A ray
    that starts below the surface (the camera inside a column) does not hit.

    Args:
        direction: unit vector (map).
        offset_m: added to every height (the geolocator's sensitivity to height errors).
    """
    o = np.asarray(origin_m, dtype=np.float64)
    d = np.asarray(direction, dtype=np.float64)
    if not grids or not (np.all(np.isfinite(o)) and np.all(np.isfinite(d))):
        return None
    lows = [g.min_height_m for g in grids if math.isfinite(g.min_height_m)]
    highs = [g.max_height_m for g in grids if math.isfinite(g.max_height_m)]
    if not lows:
        return None
    low, high = min(lows) + offset_m, max(highs) + offset_m
    t_end = max_range_m
    if d[2] < 0.0:
        t_end = min(t_end, (o[2] - low) / -d[2] + step_m)  # below the lowest surface nothing more is hit
    elif o[2] > high:
        return None  # level or climbing above every surface
    if t_end < min_range_m:
        return None
    t = np.arange(min_range_m, t_end + step_m, step_m)
    if d[2] < 0.0 and o[2] > high:
        # Samples above the highest surface cannot hit: start one sample before the ray comes down to it (the
        # same samples from there on: the first hit and its bisection are unchanged, in a fraction of the lookups).
        first = math.floor(((o[2] - high) / -d[2] - min_range_m) / step_m) - 1
        t = t[max(0, first) :]
    pts = o[None, :] + t[:, None] * d[None, :]
    h, _ = _stack_heights(grids, pts[:, 0], pts[:, 1], offset_m)
    below = pts[:, 2] <= h  # NaN compares False: unknown never hits
    hits = np.flatnonzero(below)
    if hits.size == 0 or hits[0] == 0:
        return None
    lo, hi = float(t[hits[0] - 1]), float(t[hits[0]])
    ox, oy, oz = (float(v) for v in o)
    dx, dy, dz = (float(v) for v in d)
    for _ in range(max(1, math.ceil(math.log2(max(step_m, 1e-3) / 1e-3)))):
        mid = 0.5 * (lo + hi)
        hm, _ = _stack_height_at(grids, ox + mid * dx, oy + mid * dy, offset_m)
        if oz + mid * dz <= hm:  # NaN compares False, as in the march
            hi = mid
        else:
            lo = mid
    px, py, pz = ox + hi * dx, oy + hi * dy, oz + hi * dz
    _, which = _stack_height_at(grids, px, py, offset_m)
    return RayHit(hi, (px, py, pz), which)
