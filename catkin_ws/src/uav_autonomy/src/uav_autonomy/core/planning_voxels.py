"""3D planning over the map server's voxel map (its ``octomap_binary``): occupied, free and unknown space.

Pipeline (all vectorised numpy; the map server's octree may hold millions of leaves):

1. :func:`decode_octree` decodes an ``octomap_msgs/Octomap`` binary stream into leaves (corner, size,
   occupied or free). Same result as :func:`uav_autonomy.core.octree_reader.decode_binary_octree`,
   which walks the tree node by node in Python and is far too slow for a whole map.
2. :func:`occupancy_from_leaves` accumulates the leaves on the planner's coarse lattice (``voxel_xy_m`` x
   ``voxel_z_m``, x/y cells ``[i*res, (i+1)*res)``, z cells centred on ``min_altitude_m + k*voxel_z_m``):
   which cells hold occupied space, how much of each cell is known free, and the highest occupied
   point of each column. Computed once per map version.
3. :func:`grid_from_occupancy` makes the search grid for one start/goal:

   * *solid*: occupied cells; unknown cells below the highest occupied point of their column (the inside
     of terrain and buildings, which no sensor sees); and, in columns with no known surface at all,
     cells below ``unknown_elevation_m`` (the same assumption as the DEM planner's);
   * *hazard*: every cell any point of which is closer than ``clearance_m`` to a solid cell (the gap
     between boxes, so any segment inside hazard-free cells keeps the clearance, including moves to
     any of the 26 neighbours);
   * *free*: not hazard, inside ``[min_altitude_m, max_altitude_m]``, inside the geofence and outside
     every no-fly polygon (columns next to them excluded too), and, with ``unknown_space: occupied``,
     entirely known free. With ``unknown_space: free`` unknown space counts as free.
4. :func:`plan_on_voxel_map` runs the A* + shortcut search of :mod:`uav_autonomy.core.planning` on it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import numpy as np
import numpy.typing as npt
from scipy import ndimage

from uav_autonomy.core.geometry2d import as_polygon, points_in_polygon
from uav_autonomy.core.octree_reader import KEY_OFFSET, TREE_DEPTH, OctreeLeaves
from uav_autonomy.core.planning import (
    ElevationMap,
    PathArray,
    PlannerConfig,
    VoxelGrid,
    dilate3,
    pad_grid,
    search_voxels,
)
from uav_autonomy.errors import InvalidInputError, PlanningError
from uav_common.validate import require_finite_vector

__all__ = [
    "VoxelOccupancy",
    "decode_octree",
    "grid_from_occupancy",
    "occupancy_from_leaves",
    "plan_on_voxel_map",
]

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]
MAX_VOXELS = 20_000_000
_FULL = 1.0 - 1e-6  # a cell this much known free counts as entirely known


@cache
def _tables() -> tuple[npt.NDArray[np.uint8], IntArray, IntArray]:
    """For every 16-bit node word: the 2-bit code of each child, the number of inner children, and the
    child slot of the k-th inner child (-1 past the last)."""
    words = np.arange(65536, dtype=np.int64)
    codes = ((words[:, None] >> (2 * np.arange(8))[None, :]) & 3).astype(np.uint8)
    inner = codes == 3
    n_inner = inner.sum(axis=1).astype(np.int64)
    # Stable sort puts inner slots first, in child order.
    order = np.argsort(~inner, axis=1, kind="stable").astype(np.int64)
    slots = np.where(np.arange(8)[None, :] < n_inner[:, None], order, -1)
    return codes, n_inner, slots


_CHILD_OFFSET = np.array([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], dtype=np.int64)


def decode_octree(data: bytes, resolution_m: float) -> OctreeLeaves:
    """Vectorised decoder of OctoMap's binary stream (``OcTree::writeBinaryData``).

    The stream is the tree's inner nodes in depth-first order, two bytes each: two bits per child
    (1 free leaf, 2 occupied leaf, 3 inner node, 0 none), inner children visited in child order.
    Let ``s[i]`` be the number of nodes still to read before node ``i`` (1 before the root, then
    ``s[i+1] = s[i] - 1 + inner_children(i)``); the children of node ``j`` are then the first nodes
    after ``j`` at the levels ``s[j] + c - 1, ..., s[j]`` (``c`` its inner children, first child
    first), found for all nodes at once with one sort and one binary search.

    Raises:
        InvalidInputError: bad resolution, truncated stream, bytes after the tree, a tree deeper than 16.
    """
    if not resolution_m > 0.0:
        msg = f"resolution_m must be > 0, got {resolution_m}"
        raise InvalidInputError(msg)
    empty = OctreeLeaves(float(resolution_m), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros(0, np.bool_))
    if len(data) == 0:
        return empty
    if len(data) % 2:
        msg = f"binary octree truncated at byte {len(data) - 1} of {len(data)}"
        raise InvalidInputError(msg)
    codes_t, n_inner_t, slots_t = _tables()
    words = np.frombuffer(data, dtype="<u2").astype(np.int64)
    n = len(words)
    c = n_inner_t[words]
    pending = np.empty(n + 1, dtype=np.int64)
    pending[0] = 1
    np.cumsum(c - 1, out=pending[1:])
    pending[1:] += 1
    done = np.flatnonzero(pending[:n] <= 0)
    if done.size:
        msg = f"binary octree has {2 * (n - int(done[0]))} bytes after its last node"
        raise InvalidInputError(msg)
    if pending[n] != 0:
        msg = f"binary octree truncated at byte {len(data)} of {len(data)} ({pending[n]} nodes missing)"
        raise InvalidInputError(msg)
    parent, slot = _parents(words, c, pending, slots_t)
    depth, corner = _corners(parent, slot)
    # Leaves: children with code 1 (free) or 2 (occupied) of every node.
    codes = codes_t[words]
    node, child_slot = np.nonzero((codes == 1) | (codes == 2))
    half = np.left_shift(1, TREE_DEPTH - depth[node] - 1)
    leaf_corner = corner[node] + _CHILD_OFFSET[child_slot] * half[:, None] - KEY_OFFSET
    return OctreeLeaves(
        resolution_m=float(resolution_m),
        index_min=leaf_corner.astype(np.int64),
        size_voxels=half.astype(np.int64),
        occupied=codes[node, child_slot] == 2,
    )


def _parents(words: IntArray, c: IntArray, pending: IntArray, slots_t: IntArray) -> tuple[IntArray, IntArray]:
    """Parent and child slot of every node (-1 / 0 for the root)."""
    n = len(words)
    # Children of every inner node (parent j, k-th inner child at level pending[j] + c[j] - 1 - k).
    idx = np.arange(n, dtype=np.int64)
    parent_of_pair = np.repeat(idx, c)
    k = np.arange(parent_of_pair.size, dtype=np.int64) - np.repeat(np.cumsum(c) - c, c)
    level = pending[parent_of_pair] + c[parent_of_pair] - 1 - k
    keys = pending[:n] * (n + 1) + idx
    order = np.argsort(keys, kind="stable")
    pos = np.searchsorted(keys[order], level * (n + 1) + parent_of_pair + 1)
    child = order[np.minimum(pos, n - 1)]
    if (pos >= n).any() or (pending[child] != level).any():  # pragma: no cover - excluded by the counts above
        msg = "binary octree is inconsistent"
        raise InvalidInputError(msg)
    parent = np.full(n, -1, dtype=np.int64)
    slot = np.zeros(n, dtype=np.int64)
    parent[child] = parent_of_pair
    slot[child] = slots_t[words[parent_of_pair], k]
    return parent, slot


def _corners(parent: IntArray, slot: IntArray) -> tuple[IntArray, IntArray]:
    """Depth and lowest-corner key of every node, one level at a time from the root."""
    n = len(parent)
    depth = np.full(n, -1, dtype=np.int64)
    corner = np.zeros((n, 3), dtype=np.int64)
    depth[0] = 0
    current = np.array([0], dtype=np.int64)
    children_sorted = np.argsort(parent, kind="stable")[np.count_nonzero(parent < 0) :]
    parents_sorted = parent[children_sorted]
    for d in range(TREE_DEPTH):
        lo = np.searchsorted(parents_sorted, current, side="left")
        hi = np.searchsorted(parents_sorted, current, side="right")
        counts = hi - lo
        if counts.sum() == 0:
            break
        if d + 1 >= TREE_DEPTH:
            msg = "binary octree has inner nodes below the finest depth"
            raise InvalidInputError(msg)
        take = np.repeat(lo, counts) + np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        kids = children_sorted[take]
        depth[kids] = d + 1
        half = 1 << (TREE_DEPTH - d - 1)
        corner[kids] = corner[parent[kids]] + _CHILD_OFFSET[slot[kids]] * half
        current = kids
    return depth, corner


def _box_cells(
    lo_m: FloatArray, hi_m: FloatArray, origin_m: FloatArray, cell_m: FloatArray
) -> tuple[IntArray, FloatArray, IntArray]:
    """Lattice cells overlapped by axis-aligned boxes, with the overlap volume of each (box, cell) pair.

    Cell ``c`` covers ``[origin + c*cell, origin + (c+1)*cell)`` per axis. Returns ``(M, 3)`` cell indices,
    ``(M,)`` volumes and ``(M,)`` the box of each pair (pairs with zero overlap dropped).
    """
    if lo_m.shape[0] == 0:
        return np.zeros((0, 3), np.int64), np.zeros(0), np.zeros(0, np.int64)
    first = np.floor((lo_m - origin_m) / cell_m).astype(np.int64)
    last = np.maximum(np.ceil((hi_m - origin_m) / cell_m).astype(np.int64) - 1, first)
    n_axis = last - first + 1
    single = (n_axis[:, 0] == 1) & (n_axis[:, 1] == 1) & (n_axis[:, 2] == 1)
    # Fast path: most leaves are much smaller than a planner cell and lie inside one.
    one = np.flatnonzero(single)
    d = hi_m[one] - lo_m[one]
    one_volume = d[:, 0] * d[:, 1] * d[:, 2]
    many = np.flatnonzero(~single)
    if many.size == 0:
        return first[one], one_volume, one
    n_many = n_axis[many]
    total = n_many[:, 0] * n_many[:, 1] * n_many[:, 2]
    rep = np.repeat(np.arange(many.size), total)
    box = many[rep]
    local = np.arange(box.size, dtype=np.int64) - np.repeat(np.cumsum(total) - total, total)
    ny_nz = n_many[rep, 1] * n_many[rep, 2]
    ox = local // ny_nz
    oy = (local // n_many[rep, 2]) % n_many[rep, 1]
    oz = local % n_many[rep, 2]
    cells = first[box] + np.stack([ox, oy, oz], axis=1)
    cell_lo = origin_m + cells * cell_m
    overlap = np.minimum(hi_m[box], cell_lo + cell_m) - np.maximum(lo_m[box], cell_lo)
    volume = np.clip(overlap, 0.0, None).prod(axis=1)
    keep = volume > 0.0
    return (
        np.concatenate([first[one], cells[keep]]),
        np.concatenate([one_volume, volume[keep]]),
        np.concatenate([one, box[keep]]),
    )


@dataclass(frozen=True)
class VoxelOccupancy:
    """The voxel map accumulated on the planner's lattice (see the module docstring).

    Attributes:
        res_xy_m, res_z_m: lattice cell size; ``z0_m`` is the centre height of layer 0 (``min_altitude_m``).
        occupied: ``(M, 3)`` unique ``(i, j, k)`` cells holding occupied space (within the z band of
            interest: the altitude limits widened by the clearance).
        free_cells, free_fraction: ``(F, 3)`` cells with known free space, and which fraction of each.
        columns, column_top_m: ``(C, 2)`` unique ``(i, j)`` columns holding occupied space at any height,
            and the highest occupied point of each (metres, map z).
    """

    res_xy_m: float
    res_z_m: float
    z0_m: float
    occupied: IntArray
    free_cells: IntArray
    free_fraction: FloatArray
    columns: IntArray
    column_top_m: FloatArray

    def top_at(self, x_m: float, y_m: float) -> float:
        """Highest occupied point in the lattice column of ``(x, y)`` (NaN if none)."""
        i, j = math.floor(x_m / self.res_xy_m), math.floor(y_m / self.res_xy_m)
        hit = np.flatnonzero((self.columns[:, 0] == i) & (self.columns[:, 1] == j))
        return float(self.column_top_m[hit[0]]) if hit.size else math.nan


def _unique_rows(cells: IntArray) -> tuple[IntArray, IntArray]:
    """Unique integer rows (sorted) and the inverse index, through one int64 key per row (fast)."""
    if cells.shape[0] == 0:
        return cells.reshape(0, cells.shape[1]), np.zeros(0, np.int64)
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    key = np.zeros(cells.shape[0], dtype=np.int64)
    for axis in range(cells.shape[1]):
        key = key * span[axis] + (cells[:, axis] - lo[axis])
    uniq_key, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    del uniq_key
    return cells[first], inverse.reshape(-1)


def _unique_sum(cells: IntArray, values: FloatArray) -> tuple[IntArray, FloatArray]:
    uniq, inverse = _unique_rows(cells)
    sums = np.bincount(inverse, weights=values, minlength=uniq.shape[0]) if uniq.shape[0] else np.zeros(0)
    return uniq, np.asarray(sums, dtype=np.float64)


def occupancy_from_leaves(leaves: OctreeLeaves, config: PlannerConfig) -> VoxelOccupancy:
    """Accumulate octree leaves on the planner's lattice (``voxel_xy_m`` x ``voxel_z_m``)."""
    res = leaves.resolution_m
    rxy, rz = config.voxel_xy_m, config.voxel_z_m
    lo = leaves.index_min.astype(np.float64) * res
    hi = lo + (leaves.size_voxels.astype(np.float64) * res)[:, None]
    # Columns: the highest occupied point of each lattice column, at any height.
    occ = leaves.occupied
    n_occ = int(occ.sum())
    col_cells, _, col_box = _box_cells(
        np.c_[lo[occ, :2], np.zeros(n_occ)],
        np.c_[hi[occ, :2], np.ones(n_occ)],
        np.array([0.0, 0.0, 0.0]),
        np.array([rxy, rxy, 2.0]),
    )
    col_top = hi[occ, 2][col_box]
    columns, inverse = _unique_rows(col_cells[:, :2])
    column_top = np.full(columns.shape[0], -np.inf)
    np.maximum.at(column_top, inverse, col_top)
    # The z band that matters: the altitude limits widened by the clearance (for the hazard margin).
    pad = math.ceil(config.clearance_m / rz) * rz + rz
    z_lo = config.min_altitude_m - 0.5 * rz - pad
    z_hi = config.max_altitude_m + 0.5 * rz + pad
    lo_c = lo.copy()
    hi_c = hi.copy()
    lo_c[:, 2] = np.maximum(lo[:, 2], z_lo)
    hi_c[:, 2] = np.minimum(hi[:, 2], z_hi)
    in_band = hi_c[:, 2] > lo_c[:, 2]
    origin = np.array([0.0, 0.0, config.min_altitude_m - 0.5 * rz])
    cell = np.array([rxy, rxy, rz])
    sel = in_band & occ
    occ_cells, _, _ = _box_cells(lo_c[sel], hi_c[sel], origin, cell)
    occupied = _unique_rows(occ_cells)[0]
    sel = in_band & ~occ
    free_cells, free_vol, _ = _box_cells(lo_c[sel], hi_c[sel], origin, cell)
    free_cells, free_sum = _unique_sum(free_cells, free_vol)
    return VoxelOccupancy(
        res_xy_m=rxy,
        res_z_m=rz,
        z0_m=config.min_altitude_m,
        occupied=occupied,
        free_cells=free_cells,
        free_fraction=np.minimum(free_sum / (rxy * rxy * rz), 1.0),
        columns=columns.astype(np.int64),
        column_top_m=column_top,
    )


def _clearance_structure(config: PlannerConfig) -> npt.NDArray[np.bool_]:
    """Offsets ``(dk, dj, di)`` whose cell box comes closer than ``clearance_m`` to the centre cell's box."""
    rxy, rz, c = config.voxel_xy_m, config.voxel_z_m, config.clearance_m
    nxy = math.ceil(c / rxy) + 1
    nz = math.ceil(c / rz) + 1
    dk, dj, di = np.meshgrid(np.arange(-nz, nz + 1), np.arange(-nxy, nxy + 1), np.arange(-nxy, nxy + 1), indexing="ij")
    gap = np.sqrt(
        (np.maximum(np.abs(di) - 1, 0) * rxy) ** 2
        + (np.maximum(np.abs(dj) - 1, 0) * rxy) ** 2
        + (np.maximum(np.abs(dk) - 1, 0) * rz) ** 2
    )
    return np.asarray(gap < c) if c > 0.0 else np.asarray((di == 0) & (dj == 0) & (dk == 0))


def grid_from_occupancy(
    occ: VoxelOccupancy,
    start: tuple[float, float, float],
    goal: tuple[float, float, float],
    config: PlannerConfig,
) -> VoxelGrid:
    """The search grid over the map, start, goal and geofence (plus ``domain_margin_m``).

    Raises:
        PlanningError: the domain is too large for the voxel size, or the lattice differs from the config.
    """
    rxy, rz = config.voxel_xy_m, config.voxel_z_m
    if (occ.res_xy_m, occ.res_z_m, occ.z0_m) != (rxy, rz, config.min_altitude_m):
        msg = "the voxel occupancy was accumulated for other voxel sizes or altitude limits"
        raise PlanningError(msg)
    xs = [start[0], goal[0]]
    ys = [start[1], goal[1]]
    if occ.columns.shape[0]:
        xs += [float(occ.columns[:, 0].min()) * rxy, float(occ.columns[:, 0].max() + 1) * rxy]
        ys += [float(occ.columns[:, 1].min()) * rxy, float(occ.columns[:, 1].max() + 1) * rxy]
    if config.geofence_xy_m:
        fence = np.asarray(config.geofence_xy_m)
        xs += [float(fence[:, 0].min()), float(fence[:, 0].max())]
        ys += [float(fence[:, 1].min()), float(fence[:, 1].max())]
    i0 = math.floor((min(xs) - config.domain_margin_m) / rxy)
    j0 = math.floor((min(ys) - config.domain_margin_m) / rxy)
    nx = math.floor((max(xs) + config.domain_margin_m) / rxy) - i0 + 1
    ny = math.floor((max(ys) + config.domain_margin_m) / rxy) - j0 + 1
    nz = math.floor((config.max_altitude_m - config.min_altitude_m) / rz) + 1
    structure = _clearance_structure(config)
    kpad = structure.shape[0] // 2
    nzp = nz + 2 * kpad
    if nx * ny * nzp > MAX_VOXELS:
        msg = f"3D planning domain too large ({nx}x{ny}x{nz} voxels); raise voxel_xy_m/voxel_z_m"
        raise PlanningError(msg)

    def dense(cells: IntArray) -> tuple[IntArray, IntArray, IntArray, npt.NDArray[np.bool_]]:
        i, j, k = cells[:, 0] - i0, cells[:, 1] - j0, cells[:, 2] + kpad
        ok = (i >= 0) & (i < nx) & (j >= 0) & (j < ny) & (k >= 0) & (k < nzp)
        return k[ok], j[ok], i[ok], ok

    occupied = np.zeros((nzp, ny, nx), dtype=bool)
    k, j, i, _ = dense(occ.occupied)
    occupied[k, j, i] = True
    known_free = np.zeros((nzp, ny, nx), dtype=bool)
    k, j, i, ok = dense(occ.free_cells)
    known_free[k, j, i] = occ.free_fraction[ok] >= _FULL
    top = np.full((ny, nx), np.nan)
    ci, cj = occ.columns[:, 0] - i0, occ.columns[:, 1] - j0
    ok2 = (ci >= 0) & (ci < nx) & (cj >= 0) & (cj < ny)
    top[cj[ok2], ci[ok2]] = occ.column_top_m[ok2]
    zc = config.min_altitude_m + (np.arange(nzp) - kpad) * rz  # layer centres
    unknown = ~occupied & ~known_free
    with np.errstate(invalid="ignore"):
        below_surface = (zc + 0.5 * rz)[:, None, None] <= top[None, :, :]
    no_surface_ground = np.isnan(top)[None, :, :] & ((zc - 0.5 * rz) < config.unknown_elevation_m)[:, None, None]
    solid = occupied | (unknown & below_surface) | (unknown & no_surface_ground)
    hazard_p = ndimage.binary_dilation(solid, structure=structure)
    hazard = hazard_p[kpad : kpad + nz]
    free = ~hazard & _airspace_columns(i0, j0, nx, ny, config)[None, :, :]
    if config.unknown_space == "occupied":
        free &= known_free[kpad : kpad + nz]
    return VoxelGrid(pad_grid(free, False), pad_grid(hazard, False), i0 * rxy, j0 * rxy, config.min_altitude_m, rxy, rz)


def _airspace_columns(i0: int, j0: int, nx: int, ny: int, config: PlannerConfig) -> npt.NDArray[np.bool_]:
    """Columns inside the geofence and away from every no-fly polygon (one column of margin)."""
    rxy = config.voxel_xy_m
    column_ok = np.ones((ny, nx), dtype=bool)
    centers = np.stack(
        np.meshgrid((i0 + np.arange(nx) + 0.5) * rxy, (j0 + np.arange(ny) + 0.5) * rxy, indexing="xy"), axis=-1
    )
    if config.geofence_xy_m:
        column_ok &= points_in_polygon(centers, as_polygon(config.geofence_xy_m, "geofence_xy_m"))
    for n, zone in enumerate(config.no_fly_zones_xy_m):
        column_ok &= ~points_in_polygon(centers, as_polygon(zone, f"no_fly_zones_xy_m[{n}]"))
    return np.asarray(dilate3((~column_ok).astype(np.float32)) <= 0.5)  # no corner-cutting into zones


def goal_altitude_on_map_m(
    occ: VoxelOccupancy | None, dem: ElevationMap | None, goal_xy: tuple[float, float], config: PlannerConfig
) -> float:
    """``goal_height_m`` above the highest known surface at the goal: the voxel column's top, else the
    DEM's elevation, else ``unknown_elevation_m``; clamped to the altitude limits."""
    surface = math.nan if occ is None else occ.top_at(*goal_xy)
    if math.isnan(surface) and dem is not None:
        surface = dem.at(*goal_xy)
    if math.isnan(surface):
        surface = config.unknown_elevation_m
    return float(min(max(surface + config.goal_height_m, config.min_altitude_m), config.max_altitude_m))


def plan_on_voxel_map(
    start_enu: tuple[float, float, float],
    goal_xy: tuple[float, float],
    occ: VoxelOccupancy,
    config: PlannerConfig,
    dem: ElevationMap | None = None,
) -> tuple[PathArray, VoxelGrid]:
    """A* over the voxel map from ``start_enu`` to ``goal_height_m`` above ``goal_xy``.

    Returns:
        The path (``(N, 3)`` ENU: start, shortcut voxel path, goal) and the grid it was planned on.

    Raises:
        InvalidInputError: non-finite start or goal.
        NoPathError: no path through free space (or ``max_expansions`` exceeded).
        PlanningError: the domain is too large for the voxel size.
    """
    require_finite_vector("start", start_enu, len(start_enu), error=InvalidInputError)
    require_finite_vector("goal", goal_xy, len(goal_xy), error=InvalidInputError)
    goal = (goal_xy[0], goal_xy[1], goal_altitude_on_map_m(occ, dem, goal_xy, config))
    grid = grid_from_occupancy(occ, start_enu, goal, config)
    return search_voxels(grid, start_enu, goal, config), grid
