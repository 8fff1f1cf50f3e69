"""A scenario's world: which world config, where the person of interest goes, and the ground truth.

The world itself is the sim bridge's (``uav_sim_bridge.core.world``): the same config gives
the same world the bridge renders, so the scoring compares the map with exactly what the
cameras saw. Its files (the world cache, the surface-voxel cache, the derived world YAML)
are :mod:`uav_scenarios.shell.world_store`.

* :func:`world_config_for` — the world config of a scenario (its ``world.seed`` applied).
* :func:`place_person` — the person of interest's seeded position, clear of obstacles.
* :func:`scene_truth_of` — bounds, surface voxels, terrain heights, people and vehicles.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_common.config import ConfigError
from uav_scenarios.core.config import PersonSpec, Scenario
from uav_scenarios.core.mission import point_in_polygon
from uav_scenarios.core.scoring.types import GridSnapshot, SceneTruth
from uav_scenarios.errors import ScenarioError, WorldDataError
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass, WorldConfig, load_world_config
from uav_sim_bridge.errors import SimBridgeError

__all__ = ["PersonPlacement", "place_person", "placement_json", "scene_truth_of", "world_config_for"]

#: Objects standing higher than this above the terrain (trees, roofs, cars) block a placement.
_OBSTACLE_HEIGHT_M = 0.5
_PLACEMENT_VERSION = 1


def world_config_for(scenario: Scenario) -> WorldConfig:
    """The scenario's world config, with ``world.seed`` applied when set.

    Raises:
        WorldDataError: the world file is missing or invalid (the message names it).
    """
    path = scenario.world_config_path
    try:
        cfg = load_world_config(path)
    except (ConfigError, SimBridgeError) as err:
        msg = f"scenario {scenario.name}: world config {path}: {err}"
        raise WorldDataError(msg) from err
    if scenario.world.seed is not None and scenario.world.seed != cfg.seed:
        cfg = replace(cfg, seed=scenario.world.seed, name=f"{cfg.name}-seed{scenario.world.seed}")
    return cfg


@dataclass(frozen=True)
class PersonPlacement:
    name: str
    instance_id: int
    x_m: float
    y_m: float
    yaw_rad: float

    def as_dict(self) -> dict[str, Any]:
        return {"name": self.name, "instance_id": self.instance_id, "x_m": self.x_m, "y_m": self.y_m}


def _clear(world: World, x: float, y: float, radius_m: float) -> bool:
    """No tree, building, vehicle or other person within ``radius_m`` of ``(x, y)``."""
    probes = [(x, y)]
    for r in (radius_m / 2.0, radius_m):
        probes += [(x + r * math.cos(a), y + r * math.sin(a)) for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)]
    for px, py in probes:
        z_surface, _ = world.surface_height_at(px, py)
        if z_surface - float(world.height_at(px, py)) > _OBSTACLE_HEIGHT_M:
            return False
    for obj in world.objects:
        if obj.object_class in (ObjectClass.PERSON, ObjectClass.VEHICLE):
            ox, oy, _ = obj.pose.position_m
            if math.hypot(ox - x, oy - y) < radius_m + max(obj.size_m[:2]) / 2.0:
                return False
    return True


def place_person(spec: PersonSpec, world: World) -> PersonPlacement:
    """The person of interest's position: ``position_m`` if fixed, else seeded uniform in ``region_m``.

    A random position is redrawn until it lies in the region, outside home's clear pad
    and ``clearance_m`` away from obstacles (trees, buildings, vehicles, other people),
    so the person can be seen from the air. Same seed and world, same position.

    Raises:
        ScenarioError: no person of that name in the world, or no clear spot in the region.
    """
    person = next((o for o in world.objects if o.name == spec.name), None)
    if person is None or person.object_class is not ObjectClass.PERSON:
        people = [o.name for o in world.objects_of_class(ObjectClass.PERSON)][:5]
        msg = f"search.person.name {spec.name!r} is not a person of this world (e.g. {', '.join(people)})"
        raise ScenarioError(msg)
    home_clear = world.config.home_clear_radius_m
    if spec.position_m is not None:
        return PersonPlacement(person.name, person.instance_id, spec.position_m[0], spec.position_m[1], 0.0)
    rng = np.random.default_rng(spec.placement_seed)
    xs = [p[0] for p in spec.region_m]
    ys = [p[1] for p in spec.region_m]
    x0, y0, x1, y1 = world.terrain.bounds_m
    for _ in range(2000):
        x = float(rng.uniform(min(xs), max(xs)))
        y = float(rng.uniform(min(ys), max(ys)))
        yaw = float(rng.uniform(-math.pi, math.pi))
        if not (point_in_polygon(x, y, spec.region_m) and x0 < x < x1 and y0 < y < y1):
            continue
        if math.hypot(x, y) <= home_clear + spec.clearance_m:
            continue
        if _clear(world, x, y, spec.clearance_m):
            return PersonPlacement(person.name, person.instance_id, x, y, yaw)
    msg = (
        f"no spot in search.person.region_m {spec.region_m} is {spec.clearance_m} m clear of obstacles "
        "and inside the world; move or enlarge the region, or lower clearance_m"
    )
    raise ScenarioError(msg)


def placement_json(placement: PersonPlacement) -> str:
    return json.dumps({"version": _PLACEMENT_VERSION, **placement.as_dict()}, sort_keys=True)


def scene_truth_of(
    world: World,
    *,
    surface_keys: npt.NDArray[np.int64] | None,
    resolution_m: float | None,
    moved: dict[int, tuple[float, float]] | None = None,
) -> SceneTruth:
    """The scoring's ground truth of a world.

    Args:
        surface_keys: packed keys of the world's observable-surface voxels at ``resolution_m``
            (:func:`uav_scenarios.shell.world_store.surface_keys`); ``None``: no surface voxels.
        resolution_m: their voxel size (the map's).
        moved: instance id -> new ``(x, y)`` of objects the scenario moved (the person).
    """
    terrain = world.terrain
    res = terrain.resolution_m
    # Heights are given at grid nodes; a cell centred on each node makes value_at() a
    # nearest-node lookup (terrain resolution, 4 m by default).
    ground = GridSnapshot(
        t_s=0.0,
        resolution_m=res,
        origin_x_m=terrain.origin_m[0] - res / 2.0,
        origin_y_m=terrain.origin_m[1] - res / 2.0,
        layers={"elevation_m": np.asarray(terrain.heights_m, dtype=np.float64)},
    )
    rows = []
    classes = []
    for obj in world.objects:
        if obj.object_class in (ObjectClass.PERSON, ObjectClass.VEHICLE):
            x, y, z = obj.pose.position_m
            if moved and obj.instance_id in moved:
                x, y = moved[obj.instance_id]
                z = float(world.height_at(x, y))
            rows.append((float(obj.instance_id), x, y, z))
            classes.append(obj.object_class.label)
    keys = np.zeros(0, dtype=np.int64) if surface_keys is None else surface_keys
    return SceneTruth(
        bounds_m=terrain.bounds_m,
        surface_keys=keys,
        surface_resolution_m=resolution_m or 0.0,
        ground=ground,
        objects=np.array(rows, dtype=np.float64).reshape(-1, 4),
        object_classes=tuple(classes),
    )
