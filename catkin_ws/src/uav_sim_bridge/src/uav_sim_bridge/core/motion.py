"""People who walk and vehicles that drive: seeded paths, and poses as a pure function of simulation time.

:func:`plan_motion` picks the movers of a world (how many and which: the world's ``people.moving`` and
``vehicles.moving``, overridden by an :class:`ActorsConfig`, e.g. a scenario's ``actors:``) and gives
each a closed path and a speed:

* vehicles drive in the right-hand lane of the road they are parked at, turn at the road's end and
  come back in the other lane, at a seeded road speed (the same for every vehicle of a road, so none
  overtakes another);
* people walk along a road's shoulder (clear of parked vehicles), on a seeded loop of random waypoints
  around where they stand (around buildings, trees and parked vehicles, outside home's clear pad), or
  on a path given in the configuration, at a seeded walking speed, with a gait.

:meth:`MotionPlan.states_at` is a pure function of the simulation time: position along the loop
``s = (s0 + v t) mod L``, heading along it, height on the terrain (or road), gait phase from the
distance walked. Nothing is integrated, so a lockstep run (or any replay) sees exactly the same poses
for the same times, and the ground truth of any instant can be recomputed.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.figures import PersonPose, gait_phase
from uav_sim_bridge.core.objects import ObjectPose, WorldObject
from uav_sim_bridge.core.roads import RoadNetwork, resample_polyline
from uav_sim_bridge.core.terrain import Heightfield
from uav_sim_bridge.core.world_config import PERSON_POSES, ObjectClass, WorldConfig
from uav_sim_bridge.errors import SimBridgeConfigError

__all__ = [
    "ActorOverride",
    "ActorsConfig",
    "LoopPath",
    "MotionPlan",
    "Mover",
    "MoverState",
    "PeopleMotionConfig",
    "VehicleMotionConfig",
    "plan_motion",
]

FloatArray = npt.NDArray[np.float64]

_ROAD_LIFT_M = 0.12  # the generator's road surface above the terrain (generator.ROAD_LIFT_M)
_LANE_OFFSET_M = 1.4  # lane centre from the road's centreline
_SHOULDER_CLEAR_M = 2.6  # a road walker's distance beyond the road's edge (past kerb-parked trucks)
_GRID_M = 1.0


@dataclass(frozen=True)
class PeopleMotionConfig:
    """Overrides of the world's ``people`` motion keys (``None`` keeps the world's)."""

    moving: int | None = None
    speed_mps: tuple[float, float] | None = None
    motion: Literal["mixed", "road", "random"] | None = None
    wander_radius_m: float | None = None

    def __post_init__(self) -> None:
        if self.moving is not None and self.moving < 0:
            msg = f"moving must be >= 0, got {self.moving}"
            raise ValueError(msg)
        if self.speed_mps is not None and not 0 < self.speed_mps[0] <= self.speed_mps[1] <= 4.0:
            msg = f"speed_mps must be [min, max] with 0 < min <= max <= 4 m/s, got {list(self.speed_mps)}"
            raise ValueError(msg)
        if self.wander_radius_m is not None and not self.wander_radius_m > 0:
            msg = f"wander_radius_m must be > 0, got {self.wander_radius_m}"
            raise ValueError(msg)


@dataclass(frozen=True)
class VehicleMotionConfig:
    """Overrides of the world's ``vehicles`` motion keys (``None`` keeps the world's)."""

    moving: int | None = None
    speed_mps: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.moving is not None and self.moving < 0:
            msg = f"moving must be >= 0, got {self.moving}"
            raise ValueError(msg)
        if self.speed_mps is not None and not 0 < self.speed_mps[0] <= self.speed_mps[1] <= 40.0:
            msg = f"speed_mps must be [min, max] with 0 < min <= max <= 40 m/s, got {list(self.speed_mps)}"
            raise ValueError(msg)


@dataclass(frozen=True)
class ActorOverride:
    """One named person or vehicle.

    ``motion``: ``none`` (stays where it is), ``road`` (a person: along the nearest road's shoulder; a
    vehicle: in its lane), ``random`` (a person: a loop of random waypoints), ``path`` (along ``path_m``,
    map metres: a closed loop if its ends meet, else back and forth), or ``None`` (as planned).
    ``speed_mps`` overrides the seeded speed; ``pose`` a still person's pose.
    """

    motion: Literal["none", "road", "random", "path"] | None = None
    path_m: tuple[tuple[float, float], ...] = ()
    speed_mps: float | None = None
    pose: Literal["standing", "walking", "sitting", "lying"] | None = None

    def __post_init__(self) -> None:
        if self.speed_mps is not None and not 0 < self.speed_mps <= 40.0:
            msg = f"speed_mps must be in (0, 40] m/s, got {self.speed_mps}"
            raise ValueError(msg)
        if self.path_m and self.motion not in (None, "path"):
            msg = f"path_m is only used with motion: path (got motion: {self.motion})"
            raise ValueError(msg)
        if self.motion == "path" and len(self.path_m) < 2:
            msg = "motion: path needs path_m with at least 2 points [x_m, y_m] to follow"
            raise ValueError(msg)


@dataclass(frozen=True)
class ActorsConfig:
    """Who moves and how (``actors:`` of ``config/sim_bridge.yaml`` and of scenarios).

    ``seed`` seeds the choice of movers, their paths and speeds (``None``: the world's seed).
    """

    seed: int | None = None
    people: PeopleMotionConfig = field(default_factory=PeopleMotionConfig)
    vehicles: VehicleMotionConfig = field(default_factory=VehicleMotionConfig)
    objects: dict[str, ActorOverride] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.seed is not None and self.seed < 0:
            msg = f"seed must be >= 0, got {self.seed}"
            raise ValueError(msg)


@dataclass(frozen=True)
class LoopPath:
    """A closed path: ``(N, 2)`` points, the last joined back to the first, and its arc lengths."""

    points_m: FloatArray
    cum_m: FloatArray  # (N + 1,) arc length at each point and back at the first

    @staticmethod
    def from_points(points_m: npt.ArrayLike) -> LoopPath:
        p = np.asarray(points_m, dtype=np.float64).reshape(-1, 2)
        closed = np.concatenate([p, p[:1]])
        seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
        return LoopPath(p, np.concatenate([[0.0], np.cumsum(seg)]))

    @property
    def length_m(self) -> float:
        return float(self.cum_m[-1])

    def at(self, s_m: float) -> tuple[float, float, float]:
        """``(x, y, heading_rad)`` at arc length ``s_m`` (taken modulo the length)."""
        length = self.length_m
        s = s_m % length if length > 0 else 0.0
        k = int(np.searchsorted(self.cum_m, s, side="right") - 1)
        k = min(max(k, 0), len(self.points_m) - 1)
        a = self.points_m[k]
        b = self.points_m[(k + 1) % len(self.points_m)]
        seg = self.cum_m[k + 1] - self.cum_m[k]
        f = (s - self.cum_m[k]) / seg if seg > 0 else 0.0
        p = a + (b - a) * f
        return float(p[0]), float(p[1]), math.atan2(float(b[1] - a[1]), float(b[0] - a[0]))

    def nearest_s(self, x_m: float, y_m: float) -> float:
        """Arc length of the path point closest to ``(x, y)``."""
        closed = np.concatenate([self.points_m, self.points_m[:1]])
        a, b = closed[:-1], closed[1:]
        ab = b - a
        t = np.clip(
            np.einsum("ij,ij->i", np.array([x_m, y_m]) - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12), 0, 1
        )
        d = np.linalg.norm(a + ab * t[:, None] - np.array([x_m, y_m]), axis=1)
        k = int(np.argmin(d))
        return float(self.cum_m[k] + t[k] * np.linalg.norm(ab[k]))


@dataclass(frozen=True)
class Mover:
    """One person or vehicle that moves: its path, speed and where on the path it is at time 0."""

    obj: WorldObject
    path: LoopPath
    speed_mps: float
    s0_m: float
    how: str  # road | random | path
    z_lift_m: float = 0.0  # above the terrain (road surface for vehicles)


@dataclass(frozen=True)
class MoverState:
    """Where a mover is at one instant."""

    instance_id: int
    pose: ObjectPose
    velocity_mps: tuple[float, float, float]
    distance_m: float  # along its path since time 0 (a walker's gait phase follows from it)
    gait_phase: float  # walkers; 0 for vehicles


@dataclass(frozen=True)
class MotionPlan:
    """The movers of a run and the still people whose pose a configuration changed."""

    movers: tuple[Mover, ...]
    poses: Mapping[int, PersonPose] = field(default_factory=dict)

    @property
    def ids(self) -> frozenset[int]:
        return frozenset(m.obj.instance_id for m in self.movers)

    def states_at(self, t_s: float, terrain: Heightfield) -> list[MoverState]:
        """Every mover at simulation time ``t_s`` (a pure function of ``t_s``)."""
        if not self.movers:
            return []
        xs, ys, yaws, dist = [], [], [], []
        for m in self.movers:
            d = m.speed_mps * t_s
            x, y, yaw = m.path.at(m.s0_m + d)
            xs.append(x)
            ys.append(y)
            yaws.append(yaw)
            dist.append(d)
        z = terrain.height_at(np.asarray(xs), np.asarray(ys))
        out = []
        for k, m in enumerate(self.movers):
            v = m.speed_mps
            walker = m.obj.object_class is ObjectClass.PERSON
            phase = float(gait_phase(dist[k], m.obj.shape[0] if m.obj.shape else 1.75)) if walker else 0.0
            out.append(
                MoverState(
                    m.obj.instance_id,
                    ObjectPose((xs[k], ys[k], float(z[k]) + m.z_lift_m), yaws[k]),
                    (v * math.cos(yaws[k]), v * math.sin(yaws[k]), 0.0),
                    dist[k],
                    phase,
                )
            )
        return out


# ------------------------------------------------------------------------------------------------ planning
class _Blocked:
    """Where a walker may not go: building footprints, tree trunks and vehicles (with a margin), the map's
    edge and home's clear pad; a 1 m raster."""

    def __init__(self, world_objects: tuple[WorldObject, ...], bounds: tuple[float, float, float, float],
                 home_clear_m: float) -> None:  # fmt: skip
        x0, y0, x1, y1 = bounds
        self.origin = (x0, y0)
        self.shape = (math.ceil((y1 - y0) / _GRID_M) + 1, math.ceil((x1 - x0) / _GRID_M) + 1)
        grid = np.zeros(self.shape, dtype=np.uint8)
        for o in world_objects:
            cls = o.object_class
            if cls in (ObjectClass.BUILDING, ObjectClass.VEHICLE):
                margin = 1.2 if cls is ObjectClass.BUILDING else 0.8
                local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64) * [
                    o.size_m[0] / 2 + margin, o.size_m[1] / 2 + margin]  # fmt: skip
                xy = local @ o.pose.rotation()[:2, :2].T + np.asarray(o.pose.position_m[:2])
                pts = np.round((xy - np.asarray(self.origin)) / _GRID_M * 16).astype(np.int32)
                cv2.fillPoly(grid, [pts], color=(1,), shift=4)
            elif cls is ObjectClass.TREE:
                c = np.round((np.asarray(o.pose.position_m[:2]) - np.asarray(self.origin)) / _GRID_M).astype(int)
                cv2.circle(grid, (int(c[0]), int(c[1])), 1, color=(1,), thickness=-1)
        self.grid = grid
        self.bounds = (x0 + 3.0, y0 + 3.0, x1 - 3.0, y1 - 3.0)
        self.home_clear_m = home_clear_m + 2.0

    def clear(self, a: FloatArray, b: FloatArray) -> bool:
        """Whether the segment ``a -> b`` crosses nothing."""
        n = max(2, math.ceil(float(np.linalg.norm(b - a)) / (0.5 * _GRID_M)) + 1)
        t = np.linspace(0.0, 1.0, n)[:, None]
        p = a + (b - a) * t
        x0, y0, x1, y1 = self.bounds
        if not (np.all((p[:, 0] > x0) & (p[:, 0] < x1) & (p[:, 1] > y0) & (p[:, 1] < y1))):
            return False
        if np.any(np.hypot(p[:, 0], p[:, 1]) < self.home_clear_m):
            return False
        col = np.clip(np.rint((p[:, 0] - self.origin[0]) / _GRID_M).astype(int), 0, self.shape[1] - 1)
        row = np.clip(np.rint((p[:, 1] - self.origin[1]) / _GRID_M).astype(int), 0, self.shape[0] - 1)
        return not bool(self.grid[row, col].any())


def _random_loop(start: FloatArray, radius_m: float, blocked: _Blocked, rng: np.random.Generator) -> FloatArray | None:
    """A loop of 3-6 random waypoints within ``radius_m`` of ``start``, every leg clear; None if none found."""
    for _ in range(40):
        n = int(rng.integers(3, 7))
        pts = [start]
        ok = True
        for _k in range(n - 1):
            for _try in range(25):
                ang = rng.uniform(0, 2 * math.pi)
                step = rng.uniform(0.3, 0.8) * radius_m
                cand = pts[-1] + step * np.array([math.cos(ang), math.sin(ang)])
                if np.linalg.norm(cand - start) <= radius_m and blocked.clear(pts[-1], cand):
                    pts.append(cand)
                    break
            else:
                ok = False
                break
        if ok and len(pts) >= 3 and blocked.clear(pts[-1], start):
            return np.array(pts)
    return None


def _shoulder_walk(
    line: FloatArray, near: tuple[float, float], offset_m: float, blocked: _Blocked
) -> FloatArray | None:
    """A walk along a stretch of a road's shoulders around ``near`` (up one side, across, back the other), the
    longest of 160, 80 or 40 m that is clear; None if none is."""
    p = resample_polyline(line, 2.0)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    s0 = float(s[int(np.argmin(np.hypot(p[:, 0] - near[0], p[:, 1] - near[1])))])
    for half in (80.0, 40.0, 20.0):
        part = p[(s >= s0 - half) & (s <= s0 + half)]
        if len(part) < 3:
            continue
        loop = _lane_loop(part, offset_m)
        if _loop_clear(loop, blocked):
            return loop
    return None


def _loop_clear(points: FloatArray, blocked: _Blocked) -> bool:
    """Whether a closed path crosses nothing (buildings, trees, vehicles, the map's edge, home's pad)."""
    closed = np.concatenate([points, points[:1]])
    return all(blocked.clear(a, b) for a, b in itertools.pairwise(closed))


def _lane_loop(line: FloatArray, offset_m: float) -> FloatArray:
    """Along ``line`` offset to the right by ``offset_m``, then back along it offset to the other side."""
    p = resample_polyline(line, 2.0)
    t = np.gradient(p, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True) + 1e-12
    right = np.stack([t[:, 1], -t[:, 0]], axis=1)
    out_leg = p + right * offset_m
    back_leg = (p - right * offset_m)[::-1]
    return np.concatenate([out_leg, back_leg])


def _path_loop(path_m: tuple[tuple[float, float], ...]) -> LoopPath:
    """A configured path: a loop if its ends meet, else there and back."""
    pts = np.asarray(path_m, dtype=np.float64).reshape(-1, 2)
    if len(pts) > 2 and np.allclose(pts[0], pts[-1]):
        return LoopPath.from_points(pts[:-1])
    return LoopPath.from_points(np.concatenate([pts, pts[-2:0:-1]]))


def _nearest_road(roads: RoadNetwork, x: float, y: float) -> tuple[int, float]:
    best, best_d = -1, math.inf
    for k, line in enumerate(roads.polylines):
        if len(line) < 2:
            continue
        d = float(np.min(np.hypot(line[:, 0] - x, line[:, 1] - y)))
        if d < best_d:
            best, best_d = k, d
    return best, best_d


def _rng(seed: int, label: int) -> np.random.Generator:
    return np.random.default_rng([int(seed), 0x4D4F5645, label])  # "MOVE"


def _fail(key: str, what: str) -> SimBridgeConfigError:
    return SimBridgeConfigError(f"actors.{key}: {what}")


def plan_motion(  # noqa: PLR0912, PLR0915 - one pass over people and one over vehicles
    objects: tuple[WorldObject, ...],
    roads: RoadNetwork,
    bounds_m: tuple[float, float, float, float],
    world_cfg: WorldConfig,
    actors: ActorsConfig,
) -> MotionPlan:
    """The movers of a world (see module docstring); deterministic for the same inputs.

    Args:
        objects: the world's objects (``World.objects``).
        roads: its road network.
        bounds_m: its terrain bounds.
        world_cfg: its configuration (``people``/``vehicles`` motion keys, seed, home clearance).
        actors: overrides (a scenario's ``actors:``).

    Raises:
        SimBridgeConfigError: an override names an object the world does not have, a motion the object
            cannot have (a vehicle walking at random, a pose for a vehicle), or a road or path to follow
            that is not there; the message names the key.
    """
    seed = world_cfg.seed if actors.seed is None else actors.seed
    pc, vc = world_cfg.people, world_cfg.vehicles
    ap, av = actors.people, actors.vehicles
    people_moving = pc.moving if ap.moving is None else ap.moving
    people_speed = pc.speed_mps if ap.speed_mps is None else ap.speed_mps
    people_mode = pc.motion if ap.motion is None else ap.motion
    wander = pc.wander_radius_m if ap.wander_radius_m is None else ap.wander_radius_m
    vehicles_moving = vc.moving if av.moving is None else av.moving
    vehicle_speed = vc.speed_mps if av.speed_mps is None else av.speed_mps
    by_name = {o.name: o for o in objects}
    people = [o for o in objects if o.object_class is ObjectClass.PERSON]
    vehicles = [o for o in objects if o.object_class is ObjectClass.VEHICLE]
    if people_moving > len(people):
        err = _fail("people.moving", f"{people_moving} people should walk but the world has {len(people)}")
        raise err
    if vehicles_moving > len(vehicles):
        err = _fail("vehicles.moving", f"{vehicles_moving} vehicles should drive but the world has {len(vehicles)}")
        raise err
    has_roads = any(len(p) >= 2 for p in roads.polylines)
    if vehicles_moving > 0 and not has_roads:
        err = _fail("vehicles.moving", f"{vehicles_moving} vehicles should drive but the world has no roads")
        raise err
    if people_moving > 0 and people_mode == "road" and not has_roads:
        err = _fail("people.motion", f"road: {people_moving} people should walk along roads but the world has none")
        raise err
    for name, ov in actors.objects.items():
        o = by_name.get(name)
        if o is None or o.object_class not in (ObjectClass.PERSON, ObjectClass.VEHICLE):
            err = _fail(f"objects.{name}", "no person or vehicle of this name in the world (names: objects.json)")
            raise err
        if o.object_class is ObjectClass.VEHICLE and ov.pose is not None:
            err = _fail(f"objects.{name}.pose", "only people have poses")
            raise err
        if o.object_class is ObjectClass.VEHICLE and ov.motion == "random":
            err = _fail(f"objects.{name}.motion", "random: vehicles drive on roads (use road or path)")
            raise err
        if ov.motion == "road" and not has_roads:
            err = _fail(f"objects.{name}.motion", "road: the world has no road to follow (give a path instead)")
            raise err
        if ov.pose is not None and ov.pose not in PERSON_POSES:  # pragma: no cover - Literal already checks
            err = _fail(f"objects.{name}.pose", f"unknown pose {ov.pose}")
            raise err
    blocked = _Blocked(objects, bounds_m, world_cfg.home_clear_radius_m)
    rng_pick = _rng(seed, 1)
    movers: list[Mover] = []
    poses: dict[int, PersonPose] = {}

    # ---- people
    named_people = {n for n, ov in actors.objects.items() if by_name[n].object_class is ObjectClass.PERSON}
    forced_move = [n for n in sorted(named_people) if actors.objects[n].motion not in (None, "none")]
    pool = [o for o in people if o.name not in named_people]
    order = rng_pick.permutation(len(pool)) if pool else np.zeros(0, np.int64)
    want = max(0, people_moving - len(forced_move))
    rng_people = _rng(seed, 2)
    picked = 0
    for o in [by_name[n] for n in forced_move] + [pool[int(i)] for i in order]:
        forced = o.name in actors.objects
        if not forced and picked >= want:
            break
        ov = actors.objects.get(o.name, ActorOverride())
        speed = ov.speed_mps if ov.speed_mps is not None else float(rng_people.uniform(*people_speed))
        x, y = o.pose.position_m[0], o.pose.position_m[1]
        how = ov.motion or people_mode
        if how == "mixed":
            _, road_d = _nearest_road(roads, x, y) if has_roads else (-1, math.inf)
            how = "road" if road_d < roads.width_m / 2 + 12.0 else "random"
        if how == "path":
            path = _path_loop(ov.path_m)
        elif how == "road":
            road_k, _ = _nearest_road(roads, x, y)
            loop = _shoulder_walk(roads.polylines[road_k], (x, y), roads.width_m / 2 + _SHOULDER_CLEAR_M, blocked)
            if loop is None:  # building corners or parked trucks on the shoulders all along
                if forced:
                    err = _fail(f"objects.{o.name}.motion", "road: the shoulder of its road is blocked; give a path")
                    raise err
                continue
            path = LoopPath.from_points(loop)
        else:
            pts = _random_loop(np.array([x, y]), wander, blocked, rng_people)
            if pts is None:
                if forced:
                    err = _fail(f"objects.{o.name}.motion", "random: no clear loop around this person; give a path")
                    raise err
                continue
            path = LoopPath.from_points(pts)
        movers.append(Mover(o, path, speed, path.nearest_s(x, y), how))
        picked += 0 if forced else 1
    for name in sorted(named_people):
        ov = actors.objects[name]
        if ov.pose is not None and name not in {m.obj.name for m in movers}:
            poses[by_name[name].instance_id] = PersonPose.from_label(ov.pose)

    # ---- vehicles: the ones parked at a road's kerb can drive
    named_veh = {n for n, ov in actors.objects.items() if by_name[n].object_class is ObjectClass.VEHICLE}
    forced_veh = [n for n in sorted(named_veh) if actors.objects[n].motion not in (None, "none")]
    at_kerb = []
    if has_roads:
        for o in vehicles:
            if o.name in named_veh:
                continue
            k, d = _nearest_road(roads, o.pose.position_m[0], o.pose.position_m[1])
            if d < roads.width_m / 2 + o.size_m[1] + 1.0:
                at_kerb.append((o, k))
    order_v = rng_pick.permutation(len(at_kerb)) if at_kerb else np.zeros(0, np.int64)
    rng_veh = _rng(seed, 3)
    road_speed: dict[int, float] = {}
    want_v = max(0, vehicles_moving - len(forced_veh))
    picks: list[tuple[WorldObject, int | None]] = [(by_name[n], None) for n in forced_veh]
    picks += [at_kerb[int(i)] for i in order_v[:want_v]]
    for o, road in picks:
        ov = actors.objects.get(o.name, ActorOverride())
        x, y = o.pose.position_m[0], o.pose.position_m[1]
        if ov.motion == "path":
            path = _path_loop(ov.path_m)
            speed = ov.speed_mps if ov.speed_mps is not None else float(rng_veh.uniform(*vehicle_speed))
            movers.append(Mover(o, path, speed, path.nearest_s(x, y), "path", 0.0))
            continue
        k = road if road is not None else _nearest_road(roads, x, y)[0]
        if k not in road_speed:
            road_speed[k] = float(rng_veh.uniform(*vehicle_speed))
        speed = ov.speed_mps if ov.speed_mps is not None else road_speed[k]
        path = LoopPath.from_points(_lane_loop(roads.polylines[k], _LANE_OFFSET_M))
        movers.append(Mover(o, path, speed, path.nearest_s(x, y), "road", _ROAD_LIFT_M))
    return MotionPlan(tuple(movers), poses)
