"""What the bridge does with each ground-truth state, without ROS or sockets.

:class:`BridgeEngine` takes a :class:`~uav_sim_bridge.core.vehicle_state.VehicleState`
and returns a :class:`StepOutput`: the pose to publish (exact, or degraded by the
seeded pose noise), the camera frames that are due in simulation time (rendered,
depth degraded if configured, ground-truth detections), new collisions and the
terrain report for the SITL.  The ROS node only converts and publishes it, so the
same engine can be driven by tests and benchmarks.

The engine must be used from the thread that created its renderer (GL rule).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from uav_common.geo import GeoPoint, LocalProjection
from uav_sim_bridge.config import SimBridgeConfig
from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.collision import CollisionChecker, Contact
from uav_sim_bridge.core.detections import GroundTruthDetection, ground_truth_detections, visible_candidates
from uav_sim_bridge.core.objects import ObjectPose, WorldObject
from uav_sim_bridge.core.schedule import RateSchedule
from uav_sim_bridge.core.sensor_noise import PoseNoise, degrade_depth
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.vehicle_state import VehicleState
from uav_sim_bridge.core.world import World
from uav_sim_bridge.render import RenderedFrame, Renderer

__all__ = ["BridgeEngine", "CameraOutput", "StepOutput", "TerrainReport"]

# Surfaces up to this far above base_link still count as "under" the vehicle (its gear hangs below it).
_GROUND_TOLERANCE_M = 0.5


@dataclass(frozen=True)
class CameraOutput:
    """One rendered camera frame and what derives from it.

    ``frame`` and ``depth_m`` are None when only the camera's detections are consumed: then
    just the instance ids near enough to detect anything were rendered (several times cheaper).
    """

    camera: CameraModel
    t_map_optical: RigidTransform
    frame: RenderedFrame | None
    depth_m: npt.NDArray[np.float32] | None  # degraded copy when noise is on, else frame.depth_m
    detections: list[GroundTruthDetection] | None


@dataclass(frozen=True)
class TerrainReport:
    """Fields of the TERRAIN_REPORT for the SITL."""

    lat_deg: float
    lon_deg: float
    terrain_amsl_m: float
    above_terrain_m: float
    surface_z_m: float
    instance_id: int


@dataclass(frozen=True)
class StepOutput:
    state: VehicleState
    published_pose: RigidTransform
    cameras: list[CameraOutput] = field(default_factory=list)
    new_contacts: list[Contact] = field(default_factory=list)
    terrain: TerrainReport | None = None


class BridgeEngine:
    """Per-state processing (see module docstring).

    Args:
        cfg: node configuration.
        world: the world.
        renderer: a renderer of ``world`` created in the calling thread.
    """

    def __init__(self, cfg: SimBridgeConfig, world: World, renderer: Renderer) -> None:
        self.cfg = cfg
        self.world = world
        self.renderer = renderer
        self.cameras = {name: CameraModel.from_config(name, c) for name, c in cfg.cameras.items()}
        self._schedules = {name: RateSchedule(c.rate_hz) for name, c in self.cameras.items()}
        self.collisions = CollisionChecker(world, cfg.collision)
        self._objects: dict[int, WorldObject] = {o.instance_id: o for o in world.objects if o.is_dynamic}
        self._by_name = {o.name: o.instance_id for o in world.objects}
        self._rng = np.random.default_rng(cfg.noise.seed)
        self._pose_noise = PoseNoise(cfg.noise.pose)
        self._previous_position: npt.NDArray[np.float64] | None = None
        self._touching: set[int] = set()
        # Bounding spheres (centres, radii) of the people and vehicles of the detection classes (rebuilt on a move).
        self._spheres: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]] | None = None
        # Detection-only renders stop past the detection range plus the largest movable object:
        # nothing farther can hide or be an object whose centre is in range.
        largest_m = max((float(np.linalg.norm(o.size_m)) for o in self._objects.values()), default=0.0)
        det_far_m = cfg.detections.max_range_m + largest_m + 1.0
        self._detection_cameras = {
            name: dataclasses.replace(cam, far_m=min(cam.far_m, max(det_far_m, 2.0 * cam.near_m)))
            for name, cam in self.cameras.items()
        }
        for name, (x, y, yaw_deg) in cfg.object_poses.items():
            self.move_object(name, x, y, None, math.radians(yaw_deg))

    # ------------------------------------------------------------------ objects
    def lookup(self, name_or_id: str | int) -> WorldObject:
        """A world object by instance id or name (current pose for people and vehicles).

        Raises:
            KeyError: unknown object.
        """
        iid = name_or_id if isinstance(name_or_id, int) else self._by_name.get(name_or_id, -1)
        if iid in self._objects:
            return self._objects[iid]
        return self.world.object(int(iid))

    def move_object(
        self, name_or_id: str | int, x_m: float, y_m: float, z_m: float | None, yaw_rad: float
    ) -> WorldObject:
        """Move a person or vehicle; ``z_m`` None or NaN stands it on the ground.

        Raises:
            KeyError: unknown object, or not a person/vehicle.
            ValueError: non-finite coordinates.
        """
        if not (math.isfinite(x_m) and math.isfinite(y_m) and math.isfinite(yaw_rad)):
            msg = f"object pose must be finite, got x={x_m} y={y_m} yaw={yaw_rad}"
            raise ValueError(msg)
        obj = self.lookup(name_or_id)
        if not obj.is_dynamic:
            msg = f"{obj.name} ({obj.object_class.label}) cannot be moved; only people and vehicles can"
            raise KeyError(msg)
        if z_m is None or not math.isfinite(z_m):
            z_m = self.world.ground_height_at(x_m, y_m)[0]
        pose = ObjectPose((float(x_m), float(y_m), float(z_m)), float(yaw_rad))
        self.renderer.set_object_pose(obj.instance_id, pose)
        self.collisions.set_object_pose(obj.instance_id, pose)
        moved = WorldObject(obj.instance_id, obj.object_class, obj.name, pose, obj.size_m)
        self._objects[obj.instance_id] = moved
        self._spheres = None
        return moved

    # ------------------------------------------------------------------ per state
    def step(
        self,
        state: VehicleState,
        *,
        home: GeoPoint | None,
        wanted: Callable[[str], bool],
        want_detections: bool = True,
    ) -> StepOutput:
        """Process one state.

        Args:
            state: ground truth.
            home: geodetic home for the terrain report (None: no report).
            wanted: whether anything consumes camera ``name`` now (else it is not rendered).
            want_detections: whether detections are consumed.
        """
        cfg = self.cfg
        pose = state.t_map_base
        published = self._pose_noise.apply(pose, state.sim_time_s, self._rng) if cfg.noise.enabled else pose
        outputs: list[CameraOutput] = []
        det_cams = set(cfg.detections.cameras) if want_detections else set()
        for name, cam in self.cameras.items():
            if not self._schedules[name].due(state.sim_time_s):
                continue
            full = wanted(name)
            if not (full or name in det_cams):
                continue
            t_opt = cam.optical_pose(pose)
            frame: RenderedFrame | None = None
            depth: npt.NDArray[np.float32] | None = None
            if full:
                det_cam = cam
                frame = self.renderer.render(cam, t_opt)
                instance_id = frame.instance_id
                depth = frame.depth_m
                if cfg.noise.enabled:
                    depth = degrade_depth(frame.depth_m, cfg.noise.depth, self._rng)
            else:
                det_cam = self._detection_cameras[name]
                if not self.detectables_in_view(det_cam, t_opt):  # most frames: nothing to detect, no render
                    outputs.append(CameraOutput(cam, t_opt, None, None, []))
                    continue
                instance_id = self.renderer.render_instances(det_cam, t_opt)
            dets = None
            if name in det_cams:
                cands = visible_candidates(instance_id, t_opt, self._objects, cfg.detections)
                dets = []  # most frames: nobody in view, and the per-pixel work below is skipped
                if cands:
                    alone = self.renderer.unoccluded_pixel_counts(det_cam, t_opt, cands)
                    objs = {iid: self._objects[iid] for iid in cands}
                    dets = ground_truth_detections(instance_id, t_opt, objs, cfg.detections, alone)
            outputs.append(CameraOutput(cam, t_opt, frame, depth, dets))
        contacts = self.collisions.check(self._previous_position, state.position_m)
        self._previous_position = state.position_m.copy()
        touching = {c.instance_id for c in contacts}
        new = [c for c in contacts if c.instance_id not in self._touching]
        self._touching = touching
        return StepOutput(state, published, outputs, new, self.terrain_report(state, home))

    def detectables_in_view(self, camera: CameraModel, t_map_optical: RigidTransform) -> bool:
        """Whether any person or vehicle of the detection classes could be detected in this view: its bounding
        sphere meets the camera's frustum (near and far planes included) and its centre is within the detection
        range. False means no detection is possible, whatever the render would show."""
        centers, radii = self._detectable_spheres()
        if len(radii) == 0:
            return False
        in_range = np.linalg.norm(centers - t_map_optical.translation_m, axis=1) <= self.cfg.detections.max_range_m
        if not in_range.any():
            return False
        p = t_map_optical.inverse().apply(centers[in_range])
        r = radii[in_range]
        planes = camera.frustum_planes_optical()
        inside = np.all(p @ planes[:, :3].T + planes[:, 3] >= -r[:, None], axis=1)
        return bool(inside.any())

    def _detectable_spheres(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        if self._spheres is None:
            wanted = self.cfg.detections.class_ids
            objs = [o for o in self._objects.values() if o.object_class in wanted]
            centers = np.array([o.center_m for o in objs], dtype=np.float64).reshape(-1, 3)
            # half the box diagonal, plus a metre for whatever of a mesh pokes out of its box
            radii = np.array([0.5 * float(np.linalg.norm(o.size_m)) + 1.0 for o in objs], dtype=np.float64)
            self._spheres = (centers, radii)
        return self._spheres

    def terrain_report(self, state: VehicleState, home: GeoPoint | None) -> TerrainReport | None:
        """The surface under the vehicle (terrain, road or roof at most a little above ``base_link``)."""
        if home is None:
            return None
        x, y, z = (float(v) for v in state.position_m)
        surface_z, iid = self.world.ground_height_at(x, y, z + _GROUND_TOLERANCE_M)
        geo = LocalProjection(home).to_geo(y, x, 0.0)
        return TerrainReport(geo.lat_deg, geo.lon_deg, home.alt_amsl_m + surface_z, z - surface_z, surface_z, iid)
