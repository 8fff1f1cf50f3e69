"""Village sites and the irregular road network that links them (pure numpy + heapq).

Villages are picked on gentle, low ground with a minimum spacing.  They are linked
by a minimum spanning tree plus a few extra links, and a few roads leave the map.
Each link is routed with A* over a coarse grid whose step cost grows with the
square of the slope and shrinks on existing roads, so roads wind along the valley,
share trunks and branch: an irregular network, not a grid.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.terrain import Heightfield
from uav_sim_bridge.core.world_config import RoadsConfig

__all__ = ["Raster", "RoadNetwork", "pick_village_sites", "plan_roads", "polyline_raster_distance"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Raster:
    """A float grid over the terrain: ``values[row, col]`` at ``(x0 + col*res, y0 + row*res)``."""

    origin_m: tuple[float, float]
    resolution_m: float
    values: FloatArray

    def sample(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> FloatArray:
        """Nearest-cell lookup (clamped to the grid)."""
        rows, cols = self.values.shape
        col = np.clip(np.rint((np.asarray(x_m) - self.origin_m[0]) / self.resolution_m), 0, cols - 1).astype(np.int64)
        row = np.clip(np.rint((np.asarray(y_m) - self.origin_m[1]) / self.resolution_m), 0, rows - 1).astype(np.int64)
        return np.asarray(self.values[row, col], dtype=np.float64)


@dataclass(frozen=True)
class RoadNetwork:
    """Road centrelines ``(N_k, 2)`` in map metres, one per road instance, plus the village centres."""

    polylines: tuple[FloatArray, ...]
    villages_m: FloatArray
    width_m: float

    def samples(self, spacing_m: float = 1.0) -> FloatArray:
        """All centreline points resampled to ``spacing_m``: ``(M, 2)``."""
        if not self.polylines:
            return np.zeros((0, 2))
        return np.concatenate([resample_polyline(p, spacing_m) for p in self.polylines])


def resample_polyline(points_m: FloatArray, spacing_m: float) -> FloatArray:
    """Points every ``spacing_m`` along a polyline, keeping both ends."""
    seg = np.linalg.norm(np.diff(points_m, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return points_m[:1].copy()
    n = max(2, math.ceil(s[-1] / spacing_m) + 1)
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, points_m[:, 0]), np.interp(t, s, points_m[:, 1])], axis=1)


def _chaikin(points_m: FloatArray, iterations: int) -> FloatArray:
    """Corner-cutting smoothing that keeps the end points."""
    p = points_m
    for _ in range(iterations):
        if len(p) < 3:
            return p
        q = 0.75 * p[:-1] + 0.25 * p[1:]
        r = 0.25 * p[:-1] + 0.75 * p[1:]
        mid = np.empty((2 * (len(p) - 1), 2))
        mid[0::2] = q
        mid[1::2] = r
        p = np.concatenate([p[:1], mid[1:-1], p[-1:]])
    return p


def pick_village_sites(
    terrain: Heightfield,
    *,
    count: int,
    min_spacing_m: float,
    home_clearance_m: float,
    edge_margin_m: float,
    rng: np.random.Generator,
) -> FloatArray:
    """``(count, 2)`` village centres on gentle low ground, spaced apart, away from home.

    Fewer are returned when the terrain has no room for more.
    """
    x_min, y_min, x_max, y_max = terrain.bounds_m
    step = 20.0
    xs = np.arange(x_min + edge_margin_m, x_max - edge_margin_m + 1e-9, step)
    ys = np.arange(y_min + edge_margin_m, y_max - edge_margin_m + 1e-9, step)
    if len(xs) == 0 or len(ys) == 0 or count == 0:
        return np.zeros((0, 2))
    gx, gy = np.meshgrid(xs, ys)
    cand = np.stack([gx.ravel(), gy.ravel()], axis=1) + rng.uniform(-step / 2, step / 2, (gx.size, 2))
    slope = terrain.slope_at(cand[:, 0], cand[:, 1])
    height = terrain.height_at(cand[:, 0], cand[:, 1])
    spread = max(float(np.ptp(height)), 1.0)
    weight = np.exp(-slope / 0.06) * np.exp(-2.5 * (height - height.min()) / spread)
    weight[np.hypot(cand[:, 0], cand[:, 1]) < home_clearance_m] = 0.0
    chosen: list[FloatArray] = []
    while len(chosen) < count and weight.sum() > 0:
        k = int(rng.choice(len(cand), p=weight / weight.sum()))
        chosen.append(cand[k])
        weight[np.hypot(cand[:, 0] - cand[k, 0], cand[:, 1] - cand[k, 1]) < min_spacing_m] = 0.0
    return np.asarray(chosen, dtype=np.float64).reshape(-1, 2)


def _mst_edges(points: FloatArray) -> list[tuple[int, int]]:
    """Prim's minimum spanning tree over Euclidean distances."""
    n = len(points)
    if n < 2:
        return []
    dist = np.hypot(points[:, None, 0] - points[None, :, 0], points[:, None, 1] - points[None, :, 1])
    in_tree = np.zeros(n, dtype=bool)
    in_tree[0] = True
    best = dist[0].copy()
    parent = np.zeros(n, dtype=np.int64)
    edges = []
    for _ in range(n - 1):
        cand = np.where(in_tree, np.inf, best)
        j = int(np.argmin(cand))
        edges.append((int(parent[j]), j))
        in_tree[j] = True
        closer = dist[j] < best
        best = np.where(closer, dist[j], best)
        parent = np.where(closer, j, parent)
    return edges


_NEIGHBOURS = [(dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if (dr, dc) != (0, 0)]


def _astar(
    heights: FloatArray, blocked: npt.NDArray[np.bool_], on_road: npt.NDArray[np.bool_],
    ends: tuple[tuple[int, int], tuple[int, int]], step_m: float,
) -> list[tuple[int, int]]:  # fmt: skip
    """Cheapest 8-connected path; step cost = length * (1 + 60 slope²), halved on existing roads."""
    start, goal = ends
    rows, cols = heights.shape
    best = {start: 0.0}
    came: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(0.0, 0.0, start)]
    gr, gc = goal
    while heap:
        _, cost, node = heapq.heappop(heap)
        if node == goal:
            break
        if cost > best.get(node, math.inf):
            continue
        r, c = node
        h0 = heights[r, c]
        for dr, dc in _NEIGHBOURS:
            nr, nc = r + dr, c + dc
            if not (0 <= nr < rows and 0 <= nc < cols) or (blocked[nr, nc] and (nr, nc) != goal):
                continue
            length = step_m * (1.4142135623730951 if dr and dc else 1.0)
            slope = (heights[nr, nc] - h0) / length
            step = length * (1.0 + 60.0 * slope * slope)
            if on_road[nr, nc]:
                step *= 0.5
            new = cost + step
            if new < best.get((nr, nc), math.inf):
                best[(nr, nc)] = new
                came[(nr, nc)] = node
                heur = 0.5 * step_m * math.hypot(nr - gr, nc - gc)
                heapq.heappush(heap, (new + heur, new, (nr, nc)))
    if goal not in came and goal != start:
        return []
    path = [goal]
    while path[-1] != start:
        path.append(came[path[-1]])
    return path[::-1]


def _exit_points(terrain: Heightfield, count: int, margin_m: float, rng: np.random.Generator) -> FloatArray:
    """Low points on the map border, spread apart, where roads leave the map."""
    x_min, y_min, x_max, y_max = terrain.bounds_m
    t = np.linspace(0.0, 1.0, 200, endpoint=False)
    border = np.concatenate(
        [
            np.stack([x_min + margin_m + t * (x_max - x_min - 2 * margin_m), np.full_like(t, y_min + margin_m)], 1),
            np.stack([x_min + margin_m + t * (x_max - x_min - 2 * margin_m), np.full_like(t, y_max - margin_m)], 1),
            np.stack([np.full_like(t, x_min + margin_m), y_min + margin_m + t * (y_max - y_min - 2 * margin_m)], 1),
            np.stack([np.full_like(t, x_max - margin_m), y_min + margin_m + t * (y_max - y_min - 2 * margin_m)], 1),
        ]
    )
    h = terrain.height_at(border[:, 0], border[:, 1]) + rng.uniform(0.0, 3.0, len(border))
    order = np.argsort(h)
    chosen: list[FloatArray] = []
    min_gap = 0.5 * (x_max - x_min)
    for k in order:
        if all(np.hypot(*(border[k] - p)) >= min_gap for p in chosen):
            chosen.append(border[k])
        if len(chosen) == count:
            break
    return np.asarray(chosen, dtype=np.float64).reshape(-1, 2)


def plan_roads(
    terrain: Heightfield, villages_m: FloatArray, cfg: RoadsConfig, home_clearance_m: float, rng: np.random.Generator
) -> RoadNetwork:
    """Route the road network (see module docstring)."""
    n_v = len(villages_m)
    if n_v == 0:
        return RoadNetwork((), villages_m, cfg.width_m)
    exits = _exit_points(terrain, cfg.exits, cfg.grid_m, rng) if n_v else np.zeros((0, 2))
    links = _mst_edges(villages_m)
    if n_v > 2 and cfg.extra_links:
        dist = np.hypot(
            villages_m[:, None, 0] - villages_m[None, :, 0], villages_m[:, None, 1] - villages_m[None, :, 1]
        )
        have = {tuple(sorted(e)) for e in links}
        pairs = sorted((float(dist[i, j]), i, j) for i in range(n_v) for j in range(i + 1, n_v) if (i, j) not in have)
        links += [(i, j) for _, i, j in pairs[: cfg.extra_links]]
    endpoints: list[tuple[FloatArray, FloatArray]] = [(villages_m[i], villages_m[j]) for i, j in links]
    for e in exits:
        nearest = int(np.argmin(np.hypot(villages_m[:, 0] - e[0], villages_m[:, 1] - e[1])))
        endpoints.append((villages_m[nearest], e))

    x_min, y_min, x_max, y_max = terrain.bounds_m
    step = cfg.grid_m
    cols = int((x_max - x_min) // step) + 1
    rows = int((y_max - y_min) // step) + 1
    gx = x_min + np.arange(cols) * step
    gy = y_min + np.arange(rows) * step
    mx, my = np.meshgrid(gx, gy)
    heights = terrain.height_at(mx, my)
    blocked = np.hypot(mx, my) < home_clearance_m + cfg.width_m
    on_road = np.zeros_like(blocked)

    def cell(p: FloatArray) -> tuple[int, int]:
        c = int(np.clip(round((p[0] - x_min) / step), 0, cols - 1))
        r = int(np.clip(round((p[1] - y_min) / step), 0, rows - 1))
        return r, c

    polylines = []
    for a, b in endpoints:
        path = _astar(heights, blocked, on_road, (cell(a), cell(b)), step)
        if len(path) < 2:
            continue
        for r, c in path:
            on_road[r, c] = True
        pts = np.array([[gx[c], gy[r]] for r, c in path])
        pts[0], pts[-1] = a, b
        # thin the 8-connected staircase before corner cutting, so curves come out smooth
        keep = np.unique(np.concatenate([np.arange(0, len(pts), 3), [len(pts) - 1]]))
        smooth = _chaikin(pts[keep], 4)
        polylines.append(resample_polyline(smooth, 3.0))
    return RoadNetwork(tuple(polylines), villages_m, cfg.width_m)


def polyline_raster_distance(
    polylines: tuple[FloatArray, ...], origin_m: tuple[float, float], shape: tuple[int, int], resolution_m: float
) -> Raster:
    """Distance (metres) from each raster cell centre to the nearest polyline (via a distance transform)."""
    rows, cols = shape
    canvas = np.full((rows, cols), 255, dtype=np.uint8)
    for poly in polylines:
        px = np.round((poly - np.asarray(origin_m)) / resolution_m * 16.0).astype(np.int32)
        cv2.polylines(canvas, [px.reshape(-1, 1, 2)], isClosed=False, color=(0,), thickness=1, shift=4)
    dist = cv2.distanceTransform(canvas, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64) * resolution_m
    return Raster(origin_m, resolution_m, dist)
