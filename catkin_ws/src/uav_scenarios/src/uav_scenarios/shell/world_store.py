"""A scenario's world on disk: the derived world file, the world cache and the surface-voxel cache.

The world cache is the sim bridge's (``uav_sim_bridge.shell.world_store``), so the scorer,
the mission manager and the bridge load the same generated world. The surface voxels of a
world at a resolution (~10 s for the default world at 0.5 m) are cached next to it, keyed by
the world's hash; a missing, corrupt or read-only cache only costs time.
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from uav_common.config import to_mapping
from uav_common.voxel_keys import pack_keys, sorted_unique
from uav_perception.core.detection.heightfield import HeightGrid
from uav_perception.errors import PerceptionError
from uav_perception.shell.dem import load_dem, save_dem
from uav_scenarios.core.config import Scenario
from uav_scenarios.core.scoring.types import SceneTruth
from uav_scenarios.core.world import scene_truth_of, world_config_for
from uav_scenarios.errors import WorldDataError
from uav_sim_bridge.core.world import World
from uav_sim_bridge.errors import SimBridgeError
from uav_sim_bridge.shell.world_store import cache_slot, load_or_generate

__all__ = [
    "DEFAULT_CACHE_DIR",
    "derived_world_yaml",
    "load_world",
    "scene_truth",
    "surface_keys",
    "terrain_dem",
    "world_summary",
]

#: The bridge's default world cache (``config/sim_bridge.yaml`` ``world_cache_dir: null``).
DEFAULT_CACHE_DIR = Path("~/.cache/uav_test_range/worlds").expanduser()


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
        tmp.write_text("# Derived from a scenario's world config with its world.seed (uav_scenarios).\n" + text)
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
    keys = sorted_unique(pack_keys(world.surface_voxels(resolution_m)))
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
    """The scoring's ground truth of a world, its surface voxels from the cache.

    Args:
        resolution_m: voxel size of the surface voxels (the map's); ``None`` skips them
            (bounds, ground and objects only, instantly).
        moved: instance id -> new ``(x, y)`` of objects the scenario moved (the person).
    """
    keys = None if resolution_m is None else surface_keys(world, resolution_m, cache_dir)
    return scene_truth_of(world, surface_keys=keys, resolution_m=resolution_m, moved=moved)


def world_summary(world: World, cache_dir: Path | None = None) -> dict[str, Any]:
    """What a run records about its world (name, hash, seed, cache folder)."""
    slot = cache_slot(world.config, cache_dir or DEFAULT_CACHE_DIR)
    return {"name": world.config.name, "seed": world.config.seed, "hash": world.hash, "dir": str(slot)}


def terrain_dem(world: World, cache_dir: Path | None = None, resolution_m: float = 2.0) -> Path:
    """The world's terrain (no roofs, trees, people or vehicles) as a terrain model file for the geolocator,
    sampled every ``resolution_m`` (the geolocator interpolates bilinearly between samples): the prior a
    ground station would load from SRTM. Written once per world hash next to the world cache.

    Raises:
        WorldDataError: the file cannot be written and there is no valid one.
    """
    path = (cache_dir or DEFAULT_CACHE_DIR).parent / "terrain" / f"{world.hash[:20]}-{resolution_m:g}m.npz"
    if path.is_file():
        try:
            load_dem(path)
            return path
        except PerceptionError:
            pass  # rewrite it below
    x0, y0, x1, y1 = world.terrain.bounds_m
    cols = max(2, math.ceil((x1 - x0) / resolution_m))
    rows = max(2, math.ceil((y1 - y0) / resolution_m))
    xs = x0 + (np.arange(cols) + 0.5) * resolution_m
    ys = y0 + (np.arange(rows) + 0.5) * resolution_m
    grid_x, grid_y = np.meshgrid(xs, ys)
    heights = np.asarray(world.height_at(grid_x, grid_y), dtype=np.float64)
    try:
        save_dem(path, HeightGrid(heights, x0, y0, resolution_m, "bilinear", "terrain"))
    except OSError as err:
        msg = f"cannot write the terrain model {path}: {err}"
        raise WorldDataError(msg) from err
    return path
