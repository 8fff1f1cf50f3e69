"""The simulated world: generation, identity (hash) and queries (pure; its files are ``shell.world_store``).

Typical use::

    cfg = load_world_config(Path("config/worlds/default.yaml"))
    world = generate_world(cfg)                        # shell.world_store; or load_or_generate(cfg, cache_dir)
    world.height_at(x, y)                              # terrain, vectorised
    world.surface_height_at(x, y)                      # highest surface incl. roads/roofs
    keys = world.surface_voxels(0.5)                   # (N, 3) int64 voxel keys

The world frame *is* ``map`` (x East, y North, z Up, metres); the terrain is 0 at
home (0, 0), flat around it, and no object comes within ``home_clear_radius_m``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.generator import TERRAIN_INSTANCE_ID, WorldInputs, build_world_parts
from uav_sim_bridge.core.mesh import LOD_FAR, MeshArrays
from uav_sim_bridge.core.objects import ObjectPose, WorldObject
from uav_sim_bridge.core.roads import RoadNetwork
from uav_sim_bridge.core.spatial import TriangleGrid
from uav_sim_bridge.core.terrain import Heightfield
from uav_sim_bridge.core.voxels import object_surface_voxels, terrain_surface_voxels, union_keys
from uav_sim_bridge.core.world_config import ObjectClass, WorldConfig

__all__ = ["GENERATOR_VERSION", "ObjectClass", "ObjectPose", "World", "WorldObject", "build_world"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

# Bump when the generator's output changes for the same config (invalidates caches).
GENERATOR_VERSION = (
    4  # 4: articulated people in poses, car/van/truck vehicles parked at the kerb (3: finite colours without forest)
)


@dataclass(frozen=True, eq=False)
class World:
    """A generated (or loaded) world; immutable.

    Attributes:
        config: the configuration it was generated from.
        terrain: the terrain heightfield (already conformed to the roads).
        mesh: the whole world as one triangle soup with per-vertex instance ids; the
            faces of people and vehicles are at their generated poses.
        objects: one record per instance id (``objects[i].instance_id == i + 1``; the
            first is the terrain).
        roads: road centrelines and village centres.
    """

    config: WorldConfig
    terrain: Heightfield
    mesh: MeshArrays
    objects: tuple[WorldObject, ...]
    roads: RoadNetwork
    _cache: dict[str, Any] = field(default_factory=dict, compare=False, repr=False)

    # ------------------------------------------------------------------ identity
    @cached_property
    def hash(self) -> str:
        """sha256 hex digest of everything generated (mesh, objects, terrain, roads)."""
        h = hashlib.sha256()
        h.update(f"uav_sim_bridge.world v{GENERATOR_VERSION}".encode())
        for arr in (
            self.terrain.heights_m,
            np.asarray((*self.terrain.origin_m, self.terrain.resolution_m)),
            self.mesh.vertices_m,
            self.mesh.normals,
            self.mesh.colors,
            self.mesh.vertex_instance,
            self.mesh.faces,
            self.mesh.face_lod,
            *self.roads.polylines,
            self.roads.villages_m,
        ):
            a = np.ascontiguousarray(arr)
            h.update(str(a.dtype).encode() + str(a.shape).encode())
            h.update(a.tobytes())
        h.update(json.dumps([o.to_json() for o in self.objects], sort_keys=True).encode())
        return h.hexdigest()

    def world_hash(self) -> str:
        """Same as :attr:`hash` (the documented API name)."""
        return self.hash

    # ------------------------------------------------------------------ lookups
    @cached_property
    def instance_class(self) -> npt.NDArray[np.uint8]:
        """``(max_id + 1,)`` class id of each instance id (index 0 is the sky)."""
        lut = np.zeros(len(self.objects) + 1, dtype=np.uint8)
        for obj in self.objects:
            lut[obj.instance_id] = int(obj.object_class)
        return lut

    def object(self, instance_id: int) -> WorldObject:
        """The object with this instance id.

        Raises:
            KeyError: no such instance.
        """
        if not 1 <= instance_id <= len(self.objects):
            msg = f"no world object with instance id {instance_id}"
            raise KeyError(msg)
        return self.objects[instance_id - 1]

    def objects_of_class(self, cls: ObjectClass) -> list[WorldObject]:
        return [o for o in self.objects if o.object_class is cls]

    @cached_property
    def face_instance(self) -> npt.NDArray[np.uint32]:
        """``(F,)`` instance id of each face."""
        return np.asarray(self.mesh.vertex_instance[self.mesh.faces[:, 0]], dtype=np.uint32)

    def triangles(self, face_mask: npt.NDArray[np.bool_] | None = None) -> FloatArray:
        """``(F, 3, 3)`` float64 triangle vertices (all faces, or the masked ones)."""
        faces = self.mesh.faces if face_mask is None else self.mesh.faces[face_mask]
        return np.asarray(self.mesh.vertices_m[faces], dtype=np.float64)

    # ------------------------------------------------------------------ geometry
    def height_at(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> FloatArray:
        """Terrain height (vectorised); exact on the rendered terrain triangles."""
        return self.terrain.height_at(x_m, y_m)

    @cached_property
    def static_grid(self) -> TriangleGrid:
        """Full-detail triangles of the static non-terrain objects (roads, buildings, trees, custom)."""
        cls = self.instance_class[self.face_instance]
        mask = (
            (cls != ObjectClass.TERRAIN)
            & (cls != ObjectClass.PERSON)
            & (cls != ObjectClass.VEHICLE)
            & (self.mesh.face_lod != LOD_FAR)
        )
        return TriangleGrid(self.triangles(mask), self.face_instance[mask], cell_m=8.0)

    def surface_height_at(self, x_m: float, y_m: float) -> tuple[float, int]:
        """Highest static surface (terrain, road, roof, tree top) at ``(x, y)``: ``(z_m, instance_id)``."""
        z_obj, iid = self.static_grid.highest_surface(x_m, y_m)
        z_ter = float(self.terrain.height_at(x_m, y_m))
        if z_obj > z_ter:
            return z_obj, iid
        return z_ter, TERRAIN_INSTANCE_ID

    @cached_property
    def support_grid(self) -> TriangleGrid:
        """Triangles a vehicle can stand on besides the terrain: roads and buildings (incl. custom buildings)."""
        cls = self.instance_class[self.face_instance]
        mask = ((cls == ObjectClass.ROAD) | (cls == ObjectClass.BUILDING)) & (self.mesh.face_lod != LOD_FAR)
        return TriangleGrid(self.triangles(mask), self.face_instance[mask], cell_m=8.0)

    def ground_height_at(self, x_m: float, y_m: float, below_z_m: float = float("inf")) -> tuple[float, int]:
        """Highest terrain, road or roof surface at ``(x, y)`` not above ``below_z_m``: ``(z_m, instance_id)``.

        This is what the SITL's ground should be under a vehicle at height ``below_z_m``
        (TERRAIN_REPORT): trees, people and vehicles are obstacles, not ground.
        """
        z_obj, iid = self.support_grid.highest_surface(x_m, y_m, below_z_m)
        z_ter = float(self.terrain.height_at(x_m, y_m))
        if z_obj > z_ter:
            return z_obj, iid
        return z_ter, TERRAIN_INSTANCE_ID

    def surface_voxels(self, resolution_m: float) -> IntArray:
        """``(N, 3)`` int64 keys ``floor(p / resolution_m)`` of the observable surfaces (see :mod:`.voxels`)."""
        if not resolution_m > 0:
            msg = f"resolution_m must be > 0, got {resolution_m}"
            raise ValueError(msg)
        key = f"voxels:{resolution_m!r}"
        if key not in self._cache:
            cls = self.instance_class[self.face_instance]
            covered = []
            for obj in self.objects_of_class(ObjectClass.BUILDING):
                rot = obj.pose.rotation()[:2, :2]
                sx, sy = obj.size_m[0] / 2, obj.size_m[1] / 2
                local = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]])
                covered.append(local @ rot.T + np.asarray(obj.pose.position_m[:2]))
            road_tris = self.triangles(cls == ObjectClass.ROAD)
            covered.extend(t[:, :2] for t in road_tris)
            terrain_keys = terrain_surface_voxels(self.terrain, resolution_m, covered)
            obj_mask = (cls != ObjectClass.TERRAIN) & (self.mesh.face_lod != LOD_FAR)
            obj_keys = object_surface_voxels(self.triangles(obj_mask), resolution_m, self.terrain)
            keys = union_keys(terrain_keys, obj_keys)
            keys.setflags(write=False)
            self._cache[key] = keys
        out: IntArray = self._cache[key]
        return out


def build_world(cfg: WorldConfig, inputs: WorldInputs | None = None) -> World:
    """Generate the world of ``cfg`` from the files it names, already read (``inputs``; none for a fully
    procedural world). Deterministic: the same config and inputs give the same :attr:`World.hash`.
    ``uav_sim_bridge.shell.world_store.generate_world`` reads the inputs and calls this."""
    parts = build_world_parts(cfg, inputs)
    return World(cfg, parts.terrain, parts.mesh, parts.objects, parts.roads)
