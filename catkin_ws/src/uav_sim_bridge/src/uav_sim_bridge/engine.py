"""What the bridge does with each ground-truth state, without ROS or sockets.

:class:`BridgeEngine` takes a :class:`~uav_sim_bridge.core.vehicle_state.VehicleState`
and returns a :class:`StepOutput`: the pose to publish (exact, or degraded by the
seeded pose noise), the camera frames that are due in simulation time (rendered in the
environment's light, through each camera's effects, depth degraded if configured,
ground-truth detections), new collisions, the moving objects' states and the terrain
report for the SITL.  The ROS node only converts and publishes it, so the same engine
can be driven by tests and benchmarks.

Moving people and vehicles (:mod:`uav_sim_bridge.core.motion`) are posed from the state's
simulation time only, whenever something looks at them (a camera frame, a collision test
near their path, an object-state message): a lockstep run sees the same world at the same
times, however fast it runs. An object moved by :meth:`BridgeEngine.move_object` (the
``set_object_pose`` service, ``object_poses``) leaves its path and stays where it was put.

Camera frames with a ``latency_s`` are held back and returned by the step whose time has
reached their capture time plus the latency (stamped with the capture time, as a camera
driver stamps its exposure); dropped frames are rendered (their detections are ground truth
of the scene and are kept) but their images are not returned.

Camera faults injected in flight (:meth:`BridgeEngine.set_camera_fault`; the model is
:mod:`uav_sim_bridge.core.camera_faults`) act on what the camera unit delivers, at capture time: its images
(colour, depth, and with them the points, the instance and class images that label them), its camera_info and
the box-only detector's boxes (``CameraOutput.boxes``, a detector run on those images). ``off`` and a frame an
``intermittent`` camera loses deliver none of it; ``stuck`` delivers the last good frame's images and boxes
again with the new capture stamp; ``garbage`` delivers noise of the right size and encoding (the instance
labels stay those of the scene in view; the box-only detector finds nothing in noise). The ground truth of
the scene (``detections``, ``/detections/ground_truth``) is never faulted: it is what the camera should have
seen, so the scorer counts what the fault made the autonomy miss.

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
from uav_sim_bridge.core import figures
from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.camera_effects import CameraEffects, CameraMotion, camera_rng
from uav_sim_bridge.core.camera_faults import CameraFaults, Verdict, garbage_color, garbage_depth
from uav_sim_bridge.core.collision import CollisionChecker, Contact
from uav_sim_bridge.core.detections import GroundTruthDetection, ground_truth_detections, visible_candidates
from uav_sim_bridge.core.figures import PersonPose
from uav_sim_bridge.core.lighting import Lighting, lighting_for
from uav_sim_bridge.core.motion import MotionPlan, MoverState, plan_motion
from uav_sim_bridge.core.objects import ObjectPose, ObjectState, WorldObject
from uav_sim_bridge.core.schedule import RateSchedule
from uav_sim_bridge.core.sensor_noise import PoseNoise, degrade_depth
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.vehicle_state import VehicleState
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import ObjectClass
from uav_sim_bridge.render import RenderedFrame, Renderer
from uav_sim_bridge.shell.effects_process import EffectsJob, EffectsProcess, StageSpec

__all__ = ["BridgeEngine", "CameraOutput", "ObjectState", "StepOutput", "TerrainReport"]

#: Phases of the walking cycle precomputed per walker.
_GAIT_STEPS = 30
# Surfaces up to this far above base_link still count as "under" the vehicle (its gear hangs below it).
_GROUND_TOLERANCE_M = 0.5
#: A ``garbage`` depth image is uniform between the camera's near plane and this far (or its far plane).
GARBAGE_MAX_DEPTH_M = 300.0


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
    #: Simulation time the frame was captured (its stamp); later than the step's only for delayed frames.
    t_capture_s: float = math.nan
    exposure_s: float = 0.0  # camera effects: exposure time (0: no exposure model)
    gain: float = 1.0
    #: The camera fault that shaped this output: "" (none), off, dropped (intermittent), stuck or garbage.
    fault: str = ""
    #: With a fault: what the box-only detector reports for this frame (the frozen frame's boxes when stuck,
    #: none in garbage); None: nothing. Without one, the box-only detector reports ``detections``.
    boxes: list[GroundTruthDetection] | None = None
    #: A delayed frame whose camera_info already went out with its detections at capture time (the images follow
    #: with the same stamp; its camera_info must not go out twice).
    info_sent: bool = False

    @property
    def delivered(self) -> bool:
        """Whether the camera delivered this frame (camera_info, images, the box-only detector's boxes)."""
        return self.fault not in ("off", "dropped")

    @property
    def detector_boxes(self) -> list[GroundTruthDetection] | None:
        """What the box-only detector reports for this frame (None: nothing to publish)."""
        return self.boxes if self.fault else self.detections


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
    #: The moving (and moved) people and vehicles, at ``publish.object_states_rate_hz``; None between.
    objects: list[ObjectState] | None = None


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
        # Environment: light (the renderer follows it), camera effects and depth noise per camera.
        env = cfg.environment
        self.lighting: Lighting = lighting_for(env, world.config.latitude_deg, cfg.render.haze_distance_m)
        renderer.set_lighting(self.lighting)
        # each camera's stage, built from one spec here (for the drop decisions, made before a frame renders) and in
        # the effects process (the pixels)
        self._stages = {
            name: StageSpec(env.effects_for(name), cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, env.seed)
            for name, cam in self.cameras.items()
            if env.effects_for(name).active
        }
        self.effects: dict[str, CameraEffects] = {name: spec.build(name) for name, spec in self._stages.items()}
        self._depth_rng = camera_rng(env.seed, "depth_noise")
        fc = cfg.camera_faults
        self.camera_faults: CameraFaults[CameraOutput] = CameraFaults(
            {name: camera_rng(fc.seed, f"fault:{name}") for name in self.cameras},
            intermittent_drop_probability=fc.intermittent_drop_probability,
        )
        self._fx_process: EffectsProcess | None = None  # started with the first frame that has effects
        self._delayed: list[CameraOutput] = []
        # Moving people and vehicles.
        self.motion: MotionPlan = plan_motion(
            world.objects, world.roads, world.terrain.bounds_m, world.config, cfg.actors
        )
        self._moving: dict[int, MoverState] = {}
        self._moved_ids: set[int] = set()  # moved by a request: reported in object states, no longer on a path
        self._synced_t: float | None = None
        self._object_schedule = RateSchedule(cfg.publish.object_states_rate_hz)
        self._centre: dict[tuple[int, int], npt.NDArray[np.float64]] = {}
        self._walkers = [m for m in self.motion.movers if m.obj.object_class is ObjectClass.PERSON]
        for iid, pose in self.motion.poses.items():
            self._reshape_person(self._objects[iid], pose)
        for m in self._walkers:
            self._reshape_person(m.obj, PersonPose.WALKING)
        self._gaits = self._gait_cycles([m.obj for m in self._walkers])
        # where the movers were at the last sync, how far they reach and how fast they go (collision pre-test)
        self._mover_radius = {
            m.obj.instance_id: 0.5 * float(np.linalg.norm(m.obj.size_m)) + 1.0 for m in self.motion.movers
        }
        self._mover_xy = np.zeros((0, 2))
        self._mover_reach = np.zeros(0)
        self._mover_speed = np.zeros(0)
        self._renderer_stale: list[MoverState] = []
        # Detection-only renders draw nothing past the detection range plus the largest movable object:
        # nothing farther can hide or be an object whose centre is in range. They keep the camera's projection
        # (render_instances), so their ids are the full render's; the frustum below decides whether to render.
        largest_m = max((float(np.linalg.norm(o.size_m)) for o in self._objects.values()), default=0.0)
        det_far_m = cfg.detections.max_range_m + largest_m + 1.0
        self._detection_draw_m = det_far_m
        self._detection_cameras = {
            name: dataclasses.replace(cam, far_m=min(cam.far_m, max(det_far_m, 2.0 * cam.near_m)))
            for name, cam in self.cameras.items()
        }
        for name, (x, y, yaw_deg) in cfg.object_poses.items():
            self.move_object(name, x, y, None, math.radians(yaw_deg))
        self.sync_movers(0.0)

    # ------------------------------------------------------------------ moving objects
    def _person_local(self, obj: WorldObject, pose: PersonPose, phase: float) -> npt.NDArray[np.float64]:
        """Triangle-soup vertices of a person in a pose (the renderer's vertex order)."""
        height, build = obj.shape if len(obj.shape) == 2 else (1.75, 1.0)
        key = (obj.instance_id, int(pose))
        if key not in self._centre:
            self._centre[key] = figures.person_box_centres([height], [build], [int(pose)])[0]
        verts = figures.person_vertices([height], [build], [int(pose)], [phase], centre_xy=self._centre[key][None])
        faces, _ = figures.person_faces()
        return np.asarray(verts[0][faces].reshape(-1, 3), dtype=np.float64)

    def _gait_cycles(
        self, people: list[WorldObject]
    ) -> dict[int, tuple[npt.NDArray[np.float32], npt.NDArray[np.float32]]]:
        """Each walker's mesh at :data:`_GAIT_STEPS` phases of its stride (vertices, flat normals), computed once:
        a frame picks the nearest phase (a 30th of a stride is ~5 cm of walking)."""
        if not people:
            return {}
        faces, _ = figures.person_faces()
        walking = int(PersonPose.WALKING)
        shapes = np.array([o.shape if len(o.shape) == 2 else (1.75, 1.0) for o in people])
        phases = np.arange(_GAIT_STEPS) / _GAIT_STEPS
        out = {}
        for o, (height, build) in zip(people, shapes, strict=True):
            centre = self._centre[(o.instance_id, walking)]
            v = figures.person_vertices(
                np.full(_GAIT_STEPS, height), np.full(_GAIT_STEPS, build), np.full(_GAIT_STEPS, walking), phases,
                centre_xy=np.tile(centre, (_GAIT_STEPS, 1)),
            )  # fmt: skip
            soup = v[:, faces]  # (steps, F, 3, 3)
            n = np.cross(soup[:, :, 1] - soup[:, :, 0], soup[:, :, 2] - soup[:, :, 0])
            n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-12
            out[o.instance_id] = (
                soup.reshape(_GAIT_STEPS, -1, 3).astype(np.float32),
                np.repeat(n, 3, axis=1).astype(np.float32),
            )
        return out

    def _reshape_person(self, obj: WorldObject, pose: PersonPose) -> None:
        """Give a person another pose: its mesh (renderer and collisions), kind and box."""
        height, build = obj.shape if len(obj.shape) == 2 else (1.75, 1.0)
        local = self._person_local(obj, pose, 0.0)
        self.renderer.set_object_shape(obj.instance_id, local)
        self.collisions.set_object_shape(obj.instance_id, local.reshape(-1, 3, 3))
        size = figures.person_boxes([height], [build], [int(pose)])[0]
        current = self._objects[obj.instance_id]
        self._objects[obj.instance_id] = dataclasses.replace(
            current, kind=pose.label, size_m=(float(size[0]), float(size[1]), float(size[2]))
        )
        self._spheres = None

    def sync_movers(self, t_s: float, *, render: bool = False) -> None:
        """Pose every moving person and vehicle at simulation time ``t_s`` (once per distinct time): their records,
        collision shapes and, before the next render (``render``: now), the renderer's meshes."""
        if self._synced_t == t_s or not self.motion.movers:
            self._synced_t = t_s
            if render:
                self._sync_renderer()
            return
        self._synced_t = t_s
        states = [st for st in self.motion.states_at(t_s, self.world.terrain) if st.instance_id not in self._moved_ids]
        for st in states:
            iid = st.instance_id
            self._moving[iid] = st
            self.collisions.set_object_pose(iid, st.pose)
            o = self._objects[iid]
            self._objects[iid] = WorldObject(o.instance_id, o.object_class, o.name, st.pose, o.size_m, o.kind, o.shape)
        if states:
            self._mover_xy = np.array([st.pose.position_m[:2] for st in states])
            self._mover_reach = np.array([self._mover_radius[st.instance_id] for st in states])
            self._mover_speed = np.array([math.hypot(*st.velocity_mps[:2]) for st in states])
        self._renderer_stale = states
        self._spheres = None
        if render:
            self._sync_renderer()

    def _sync_renderer(self) -> None:
        """Give the renderer the movers' last synced poses and gait (only when something is about to be drawn)."""
        states = self._renderer_stale
        if not states:
            return
        self._renderer_stale = []
        states = [st for st in states if st.instance_id not in self._moved_ids]  # moved by a request since
        walkers = [st for st in states if st.instance_id in self._gaits]
        if walkers:  # the gait: new limb positions first (one batch), then every mover's pose
            ids = [st.instance_id for st in walkers]
            k = [round(st.gait_phase * _GAIT_STEPS) % _GAIT_STEPS for st in walkers]
            verts = np.stack([self._gaits[i][0][j] for i, j in zip(ids, k, strict=True)])
            normals = np.stack([self._gaits[i][1][j] for i, j in zip(ids, k, strict=True)])
            self.renderer.set_object_shapes(ids, verts, normals)
        for st in states:
            self.renderer.set_object_pose(st.instance_id, st.pose)

    def _movers_near(self, position_m: npt.NDArray[np.float64], t_s: float, margin_m: float) -> bool:
        """Whether any moving object may be within ``margin_m`` of ``position_m`` at ``t_s``: its distance at the
        last sync, less its size and how far it can have moved since."""
        if not len(self._mover_xy) or self._synced_t is None:
            return False
        d = np.hypot(*(self._mover_xy - position_m[:2]).T)
        travel = self._mover_speed * abs(t_s - self._synced_t)
        return bool(np.any(d - self._mover_reach - travel <= margin_m))

    def object_states(self) -> list[ObjectState]:
        """The moving people and vehicles (and those moved by a request) as of the last sync."""
        out = []
        for iid in sorted(set(self._moving) | self._moved_ids):
            st = self._moving.get(iid)
            moving = iid not in self._moved_ids and st is not None
            vel = st.velocity_mps if (st is not None and moving) else (0.0, 0.0, 0.0)
            out.append(ObjectState(self._objects[iid], vel, moving))
        return out

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
        self._moved_ids.add(obj.instance_id)  # off its path, if it had one: it stays where it was put
        self._moving.pop(obj.instance_id, None)
        if self._objects[obj.instance_id].kind == PersonPose.WALKING.label:  # a walker stops: it stands still
            generated = self.world.object(obj.instance_id).kind
            still = self.motion.poses.get(obj.instance_id) or (
                PersonPose.from_label(generated) if generated and generated != "walking" else PersonPose.STANDING
            )
            self._reshape_person(self._objects[obj.instance_id], still)
        moved = dataclasses.replace(self._objects[obj.instance_id], pose=pose)
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
        t = state.sim_time_s
        pose = state.t_map_base
        published = self._pose_noise.apply(pose, t, self._rng) if cfg.noise.enabled else pose
        outputs: list[CameraOutput] = []
        det_cams = set(cfg.detections.cameras) if want_detections else set()
        due = [name for name in self.cameras if self._schedules[name].due(t)]
        due = [name for name in due if wanted(name) or name in det_cams]
        if due:
            self.sync_movers(t)
        pending: list[tuple[CameraOutput, EffectsJob | None]] = []
        for name in due:
            # a camera's effects run in the effects process while the next camera renders (GL stays in this thread)
            out, job = self._camera(name, state, full=wanted(name), detect=name in det_cams)
            if out is not None:
                pending.append((out, job))
        for out, job in pending:
            if job is None:
                outputs.append(out)
            elif self.cfg.environment.effects_for(out.camera.name).latency_s > 0.0:
                # a delayed camera's image is not delivered before its latency has passed: its effects finish in
                # the effects process meanwhile (the next cameras render) and its colour waits for them when read
                outputs.append(_pending_effects(out, job))
            else:
                outputs.append(_with_effects(out, job))
        outputs = self._deliver([f for f in map(self._faulted, outputs) if f is not None], t)
        reach = cfg.collision.vehicle_radius_m + 1.0
        if self._movers_near(state.position_m, t, reach) or (
            self._previous_position is not None and self._movers_near(self._previous_position, t, reach)
        ):
            self.sync_movers(t)  # a mover may be within reach: collisions need it where it is now
        contacts = self.collisions.check(self._previous_position, state.position_m)
        self._previous_position = state.position_m.copy()
        touching = {c.instance_id for c in contacts}
        new = [c for c in contacts if c.instance_id not in self._touching]
        self._touching = touching
        objects = None
        if (self.motion.movers or self._moved_ids) and self._object_schedule.due(t):
            self.sync_movers(t)
            objects = self.object_states()
        return StepOutput(state, published, outputs, new, self.terrain_report(state, home), objects)

    def _camera(
        self, name: str, state: VehicleState, *, full: bool, detect: bool
    ) -> tuple[CameraOutput | None, EffectsJob | None]:
        """Render camera ``name`` for this state (all images, or only the ids its detections need); its camera
        effects, if any, are submitted to the effects process (the returned job)."""
        cfg = self.cfg
        t = state.sim_time_s
        cam = self.cameras[name]
        t_opt = cam.optical_pose(state.t_map_base)
        frame: RenderedFrame | None = None
        depth: npt.NDArray[np.float32] | None = None
        job: EffectsJob | None = None
        dropped = False
        if full:
            effects = self.effects.get(name)
            dropped = effects.drop() if effects is not None else False
            self._sync_renderer()
            frame = self.renderer.render(cam, t_opt)
            instance_id = frame.instance_id
            depth = frame.depth_m
            if cfg.noise.enabled:
                depth = degrade_depth(frame.depth_m, cfg.noise.depth, self._rng)
            elif cfg.environment.depth_noise is not None:
                depth = degrade_depth(frame.depth_m, cfg.environment.depth_noise, self._depth_rng)
            if effects is not None and not dropped:
                # the effects (and, with shadows, finishing the colour) run in the effects process beside the next
                # render: the frame's images go there through shared memory
                unshaded = frame.unshaded
                job = self._effects_process().submit(
                    name,
                    frame.depth_m,
                    t,
                    self._camera_motion(cam, state),
                    color_rgb=None if unshaded is not None else frame.color_rgb,
                    unshaded=unshaded,
                )
        else:
            # most frames: nothing to detect, no render
            if not self.detectables_in_view(self._detection_cameras[name], t_opt):
                return CameraOutput(cam, t_opt, None, None, [], t), None
            self._sync_renderer()
            instance_id = self.renderer.render_instances(cam, t_opt, draw_within_m=self._detection_draw_m)
        dets = None
        if detect:
            cands = visible_candidates(instance_id, t_opt, self._objects, cfg.detections)
            dets = []  # most frames: nobody in view, and the per-pixel work below is skipped
            if cands:
                self._sync_renderer()
                alone = self.renderer.unoccluded_pixel_counts(cam, t_opt, cands)
                objs = {iid: self._objects[iid] for iid in cands}
                dets = ground_truth_detections(instance_id, t_opt, objs, cfg.detections, alone)
        if dropped:  # the camera lost the frame: only the (ground-truth) detections remain
            frame, depth = None, None
            if dets is None:
                return None, None
        return CameraOutput(cam, t_opt, frame, depth, dets, t), job

    def set_camera_fault(self, camera: str, failure_type: str) -> None:
        """Inject a fault into a camera (``ok`` clears it); frames captured from the next step on carry it.

        Raises:
            CameraFaultError: an unknown camera or fault type.
        """
        self.camera_faults.set(camera, failure_type)

    def _faulted(self, out: CameraOutput) -> CameraOutput | None:  # noqa: PLR0911 - one return per verdict
        """A captured frame through its camera's fault (None: nothing of it is left to publish)."""
        name = out.camera.name
        complete = out.frame is not None and out.depth_m is not None
        r = self.camera_faults.apply(name, out, complete=complete)
        if r.verdict is Verdict.DELIVERED:
            return out
        if r.verdict is Verdict.GARBAGE:
            cam, rng = out.camera, self.camera_faults.rng(name)
            if not complete or out.frame is None:
                return dataclasses.replace(out, fault="garbage", boxes=[])
            color = garbage_color(rng, cam.height, cam.width)
            depth = garbage_depth(rng, cam.height, cam.width, cam.near_m, min(cam.far_m, GARBAGE_MAX_DEPTH_M))
            frame = RenderedFrame(color, depth, out.frame.instance_id)
            return dataclasses.replace(out, frame=frame, depth_m=depth, fault="garbage", boxes=[])
        if r.verdict is Verdict.STUCK:
            frozen = r.frame
            if frozen is None:  # stuck before the camera ever delivered an image: it shows nothing
                return dataclasses.replace(out, frame=None, depth_m=None, fault="stuck", boxes=None)
            boxes = (frozen.detections or []) if out.detections is not None else None
            if complete:
                return dataclasses.replace(out, frame=frozen.frame, depth_m=frozen.depth_m, fault="stuck", boxes=boxes)
            return dataclasses.replace(out, fault="stuck", boxes=boxes)
        # off, or a frame an intermittent camera lost: only the scene's ground truth remains
        if out.detections is None:
            return None
        return dataclasses.replace(out, frame=None, depth_m=None, fault=r.verdict.value, boxes=None)

    def _effects_process(self) -> EffectsProcess:
        """The camera-effects process (:mod:`uav_sim_bridge.shell.effects_process`): every camera's effects, one frame
        after the other in submission order (deterministic), beside the GL thread and without its GIL."""
        if self._fx_process is None:
            self._fx_process = EffectsProcess(self._stages)
        return self._fx_process

    @property
    def effects_pid(self) -> int | None:
        """The effects process's pid (None until the first frame with effects starts it)."""
        return self._fx_process.pid if self._fx_process is not None else None

    def wait_effects(self) -> None:
        """Wait until the effects process has finished every frame submitted so far (a benchmark charges this
        engine for the work it left running)."""
        if self._fx_process is not None:
            self._fx_process.wait_all()

    def close(self) -> None:
        """Stop the effects process (the renderer is the caller's)."""
        if self._fx_process is not None:
            self._fx_process.close()
            self._fx_process = None

    def _deliver(self, outputs: list[CameraOutput], t_s: float) -> list[CameraOutput]:
        """Hold back delayed camera images until their capture time plus the camera's latency (an image whose
        effects still run in the effects process gets its exposure and gain from them then)."""
        ready: list[CameraOutput] = []
        for out in outputs:
            latency = self.cfg.environment.effects_for(out.camera.name).latency_s
            if latency > 0.0 and out.frame is not None:
                early = out.detections is not None
                if early:  # detections are ground truth: never delayed (the camera_info goes out with them)
                    ready.append(dataclasses.replace(out, frame=None, depth_m=None))
                self._delayed.append(dataclasses.replace(out, info_sent=early))
            else:
                ready.append(out)
        keep = []
        for out in self._delayed:
            latency = self.cfg.environment.effects_for(out.camera.name).latency_s
            if out.t_capture_s + latency <= t_s + 1e-9:
                done = dataclasses.replace(out, detections=None)
                if isinstance(out.frame, _PendingFrame):
                    result = out.frame.job.result()
                    done = dataclasses.replace(done, exposure_s=result.exposure_s, gain=result.gain)
                ready.append(done)
            else:
                keep.append(out)
        self._delayed = keep
        return ready

    @staticmethod
    def _camera_motion(cam: CameraModel, state: VehicleState) -> CameraMotion:
        """The camera's linear and angular velocity in its optical frame (the mount's lever arm neglected)."""
        r = cam.t_base_optical.rotation.T  # base_link -> optical
        v = r @ np.asarray(state.velocity_body_mps, dtype=np.float64)
        w = r @ np.asarray(state.angular_velocity_body_radps, dtype=np.float64)
        return CameraMotion((float(v[0]), float(v[1]), float(v[2])), (float(w[0]), float(w[1]), float(w[2])))

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


def _with_effects(out: CameraOutput, job: EffectsJob) -> CameraOutput:
    """``out`` with its camera effects applied (waits for the effects process)."""
    result = job.result()
    frame = out.frame
    assert frame is not None
    effected = RenderedFrame(result.color_rgb, frame.depth_m, frame.instance_id)
    return dataclasses.replace(out, frame=effected, exposure_s=result.exposure_s, gain=result.gain)


class _PendingFrame(RenderedFrame):
    """A delayed camera's frame whose effects still run in the effects process: its colour waits for them when
    first read (a camera fault may keep it, a stuck camera show it again); ``job`` gives exposure and gain."""

    __slots__ = ("job",)

    def __init__(self, frame: RenderedFrame, job: EffectsJob) -> None:
        super().__init__(None, frame.depth_m, frame.instance_id, shade=lambda: job.result().color_rgb)
        self.job = job


def _pending_effects(out: CameraOutput, job: EffectsJob) -> CameraOutput:
    """``out`` with a frame whose colour is the effects' result, waited for when read (see :class:`_PendingFrame`)."""
    frame = out.frame
    assert frame is not None
    return dataclasses.replace(out, frame=_PendingFrame(frame, job))
