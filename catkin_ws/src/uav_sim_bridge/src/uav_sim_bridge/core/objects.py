"""World objects: one record per instance id, and object poses that can change at run time."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.world_config import ObjectClass

__all__ = ["DYNAMIC_CLASSES", "ObjectPose", "ObjectState", "WorldObject"]

# Classes whose objects can be moved at run time (their meshes are re-posed by the renderer).
DYNAMIC_CLASSES = frozenset({ObjectClass.PERSON, ObjectClass.VEHICLE})


@dataclass(frozen=True)
class ObjectPose:
    """Pose of an object's local frame: origin at the centre of its base, z up, heading ``yaw_rad``."""

    position_m: tuple[float, float, float]
    yaw_rad: float = 0.0

    def rotation(self) -> npt.NDArray[np.float64]:
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def to_world(self, local_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Local ``(N, 3)`` points -> ``map``."""
        return np.asarray(np.asarray(local_m, dtype=np.float64) @ self.rotation().T + np.asarray(self.position_m))

    def to_local(self, world_m: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """``map`` ``(N, 3)`` points -> local."""
        return np.asarray((np.asarray(world_m, dtype=np.float64) - np.asarray(self.position_m)) @ self.rotation())


@dataclass(frozen=True)
class WorldObject:
    """One instance of the world.

    Attributes:
        instance_id: id written into instance images (1..65534; 0 is the sky).
        object_class: semantic class.
        name: unique readable name (``tree_0042``).
        pose: base centre on the ground and heading, in ``map``.
        size_m: extents ``(length along local x, width along local y, height)``: the 3D box is centred on
            the pose's x, y and stands on its z.
        kind: what the object is within its class, "" if nothing more is known: a person's pose
            (``standing``, ``walking``, ``sitting``, ``lying``), a vehicle's type (``car``, ``van``, ``truck``).
        shape: the parameters its mesh was built from: a person's ``(height_m, build)``; empty otherwise.
    """

    instance_id: int
    object_class: ObjectClass
    name: str
    pose: ObjectPose
    size_m: tuple[float, float, float]
    kind: str = ""
    shape: tuple[float, ...] = ()

    @property
    def is_dynamic(self) -> bool:
        return self.object_class in DYNAMIC_CLASSES

    @property
    def center_m(self) -> npt.NDArray[np.float64]:
        """Centre of the object's bounding box in ``map`` (its base centre lifted by half its height)."""
        x, y, z = self.pose.position_m
        return np.array([x, y, z + self.size_m[2] / 2.0])

    def to_json(self) -> dict[str, Any]:
        return {
            "instance_id": self.instance_id,
            "class": self.object_class.label,
            "name": self.name,
            "position_m": [float(v) for v in self.pose.position_m],
            "yaw_rad": float(self.pose.yaw_rad),
            "size_m": [float(v) for v in self.size_m],
            "kind": self.kind,
            "shape": [float(v) for v in self.shape],
        }

    @staticmethod
    def from_json(data: dict[str, Any]) -> WorldObject:
        px, py, pz = (float(v) for v in data["position_m"])
        sx, sy, sz = (float(v) for v in data["size_m"])
        return WorldObject(
            instance_id=int(data["instance_id"]),
            object_class=ObjectClass.from_label(str(data["class"])),
            name=str(data["name"]),
            pose=ObjectPose((px, py, pz), float(data["yaw_rad"])),
            size_m=(sx, sy, sz),
            kind=str(data.get("kind", "")),
            shape=tuple(float(v) for v in data.get("shape", ())),
        )


@dataclass(frozen=True)
class ObjectState:
    """A person or vehicle at one instant (the ground truth of moving objects).

    Attributes:
        obj: the object with its current pose, kind and box.
        velocity_mps: map (ENU) velocity.
        moving: it follows a path (False: put somewhere by a request and left there).
    """

    obj: WorldObject
    velocity_mps: tuple[float, float, float]
    moving: bool
