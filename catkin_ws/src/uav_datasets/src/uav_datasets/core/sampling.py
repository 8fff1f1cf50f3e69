"""Seeded viewpoint sampling over a world (pure numpy; randomness is a passed-in generator).

A viewpoint is drawn in this order from the frame's own generator (so a frame's viewpoint depends
only on the sampling seed, the world seed and the frame's index: any worker draws the same one):

1. a position mode by weight (``uniform``, ``near_objects``, ``roads``) and, by that mode, a target
   point on the ground;
2. an altitude above the terrain, a pitch and a yaw, uniform in their ranges;
3. the camera position: back from the target against the yaw by ``altitude / tan(pitch)`` (at most
   ``max_standoff_m``), ``altitude`` above the terrain there;
4. the checks: inside the world, ``clearance_m`` above the terrain around it, outside every object's 3D
   box grown by ``clearance_m`` (buildings, trees, people, vehicles, custom objects; the terrain and the
   roads are surfaces, covered by the terrain check), and at least ``min_objects_in_view`` labelled
   objects in view. A draw that fails is drawn again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from uav_datasets.core.config import ViewpointSpec
from uav_datasets.errors import SamplingError
from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.objects import WorldObject
from uav_sim_bridge.core.transforms import OPTICAL_FROM_FLU, RigidTransform, rotation_from_rpy
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass

__all__ = ["Viewpoint", "ViewpointSampler", "frame_rng", "optical_pose"]

FloatArray = npt.NDArray[np.float64]
#: Directions around the camera at which the terrain clearance is checked (plus the point under it).
_SURFACES = frozenset({ObjectClass.TERRAIN, ObjectClass.ROAD})
_RING = np.array([[math.cos(a), math.sin(a)] for a in np.linspace(0.0, 2 * math.pi, 8, endpoint=False)])


def frame_rng(sampling_seed: int, world_seed: int, index: int) -> np.random.Generator:
    """The generator of one frame: a function of the dataset's sampling seed, the world and the frame index."""
    return np.random.default_rng(np.random.SeedSequence([int(sampling_seed), int(world_seed), int(index)]))


def optical_pose(position_m: npt.ArrayLike, pitch_rad: float, yaw_rad: float) -> RigidTransform:
    """``T_map_optical`` of a camera at ``position_m`` whose view is pitched ``pitch_rad`` below the horizon
    and heads ``yaw_rad`` (counter-clockwise from east); no roll, so image rows stay level and a nadir view
    has the yaw direction at the top of the image."""
    rot = rotation_from_rpy(0.0, pitch_rad, yaw_rad) @ OPTICAL_FROM_FLU
    return RigidTransform(rot, np.asarray(position_m, dtype=np.float64))


@dataclass(frozen=True)
class Viewpoint:
    t_map_optical: RigidTransform
    target_m: tuple[float, float, float]
    mode: str
    attempts: int


class ViewpointSampler:
    """Draws valid viewpoints over one world (see the module docstring).

    Args:
        world: the world (objects at their generated poses).
        spec: the sampling settings.
        camera: the camera the frames are rendered with.
        labelled: the labelled classes (for ``min_objects_in_view``).
        max_range_m: the labels' range limit, if any (objects beyond it do not count as in view).
        where: names the world in error messages (e.g. ``"world seed 3"``).

    Raises:
        SamplingError: the area lies outside the world, or a mode has nothing to aim at (no object of
            its classes, no road) in the area.
    """

    def __init__(
        self,
        world: World,
        spec: ViewpointSpec,
        camera: CameraModel,
        labelled: tuple[ObjectClass, ...],
        *,
        max_range_m: float | None = None,
        where: str = "the world",
    ) -> None:
        self.world = world
        self.spec = spec
        self.camera = camera
        self.where = where
        self.max_range_m = max_range_m
        bx0, by0, bx1, by1 = world.terrain.bounds_m
        self.bounds = (bx0, by0, bx1, by1)
        if spec.area_m is not None:
            ax0, ay0, ax1, ay1 = spec.area_m
            x0, y0, x1, y1 = max(ax0, bx0), max(ay0, by0), min(ax1, bx1), min(ay1, by1)
            what = f"viewpoints.area_m {list(spec.area_m)}"
        else:
            m = spec.margin_m
            x0, y0, x1, y1 = bx0 + m, by0 + m, bx1 - m, by1 - m
            what = f"the world's bounds less viewpoints.margin_m {m:g}"
        if x0 >= x1 or y0 >= y1:
            msg = f"{what} leaves no area inside {where} (bounds {[round(v, 1) for v in self.bounds]} m)"
            raise SamplingError(msg)
        self.area = (x0, y0, x1, y1)
        objs = list(world.objects)
        # Obstacles: every object but the terrain and the roads, whose "boxes" span hills (surfaces, not volumes;
        # the terrain check keeps the camera above both).
        solid = [o for o in objs if o.object_class not in _SURFACES]
        self._base = np.array([o.pose.position_m for o in solid], dtype=np.float64).reshape(-1, 3)
        yaw = np.array([o.pose.yaw_rad for o in solid], dtype=np.float64)
        self._cos, self._sin = np.cos(yaw), np.sin(yaw)
        self._half = np.array([(o.size_m[0] / 2, o.size_m[1] / 2, o.size_m[2]) for o in solid], dtype=np.float64)
        self._half = self._half.reshape(-1, 3)
        self._targets: dict[int, list[WorldObject]] = {}
        for k, mode in enumerate(spec.positions):
            if mode.kind == "near_objects":
                cls = mode.class_ids
                inside = [o for o in objs if o.object_class in cls and self._in_area(o.pose.position_m)]
                if not inside:
                    msg = (
                        f"viewpoints.positions[{k}]: no {'/'.join(mode.classes)} in {what} of {where}; "
                        "widen the area or choose other classes"
                    )
                    raise SamplingError(msg)
                self._targets[k] = inside
        self._segments = self._road_segments()
        if any(m.kind == "roads" for m in spec.positions) and len(self._segments[0]) == 0:
            msg = f"viewpoints.positions: kind roads, but {where} has no road in {what}"
            raise SamplingError(msg)
        wanted = set(labelled)
        self._labelled_centres = np.array(
            [o.center_m for o in objs if o.object_class in wanted], dtype=np.float64
        ).reshape(-1, 3)
        weights = np.array([m.weight for m in spec.positions], dtype=np.float64)
        self._weights = weights / weights.sum()

    def _in_area(self, p: tuple[float, float, float] | npt.ArrayLike) -> bool:
        x, y = float(np.asarray(p)[0]), float(np.asarray(p)[1])
        x0, y0, x1, y1 = self.area
        return x0 <= x <= x1 and y0 <= y <= y1

    def _road_segments(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Road centreline segments with both ends in the area: starts, ends and cumulative lengths."""
        starts, ends = [], []
        for line in self.world.roads.polylines:
            if len(line) < 2:
                continue
            a, b = line[:-1], line[1:]
            keep = np.array([self._in_area(p) and self._in_area(q) for p, q in zip(a, b, strict=True)], dtype=bool)
            starts.append(a[keep])
            ends.append(b[keep])
        if not starts:
            return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
        s = np.concatenate(starts)
        e = np.concatenate(ends)
        return s, e, np.cumsum(np.linalg.norm(e - s, axis=1))

    # ------------------------------------------------------------------ drawing
    def _target(self, k: int, rng: np.random.Generator) -> tuple[float, float]:
        mode = self.spec.positions[k]
        x0, y0, x1, y1 = self.area
        if mode.kind == "uniform":
            return float(rng.uniform(x0, x1)), float(rng.uniform(y0, y1))
        if mode.kind == "near_objects":
            objs = self._targets[k]
            o = objs[int(rng.integers(len(objs)))]
            bx, by = float(o.pose.position_m[0]), float(o.pose.position_m[1])
        else:
            s, e, cum = self._segments
            at = float(rng.uniform(0.0, cum[-1]))
            i = int(np.searchsorted(cum, at, side="right"))
            i = min(i, len(cum) - 1)
            seg_len = float(cum[i] - (cum[i - 1] if i else 0.0))
            t = (at - (cum[i - 1] if i else 0.0)) / seg_len if seg_len > 0 else 0.0
            bx, by = (float(v) for v in s[i] + t * (e[i] - s[i]))
        r = mode.max_offset_m * math.sqrt(float(rng.uniform()))
        a = float(rng.uniform(0.0, 2 * math.pi))
        return bx + r * math.cos(a), by + r * math.sin(a)

    def _clear(self, eye: FloatArray) -> bool:
        spec = self.spec
        clearance = max(spec.clearance_m, self.camera.near_m)
        x, y, z = (float(v) for v in eye)
        bx0, by0, bx1, by1 = self.bounds
        if not (bx0 <= x <= bx1 and by0 <= y <= by1):
            return False
        ring = np.vstack([[x, y], np.array([x, y]) + clearance * _RING])
        ring[:, 0] = np.clip(ring[:, 0], bx0, bx1)
        ring[:, 1] = np.clip(ring[:, 1], by0, by1)
        if z - float(np.max(self.world.height_at(ring[:, 0], ring[:, 1]))) < clearance:
            return False
        if len(self._base) == 0:
            return True
        rel = eye - self._base
        lx = self._cos * rel[:, 0] + self._sin * rel[:, 1]
        ly = -self._sin * rel[:, 0] + self._cos * rel[:, 1]
        c = spec.clearance_m
        inside = (
            (np.abs(lx) <= self._half[:, 0] + c)
            & (np.abs(ly) <= self._half[:, 1] + c)
            & (rel[:, 2] >= -c)
            & (rel[:, 2] <= self._half[:, 2] + c)
        )
        return not bool(inside.any())

    def objects_in_view(self, t_map_optical: RigidTransform) -> int:
        """Labelled objects whose box centre projects into the image, between the clip planes (and in range)."""
        if len(self._labelled_centres) == 0:
            return 0
        centres = self._labelled_centres
        if self.max_range_m is not None:
            centres = centres[np.linalg.norm(centres - t_map_optical.translation_m, axis=1) <= self.max_range_m]
        p = t_map_optical.inverse().apply(centres)
        cam = self.camera
        ok = (p[:, 2] >= cam.near_m) & (p[:, 2] <= cam.far_m)
        uv, _ = cam.project(p[ok])
        return int(np.count_nonzero(cam.in_image(uv))) if len(uv) else 0

    def sample(self, rng: np.random.Generator) -> Viewpoint:
        """A valid viewpoint (see the module docstring).

        Raises:
            SamplingError: ``max_attempts`` draws in a row were rejected.
        """
        spec = self.spec
        for attempt in range(1, spec.max_attempts + 1):
            k = int(rng.choice(len(self._weights), p=self._weights))
            tx, ty = self._target(k, rng)
            agl = float(rng.uniform(*spec.altitude_agl_m))
            pitch = math.radians(float(rng.uniform(*spec.pitch_deg)))
            yaw = math.radians(float(rng.uniform(*spec.yaw_deg)))
            tan_p = math.tan(pitch)
            standoff = spec.max_standoff_m if tan_p <= agl / spec.max_standoff_m else agl / tan_p
            cx, cy = tx - standoff * math.cos(yaw), ty - standoff * math.sin(yaw)
            bx0, by0, bx1, by1 = self.bounds
            if not (bx0 <= cx <= bx1 and by0 <= cy <= by1):
                continue
            eye = np.array([cx, cy, float(self.world.height_at(cx, cy)) + agl])
            if not self._clear(eye):
                continue
            pose = optical_pose(eye, pitch, yaw)
            if spec.min_objects_in_view and self.objects_in_view(pose) < spec.min_objects_in_view:
                continue
            tz = float(self.world.height_at(tx, ty)) if bx0 <= tx <= bx1 and by0 <= ty <= by1 else 0.0
            return Viewpoint(pose, (tx, ty, tz), spec.positions[k].kind, attempt)
        msg = (
            f"no valid viewpoint in {spec.max_attempts} draws in {self.where}: every camera was outside the world, "
            "too close to the terrain or an object, or saw fewer than viewpoints.min_objects_in_view "
            f"({spec.min_objects_in_view}) labelled objects; check viewpoints.altitude_agl_m "
            f"{list(spec.altitude_agl_m)}, area_m and min_objects_in_view"
        )
        raise SamplingError(msg)
