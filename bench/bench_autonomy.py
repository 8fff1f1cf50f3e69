"""Autonomy benchmarks: features + score + argmax on a 1000 x 1000 grid, and planning a 1 km path.

Targets: all features and the score in <= 20 ms; the straight-line plan in <= 5 ms.

Baselines, measured in the same run:

* features: a straightforward per-cell implementation (Python loops; the frontier
  distance by brute force over the boundary cells). It is far too slow for the
  whole grid, so it runs on a random subsample of cells of the *same* 1000 x 1000
  problem and its time per cell is scaled to 10^6 cells (said in the notes). Its
  values at those cells are also checked against the vectorised ones.
* straight plan: the same profile with a per-sample Python loop over the DEM.
* 3D A*: reported with optimal A* (heuristic_weight 1) as the baseline for the
  default weighted A* (1.5).
* 3D A* over the voxel map: the same 1 km terrain as OctoMap leaves (0.5 m voxels: the
  surface of every observed 1 m DEM cell, 4 voxels each), through the steps the planner
  node runs: decode (the map server's binary stream is built from those leaves by an encoder
  here), accumulate on the planner lattice, build the search grid, search. Baselines: the
  reference node-by-node decoder of uav_autonomy.core.octree_reader for the decode step,
  and the DEM-derived A* for the whole plan.

The machine is shared (2 cores, several engineers building and testing at once),
so timings are medians over repeats and can be noisy.
"""

from __future__ import annotations

import math
import time

import numpy as np
from benchlib import median, record, time_it

from uav_autonomy.core.features import (
    FeatureConfig,
    FeatureEvaluator,
    MapLayers,
    Target,
)
from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.core.mcdm import argmax_cell, weighted_score
from uav_autonomy.core.octree_reader import decode_binary_octree
from uav_autonomy.core.planning import ElevationMap, PlannerConfig, plan_astar, plan_straight
from uav_autonomy.core.planning_voxels import (
    decode_octree,
    grid_from_occupancy,
    occupancy_from_leaves,
    plan_on_voxel_map,
)

N = 1000
RES_M = 1.0
NOW_S = 500.0
HALF_LIFE_S = 60.0
WEIGHTS = {"age": 1.0, "frontier": 1.0, "target": 1.0, "drone": 1.0, "origin": 0.0}
SHARED = "2 shared cores, 5 engineers working; medians"


def make_problem() -> tuple[MapLayers, Target, tuple[float, float]]:
    rng = np.random.default_rng(7)
    spec = GridSpec(RES_M, -500.0, -500.0, N, N)
    yy, xx = np.mgrid[0:N, 0:N]
    # An irregular observed region: union of discs along a meandering flight.
    observed = np.zeros((N, N), dtype=bool)
    cx, cy = 500.0, 500.0
    for _ in range(60):
        cx = float(np.clip(cx + rng.normal(0, 40), 100, 900))
        cy = float(np.clip(cy + rng.normal(0, 40), 100, 900))
        r = rng.uniform(30, 80)
        observed |= (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
    elev = np.where(observed, 20.0 * np.sin(xx / 90.0) * np.cos(yy / 70.0) + 20.0, np.nan).astype(np.float32)
    seen = np.where(observed, rng.uniform(0.0, NOW_S, (N, N)), np.nan).astype(np.float32)
    layers = MapLayers(spec, elev, seen, observed)
    target = Target(((-300.0, -400.0), (-100.0, -420.0), (-150.0, -250.0), (-320.0, -280.0)))
    return layers, target, (20.0, -35.0)


def features_and_score(ev: FeatureEvaluator, layers: MapLayers, target: Target, drone: tuple[float, float]) -> None:
    maps = ev.evaluate(layers, now_s=NOW_S, drone_xy_m=drone, target=target)
    argmax_cell(weighted_score(maps.scored(), WEIGHTS))


def per_cell_baseline(
    layers: MapLayers, target: Target, drone: tuple[float, float], cells: list[tuple[int, int]]
) -> tuple[float, dict[tuple[int, int], dict[str, float]]]:
    """Seconds per cell of a straightforward per-cell implementation, and its values."""
    spec = layers.spec
    obs = layers.observed
    poly = target.points_xy_m
    t0 = time.perf_counter()
    # Boundary cells, one cell at a time (outside the grid counts as unobserved).
    boundary = []
    for r in range(N):
        for c in range(N):
            if not obs[r, c]:
                continue
            for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1)):
                rr, cc = r + dr, c + dc
                if not (0 <= rr < N and 0 <= cc < N) or not obs[rr, cc]:
                    boundary.append((r, c))
                    break
    boundary_s = time.perf_counter() - t0
    corners = [spec.cell_center_m(r, c) for r in (0, N - 1) for c in (0, N - 1)]
    d_drone_max = max(math.dist(drone, p) for p in corners)
    out: dict[tuple[int, int], dict[str, float]] = {}
    t1 = time.perf_counter()
    for r, c in cells:
        x, y = spec.cell_center_m(r, c)
        seen = float(layers.last_seen_s[r, c])
        age = 0.0 if math.isnan(seen) else 2.0 ** (-max(NOW_S - seen, 0.0) / HALF_LIFE_S)
        d_front = min(math.hypot(r - br, c - bc) for br, bc in boundary) * RES_M
        inside = False
        d_t = math.inf
        for i in range(len(poly)):
            (ax, ay), (bx, by) = poly[i], poly[(i + 1) % len(poly)]
            if (ay > y) != (by > y) and x < ax + (y - ay) * (bx - ax) / (by - ay):
                inside = not inside
            ex, ey = bx - ax, by - ay
            t = max(0.0, min(1.0, ((x - ax) * ex + (y - ay) * ey) / (ex * ex + ey * ey)))
            d_t = min(d_t, math.hypot(x - ax - t * ex, y - ay - t * ey))
        d_t = 0.0 if inside else d_t
        d_d = math.dist((x, y), drone)
        out[(r, c)] = {"age": age, "frontier_d": d_front, "target_d": d_t, "drone": 1.0 - d_d / d_drone_max}
    per_cell_s = (time.perf_counter() - t1) / len(cells)
    # The max-normalisations need the max over every cell: one more pass (a per-cell max).
    return per_cell_s + boundary_s / (N * N), out


def bench_features() -> None:
    layers, target, drone = make_problem()
    ev = FeatureEvaluator(FeatureConfig(age_half_life_s=HALF_LIFE_S))
    t0 = time.perf_counter()
    features_and_score(ev, layers, target, drone)  # cold: includes the target polygon distance
    cold_ms = (time.perf_counter() - t0) * 1e3
    warm = time_it(lambda: features_and_score(ev, layers, target, drone), repeat=15, warmup=2)
    warm_ms = median(warm) * 1e3
    rng = np.random.default_rng(1)
    cells = [(int(r), int(c)) for r, c in rng.integers(0, N, size=(300, 2))]
    per_cell_s, values = per_cell_baseline(layers, target, drone, cells)
    baseline_ms = per_cell_s * N * N * 1e3
    # Cross-check the per-cell values against the vectorised features.
    maps = ev.evaluate(layers, now_s=NOW_S, drone_xy_m=drone, target=target)
    from uav_autonomy.core.features import distance_to_polygon_m  # noqa: PLC0415

    d_poly = distance_to_polygon_m(layers.spec, target.as_array())
    worst = 0.0
    for (r, c), v in values.items():
        worst = max(worst, abs(v["age"] - float(maps.layers["age"][r, c])))
        worst = max(worst, abs(v["target_d"] - float(d_poly[r, c])) / 1000.0)
        worst = max(worst, abs(v["drone"] - float(maps.layers["drone"][r, c])))
    assert worst < 1e-3, f"per-cell baseline disagrees with the vectorised features by {worst}"
    record(
        "autonomy.features_score.1000x1000",
        warm_ms,
        "ms",
        baseline_ms,
        target="<= 20",
        met=warm_ms <= 20.0,
        notes=(
            f"6 features + weighted score + argmax per new map (target/origin layers cached: they depend only on "
            f"grid and target); cold first call incl. the target polygon distance "
            f"{cold_ms:.1f} ms. Baseline: per-cell Python on {len(cells)} random cells scaled to 1e6 cells. {SHARED}"
        ),
    )


def bench_planner() -> None:
    layers, _, _ = make_problem()
    dem = ElevationMap(layers.spec, layers.elevation_m)
    cfg = PlannerConfig(max_altitude_m=300.0)
    start, goal = (-450.0, -300.0, 0.0), (450.0, 135.0)  # 1.0 km
    assert abs(math.dist(start[:2], goal) - 1000.0) < 1.0
    ms = median(time_it(lambda: plan_straight(start, goal, dem, cfg), repeat=50, warmup=3)) * 1e3

    def per_sample() -> float:
        spec = dem.spec
        length = math.dist(start[:2], goal)
        n = math.ceil(length / (spec.resolution_m * 0.25)) + 1
        best = -math.inf
        for i in range(n):
            t = i / (n - 1)
            x = start[0] + t * (goal[0] - start[0])
            y = start[1] + t * (goal[1] - start[1])
            cell = spec.cell_of(x, y)
            if cell is not None:
                e = float(dem.elevation_m[cell])
                if not math.isnan(e) and e > best:
                    best = e
        return best

    base_ms = median(time_it(per_sample, repeat=5, warmup=1)) * 1e3
    record(
        "autonomy.plan_straight.1km",
        ms,
        "ms",
        base_ms,
        target="<= 5",
        met=ms <= 5.0,
        notes=f"climb-cruise-descend over a 1000x1000 m DEM at 1 m; baseline: per-sample Python DEM scan. {SHARED}",
    )
    astar = PlannerConfig(algorithm="astar", max_altitude_m=150.0, unknown_space="free")
    optimal = PlannerConfig(algorithm="astar", max_altitude_m=150.0, unknown_space="free", heuristic_weight=1.0)
    a_ms = median(time_it(lambda: plan_astar(start, goal, dem, astar), repeat=3, warmup=1)) * 1e3
    o_ms = median(time_it(lambda: plan_astar(start, goal, dem, optimal), repeat=3, warmup=1)) * 1e3
    record(
        "autonomy.plan_astar.1km",
        a_ms,
        "ms",
        o_ms,
        notes=(
            "3D A* (10 m x 5 m voxels, weighted 1.5, shortcut) over the same DEM; "
            f"baseline: optimal A* (weight 1). No target is set for it. {SHARED}"
        ),
    )


def encode_octree(occupied_keys: np.ndarray) -> bytes:
    """OctoMap binary stream (depth-first, 2 bits per child) of occupied unit voxels at the given keys.

    Only occupied leaves (code 2) and inner nodes (3): enough for a benchmark input the decoder must walk.
    """
    out = bytearray()
    keys = np.unique(occupied_keys, axis=0)

    def node(sub: np.ndarray, depth: int) -> None:
        half = 1 << (15 - depth)
        child = ((sub[:, 0] & half) > 0) * 1 + ((sub[:, 1] & half) > 0) * 2 + ((sub[:, 2] & half) > 0) * 4
        bits = 0
        groups = []
        for c in range(8):
            part = sub[child == c]
            if len(part) == 0:
                continue
            code = 2 if depth == 15 else 3
            bits |= code << (2 * c)
            groups.append(part)
        out.extend(int(bits).to_bytes(2, "little"))
        if depth < 15:
            for part in groups:
                node(part, depth + 1)

    node(keys, 0)
    return bytes(out)


def bench_voxel_planner() -> None:
    layers, _, _ = make_problem()
    dem = ElevationMap(layers.spec, layers.elevation_m)
    start, goal = (-450.0, -300.0, 0.0), (450.0, 135.0)
    # Surface voxels (0.5 m) of every observed 1 m DEM cell, over a 400 x 400 m block around the route's middle
    # (a whole 1 km^2 map at 0.5 m is ~4e6 leaves; the block keeps the pure-Python encoder of this bench short).
    rows, cols = np.nonzero(np.isfinite(layers.elevation_m))
    xs = layers.spec.origin_x_m + cols * RES_M
    ys = layers.spec.origin_y_m + rows * RES_M
    keep = (np.abs(xs) < 200.0) & (np.abs(ys + 80.0) < 200.0)
    xs, ys, zs = xs[keep], ys[keep], layers.elevation_m[rows[keep], cols[keep]]
    idx = []
    for dx in (0.0, 0.5):
        for dy in (0.0, 0.5):
            idx.append(np.stack([np.floor((xs + dx) / 0.5), np.floor((ys + dy) / 0.5), np.floor(zs / 0.5)], 1))
    keys = (np.concatenate(idx) + 32768).astype(np.int64)
    data = encode_octree(keys)
    cfg = PlannerConfig(algorithm="astar", max_altitude_m=150.0, unknown_space="free")
    n_leaves = len(decode_octree(data, 0.5).occupied)
    dec_ms = median(time_it(lambda: decode_octree(data, 0.5), repeat=3, warmup=1)) * 1e3
    ref_ms = median(time_it(lambda: decode_binary_octree(data, 0.5), repeat=1, warmup=0)) * 1e3
    leaves = decode_octree(data, 0.5)
    occ_ms = median(time_it(lambda: occupancy_from_leaves(leaves, cfg), repeat=3, warmup=1)) * 1e3
    occ = occupancy_from_leaves(leaves, cfg)
    grid_ms = median(time_it(lambda: grid_from_occupancy(occ, start, (*goal, 50.0), cfg), repeat=3, warmup=1)) * 1e3
    plan_ms = median(time_it(lambda: plan_on_voxel_map(start, goal, occ, cfg), repeat=3, warmup=1)) * 1e3
    dem_ms = median(time_it(lambda: plan_astar(start, goal, dem, cfg), repeat=3, warmup=1)) * 1e3
    record(
        "autonomy.decode_octree",
        dec_ms,
        "ms",
        ref_ms,
        notes=f"{len(data) // 2} inner nodes, {n_leaves} leaves (0.5 m); baseline: node-by-node reference decoder. "
        f"{SHARED}",
    )
    record(
        "autonomy.plan_voxel_map.1km",
        occ_ms + plan_ms,
        "ms",
        dem_ms,
        notes=(
            f"lattice accumulation {occ_ms:.0f} ms (once per map) + grid and A* {plan_ms:.0f} ms (of which the grid "
            f"{grid_ms:.0f} ms), 10 m x 5 m voxels, weighted 1.5, {n_leaves} voxel-map leaves; decode not included. "
            f"Baseline: the DEM-derived A* on the same route. {SHARED}"
        ),
    )


if __name__ == "__main__":
    bench_features()
    bench_planner()
    bench_voxel_planner()
