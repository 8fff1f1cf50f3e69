"""Scripted flight patterns as ENU waypoint arrays: waypoint list, lawnmower, expanding square,
and terrain following.

All patterns return ``(N, 3)`` float64 waypoints in ``map`` (ENU, metres); z is the
flight altitude relative to home (the same datum as the DEM), constant over the
pattern unless the waypoints say otherwise. :func:`follow_terrain` turns a pattern
into one flown a fixed height above a prior terrain model (what a ground station's
survey does in its terrain frame with SRTM tiles).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from uav_autonomy.core.geometry2d import as_polygon
from uav_autonomy.errors import InvalidInputError
from uav_common.validate import require_finite, require_positive

__all__ = ["expanding_square", "follow_terrain", "lawnmower", "waypoint_list"]

PathArray = npt.NDArray[np.float64]


def waypoint_list(points_enu_m: npt.ArrayLike) -> PathArray:
    """Validate an explicit ``(N, 3)`` list of ENU waypoints (N >= 1, all finite)."""
    try:
        pts = np.asarray(points_enu_m, dtype=np.float64).reshape(-1, 3)
    except (TypeError, ValueError) as err:
        msg = f"waypoints must be a list of [x, y, z], got {points_enu_m!r}"
        raise InvalidInputError(msg) from err
    if pts.shape[0] == 0 or not np.isfinite(pts).all():
        msg = f"waypoints must be >= 1 finite [x, y, z] points, got {pts.tolist()}"
        raise InvalidInputError(msg)
    return pts


def lawnmower(
    polygon_xy_m: npt.ArrayLike, spacing_m: float, altitude_m: float, *, sweep_heading_rad: float | None = None
) -> PathArray:
    """Boustrophedon (parallel-track) coverage of a polygon.

    Tracks run parallel to ``sweep_heading_rad`` (ENU yaw of the track direction;
    default: the polygon's longest edge), ``spacing_m`` apart, the first half a
    spacing in from the polygon's edge (IAMSAR parallel sweep). Consecutive tracks
    alternate direction. For a non-convex polygon a track may have several
    inside pieces; each is flown, and transits between pieces may leave it.

    Returns:
        ``(N, 3)`` ENU waypoints at ``altitude_m``: the two ends of each track piece.

    Raises:
        InvalidInputError: a degenerate polygon, non-positive spacing, NaN inputs.
    """
    poly = as_polygon(polygon_xy_m, "lawnmower polygon")
    require_positive("spacing_m", spacing_m, error=InvalidInputError)
    require_finite("altitude_m", altitude_m, error=InvalidInputError)
    if sweep_heading_rad is None:
        edges = np.roll(poly, -1, axis=0) - poly
        longest = edges[int(np.argmax(np.hypot(edges[:, 0], edges[:, 1])))]
        sweep_heading_rad = math.atan2(longest[1], longest[0])
    require_finite("sweep_heading_rad", sweep_heading_rad, error=InvalidInputError)
    c, s = math.cos(sweep_heading_rad), math.sin(sweep_heading_rad)
    # Rotate into a frame whose u axis runs along the tracks and v across them.
    rot = np.array([[c, s], [-s, c]])
    local = poly @ rot.T
    v_min, v_max = float(local[:, 1].min()), float(local[:, 1].max())
    if v_max - v_min <= 0.0:
        msg = "lawnmower polygon has zero width across the sweep direction"
        raise InvalidInputError(msg)
    n_tracks = max(1, math.ceil((v_max - v_min) / spacing_m))
    offsets = v_min + (np.arange(n_tracks) + 0.5) * ((v_max - v_min) / n_tracks)
    waypoints: list[tuple[float, float]] = []
    n = local.shape[0]
    for t, v in enumerate(offsets):
        crossings = []
        for i in range(n):
            (u0, v0), (u1, v1) = local[i], local[(i + 1) % n]
            if (v0 > v) != (v1 > v):
                crossings.append(u0 + (v - v0) * (u1 - u0) / (v1 - v0))
        crossings.sort()
        pieces = [(crossings[k], crossings[k + 1]) for k in range(0, len(crossings) - 1, 2)]
        if t % 2 == 1:
            pieces = [(b, a) for a, b in reversed(pieces)]
        for a, b in pieces:
            waypoints.extend([(a, float(v)), (b, float(v))])
    if not waypoints:
        msg = "lawnmower produced no tracks for this polygon"
        raise InvalidInputError(msg)
    xy = np.asarray(waypoints) @ rot  # back to ENU (rot is orthonormal)
    return np.column_stack([xy, np.full(len(xy), float(altitude_m))])


def expanding_square(
    center_xy_m: tuple[float, float],
    spacing_m: float,
    altitude_m: float,
    *,
    max_radius_m: float,
    first_heading_rad: float = math.pi / 2.0,
) -> PathArray:
    """IAMSAR expanding-square search from a datum.

    Legs of length ``S, S, 2S, 2S, 3S, 3S, ...`` (``S = spacing_m``), each turning
    90 degrees to the right (clockwise seen from above), the first along
    ``first_heading_rad`` (ENU yaw; default north). Stops once a leg would end
    farther than ``max_radius_m`` from the datum (in either axis).

    Returns:
        ``(N, 3)`` ENU waypoints at ``altitude_m``, starting at the datum.
    """
    require_positive("spacing_m", spacing_m, error=InvalidInputError)
    require_positive("max_radius_m", max_radius_m, error=InvalidInputError)
    require_finite("altitude_m", altitude_m, error=InvalidInputError)
    require_finite("first_heading_rad", first_heading_rad, error=InvalidInputError)
    cx, cy = center_xy_m
    require_finite("center x", cx, error=InvalidInputError)
    require_finite("center y", cy, error=InvalidInputError)
    x, y = cx, cy
    heading = first_heading_rad
    pts = [(x, y)]
    leg = 0
    while True:
        length = spacing_m * (leg // 2 + 1)
        nx = x + length * math.cos(heading)
        ny = y + length * math.sin(heading)
        if max(abs(nx - cx), abs(ny - cy)) > max_radius_m + 1e-9:
            break
        x, y = nx, ny
        pts.append((x, y))
        heading -= math.pi / 2.0  # right turn in ENU (clockwise)
        leg += 1
    if len(pts) < 2:
        msg = f"max_radius_m {max_radius_m} is smaller than the first leg ({spacing_m} m)"
        raise InvalidInputError(msg)
    xy = np.asarray(pts, dtype=np.float64)
    return np.column_stack([xy, np.full(len(xy), float(altitude_m))])


def follow_terrain(
    waypoints_enu_m: npt.ArrayLike,
    ground_m: Callable[[npt.NDArray[np.float64], npt.NDArray[np.float64]], npt.ArrayLike],
    agl_m: float,
    *,
    max_leg_m: float = 25.0,
    sample_m: float = 2.0,
) -> PathArray:
    """The same track flown ``agl_m`` above the ground (the waypoints' z are replaced).

    Legs longer than ``max_leg_m`` are split evenly. Each waypoint's z is the highest ground
    under the legs on either side of it (``ground_m(x, y)``, vectorised, metres above home,
    sampled every ``sample_m`` or closer) plus ``agl_m``: both ends of every leg are at least
    ``agl_m`` above the highest ground under it, so the straight line between them is too
    (up to the sampling).

    Raises:
        InvalidInputError: bad waypoints or parameters, or the track leaves the terrain model
            (``ground_m`` is NaN somewhere under it).
    """
    wp = waypoint_list(waypoints_enu_m)
    require_positive("agl_m", agl_m, error=InvalidInputError)
    require_positive("max_leg_m", max_leg_m, error=InvalidInputError)
    require_positive("sample_m", sample_m, error=InvalidInputError)
    xy = [wp[0, :2]]
    for a, b in zip(wp[:-1, :2], wp[1:, :2], strict=True):
        pieces = max(1, math.ceil(float(np.linalg.norm(b - a)) / max_leg_m))
        xy.extend(a + (b - a) * (k / pieces) for k in range(1, pieces + 1))
    track = np.asarray(xy, dtype=np.float64)
    # the ground under each leg (a lone waypoint: under the point itself)
    legs = [(track[i], track[i + 1]) for i in range(len(track) - 1)] or [(track[0], track[0])]
    leg_top = np.empty(len(legs), dtype=np.float64)
    for i, (a, b) in enumerate(legs):
        n = max(2, math.ceil(float(np.linalg.norm(b - a)) / sample_m) + 1)
        pts = a + (b - a) * np.linspace(0.0, 1.0, n)[:, None]
        ground = np.asarray(ground_m(pts[:, 0], pts[:, 1]), dtype=np.float64).reshape(-1)
        if not np.isfinite(ground).all():
            bad = pts[int(np.argmax(~np.isfinite(ground)))]
            msg = f"the track leaves the terrain model at ({bad[0]:.1f}, {bad[1]:.1f}) m; keep the pattern in the world"
            raise InvalidInputError(msg)
        leg_top[i] = float(ground.max())
    if len(track) == 1:
        return np.column_stack([track, leg_top + agl_m])
    before = np.concatenate([leg_top[:1], leg_top])
    after = np.concatenate([leg_top, leg_top[-1:]])
    return np.column_stack([track, np.maximum(before, after) + agl_m])
