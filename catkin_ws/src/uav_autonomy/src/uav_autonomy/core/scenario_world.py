"""A scenario's world: which world file, where the person of interest goes, and the ground truth.

The world itself is the sim bridge's (``uav_sim_bridge.core.world``, pure Python):
the same config and cache folder give the same world the bridge renders, so the
scoring compares the map with exactly what the cameras saw.

* :func:`world_config_for` — the world config of a scenario (its ``world.seed`` applied);
  :func:`derived_world_yaml` writes it as a file the bridge can load.
* :func:`place_person` — the person of interest's seeded position, clear of obstacles.
* :func:`scene_truth` — bounds, surface voxels at the map resolution (cached on disk:
  the default world takes ~10 s at 0.5 m), terrain heights, people and vehicles.

File I/O only (world cache, voxel cache); no ROS, sockets or clocks.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from uav_autonomy.core.scenario_config import PersonSpec, Scenario
from uav_autonomy.core.scenario_errors import ScenarioError, WorldDataError
from uav_autonomy.core.scenario_mission import point_in_polygon
from uav_autonomy.core.scoring_metrics import voxel_keys_from_indices
from uav_autonomy.core.scoring_types import GridSnapshot, SceneTruth
from uav_common.config import ConfigError, to_mapping
from uav_sim_bridge.core.world import World, cache_slot, load_or_generate
from uav_sim_bridge.core.world_config import ObjectClass, WorldConfig, load_world_config
from uav_sim_bridge.errors import SimBridgeError

__all__ = [
    "DEFAULT_CACHE_DIR",
    "PersonPlacement",
    "derived_world_yaml",
    "load_world",
    "place_person",
    "scene_truth",
    "world_config_for",
]

#: The bridge's default world cache (``config/sim_bridge.yaml`` ``world_cache_dir: null``).
DEFAULT_CACHE_DIR = Path("~/.cache/uav_test_range/worlds").expanduser()
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


def derived_world_yaml(scenario: Scenario, out_dir: Path) -> Path:
    """A world YAML the bridge can load for this scenario.

    Without a scenario seed this is the scenario's world file itself. With one, a copy
    with that seed (and absolute file paths) is written to ``out_dir`` (same content,
    same file: written atomically, idempotent).
    """
    if scenario.world.seed is None:
        return scenario.world_config_path
    cfg = world_config_for(scenario)
    text = yaml.safe_dump(to_mapping(cfg), sort_keys=True)
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    path = out_dir / f"{cfg.name}-{digest}.yaml"
    if not path.is_file():
        out_dir.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_text("# Derived from a scenario's world config with its world.seed (uav_autonomy).\n" + text)
        os.replace(tmp, path)
    return path


def load_world(scenario: Scenario, cache_dir: Path | None = None) -> World:
    """The scenario's world, from the bridge's cache (or generated into it, ~1 s).

    Raises:
        WorldDataError: invalid world config or unreadable cache folder.
    """
    cfg = world_config_for(scenario)
    try:
        return load_or_generate(cfg, cache_dir or DEFAULT_CACHE_DIR)
    except (OSError, SimBridgeError, ValueError) as err:
        msg = f"cannot load or generate the world of scenario {scenario.name} ({cfg.name}): {err}"
        raise WorldDataError(msg) from err


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


def _truth_cache_path(world: World, resolution_m: float, cache_dir: Path) -> Path:
    return cache_dir.parent / "truth" / f"{world.hash[:20]}-{resolution_m:g}m.npy"


def surface_keys(world: World, resolution_m: float, cache_dir: Path | None = None) -> np.ndarray[Any, Any]:
    """Packed int64 keys of the world's observable-surface voxels (cached on disk by world hash)."""
    path = _truth_cache_path(world, resolution_m, cache_dir or DEFAULT_CACHE_DIR)
    if path.is_file():
        try:
            keys = np.load(path)
            if keys.dtype == np.int64 and keys.ndim == 1:
                return np.asarray(keys, dtype=np.int64)
        except (OSError, ValueError):
            pass  # recompute below
    keys = voxel_keys_from_indices(world.surface_voxels(resolution_m))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}.npy")
        np.save(tmp, keys)
        os.replace(tmp, path)
    except OSError:
        pass  # a read-only cache only costs time
    return keys


def scene_truth(
    world: World,
    *,
    resolution_m: float | None,
    cache_dir: Path | None = None,
    moved: dict[int, tuple[float, float]] | None = None,
) -> SceneTruth:
    """The scoring's ground truth of a world.

    Args:
        resolution_m: voxel size of the surface voxels (the map's); ``None`` skips them
            (bounds, ground and objects only, instantly).
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
    keys = np.zeros(0, dtype=np.int64)
    if resolution_m is not None:
        keys = surface_keys(world, resolution_m, cache_dir)
    return SceneTruth(
        bounds_m=terrain.bounds_m,
        surface_keys=keys,
        surface_resolution_m=resolution_m or 0.0,
        ground=ground,
        objects=np.array(rows, dtype=np.float64).reshape(-1, 4),
        object_classes=tuple(classes),
    )


def world_summary(world: World, cache_dir: Path | None = None) -> dict[str, Any]:
    """What a run records about its world (name, hash, seed, cache folder)."""
    slot = cache_slot(world.config, cache_dir or DEFAULT_CACHE_DIR)
    return {"name": world.config.name, "seed": world.config.seed, "hash": world.hash, "dir": str(slot)}


def placement_json(placement: PersonPlacement) -> str:
    return json.dumps({"version": _PLACEMENT_VERSION, **placement.as_dict()}, sort_keys=True)
