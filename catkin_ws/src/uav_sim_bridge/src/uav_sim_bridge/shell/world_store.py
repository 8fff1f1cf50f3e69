"""The world's files: the on-disk cache of generated worlds, and save/load of one world's folder.

A world folder holds ``world.npz`` (terrain, mesh, roads), ``objects.json`` and ``meta.json``
(generator version, world hash, config key, config); it is written to a temporary folder and
renamed into place, and a folder whose files, version or hash do not match is regenerated,
never trusted. The cache key covers the config and the contents of the files it names.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uav_common.config import ConfigError, from_mapping, to_mapping
from uav_sim_bridge.core.generator import WorldInputs
from uav_sim_bridge.core.mesh import MeshArrays
from uav_sim_bridge.core.objects import WorldObject
from uav_sim_bridge.core.roads import RoadNetwork
from uav_sim_bridge.core.terrain import Heightfield, normalized_heightmap
from uav_sim_bridge.core.world import GENERATOR_VERSION, World, build_world
from uav_sim_bridge.core.world_config import WorldConfig
from uav_sim_bridge.errors import WorldFileError

__all__ = [
    "cache_slot",
    "config_key",
    "generate_world",
    "load_or_generate",
    "load_world_dir",
    "load_world_inputs",
    "save_world",
]

_FILES = ("world.npz", "objects.json", "meta.json")


def load_world_inputs(cfg: WorldConfig) -> WorldInputs:
    """Read the files a world config names: the heightmap image and the custom objects' meshes.

    Raises:
        WorldFileError: a file is missing or cannot be decoded (the message names it and the key).
    """
    heightmap = None
    path = cfg.terrain.heightmap_image
    if path is not None:
        if not Path(path).is_file():
            msg = f"terrain.heightmap_image: heightmap image {path} not found"
            raise WorldFileError(msg)
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            msg = f"terrain.heightmap_image: {path} could not be decoded (use an 8- or 16-bit PNG or TIFF)"
            raise WorldFileError(msg)
        heightmap = normalized_heightmap(img)
    meshes = []
    if cfg.custom_objects:
        import trimesh  # noqa: PLC0415  (heavy import, only when user meshes are configured)

        for k, c in enumerate(cfg.custom_objects):
            mesh_path = Path(c.mesh)
            if not mesh_path.is_file():
                msg = f"custom_objects[{k}].mesh: file {mesh_path} not found"
                raise WorldFileError(msg)
            try:
                loaded: Any = trimesh.load(str(mesh_path), force="mesh")
            except Exception as err:  # trimesh raises many types for bad files
                msg = f"custom_objects[{k}].mesh: cannot read {mesh_path}: {err}"
                raise WorldFileError(msg) from err
            meshes.append((np.asarray(loaded.vertices, dtype=np.float64), np.asarray(loaded.faces, dtype=np.int64)))
    return WorldInputs(heightmap, tuple(meshes))


def generate_world(cfg: WorldConfig) -> World:
    """Generate the world of ``cfg``, reading the files it names (deterministic, no cache)."""
    return build_world(cfg, load_world_inputs(cfg))


def save_world(world: World, directory: Path) -> None:
    """Write the world to ``directory`` (created; existing files are replaced atomically)."""
    directory = Path(directory)
    directory.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{directory.name}.", dir=directory.parent))
    try:
        lines = world.roads.polylines
        np.savez(
            tmp / "world.npz",
            heights_m=world.terrain.heights_m,
            terrain_grid=np.array([*world.terrain.origin_m, world.terrain.resolution_m]),
            vertices_m=world.mesh.vertices_m,
            normals=world.mesh.normals,
            colors=world.mesh.colors,
            vertex_instance=world.mesh.vertex_instance,
            faces=world.mesh.faces,
            face_lod=world.mesh.face_lod,
            road_points=np.concatenate(lines) if lines else np.zeros((0, 2)),
            road_lengths=np.array([len(p) for p in lines], dtype=np.int64),
            villages_m=world.roads.villages_m,
            road_width_m=np.array(world.roads.width_m),
        )
        (tmp / "objects.json").write_text(json.dumps([o.to_json() for o in world.objects]))
        meta = {
            "generator_version": GENERATOR_VERSION,
            "world_hash": world.hash,
            "config_key": config_key(world.config),
            "config": to_mapping(world.config),
        }
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1, sort_keys=True))
        if directory.exists():
            shutil.rmtree(directory)
        os.replace(tmp, directory)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def load_world_dir(directory: Path) -> World:
    """Read a world written by :func:`save_world` and check its hash.

    Raises:
        WorldFileError: missing or corrupt files, or a hash mismatch.
    """
    directory = Path(directory)
    missing = [f for f in _FILES if not (directory / f).is_file()]
    if missing:
        msg = f"{directory}: not a saved world (missing {', '.join(missing)})"
        raise WorldFileError(msg)
    try:
        meta = json.loads((directory / "meta.json").read_text())
        objects = tuple(WorldObject.from_json(o) for o in json.loads((directory / "objects.json").read_text()))
        cfg = from_mapping(WorldConfig, meta["config"], source=str(directory / "meta.json"), prefix="config")
        with np.load(directory / "world.npz") as z:
            grid = z["terrain_grid"]
            terrain = Heightfield((float(grid[0]), float(grid[1])), float(grid[2]), z["heights_m"])
            mesh = MeshArrays(
                z["vertices_m"], z["normals"], z["colors"], z["vertex_instance"], z["faces"], z["face_lod"]
            )
            split = np.cumsum(z["road_lengths"])[:-1]
            lines = tuple(np.split(z["road_points"], split)) if len(z["road_lengths"]) else ()
            roads = RoadNetwork(lines, z["villages_m"], float(z["road_width_m"]))
    except (OSError, ValueError, KeyError, TypeError, json.JSONDecodeError, ConfigError) as err:
        msg = f"{directory}: corrupt saved world: {err}"
        raise WorldFileError(msg) from err
    if meta.get("generator_version") != GENERATOR_VERSION:
        msg = f"{directory}: saved by generator v{meta.get('generator_version')}, this is v{GENERATOR_VERSION}"
        raise WorldFileError(msg)
    world = World(cfg, terrain, mesh, objects, roads)
    if world.hash != meta.get("world_hash"):
        msg = f"{directory}: world hash mismatch (files modified or truncated)"
        raise WorldFileError(msg)
    return world


def _file_digest(path: Path) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError as err:
        msg = f"cannot read {path}: {err.strerror}"
        raise WorldFileError(msg) from err


def config_key(cfg: WorldConfig) -> str:
    """Digest of a config and the contents of the files it names (the cache key)."""
    data = to_mapping(cfg)
    files = []
    if cfg.terrain.heightmap_image is not None:
        files.append(_file_digest(cfg.terrain.heightmap_image))
    files.extend(_file_digest(c.mesh) for c in cfg.custom_objects)
    blob = json.dumps({"v": GENERATOR_VERSION, "config": data, "files": files}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def cache_slot(cfg: WorldConfig, cache_dir: Path) -> Path:
    """The folder under ``cache_dir`` where :func:`load_or_generate` keeps the world of ``cfg``."""
    return Path(cache_dir) / f"{cfg.name}-{config_key(cfg)[:16]}"


def load_or_generate(cfg: WorldConfig, cache_dir: Path) -> World:
    """Load the cached world of ``cfg`` from ``cache_dir``, or generate and cache it.

    A corrupt or stale cache entry is regenerated, never trusted.
    """
    slot = cache_slot(cfg, cache_dir)
    if slot.is_dir():
        try:
            return load_world_dir(slot)
        except WorldFileError:
            pass  # regenerate below
    world = generate_world(cfg)
    save_world(world, slot)
    return world
