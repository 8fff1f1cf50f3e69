"""Collisions of the vehicle (a sphere around ``base_link``) with the world mesh.

Terrain and roads are the SITL's ground (it follows them through TERRAIN_REPORT), so
touching them is not a collision.  Neither is resting on an upward-facing surface
below the vehicle's centre (landing on a roof or a car).  Anything else the sphere
touches (walls, tree crowns and trunks, people, the sides of vehicles) is.  The path
between two states is swept in steps of half the radius, so a fast vehicle cannot
tunnel through a thin object.

Flying into a hillside is a collision with the terrain: a swept position whose centre
is more than the vehicle's radius below the terrain surface.  (The SITL cannot tell:
JSBSim has one flat ground height, which it clamps to the landing gear when the
reported terrain jumps above it, so without this check the vehicle would fly on
inside the hill.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.generator import TERRAIN_INSTANCE_ID
from uav_sim_bridge.core.objects import ObjectPose
from uav_sim_bridge.core.spatial import TriangleGrid
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass

__all__ = ["CollisionChecker", "CollisionConfig", "Contact"]


@dataclass(frozen=True)
class CollisionConfig:
    """``collision`` section of ``config/sim_bridge.yaml``."""

    enabled: bool = True
    vehicle_radius_m: float = 0.35
    support_normal_z: float = 0.7

    def __post_init__(self) -> None:
        if not 0.05 <= self.vehicle_radius_m <= 5.0:
            msg = f"vehicle_radius_m must be in [0.05, 5], got {self.vehicle_radius_m}"
            raise ValueError(msg)


@dataclass(frozen=True)
class Contact:
    """The vehicle touched an object."""

    instance_id: int
    object_class: ObjectClass
    point_m: tuple[float, float, float]


_GROUND = frozenset({ObjectClass.TERRAIN, ObjectClass.ROAD})
_Hit = tuple[int, tuple[float, float, float], tuple[float, float, float]]  # id, point, normal


class CollisionChecker:
    """Sphere-vs-mesh contacts against static objects and the moving people/vehicles."""

    def __init__(self, world: World, cfg: CollisionConfig) -> None:
        self.cfg = cfg
        self._classes = world.instance_class
        self._terrain = world.terrain
        self._static: TriangleGrid = world.static_grid
        cls = world.instance_class[world.face_instance]
        dyn = (cls == ObjectClass.PERSON) | (cls == ObjectClass.VEHICLE)
        tris = world.triangles(dyn)
        ids = world.face_instance[dyn]
        self._dynamic: dict[int, npt.NDArray[np.float64]] = {}
        self._dyn_radius: dict[int, float] = {}
        for iid in np.unique(ids):
            pose = world.object(int(iid)).pose
            local = pose.to_local(tris[ids == iid].reshape(-1, 3)).reshape(-1, 3, 3)
            self._dynamic[int(iid)] = local
            self._dyn_radius[int(iid)] = float(np.max(np.linalg.norm(local.reshape(-1, 3), axis=1)))
        self._poses = {iid: world.object(iid).pose for iid in self._dynamic}

    def set_object_pose(self, instance_id: int, pose: ObjectPose) -> None:
        if instance_id in self._dynamic:
            self._poses[instance_id] = pose

    def set_object_shape(self, instance_id: int, local_triangles_m: npt.ArrayLike) -> None:
        """New ``(N, 3, 3)`` triangles of a person or vehicle in its local frame (another pose)."""
        if instance_id in self._dynamic:
            local = np.asarray(local_triangles_m, dtype=np.float64).reshape(-1, 3, 3)
            self._dynamic[instance_id] = local
            self._dyn_radius[instance_id] = float(np.max(np.linalg.norm(local.reshape(-1, 3), axis=1)))

    def _dynamic_contacts(
        self, p: npt.NDArray[np.float64], r: float
    ) -> list[tuple[int, tuple[float, float, float], tuple[float, float, float]]]:
        out: list[_Hit] = []
        for iid, local in self._dynamic.items():
            pose = self._poses[iid]
            if math.dist(p, pose.position_m) > self._dyn_radius[iid] + r:
                continue
            grid = TriangleGrid(
                pose.to_world(local.reshape(-1, 3)).reshape(-1, 3, 3), np.full(len(local), iid), cell_m=4.0
            )
            out.extend((c.instance_id, c.point_m, c.normal) for c in grid.sphere_contacts(p, r))
        return out

    def check(self, previous_m: npt.ArrayLike | None, current_m: npt.ArrayLike) -> list[Contact]:
        """Objects the sphere touches anywhere on the segment ``previous -> current`` (one per instance)."""
        if not self.cfg.enabled:
            return []
        cur = np.asarray(current_m, dtype=np.float64)
        r = self.cfg.vehicle_radius_m
        if previous_m is None:
            samples = cur[None]
        else:
            prev = np.asarray(previous_m, dtype=np.float64)
            n = max(1, math.ceil(float(np.linalg.norm(cur - prev)) / (0.5 * r)))
            n = min(n, 200)
            samples = prev + (cur - prev) * (np.arange(1, n + 1) / n)[:, None]
        found: dict[int, Contact] = {}
        ground_m = self._terrain.height_at(samples[:, 0], samples[:, 1])
        buried = np.flatnonzero(samples[:, 2] < ground_m - r)
        if len(buried):
            k = int(buried[0])
            point = (float(samples[k, 0]), float(samples[k, 1]), float(ground_m[k]))
            found[TERRAIN_INSTANCE_ID] = Contact(TERRAIN_INSTANCE_ID, ObjectClass.TERRAIN, point)
        for p in samples:
            hits: list[_Hit] = [(c.instance_id, c.point_m, c.normal) for c in self._static.sphere_contacts(p, r)]
            hits += self._dynamic_contacts(p, r)
            for iid, point, normal in hits:
                cls = ObjectClass(int(self._classes[iid]))
                if cls in _GROUND or iid in found:
                    continue
                support = abs(normal[2]) >= self.cfg.support_normal_z and point[2] <= p[2]
                if support:
                    continue
                found[iid] = Contact(iid, cls, point)
        return list(found.values())
