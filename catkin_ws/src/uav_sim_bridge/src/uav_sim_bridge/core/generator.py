"""Procedural world content: terrain conformed to roads, villages, forest, people, vehicles.

:func:`build_world_parts` is deterministic: every stage draws from its own random
stream spawned from ``WorldConfig.seed``, so changing, say, the number of people
leaves the terrain, roads and trees untouched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core import figures
from uav_sim_bridge.core import mesh as prim
from uav_sim_bridge.core.figures import VEHICLE_SIZE_M, PersonPose, VehicleType
from uav_sim_bridge.core.mesh import LOD_ALWAYS, LOD_FAR, LOD_NEAR, MeshAccumulator, MeshArrays
from uav_sim_bridge.core.objects import ObjectPose, WorldObject
from uav_sim_bridge.core.roads import Raster, RoadNetwork, pick_village_sites, plan_roads, polyline_raster_distance
from uav_sim_bridge.core.terrain import Heightfield, fbm_noise, generate_terrain, smoothstep
from uav_sim_bridge.core.world_config import CustomObjectConfig, ObjectClass, WorldConfig
from uav_sim_bridge.errors import WorldError, WorldFileError

__all__ = ["ROAD_LIFT_M", "TERRAIN_INSTANCE_ID", "WorldParts", "build_world_parts"]

FloatArray = npt.NDArray[np.float64]

TERRAIN_INSTANCE_ID = 1
MAX_INSTANCE_ID = 65534  # instance images are 16UC1 and 0 is the sky
ROAD_LIFT_M = 0.12  # road surface above the (conformed) terrain
_ROAD_SINK_M = 0.05  # terrain under a road is lowered by this much below the smooth road bed
_RASTER_RES_M = 1.0
#: A vehicle parked at the kerb stands this far onto the road (the rest on the verge), clear of both lanes.
KERB_OVERLAP_M = 0.2


@dataclass(frozen=True)
class WorldInputs:
    """What a world config names on disk, read by the shell (``shell.world_store.load_world_inputs``).

    ``heightmap``: the terrain image as heights in [0, 1] (:func:`~uav_sim_bridge.core.terrain.normalized_heightmap`);
    ``meshes``: per ``custom_objects`` entry, its triangles as ``(vertices (N, 3) m, faces (M, 3))``.
    """

    heightmap: FloatArray | None = None
    meshes: tuple[tuple[FloatArray, npt.NDArray[np.int64]], ...] = ()


@dataclass(frozen=True)
class WorldParts:
    """Everything :func:`build_world_parts` makes; :class:`~uav_sim_bridge.core.world.World` wraps it."""

    terrain: Heightfield
    mesh: MeshArrays
    objects: tuple[WorldObject, ...]
    roads: RoadNetwork


@dataclass(frozen=True)
class _Site:
    """What the placement stages share: config, terrain, roads and distance rasters."""

    cfg: WorldConfig
    terrain: Heightfield
    roads: RoadNetwork
    road_dist: Raster
    bld_dist: Raster | None = None


class _Ids:
    """Hands out instance ids and records the object list."""

    def __init__(self) -> None:
        self.objects: list[WorldObject] = []
        self._next = TERRAIN_INSTANCE_ID
        self._per_class: dict[ObjectClass, int] = {}

    def add(
        self,
        cls: ObjectClass,
        pose: ObjectPose,
        size_m: tuple[float, float, float],
        name: str = "",
        *,
        kind: str = "",
        shape: tuple[float, ...] = (),
    ) -> int:
        if self._next > MAX_INSTANCE_ID:
            msg = f"the world has more than {MAX_INSTANCE_ID} objects; reduce forest.max_trees or other counts"
            raise WorldError(msg)
        iid = self._next
        self._next += 1
        k = self._per_class.get(cls, 0)
        self._per_class[cls] = k + 1
        self.objects.append(WorldObject(iid, cls, name or f"{cls.label}_{k:04d}", pose, size_m, kind, shape))
        return iid


def _raster_grid(terrain: Heightfield) -> tuple[tuple[float, float], tuple[int, int]]:
    x_min, y_min, x_max, y_max = terrain.bounds_m
    cols = math.ceil((x_max - x_min) / _RASTER_RES_M) + 1
    rows = math.ceil((y_max - y_min) / _RASTER_RES_M) + 1
    return (x_min, y_min), (rows, cols)


def _conform_terrain_to_roads(terrain: Heightfield, road_dist: Raster, width_m: float) -> Heightfield:
    """Lay a smooth road bed: near roads the terrain follows a blurred copy of itself."""
    sigma_cells = max(1.0, 12.0 / terrain.resolution_m)
    blurred = cv2.GaussianBlur(terrain.heights_m, (0, 0), sigmaX=sigma_cells, borderType=cv2.BORDER_REFLECT)
    gx, gy = terrain.node_xy()
    d = road_dist.sample(gx, gy)
    keep = smoothstep(width_m / 2 + 1.0 + terrain.resolution_m, width_m / 2 + 9.0 + terrain.resolution_m, d)
    heights = (blurred - _ROAD_SINK_M) * (1.0 - keep) + terrain.heights_m * keep
    field = terrain.with_heights(heights)
    return field.with_heights(field.heights_m - float(field.height_at(0.0, 0.0)))


def _road_surface_height(terrain: Heightfield, x: FloatArray, y: FloatArray) -> FloatArray:
    return terrain.height_at(x, y) + ROAD_LIFT_M


def _add_roads(acc: MeshAccumulator, ids: _Ids, terrain: Heightfield, roads: RoadNetwork) -> None:
    half = roads.width_m / 2.0
    for k, line in enumerate(roads.polylines):
        tangent = np.gradient(line, axis=0)
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        offsets = np.array([-half, -half * 0.5, 0.0, half * 0.5, half])
        xy = line[:, None, :] + offsets[None, :, None] * normal[:, None, :]  # (N, 5, 2)
        lift = 0.004 * (k % 5)  # distinct heights where two roads overlap at a junction
        z = _road_surface_height(terrain, xy[..., 0], xy[..., 1]) + lift
        verts = np.concatenate([xy, z[..., None]], axis=-1).reshape(-1, 3)
        n_across = len(offsets)
        idx = np.arange(len(line) * n_across).reshape(len(line), n_across)
        a, b = idx[:-1, :-1], idx[:-1, 1:]
        c, d = idx[1:, :-1], idx[1:, 1:]
        # Cross-sections run right -> left of the travel direction, so (a, d, b) is CCW from above.
        faces = np.concatenate([np.stack([a, d, b], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
        edge = np.abs(offsets) / half
        shade = 0.30 + 0.04 * edge  # asphalt, lighter worn edges
        colors = np.repeat((shade[None, :, None] * np.array([1.0, 0.98, 0.95])[None, None, :]), len(line), 0)
        lo = verts.min(axis=0)
        hi = verts.max(axis=0)
        centre = (lo + hi) / 2.0
        iid = ids.add(
            ObjectClass.ROAD,
            ObjectPose((float(centre[0]), float(centre[1]), float(lo[2])), 0.0),
            (float(hi[0] - lo[0]), float(hi[1] - lo[1]), float(hi[2] - lo[2])),
        )
        normals = np.tile([0.0, 0.0, 1.0], (len(verts), 1))
        acc.add_smooth(verts, normals, faces, colors.reshape(-1, 3), iid)


_WALL_COLORS = np.array(
    [[0.86, 0.83, 0.76], [0.78, 0.72, 0.60], [0.90, 0.88, 0.84], [0.70, 0.62, 0.50], [0.80, 0.76, 0.70],
     [0.62, 0.60, 0.58], [0.84, 0.74, 0.56]]
)  # fmt: skip
_ROOF_COLORS = np.array(
    [[0.62, 0.24, 0.16], [0.52, 0.20, 0.14], [0.36, 0.34, 0.34], [0.42, 0.30, 0.22], [0.70, 0.34, 0.20],
     [0.28, 0.29, 0.33]]
)  # fmt: skip


def _footprint_corners(x: float, y: float, length: float, depth: float, yaw: float) -> FloatArray:
    c, s = math.cos(yaw), math.sin(yaw)
    local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64) * [length / 2, depth / 2]
    return np.stack([x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1]], axis=1)


@dataclass(frozen=True)
class _Lot:
    """A candidate building: centre, heading and footprint."""

    x: float
    y: float
    yaw: float
    length: float
    depth: float
    big: bool

    @property
    def radius(self) -> float:
        return 0.5 * math.hypot(self.length, self.depth)


def _propose_lot(site: _Site, village: FloatArray, near: FloatArray, rng: np.random.Generator) -> _Lot:
    """Mostly facing a road of the village, sometimes anywhere in it."""
    big = bool(rng.random() < 0.2)
    length = rng.uniform(14.0, 24.0) if big else rng.uniform(7.0, 13.0)
    depth = rng.uniform(9.0, 14.0) if big else rng.uniform(6.0, 9.0)
    if len(near) and rng.random() < 0.75:
        k = int(rng.integers(len(near)))
        j = min(k + 1, len(near) - 1)
        i = max(j - 1, 0)
        tangent = near[j] - near[i]
        heading = math.atan2(tangent[1], tangent[0]) if np.any(tangent) else rng.uniform(0, math.pi)
        side = 1.0 if rng.random() < 0.5 else -1.0
        setback = site.roads.width_m / 2.0 + rng.uniform(3.0, 8.0) + depth / 2.0
        x = near[k, 0] - side * math.sin(heading) * setback
        y = near[k, 1] + side * math.cos(heading) * setback
        return _Lot(x, y, heading + rng.normal(0.0, 0.04), length, depth, big)
    ang, rad = rng.uniform(0, 2 * math.pi), site.cfg.buildings.village_radius_m * math.sqrt(rng.random())
    x, y = village[0] + rad * math.cos(ang), village[1] + rad * math.sin(ang)
    return _Lot(x, y, rng.uniform(0.0, math.pi), length, depth, big)


def _lot_fits(site: _Site, lot: _Lot, discs: list[tuple[float, float, float]]) -> FloatArray | None:
    """The lot's footprint corners if it is inside the map, off roads and home, apart from others, not too steep."""
    x_min, y_min, x_max, y_max = site.terrain.bounds_m
    r = lot.radius
    if not (x_min + r < lot.x < x_max - r and y_min + r < lot.y < y_max - r):
        return None
    if math.hypot(lot.x, lot.y) < site.cfg.home_clear_radius_m + r + 5.0:
        return None
    if any(math.hypot(lot.x - bx, lot.y - by) < r + br + 2.5 for bx, by, br in discs):
        return None
    corners = _footprint_corners(lot.x, lot.y, lot.length, lot.depth, lot.yaw)
    probe = np.concatenate([corners, [[lot.x, lot.y]], (corners + np.roll(corners, 1, axis=0)) / 2.0])
    if np.min(site.road_dist.sample(probe[:, 0], probe[:, 1])) < site.roads.width_m / 2.0 + 1.5:
        return None
    if float(np.ptp(site.terrain.height_at(corners[:, 0], corners[:, 1]))) > 4.0:
        return None
    return corners


def _add_buildings(acc: MeshAccumulator, ids: _Ids, site: _Site, rng: np.random.Generator) -> list[FloatArray]:
    """Houses along the roads of each village; returns the footprints ``(4, 2)``."""
    bcfg = site.cfg.buildings
    terrain = site.terrain
    samples = site.roads.samples(2.0)
    footprints: list[FloatArray] = []
    discs: list[tuple[float, float, float]] = []
    walls: list[tuple[FloatArray, FloatArray, float]] = []  # (bottom centre, size, yaw)
    roofs: list[tuple[FloatArray, FloatArray, float, float]] = []  # (eave centre, footprint, height, yaw)
    wall_cols: list[FloatArray] = []
    roof_cols: list[FloatArray] = []
    wall_ids: list[int] = []
    roof_ids: list[int] = []
    for village in site.roads.villages_m:
        near = samples[np.hypot(samples[:, 0] - village[0], samples[:, 1] - village[1]) < bcfg.village_radius_m]
        target = int(rng.integers(bcfg.per_village_min, bcfg.per_village_max + 1))
        placed = 0
        for _ in range(target * 60):
            if placed >= target:
                break
            lot = _propose_lot(site, village, near, rng)
            corners = _lot_fits(site, lot, discs)
            if corners is None:
                continue
            zs = terrain.height_at(corners[:, 0], corners[:, 1])
            z_ground = float(terrain.height_at(lot.x, lot.y))
            base = float(zs.min()) - 0.5
            storeys = int(rng.integers(1, 3)) if not lot.big else 1
            wall_top = float(zs.max()) + (rng.uniform(5.0, 8.0) if lot.big else 2.9 * storeys + rng.uniform(0.0, 0.6))
            flat = rng.random() < (0.6 if lot.big else bcfg.flat_roof_fraction)
            roof_h = 0.0 if flat else min(lot.length, lot.depth) * rng.uniform(0.25, 0.45)
            # the ridge runs along the longer side
            ridge_yaw = lot.yaw if lot.length >= lot.depth else lot.yaw + math.pi / 2
            roof_fp = (max(lot.length, lot.depth) + 0.6, min(lot.length, lot.depth) + 0.8)
            iid = ids.add(
                ObjectClass.BUILDING,
                ObjectPose((lot.x, lot.y, z_ground), lot.yaw),
                (lot.length, lot.depth, wall_top + roof_h - z_ground),
            )
            walls.append((np.array([lot.x, lot.y, base]), np.array([lot.length, lot.depth, wall_top - base]), lot.yaw))
            wall_cols.append(_WALL_COLORS[rng.integers(len(_WALL_COLORS))] * rng.uniform(0.92, 1.05))
            wall_ids.append(iid)
            if not flat:
                roofs.append((np.array([lot.x, lot.y, wall_top]), np.array(roof_fp), roof_h, ridge_yaw))
                roof_cols.append(_ROOF_COLORS[rng.integers(len(_ROOF_COLORS))] * rng.uniform(0.9, 1.08))
                roof_ids.append(iid)
            footprints.append(corners)
            discs.append((lot.x, lot.y, lot.radius))
            placed += 1
    if walls:
        v, f = prim.boxes(
            np.array([w[0] for w in walls]), np.array([w[1] for w in walls]), np.array([w[2] for w in walls])
        )
        acc.add_flat(v, f, np.clip(np.array(wall_cols), 0, 1), np.array(wall_ids))
    if roofs:
        v, f = prim.gable_roofs(
            np.array([r[0] for r in roofs]),
            np.array([r[1] for r in roofs]),
            np.array([r[2] for r in roofs]),
            np.array([r[3] for r in roofs]),
        )
        acc.add_flat(v, f, np.clip(np.array(roof_cols), 0, 1), np.array(roof_ids))
    return footprints


def _footprint_distance(footprints: list[FloatArray], origin: tuple[float, float], shape: tuple[int, int]) -> Raster:
    canvas = np.full(shape, 255, dtype=np.uint8)
    if footprints:
        polys = [np.round((fp - np.asarray(origin)) / _RASTER_RES_M * 16).astype(np.int32) for fp in footprints]
        cv2.fillPoly(canvas, polys, color=(0,), shift=4)
    dist = cv2.distanceTransform(canvas, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64) * _RASTER_RES_M
    return Raster(origin, _RASTER_RES_M, dist)


def _vehicle_types(cfg: WorldConfig, n: int, rng: np.random.Generator) -> npt.NDArray[np.int64]:
    labels = list(cfg.vehicles.types)
    w = np.array([cfg.vehicles.types[k] for k in labels], dtype=np.float64)
    picks = rng.choice(len(labels), size=n, p=w / w.sum()) if n else np.zeros(0, np.int64)
    return np.array([int(VehicleType.from_label(labels[int(i)])) for i in picks], dtype=np.int64)


def _place_vehicles(site: _Site, rng: np.random.Generator) -> tuple[FloatArray, FloatArray, npt.NDArray[np.int64]]:
    """Positions ``(N, 3)``, headings and :class:`VehicleType` values of the vehicles: parked at the kerb of a
    road (mostly on the verge, aligned with the road, clear of both lanes) or anywhere in a village."""
    cfg, terrain, roads, road_dist, bld_dist = site.cfg, site.terrain, site.roads, site.road_dist, site.bld_dist
    assert bld_dist is not None
    types = _vehicle_types(cfg, cfg.vehicles.count, rng)
    pos: list[tuple[float, float, float]] = []
    yaw: list[float] = []
    kinds: list[int] = []
    x_min, y_min, x_max, y_max = terrain.bounds_m
    lines = [p for p in roads.polylines if len(p) >= 3]
    for _ in range(cfg.vehicles.count * 50):
        if len(pos) >= cfg.vehicles.count:
            break
        vtype = VehicleType(int(types[len(pos)]))
        length, width, _ = VEHICLE_SIZE_M[vtype]
        if lines and rng.random() < 0.65:
            line = lines[int(rng.integers(len(lines)))]
            k = int(rng.integers(1, len(line) - 1))
            t = line[k + 1] - line[k - 1]
            heading = math.atan2(t[1], t[0])
            side = 1.0 if rng.random() < 0.5 else -1.0  # right (1) or left kerb, facing the traffic of that side
            heading += 0.0 if side > 0 else math.pi
            offset = roads.width_m / 2.0 + width / 2.0 - KERB_OVERLAP_M
            x = line[k, 0] + math.sin(heading) * offset
            y = line[k, 1] - math.cos(heading) * offset
            z = float(terrain.height_at(x, y))
            if road_dist.sample(x, y) < roads.width_m / 2.0 + width / 2.0 - KERB_OVERLAP_M - 0.5:
                continue  # another road passes by (a junction): this kerb is someone's lane
        elif len(roads.villages_m):
            v = roads.villages_m[int(rng.integers(len(roads.villages_m)))]
            ang, rad = rng.uniform(0, 2 * math.pi), cfg.buildings.village_radius_m * math.sqrt(rng.random())
            x, y = v[0] + rad * math.cos(ang), v[1] + rad * math.sin(ang)
            if road_dist.sample(x, y) < roads.width_m / 2 + length / 2 + 0.5 or bld_dist.sample(x, y) < length / 2 + 1:
                continue
            heading = rng.uniform(-math.pi, math.pi)
            z = float(terrain.height_at(x, y))
        else:
            break
        if not (x_min + 5 < x < x_max - 5 and y_min + 5 < y < y_max - 5):
            continue
        if math.hypot(x, y) < cfg.home_clear_radius_m + length / 2 + 2.0 or bld_dist.sample(x, y) < width / 2 + 1.5:
            continue
        if any(math.hypot(x - px, y - py) < 9.0 for px, py, _ in pos):
            continue
        pos.append((x, y, z))
        yaw.append(heading)
        kinds.append(int(vtype))
    return (
        np.array(pos, dtype=np.float64).reshape(-1, 3),
        np.array(yaw, dtype=np.float64),
        np.array(kinds, dtype=np.int64),
    )


def _place_people(site: _Site, taken: FloatArray, rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
    cfg, terrain, roads, road_dist, bld_dist = site.cfg, site.terrain, site.roads, site.road_dist, site.bld_dist
    assert bld_dist is not None
    pos: list[tuple[float, float, float]] = []
    x_min, y_min, x_max, y_max = terrain.bounds_m
    lines = [p for p in roads.polylines if len(p) >= 3]
    for _ in range(cfg.people.count * 60):
        if len(pos) >= cfg.people.count:
            break
        u = rng.random()
        if lines and u < 0.3:
            line = lines[int(rng.integers(len(lines)))]
            k = int(rng.integers(1, len(line) - 1))
            t = line[k + 1] - line[k - 1]
            t = t / (np.linalg.norm(t) + 1e-12)
            side = rng.choice([-1.0, 1.0]) * (roads.width_m / 2 + rng.uniform(0.6, 1.8))
            x, y = line[k, 0] - t[1] * side, line[k, 1] + t[0] * side
        elif len(roads.villages_m) and u < 0.7:
            v = roads.villages_m[int(rng.integers(len(roads.villages_m)))]
            ang, rad = rng.uniform(0, 2 * math.pi), cfg.buildings.village_radius_m * math.sqrt(rng.random())
            x, y = v[0] + rad * math.cos(ang), v[1] + rad * math.sin(ang)
        else:
            x, y = rng.uniform(x_min + 10, x_max - 10), rng.uniform(y_min + 10, y_max - 10)
        if not (x_min + 2 < x < x_max - 2 and y_min + 2 < y < y_max - 2):
            continue
        if math.hypot(x, y) < cfg.home_clear_radius_m + 1.0:
            continue
        if road_dist.sample(x, y) < roads.width_m / 2 + 0.4 or bld_dist.sample(x, y) < 1.5:
            continue
        if len(taken) and np.min(np.hypot(taken[:, 0] - x, taken[:, 1] - y)) < 4.0:
            continue
        if any(math.hypot(x - px, y - py) < 2.0 for px, py, _ in pos):
            continue
        pos.append((x, y, float(terrain.height_at(x, y))))
    yaws = rng.uniform(-math.pi, math.pi, len(pos))
    return np.array(pos, dtype=np.float64).reshape(-1, 3), yaws


def _person_poses(cfg: WorldConfig, n: int, rng: np.random.Generator) -> npt.NDArray[np.int64]:
    labels = list(cfg.people.poses)
    w = np.array([cfg.people.poses[k] for k in labels], dtype=np.float64)
    picks = rng.choice(len(labels), size=n, p=w / w.sum()) if n else np.zeros(0, np.int64)
    return np.array([int(PersonPose.from_label(labels[int(i)])) for i in picks], dtype=np.int64)


def _add_people(
    acc: MeshAccumulator, ids: _Ids, cfg: WorldConfig, placed: tuple[FloatArray, FloatArray], rng: np.random.Generator
) -> None:
    """Articulated people (:mod:`.figures`) in seeded poses, heights, builds and clothes."""
    positions, yaws = placed
    n = len(positions)
    if n == 0:
        return
    poses = _person_poses(cfg, n, rng)
    lo, hi = cfg.people.height_m
    # rounded as the object records store them: the mesh and the box are built from exactly those values
    heights = np.round(np.clip(rng.normal((lo + hi) / 2, (hi - lo) / 4, n), lo, hi), 4)
    builds = np.round(rng.uniform(0.88, 1.18, n), 4)
    colors = figures.random_person_colors(n, rng)
    sizes = figures.person_boxes(heights, builds, poses)
    iids = np.array(
        [
            ids.add(
                ObjectClass.PERSON,
                ObjectPose((float(p[0]), float(p[1]), float(p[2])), float(a)),
                (float(sz[0]), float(sz[1]), float(sz[2])),
                kind=PersonPose(int(ps)).label,
                shape=(float(h), float(b)),
            )
            for p, a, sz, ps, h, b in zip(positions, yaws, sizes, poses, heights, builds, strict=True)
        ]
    )
    local = figures.person_vertices(heights, builds, poses)
    faces, roles = figures.person_faces()
    world = np.stack(
        [ObjectPose(tuple(p), float(a)).to_world(v) for p, a, v in zip(positions, yaws, local, strict=True)]
    )
    acc.add_flat(world, faces, figures.face_colors(roles, colors), iids)


def _add_vehicles(
    acc: MeshAccumulator,
    ids: _Ids,
    placed: tuple[FloatArray, FloatArray, npt.NDArray[np.int64]],
    rng: np.random.Generator,
) -> None:
    """Cars, vans and trucks (:mod:`.figures`) in seeded colours."""
    positions, yaws, types = placed
    n = len(positions)
    if n == 0:
        return
    colors = figures.random_vehicle_colors(n, rng)
    iids = np.array(
        [
            ids.add(
                ObjectClass.VEHICLE,
                ObjectPose((float(p[0]), float(p[1]), float(p[2])), float(a)),
                VEHICLE_SIZE_M[VehicleType(int(t))],
                kind=VehicleType(int(t)).label,
            )
            for p, a, t in zip(positions, yaws, types, strict=True)
        ]
    )
    for vtype in VehicleType:
        sel = np.flatnonzero(types == int(vtype))
        if len(sel) == 0:
            continue
        verts, faces, roles = figures.vehicle_template(vtype)
        world = np.stack([ObjectPose(tuple(positions[i]), float(yaws[i])).to_world(verts) for i in sel])
        acc.add_flat(world, faces, figures.face_colors(roles, colors[sel]), iids[sel])


def _place_trees(site: _Site, avoid: FloatArray, rng: np.random.Generator) -> tuple[FloatArray, FloatArray]:
    """Tree positions ``(N, 3)`` and the forest density field at the terrain nodes."""
    cfg, terrain, road_dist, bld_dist = site.cfg, site.terrain, site.road_dist, site.bld_dist
    assert bld_dist is not None
    width_m = site.roads.width_m
    fcfg = cfg.forest
    x_min, y_min, x_max, y_max = terrain.bounds_m
    gx_n, gy_n = terrain.node_xy()
    height = terrain.heights_m
    spread = max(float(np.ptp(height)), 1.0)
    density_nodes = fbm_noise(gx_n, gy_n, 230.0, 4, rng) + 0.5 * (height - height.min()) / spread
    s = fcfg.spacing_m
    xs = np.arange(x_min + s / 2, x_max, s)
    ys = np.arange(y_min + s / 2, y_max, s)
    cx, cy = np.meshgrid(xs, ys)
    cand = np.stack([cx.ravel(), cy.ravel()], axis=1) + rng.uniform(-0.45 * s, 0.45 * s, (cx.size, 2))
    dens_field = Heightfield(terrain.origin_m, terrain.resolution_m, density_nodes)
    dens = dens_field.height_at(cand[:, 0], cand[:, 1])
    thr = float(np.quantile(density_nodes, 1.0 - fcfg.coverage)) if fcfg.coverage > 0 else np.inf
    lone = rng.random(len(cand)) < (0.006 if fcfg.coverage > 0 else 0.0)  # a few lone trees in the fields
    keep = (dens > thr) | lone
    keep &= road_dist.sample(cand[:, 0], cand[:, 1]) > width_m / 2 + 3.0
    keep &= bld_dist.sample(cand[:, 0], cand[:, 1]) > 4.0
    keep &= np.hypot(cand[:, 0], cand[:, 1]) > cfg.home_clear_radius_m + 5.0
    cand = cand[keep]
    if len(avoid) and len(cand):
        d2 = np.full(len(cand), np.inf)
        for p in avoid:
            d2 = np.minimum(d2, (cand[:, 0] - p[0]) ** 2 + (cand[:, 1] - p[1]) ** 2)
        cand = cand[d2 > 4.0**2]
    if len(cand) > fcfg.max_trees:
        cand = cand[np.sort(rng.choice(len(cand), fcfg.max_trees, replace=False))]
    z = terrain.height_at(cand[:, 0], cand[:, 1])
    return np.concatenate([cand, z[:, None]], axis=1), density_nodes


def _add_trees(
    acc: MeshAccumulator, ids: _Ids, cfg: WorldConfig, positions: FloatArray, rng: np.random.Generator
) -> None:
    n = len(positions)
    if n == 0:
        return
    conifer = rng.random(n) < cfg.forest.conifer_fraction
    trunk_h = np.where(conifer, rng.uniform(1.2, 2.6, n), rng.uniform(1.8, 3.2, n))
    trunk_r = np.where(conifer, rng.uniform(0.18, 0.3, n), rng.uniform(0.22, 0.36, n))
    crown_r = np.where(conifer, rng.uniform(1.6, 3.0, n), rng.uniform(2.2, 4.2, n))
    crown_h = np.where(conifer, rng.uniform(6.0, 13.0, n), rng.uniform(3.5, 6.5, n))
    tint = rng.uniform(0.8, 1.15, n)[:, None]
    green = np.where(
        conifer[:, None], np.array([[0.11, 0.27, 0.12]]) * tint, np.array([[0.26, 0.42, 0.15]]) * tint
    ) + rng.normal(0.0, 0.015, (n, 3))
    green = np.clip(green, 0.0, 1.0)
    total_h = np.where(conifer, trunk_h + crown_h, trunk_h + crown_h * 0.95)
    yaw = rng.uniform(0, 2 * math.pi, n)
    iids = np.array(
        [
            ids.add(
                ObjectClass.TREE,
                ObjectPose((float(p[0]), float(p[1]), float(p[2])), float(a)),
                (2 * r, 2 * r, float(h)),
            )
            for p, a, r, h in zip(positions, yaw, crown_r, total_h, strict=True)
        ]
    )
    trunk_col = np.array([0.32, 0.23, 0.15])
    base = positions - np.array([0.0, 0.0, 0.3])
    v, f = prim.cylinders(base, trunk_r, trunk_h + 0.3 + 0.5, 5)
    acc.add_flat(v, f, trunk_col, iids, lod=LOD_NEAR)
    top = positions + np.stack([np.zeros(n), np.zeros(n), trunk_h], axis=1)
    c_idx, d_idx = np.flatnonzero(conifer), np.flatnonzero(~conifer)
    if len(c_idx):
        v, f = prim.cones(top[c_idx], crown_r[c_idx], crown_h[c_idx], 7)
        acc.add_flat(v, f, green[c_idx], iids[c_idx], lod=LOD_NEAR)
        v, f = prim.cones(top[c_idx], crown_r[c_idx], crown_h[c_idx], 4, base=False)
        acc.add_flat(v, f, green[c_idx], iids[c_idx], lod=LOD_FAR)
    if len(d_idx):
        rz = crown_h[d_idx] / 2
        centre = top[d_idx] + np.stack([np.zeros(len(d_idx)), np.zeros(len(d_idx)), rz * 0.9], axis=1)
        radii = np.stack([crown_r[d_idx], crown_r[d_idx] * rng.uniform(0.85, 1.0, len(d_idx)), rz], axis=1)
        v, f = prim.ellipsoids(centre, radii)
        acc.add_flat(v, f, green[d_idx], iids[d_idx], lod=LOD_NEAR)
        v, f = prim.ellipsoids(centre, radii, low_poly=True)
        acc.add_flat(v, f, green[d_idx], iids[d_idx], lod=LOD_FAR)


def _add_custom_objects(
    acc: MeshAccumulator,
    ids: _Ids,
    customs: tuple[CustomObjectConfig, ...],
    meshes: tuple[tuple[FloatArray, npt.NDArray[np.int64]], ...],
    terrain: Heightfield,
) -> None:
    if len(meshes) != len(customs):
        msg = f"{len(customs)} custom_objects but {len(meshes)} meshes loaded (load_world_inputs reads them)"
        raise WorldFileError(msg)
    for k, (c, (raw_verts, raw_faces)) in enumerate(zip(customs, meshes, strict=True)):
        path = Path(c.mesh)
        verts = np.asarray(raw_verts, dtype=np.float64) * c.scale
        faces = np.asarray(raw_faces, dtype=np.int64)
        if len(faces) == 0:
            msg = f"custom_objects[{k}].mesh: {path} has no triangles"
            raise WorldFileError(msg)
        if len(faces) > 200_000:
            msg = f"custom_objects[{k}].mesh: {path} has {len(faces)} triangles; the limit is 200000"
            raise WorldFileError(msg)
        x, y = c.position_m
        ground = float(terrain.height_at(x, y))
        pose = ObjectPose((x, y, ground + c.z_offset_m), math.radians(c.yaw_deg))
        world = pose.to_world(verts)
        ext = verts.max(axis=0) - verts.min(axis=0)
        iid = ids.add(
            ObjectClass.from_label(c.object_class),
            pose,
            (float(ext[0]), float(ext[1]), float(verts[:, 2].max())),
            name=c.name or f"custom_{k:02d}_{path.stem}",
        )
        acc.add_flat(world[None, :, :], faces, np.asarray(c.color_rgb), np.array([iid]), lod=LOD_ALWAYS)


def _terrain_colors(
    terrain: Heightfield, forest_density: FloatArray, forest_thr: float, roads: RoadNetwork, rng: np.random.Generator
) -> FloatArray:
    """Per-node base colors: meadows, fields around villages, forest floor, rock on steep slopes."""
    gx, gy = terrain.node_xy()
    n = terrain.vertex_normals()
    slope = np.sqrt(np.maximum(0.0, 1.0 - n[..., 2] ** 2)) / np.maximum(n[..., 2], 1e-3)
    var = 0.5 + 0.5 * fbm_noise(gx, gy, 120.0, 3, rng)
    lush = np.array([0.30, 0.46, 0.18])
    dry = np.array([0.52, 0.53, 0.29])
    col = lush[None, None, :] * (1 - var[..., None]) + dry[None, None, :] * var[..., None]
    # fields: parcels of crops around each village
    palette = np.array([[0.78, 0.70, 0.36], [0.46, 0.58, 0.22], [0.50, 0.38, 0.26], [0.66, 0.64, 0.30],
                        [0.38, 0.52, 0.20], [0.72, 0.62, 0.42]])  # fmt: skip
    for v in roads.villages_m:
        ang = rng.uniform(0, math.pi)
        ca, sa = math.cos(ang), math.sin(ang)
        u = (gx - v[0]) * ca + (gy - v[1]) * sa
        w = -(gx - v[0]) * sa + (gy - v[1]) * ca
        pu, pw = rng.uniform(35, 60), rng.uniform(16, 28)
        strip = np.floor(w / pw)
        shift = ((strip * 0.61803398875) % 1.0) * pu  # parcels of neighbouring strips do not line up
        parcel = np.floor((u + shift) / (pu * (0.7 + 0.6 * ((strip * 0.41421356) % 1.0))))
        cell = (np.abs(parcel * 7919 + strip * 104729) + rng.integers(1000)).astype(np.int64)
        pick = palette[(cell * 2654435761 >> 7) % len(palette)]
        r = np.hypot(gx - v[0], gy - v[1])
        amount = (1 - smoothstep(160.0, 260.0, r)) * (1 - smoothstep(0.12, 0.22, slope)) * ((cell % 5) != 0)
        col = col * (1 - amount[..., None]) + pick * amount[..., None]
    floor = np.array([0.20, 0.28, 0.13])
    if math.isfinite(forest_thr):
        f_amt = smoothstep(forest_thr - 0.15, forest_thr + 0.05, forest_density)
    else:  # no forest (coverage 0): the ramp between two infinite edges would be NaN, i.e. black terrain
        f_amt = np.zeros_like(forest_density)
    col = col * (1 - 0.8 * f_amt[..., None]) + floor * 0.8 * f_amt[..., None]
    rock = np.array([0.50, 0.47, 0.43])
    r_amt = smoothstep(0.7, 1.1, slope) * (0.5 + 0.5 * var)
    col = col * (1 - r_amt[..., None]) + rock * r_amt[..., None]
    return np.asarray(np.clip(col, 0.0, 1.0), dtype=np.float64)


def build_world_parts(cfg: WorldConfig, inputs: WorldInputs | None = None) -> WorldParts:
    """Generate the world (see module docstring) from its config and the files it names (``inputs``).

    Raises:
        WorldError: too many objects for 16-bit instance ids.
        WorldFileError: a configured heightmap image or mesh was not given, or a mesh is unusable.
    """
    inputs = inputs or WorldInputs()
    streams = [np.random.default_rng(s) for s in np.random.SeedSequence(cfg.seed).spawn(10)]
    rng_terrain, rng_sites, rng_roads, rng_bld, rng_veh, rng_ppl, rng_trees, rng_col, rng_mesh, _ = streams
    terrain = generate_terrain(cfg.terrain, rng_terrain, inputs.heightmap)
    size = cfg.terrain.size_m
    villages = pick_village_sites(
        terrain,
        count=cfg.roads.villages,
        min_spacing_m=cfg.roads.min_village_spacing_m,
        home_clearance_m=cfg.home_clear_radius_m + 0.6 * cfg.buildings.village_radius_m + 40.0,
        edge_margin_m=min(0.8 * cfg.buildings.village_radius_m, size / 4),
        rng=rng_sites,
    )
    roads = plan_roads(
        terrain, villages, cfg.roads, cfg.home_clear_radius_m + cfg.terrain.home_pad_radius_m + 25.0, rng_roads
    )
    origin, shape = _raster_grid(terrain)
    road_dist = polyline_raster_distance(roads.polylines, origin, shape, _RASTER_RES_M)
    if roads.polylines:
        terrain = _conform_terrain_to_roads(terrain, road_dist, roads.width_m)

    acc = MeshAccumulator()
    ids = _Ids()
    x_min, y_min, x_max, y_max = terrain.bounds_m
    ids.add(
        ObjectClass.TERRAIN,
        ObjectPose(((x_min + x_max) / 2, (y_min + y_max) / 2, float(terrain.heights_m.min())), 0.0),
        (x_max - x_min, y_max - y_min, float(np.ptp(terrain.heights_m))),
        name="terrain",
    )
    _add_roads(acc, ids, terrain, roads)
    site = _Site(cfg, terrain, roads, road_dist)
    footprints = _add_buildings(acc, ids, site, rng_bld)
    site = _Site(cfg, terrain, roads, road_dist, _footprint_distance(footprints, origin, shape))
    vehicles = _place_vehicles(site, rng_veh)
    people = _place_people(site, vehicles[0], rng_ppl)
    avoid = np.concatenate([vehicles[0][:, :2], people[0][:, :2]])
    tree_pos, forest_density = _place_trees(site, avoid, rng_trees)
    _add_trees(acc, ids, cfg, tree_pos, rng_trees)
    _add_people(acc, ids, cfg, people, rng_mesh)
    _add_vehicles(acc, ids, vehicles, rng_mesh)
    _add_custom_objects(acc, ids, cfg.custom_objects, inputs.meshes, terrain)

    thr = float(np.quantile(forest_density, 1.0 - cfg.forest.coverage)) if cfg.forest.coverage > 0 else np.inf
    colors = _terrain_colors(terrain, forest_density, thr, roads, rng_col)
    verts, faces = terrain.mesh()
    normals = terrain.vertex_normals().reshape(-1, 3)
    terrain_acc = MeshAccumulator()
    terrain_acc.add_smooth(verts, normals, faces, colors.reshape(-1, 3), TERRAIN_INSTANCE_ID)
    mesh = _concat(terrain_acc.finish(), acc.finish() if acc.vertex_count else None)
    return WorldParts(terrain, mesh, tuple(ids.objects), roads)


def _concat(first: MeshArrays, second: MeshArrays | None) -> MeshArrays:
    if second is None:
        return first
    offset = np.uint32(len(first.vertices_m))
    return MeshArrays(
        vertices_m=np.concatenate([first.vertices_m, second.vertices_m]),
        normals=np.concatenate([first.normals, second.normals]),
        colors=np.concatenate([first.colors, second.colors]),
        vertex_instance=np.concatenate([first.vertex_instance, second.vertex_instance]),
        faces=np.concatenate([first.faces, second.faces + offset]),
        face_lod=np.concatenate([first.face_lod, second.face_lod]),
    )
