"""Mesh and object-list export of a :class:`~uav_sim_bridge.core.world.World` (through trimesh)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from uav_sim_bridge.core.mesh import LOD_FAR
from uav_sim_bridge.errors import WorldFileError

if TYPE_CHECKING:
    from uav_sim_bridge.core.world import World

__all__ = ["export_mesh", "export_objects_json"]

_FORMATS = {".ply": "ply", ".glb": "glb", ".gltf": "gltf", ".obj": "obj", ".stl": "stl"}


def export_mesh(world: World, path: Path, *, include_far_lod: bool = False) -> None:
    """Write the world mesh (vertex colors as RGBA8) in the format given by ``path``'s suffix.

    Raises:
        WorldFileError: unknown suffix or the file cannot be written.
    """
    import trimesh  # noqa: PLC0415

    fmt = _FORMATS.get(path.suffix.lower())
    if fmt is None:
        msg = f"{path}: unknown mesh format; use one of {', '.join(sorted(_FORMATS))}"
        raise WorldFileError(msg)
    mask = np.ones(len(world.mesh.faces), dtype=bool) if include_far_lod else world.mesh.face_lod != LOD_FAR
    faces = world.mesh.faces[mask]
    used, inverse = np.unique(faces, return_inverse=True)
    colors = np.clip(world.mesh.colors[used] * 255.0, 0, 255).astype(np.uint8)
    rgba = np.concatenate([colors, np.full((len(used), 1), 255, np.uint8)], axis=1)
    tm = trimesh.Trimesh(
        vertices=world.mesh.vertices_m[used].astype(np.float64),
        faces=inverse.reshape(-1, 3),
        vertex_colors=rgba,
        process=False,
    )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tm.export(str(path), file_type=fmt)
    except OSError as err:
        msg = f"{path}: cannot write mesh: {err}"
        raise WorldFileError(msg) from err


def export_objects_json(world: World, path: Path) -> None:
    """Write ``{"world": ..., "classes": ..., "objects": [...]}`` as JSON.

    Raises:
        WorldFileError: the file cannot be written.
    """
    from uav_sim_bridge.core.world_config import ObjectClass  # noqa: PLC0415

    doc = {
        "world": {
            "name": world.config.name,
            "seed": world.config.seed,
            "hash": world.hash,
            "frame_id": "map",
            "bounds_m": list(world.terrain.bounds_m),
            "terrain_resolution_m": world.terrain.resolution_m,
        },
        "classes": {c.label: int(c) for c in ObjectClass},
        "objects": [o.to_json() for o in world.objects],
    }
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(doc, indent=1))
    except OSError as err:
        msg = f"{path}: cannot write object list: {err}"
        raise WorldFileError(msg) from err
