"""Path planning over the known elevation (DEM) of the map: straight-line and 3D A*.

Paths are ``(N, 3)`` float64 arrays of waypoints in ``map`` (ENU, metres; z is
height above home, the same datum as the DEM's ``elevation_m``). The first
waypoint is the start, the last the goal.

*Straight-line planner* (:func:`plan_straight`): climb vertically to a cruise
altitude, cruise to above the goal, descend to the goal altitude. The goal
altitude is ``goal_height_m`` (default 50 m) above the known elevation at the
goal; the cruise altitude is the highest known elevation along the segment plus
``cruise_buffer_m``, and never below the goal altitude or the start altitude (the
drone does not descend before cruising).

*3D planner* (:func:`plan_astar`): A* over a voxel grid derived from the DEM at
``voxel_xy_m`` x ``voxel_z_m`` resolution (voxels are boxes centred on ``min_altitude_m + k*voxel_z_m``).
A voxel is free if its bottom is at least ``clearance_m`` above the highest known surface in its column and the eight
around it (so straight moves between voxel centres keep the clearance too), between
``min_altitude_m`` and ``max_altitude_m``, inside the geofence and outside every
no-fly polygon. Columns with no known elevation are free (``unknown_space:
free``, with the surface assumed at ``unknown_elevation_m``) or blocked
(``unknown_space: occupied``). 26-connected moves with metric costs, Euclidean
heuristic (weighted by ``heuristic_weight`` >= 1 for a bounded-suboptimal, faster
search), then line-of-sight shortcutting of the voxel path.
"""

from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from uav_autonomy.core.geometry2d import as_polygon, points_in_polygon, segment_samples
from uav_autonomy.core.grid_geometry import FloatGrid, GridSpec
from uav_autonomy.errors import InvalidInputError, NoPathError, PlanningError
from uav_common.validate import require_finite_vector

__all__ = [
    "ElevationMap",
    "PlannerConfig",
    "VoxelGrid",
    "build_voxels",
    "dem_conflict_m",
    "dilate3",
    "goal_altitude_m",
    "max_elevation_along_m",
    "pad_grid",
    "path_conflict_m",
    "plan",
    "plan_astar",
    "plan_straight",
    "remaining_path",
    "search_voxels",
]

PathArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PlannerConfig:
    """Settings of the path planner (section ``planner`` of ``config/autonomy.yaml``)."""

    algorithm: Literal["straight", "astar"] = "straight"
    voxel_source: Literal["octomap", "dem"] = "octomap"
    cruise_buffer_m: float = 50.0
    goal_height_m: float = 50.0
    unknown_elevation_m: float = 0.0
    min_altitude_m: float = 5.0
    max_altitude_m: float = 150.0
    clearance_m: float = 15.0
    voxel_xy_m: float = 10.0
    voxel_z_m: float = 5.0
    unknown_space: Literal["free", "occupied"] = "free"
    geofence_xy_m: tuple[tuple[float, float], ...] = ()
    no_fly_zones_xy_m: tuple[tuple[tuple[float, float], ...], ...] = ()
    heuristic_weight: float = 1.5
    max_expansions: int = 400_000
    domain_margin_m: float = 50.0
    replan_distance_m: float = 2.0
    map_check_period_s: float = 1.0

    def __post_init__(self) -> None:
        for name in (
            "cruise_buffer_m",
            "goal_height_m",
            "clearance_m",
            "domain_margin_m",
            "replan_distance_m",
            "map_check_period_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                msg = f"{name} must be a finite number >= 0, got {value}"
                raise ValueError(msg)
        for name in ("voxel_xy_m", "voxel_z_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f"{name} must be > 0, got {value}"
                raise ValueError(msg)
        if not (self.min_altitude_m < self.max_altitude_m):
            msg = f"min_altitude_m ({self.min_altitude_m}) must be below max_altitude_m ({self.max_altitude_m})"
            raise ValueError(msg)
        if not self.heuristic_weight >= 1.0:
            msg = f"heuristic_weight must be >= 1 (1 = optimal A*), got {self.heuristic_weight}"
            raise ValueError(msg)
        if self.max_expansions < 1:
            msg = f"max_expansions must be >= 1, got {self.max_expansions}"
            raise ValueError(msg)
        try:
            if self.geofence_xy_m:
                as_polygon(self.geofence_xy_m, "geofence_xy_m")
            for i, zone in enumerate(self.no_fly_zones_xy_m):
                as_polygon(zone, f"no_fly_zones_xy_m[{i}]")
        except InvalidInputError as err:
            raise ValueError(str(err)) from err


@dataclass(frozen=True)
class ElevationMap:
    """Known surface height: ``elevation_m`` ``(H, W)`` float32 metres ENU on ``spec``, NaN unknown."""

    spec: GridSpec
    elevation_m: FloatGrid

    def __post_init__(self) -> None:
        self.spec.check_layer("elevation_m", self.elevation_m)

    def at(self, x_m: float, y_m: float) -> float:
        """Known elevation at a point (NaN if unknown or off the grid)."""
        cell = self.spec.cell_of(x_m, y_m)
        return math.nan if cell is None else float(self.elevation_m[cell])


def max_elevation_along_m(dem: ElevationMap, a_xy: tuple[float, float], b_xy: tuple[float, float]) -> float:
    """Highest known elevation of the cells the segment ``a -> b`` crosses (NaN if none known).

    Samples every quarter cell, so no crossed cell is missed by more than a corner.
    """
    pts = segment_samples(a_xy, b_xy, dem.spec.resolution_m * 0.25)
    rows, cols, inside = dem.spec.cells_of(pts)
    if not inside.any():
        return math.nan
    values = dem.elevation_m[rows[inside], cols[inside]]
    known = values[np.isfinite(values)]
    return float(known.max()) if known.size else math.nan


def goal_altitude_m(dem: ElevationMap, goal_xy: tuple[float, float], config: PlannerConfig) -> float:
    """``goal_height_m`` above the known elevation at the goal (``unknown_elevation_m`` if unknown)."""
    elev = dem.at(*goal_xy)
    if math.isnan(elev):
        elev = config.unknown_elevation_m
    return elev + config.goal_height_m


def _check_airspace(points_xy: npt.NDArray[np.float64], config: PlannerConfig) -> None:
    if config.geofence_xy_m:
        fence = as_polygon(config.geofence_xy_m, "geofence_xy_m")
        if not points_in_polygon(points_xy, fence).all():
            msg = "the straight path leaves the geofence; use the 3D planner (algorithm: astar)"
            raise NoPathError(msg)
    for i, zone in enumerate(config.no_fly_zones_xy_m):
        if points_in_polygon(points_xy, as_polygon(zone, f"no_fly_zones_xy_m[{i}]")).any():
            msg = f"the straight path crosses no-fly zone {i}; use the 3D planner (algorithm: astar)"
            raise NoPathError(msg)


def plan_straight(
    start_enu: tuple[float, float, float], goal_xy: tuple[float, float], dem: ElevationMap, config: PlannerConfig
) -> PathArray:
    """Climb-cruise-descend path from ``start_enu`` to above ``goal_xy``.

    Returns:
        ``(N, 3)`` float64 ENU waypoints, N <= 4 (duplicates dropped).

    Raises:
        InvalidInputError: non-finite start or goal.
        NoPathError: the segment leaves the geofence or enters a no-fly zone, or
            the cruise altitude exceeds ``max_altitude_m``.
    """
    require_finite_vector("start", start_enu, len(start_enu), error=InvalidInputError)
    require_finite_vector("goal", goal_xy, len(goal_xy), error=InvalidInputError)
    sx, sy, sz = start_enu
    goal_z = goal_altitude_m(dem, goal_xy, config)
    highest = max_elevation_along_m(dem, (sx, sy), goal_xy)
    if math.isnan(highest):
        highest = config.unknown_elevation_m
    cruise_z = max(highest + config.cruise_buffer_m, goal_z, sz)
    if cruise_z > config.max_altitude_m:
        msg = (
            f"straight path needs cruise altitude {cruise_z:.1f} m > max_altitude_m {config.max_altitude_m:.1f} m "
            f"(highest known elevation {highest:.1f} m + buffer {config.cruise_buffer_m:.1f} m)"
        )
        raise NoPathError(msg)
    _check_airspace(segment_samples((sx, sy), goal_xy, max(dem.spec.resolution_m, 1.0)), config)
    raw = [(sx, sy, sz), (sx, sy, cruise_z), (goal_xy[0], goal_xy[1], cruise_z), (goal_xy[0], goal_xy[1], goal_z)]
    out = [raw[0]]
    for p in raw[1:]:
        if math.dist(p, out[-1]) > 1e-6:
            out.append(p)
    return np.asarray(out, dtype=np.float64)


@dataclass(frozen=True)
class VoxelGrid:
    """Padded planning voxels: ``free[z, y, x]`` with a blocked 1-voxel border.

    Unpadded voxel ``(k, j, i)`` (padded ``(k+1, j+1, i+1)``) covers ``x`` in ``[x0 + i*res_xy, x0 + (i+1)*res_xy)``,
    the same in ``y``, and ``z`` within half a ``res_z`` of its centre ``z0 + k*res_z``.

    Attributes:
        free: where the search may go (clear of obstacles, inside the airspace, known enough).
        hazard: voxels too close to a known obstacle (occupied space or a known surface, with the
            clearance); what a path planned earlier must not cross after the map grew. Same shape.
    """

    free: npt.NDArray[np.bool_]
    hazard: npt.NDArray[np.bool_]
    x0_m: float
    y0_m: float
    z0_m: float
    res_xy_m: float
    res_z_m: float

    def center(self, k: int, j: int, i: int) -> tuple[float, float, float]:
        return (
            self.x0_m + (i - 0.5) * self.res_xy_m,
            self.y0_m + (j - 0.5) * self.res_xy_m,
            self.z0_m + (k - 1) * self.res_z_m,
        )

    def index_of(self, x: float, y: float, z: float) -> tuple[int, int, int]:
        """Padded index of the voxel holding a point, clamped into the unpadded grid."""
        nz, ny, nx = self.free.shape
        i = min(max(math.floor((x - self.x0_m) / self.res_xy_m) + 1, 1), nx - 2)
        j = min(max(math.floor((y - self.y0_m) / self.res_xy_m) + 1, 1), ny - 2)
        k = min(max(round((z - self.z0_m) / self.res_z_m) + 1, 1), nz - 2)
        return k, j, i

    def sample_indices(
        self, a: tuple[float, float, float], b: tuple[float, float, float]
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
        """Padded voxels ``(k, j, i)`` holding points every half voxel along ``a -> b``.

        Indices may fall outside the array (the caller decides what outside means).
        """
        length = math.dist(a, b)
        n = max(2, math.ceil(length / (0.5 * min(self.res_xy_m, self.res_z_m))) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        pts = np.asarray(a) + t * (np.asarray(b) - np.asarray(a))
        i = np.floor((pts[:, 0] - self.x0_m) / self.res_xy_m).astype(np.int64) + 1
        j = np.floor((pts[:, 1] - self.y0_m) / self.res_xy_m).astype(np.int64) + 1
        k = np.floor((pts[:, 2] - self.z0_m) / self.res_z_m + 0.5).astype(np.int64) + 1
        return k, j, i


def _surface_on_blocks(
    dem: ElevationMap, origin_xy_m: tuple[float, float], shape: tuple[int, int], res: float
) -> FloatGrid:
    """Max known elevation of the DEM cells in each ``res`` block (NaN if none known)."""
    x0, y0 = origin_xy_m
    ny, nx = shape
    spec = dem.spec
    xs = spec.cell_centers_x_m()
    ys = spec.cell_centers_y_m()
    bi = np.floor((xs - x0) / res).astype(np.int64)
    bj = np.floor((ys - y0) / res).astype(np.int64)
    ok_i = (bi >= 0) & (bi < nx)
    ok_j = (bj >= 0) & (bj < ny)
    elev = dem.elevation_m[np.ix_(ok_j, ok_i)]
    jj, ii = np.meshgrid(bj[ok_j], bi[ok_i], indexing="ij")
    surface = np.full(ny * nx, -np.inf, dtype=np.float64)
    known = np.isfinite(elev)
    np.maximum.at(surface, (jj[known] * nx + ii[known]), elev[known].astype(np.float64))
    surface[np.isinf(surface)] = np.nan
    return surface.reshape(ny, nx).astype(np.float32)


def dilate3(grid: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
    """3x3 max filter. A move between neighbouring voxel centres passes over the
    blocks around its source only, so checking a voxel against the dilated
    surface keeps the clearance along every move, not just at voxel centres."""
    out = cv2.dilate(grid, np.ones((3, 3), np.uint8), borderType=cv2.BORDER_REPLICATE)
    return np.asarray(out, dtype=np.float32)


def build_voxels(
    dem: ElevationMap, start: tuple[float, float, float], goal: tuple[float, float, float], config: PlannerConfig
) -> VoxelGrid:
    """The free-space voxel grid of a 2.5D elevation map around ``start`` and ``goal`` (for :func:`search_voxels`)."""
    x_min, x_max, y_min, y_max = dem.spec.extent_m()
    xs = [x_min, x_max, start[0], goal[0]]
    ys = [y_min, y_max, start[1], goal[1]]
    if config.geofence_xy_m:
        fence = np.asarray(config.geofence_xy_m)
        xs += [float(fence[:, 0].min()), float(fence[:, 0].max())]
        ys += [float(fence[:, 1].min()), float(fence[:, 1].max())]
    res = config.voxel_xy_m
    x0 = min(xs) - config.domain_margin_m
    y0 = min(ys) - config.domain_margin_m
    nx = math.ceil((max(xs) + config.domain_margin_m - x0) / res)
    ny = math.ceil((max(ys) + config.domain_margin_m - y0) / res)
    nz = math.floor((config.max_altitude_m - config.min_altitude_m) / config.voxel_z_m) + 1
    if nx * ny * nz > 20_000_000:
        msg = f"3D planning domain too large ({nx}x{ny}x{nz} voxels); raise voxel_xy_m/voxel_z_m"
        raise PlanningError(msg)
    raw = _surface_on_blocks(dem, (x0, y0), (ny, nx), res)
    unknown_raw = np.isnan(raw)
    surface = dilate3(np.where(unknown_raw, np.float32(config.unknown_elevation_m), raw).astype(np.float32))
    unknown = dilate3(unknown_raw.astype(np.float32)) > 0.5
    # Each voxel is a box around its centre: free if its bottom keeps the clearance.
    bottoms = config.min_altitude_m + (np.arange(nz) - 0.5) * config.voxel_z_m
    free = bottoms[:, None, None] >= surface[None, :, :] + config.clearance_m
    # Hazard: too close to a *known* surface (unknown columns are not obstacles for path checks).
    known_surface = dilate3(np.where(unknown_raw, np.float32(-np.inf), raw).astype(np.float32))
    hazard = bottoms[:, None, None] < known_surface[None, :, :] + config.clearance_m
    column_ok = np.ones((ny, nx), dtype=bool)
    if config.unknown_space == "occupied":
        column_ok &= ~unknown
    centers = np.stack(
        np.meshgrid(x0 + (np.arange(nx) + 0.5) * res, y0 + (np.arange(ny) + 0.5) * res, indexing="xy"), axis=-1
    )
    if config.geofence_xy_m:
        column_ok &= points_in_polygon(centers, as_polygon(config.geofence_xy_m, "geofence_xy_m"))
    for i, zone in enumerate(config.no_fly_zones_xy_m):
        column_ok &= ~points_in_polygon(centers, as_polygon(zone, f"no_fly_zones_xy_m[{i}]"))
    column_ok = ~(dilate3((~column_ok).astype(np.float32)) > 0.5)  # no corner-cutting into zones
    free &= column_ok[None, :, :]
    return VoxelGrid(
        pad_grid(free, False), pad_grid(hazard, False), x0, y0, config.min_altitude_m, res, config.voxel_z_m
    )


def pad_grid(grid: npt.NDArray[np.bool_], value: bool) -> npt.NDArray[np.bool_]:
    """``grid`` with a one-voxel border of ``value`` on every side."""
    padded = np.full((grid.shape[0] + 2, grid.shape[1] + 2, grid.shape[2] + 2), value, dtype=bool)
    padded[1:-1, 1:-1, 1:-1] = grid
    return padded


def _nearest_free(grid: VoxelGrid, k: int, j: int, i: int, name: str) -> tuple[int, int, int]:
    """The free voxel nearest ``(k, j, i)`` in its column, preferring above; else nearby columns."""
    nz = grid.free.shape[0]
    for radius in range(4):
        best: tuple[int, int, int] | None = None
        best_cost = math.inf
        for dj in range(-radius, radius + 1):
            for di in range(-radius, radius + 1):
                if max(abs(dj), abs(di)) != radius:
                    continue
                jj, ii = j + dj, i + di
                if not (0 <= jj < grid.free.shape[1] and 0 <= ii < grid.free.shape[2]):
                    continue
                column = np.flatnonzero(grid.free[:, jj, ii])
                if column.size == 0:
                    continue
                kk = int(column[np.argmin(np.abs(column - k) + (column < k) * nz)])
                cost = abs(kk - k) + radius * 4
                if cost < best_cost:
                    best, best_cost = (kk, jj, ii), cost
        if best is not None:
            return best
    msg = f"no free voxel near the {name}; it is inside terrain clearance, a no-fly zone or outside the geofence"
    raise NoPathError(msg)


def _line_free(grid: VoxelGrid, a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
    k, j, i = grid.sample_indices(a, b)
    nz, ny, nx = grid.free.shape
    if (i < 0).any() or (i >= nx).any() or (j < 0).any() or (j >= ny).any() or (k < 0).any() or (k >= nz).any():
        return False
    return bool(grid.free[k, j, i].all())


def path_conflict_m(path: npt.NDArray[np.float64], grid: VoxelGrid, skip_m: float = 0.0) -> float | None:
    """Arc length along ``path`` of its first point in a hazard voxel, ignoring the first ``skip_m``.

    Points outside the grid are not hazards (nothing is known there). Returns None when the path
    keeps clear of every known obstacle: it may still be flown after the map changed.
    """
    travelled = 0.0
    nz, ny, nx = grid.hazard.shape
    for a, b in itertools.pairwise(path):
        pa = (float(a[0]), float(a[1]), float(a[2]))
        pb = (float(b[0]), float(b[1]), float(b[2]))
        length = math.dist(pa, pb)
        k, j, i = grid.sample_indices(pa, pb)
        s = travelled + np.linspace(0.0, length, len(i))
        inside = (i >= 0) & (i < nx) & (j >= 0) & (j < ny) & (k >= 0) & (k < nz)
        hit = np.zeros(len(i), dtype=bool)
        hit[inside] = grid.hazard[k[inside], j[inside], i[inside]]
        hit &= s >= skip_m
        if hit.any():
            return float(s[np.argmax(hit)])
        travelled += length
    return None


def _neighbours(shape: tuple[int, ...], res_xy: float, res_z: float) -> list[tuple[int, float]]:
    _, ny, nx = shape
    out = []
    for dk in (-1, 0, 1):
        for dj in (-1, 0, 1):
            for di in (-1, 0, 1):
                if dk == dj == di == 0:
                    continue
                out.append(
                    (
                        dk * ny * nx + dj * nx + di,
                        math.sqrt((di * res_xy) ** 2 + (dj * res_xy) ** 2 + (dk * res_z) ** 2),
                    )
                )
    return out


def _astar(
    grid: VoxelGrid, start: tuple[int, int, int], goal: tuple[int, int, int], config: PlannerConfig
) -> list[int]:
    shape = grid.free.shape
    _, ny, nx = shape
    free = grid.free.ravel()
    s = (start[0] * ny + start[1]) * nx + start[2]
    g_idx = (goal[0] * ny + goal[1]) * nx + goal[2]
    gk, gj, gi = goal
    rxy, rz = grid.res_xy_m, grid.res_z_m
    w = config.heuristic_weight
    g_cost = np.full(free.size, np.inf)
    parent = np.full(free.size, -1, dtype=np.int64)
    closed = np.zeros(free.size, dtype=bool)
    g_cost[s] = 0.0
    neigh = _neighbours(shape, rxy, rz)
    plane = ny * nx

    def h(idx: int) -> float:
        k, rem = divmod(idx, plane)
        j, i = divmod(rem, nx)
        return w * math.sqrt(((i - gi) * rxy) ** 2 + ((j - gj) * rxy) ** 2 + ((k - gk) * rz) ** 2)

    # Entries (f, -g, idx): ties on f go to the deeper node, which keeps open sets small.
    heap: list[tuple[float, float, int]] = [(h(s), 0.0, s)]
    expansions = 0
    while heap:
        _, neg_g, cur = heapq.heappop(heap)
        if closed[cur]:
            continue
        if cur == g_idx:
            path = [cur]
            while parent[path[-1]] >= 0:
                path.append(int(parent[path[-1]]))
            return path[::-1]
        closed[cur] = True
        expansions += 1
        if expansions > config.max_expansions:
            msg = f"A* gave up after {config.max_expansions} expansions (max_expansions); no path found yet"
            raise NoPathError(msg)
        g_cur = -neg_g
        for off, cost in neigh:
            nxt = cur + off
            if not free[nxt] or closed[nxt]:
                continue
            g_new = g_cur + cost
            if g_new < g_cost[nxt]:
                g_cost[nxt] = g_new
                parent[nxt] = cur
                heapq.heappush(heap, (g_new + h(nxt), -g_new, nxt))
    msg = "no collision-free path: the goal is not reachable through known-free space"
    raise NoPathError(msg)


def plan_astar(
    start_enu: tuple[float, float, float], goal_xy: tuple[float, float], dem: ElevationMap, config: PlannerConfig
) -> PathArray:
    """3D A* path from ``start_enu`` to ``goal_height_m`` above ``goal_xy`` over voxels derived from the DEM.

    Returns:
        ``(N, 3)`` float64 ENU waypoints: the start, the shortcut voxel path, the goal.

    Raises:
        InvalidInputError: non-finite start or goal.
        NoPathError: no path through free space (or ``max_expansions`` exceeded).
        PlanningError: the domain is too large for the voxel size.
    """
    require_finite_vector("start", start_enu, len(start_enu), error=InvalidInputError)
    require_finite_vector("goal", goal_xy, len(goal_xy), error=InvalidInputError)
    goal_z = min(max(goal_altitude_m(dem, goal_xy, config), config.min_altitude_m), config.max_altitude_m)
    goal = (goal_xy[0], goal_xy[1], goal_z)
    return search_voxels(build_voxels(dem, start_enu, goal, config), start_enu, goal, config)


def search_voxels(
    grid: VoxelGrid, start_enu: tuple[float, float, float], goal_enu: tuple[float, float, float], config: PlannerConfig
) -> PathArray:
    """A* from the free voxel nearest the start to the one nearest the goal, then line-of-sight shortcuts.

    Raises:
        NoPathError: start or goal have no free voxel nearby, or the goal is unreachable.
    """
    s_vox = _nearest_free(grid, *grid.index_of(*start_enu), "start")
    g_vox = _nearest_free(grid, *grid.index_of(*goal_enu), "goal")
    _, ny, nx = grid.free.shape
    plane = ny * nx
    voxel_path = []
    for idx in _astar(grid, s_vox, g_vox, config):
        k, rem = divmod(idx, plane)
        j, i = divmod(rem, nx)
        voxel_path.append(grid.center(k, j, i))
    g_center = voxel_path[-1]
    # The exact goal replaces its voxel centre when the last leg stays in free space; else the goal's x, y
    # at the height of that (free) voxel, which is in the goal's column when the column has a free voxel.
    raised = (goal_enu[0], goal_enu[1], g_center[2])
    end = (
        goal_enu if _line_free(grid, g_center, goal_enu) else raised if _line_free(grid, g_center, raised) else g_center
    )
    points: list[tuple[float, float, float]] = [start_enu, *voxel_path, end]
    # Shortcut: from each kept point, jump to the farthest later point in line of sight.
    out = [points[0], points[1]] if len(points) > 1 else [points[0]]
    anchor = 1
    while anchor < len(points) - 1:
        nxt = anchor + 1
        for cand in range(len(points) - 1, anchor, -1):
            if _line_free(grid, points[anchor], points[cand]):
                nxt = cand
                break
        out.append(points[nxt])
        anchor = nxt
    return _dedupe(np.asarray(out, dtype=np.float64))


def remaining_path(path: PathArray, position_enu: tuple[float, float, float]) -> PathArray:
    """What is left of ``path`` for a vehicle at ``position_enu``: the position, then the waypoints after
    the point of the path nearest to it (ties go to the later leg)."""
    p = np.asarray(position_enu, dtype=np.float64)
    if len(path) < 2:
        return np.vstack([p, path])
    best, best_d = 0, math.inf
    for n, (a, b) in enumerate(itertools.pairwise(path)):
        ab = b - a
        denom = float(ab @ ab)
        t = 0.0 if denom == 0.0 else min(max(float((p - a) @ ab) / denom, 0.0), 1.0)
        d = float(np.linalg.norm(a + t * ab - p))
        if d <= best_d + 1e-9:
            best, best_d = n, d
    return np.vstack([p, path[best + 1 :]])


def dem_conflict_m(path: PathArray, dem: ElevationMap, clearance_m: float, skip_m: float = 0.0) -> float | None:
    """Arc length of the first point of ``path`` less than ``clearance_m`` above the known DEM (after
    ``skip_m``); None if the whole path keeps the clearance over every known cell."""
    travelled = 0.0
    step = 0.25 * dem.spec.resolution_m
    for a, b in itertools.pairwise(path):
        length = float(np.linalg.norm(b - a))
        n = max(2, math.ceil(length / step) + 1)
        t = np.linspace(0.0, 1.0, n)
        pts = a[None, :] + t[:, None] * (b - a)[None, :]
        rows, cols, inside = dem.spec.cells_of(pts[:, :2])
        elev = np.full(n, np.nan)
        elev[inside] = dem.elevation_m[rows[inside], cols[inside]]
        s = travelled + t * length
        with np.errstate(invalid="ignore"):
            hit = (pts[:, 2] < elev + clearance_m) & (s >= skip_m)
        if hit.any():
            return float(s[np.argmax(hit)])
        travelled += length
    return None


def _dedupe(path: PathArray) -> PathArray:
    keep = [0, *[i for i in range(1, len(path)) if np.linalg.norm(path[i] - path[i - 1]) > 1e-6]]
    return path[keep]


def plan(
    start_enu: tuple[float, float, float], goal_xy: tuple[float, float], dem: ElevationMap, config: PlannerConfig
) -> PathArray:
    """Dispatch on ``config.algorithm``."""
    if config.algorithm == "astar":
        return plan_astar(start_enu, goal_xy, dem, config)
    return plan_straight(start_enu, goal_xy, dem, config)
