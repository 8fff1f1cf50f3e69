"""Small vectorised 2D geometry helpers: point-in-polygon and polygon validation."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from uav_autonomy.errors import InvalidInputError

__all__ = ["as_polygon", "points_in_polygon", "segment_samples"]


def as_polygon(points: object, name: str) -> npt.NDArray[np.float64]:
    """``(N, 2)`` float64 vertices from a sequence of ``(x, y)``; N >= 3, all finite.

    Raises:
        InvalidInputError: fewer than 3 vertices or non-finite coordinates.
    """
    try:
        poly = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    except (TypeError, ValueError) as err:
        msg = f"{name}: expected a list of [x, y] vertices, got {points!r}"
        raise InvalidInputError(msg) from err
    if poly.shape[0] < 3 or not np.isfinite(poly).all():
        msg = f"{name}: a polygon needs >= 3 finite [x, y] vertices, got {poly.tolist()}"
        raise InvalidInputError(msg)
    return poly


def points_in_polygon(xy_m: npt.ArrayLike, polygon: npt.NDArray[np.float64]) -> npt.NDArray[np.bool_]:
    """Crossing-number test of ``(..., 2)`` points against an ``(N, 2)`` polygon.

    Returns:
        bool array of shape ``(...)``; points exactly on an edge may go either way.
    """
    pts = np.asarray(xy_m, dtype=np.float64)
    px, py = pts[..., 0], pts[..., 1]
    inside = np.zeros(px.shape, dtype=bool)
    n = polygon.shape[0]
    for i in range(n):
        ax, ay = polygon[i]
        bx, by = polygon[(i + 1) % n]
        if ay == by:
            continue
        straddles = (ay > py) != (by > py)
        x_cross = ax + (py - ay) * (bx - ax) / (by - ay)
        inside ^= straddles & (px < x_cross)
    return inside


def segment_samples(a_xy: tuple[float, float], b_xy: tuple[float, float], step_m: float) -> npt.NDArray[np.float64]:
    """``(K, 2)`` points from ``a`` to ``b`` inclusive, at most ``step_m`` apart."""
    length = math.dist(a_xy, b_xy)
    k = max(2, math.ceil(length / step_m) + 1)
    t = np.linspace(0.0, 1.0, k)[:, None]
    a = np.asarray(a_xy, dtype=np.float64)
    out: npt.NDArray[np.float64] = a + t * (np.asarray(b_xy, dtype=np.float64) - a)
    return out
