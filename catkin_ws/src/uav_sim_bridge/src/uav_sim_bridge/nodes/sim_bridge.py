"""sim_bridge node: SITL ground truth -> rendered cameras, tf, odometry and detections in simulation time.

ROS interface (names are defaults; remap as usual):

Publishes:
    /clock (rosgraph_msgs/Clock): simulation time of every ground-truth state.
    /tf: map -> base_link (ground truth, or with seeded pose noise if ``noise.enabled``), unless
        ``~publish_pose_tf`` is false (the pose then comes from the autopilot's estimate: autopilot_odometry).
    /tf_static: base_link -> camera_<cam> (mount) -> camera_<cam>_optical, from the robot description, unless
        ``~publish_camera_tf`` is false (scenario runs: the robot_description node publishes them, as on a
        real vehicle).
    /uav/ground_truth/odom (nav_msgs/Odometry): exact pose in map, twist in base_link.
    /uav/sim_state (uav_msgs/SimState): armed, crashed, lockstep, motors, real-time factor;
        published last for each state, so a lockstep master can wait for it.
    /cameras/<cam>/color/image_raw (sensor_msgs/Image rgb8), .../color/camera_info
    /cameras/<cam>/depth/image_raw (Image 32FC1, metres z-depth, NaN = no return), .../depth/camera_info
    /cameras/<cam>/instance/image_raw (Image 16UC1, world instance id, 0 = sky)
    /cameras/<cam>/class/image_color (Image rgb8, class colors for people)
    /cameras/<cam>/points (sensor_msgs/PointCloud2 x y z rgb, frame camera_<cam>_optical, finite points)
    /detections/ground_truth (uav_msgs/DetectionArray): people and vehicles per detection camera frame, the
        truth for scoring (instance ids, true centres, ranges, visible fractions).
    /detections/<cam>/ground_truth (vision_msgs/Detection2DArray): the same boxes as a box-only detector
        (class ids from config/detection_classes.yaml, score 1; no ids, no positions): the detector contract.
    /sim/collision (uav_msgs/Collision): the vehicle touched an object (also sent to the SITL).
    /sim/object_states (uav_msgs/ObjectStateArray): the moving (and moved) people and vehicles: pose, kind,
        box, velocity, at ``publish.object_states_rate_hz`` of simulation time (their ground-truth tracks).
    /sim/world_mesh (visualization_msgs/Marker, latched): the world mesh for rviz.

Services:
    ~set_object_pose (uav_msgs/SetObjectPose): move a person or vehicle.
    ~set_camera_fault (uav_msgs/SetCameraFault): inject a fault into a camera (off, stuck, garbage,
        intermittent; ok clears it), from the next state's frames on; answers ACCEPTED with the simulation
        time it applies after, or DENIED naming the known cameras or types. A faulted camera's camera_info,
        images, points and box-only detections follow the fault; /detections/ground_truth does not
        (uav_sim_bridge.engine, docs/sim_bridge.md "Camera faults").

Parameters:
    ~config_file (str, default: the project's config/sim_bridge.yaml): node configuration.
    ~overrides (dict, default {}): deep-merged over the file (e.g. from a scenario).
    ~world, ~world_cache_dir, ~sim_host, ~sim_port, ~local_port, ~lockstep_role (str/int, "" = from file).
    ~cameras (str, "" = all): comma-separated subset of the configured cameras to run.
    ~robot_description (str, default: the project's config/robot.yaml): the camera mounts (extrinsics) come
        from this file, the one a real airframe edits; config/sim_bridge.yaml holds the intrinsics only.
    ~publish_pose_tf, ~publish_camera_tf (bool, default true): see /tf and /tf_static above.
    Causal lockstep (docs/lockstep.md): with ``/lockstep/causal`` true the bridge, as lockstep master, is the step
    master of the run: it serves ``/lockstep/join``, starts once every node of ``/lockstep/participants`` has joined
    and the graph is connected, grants step k + 1 only once every participant is done with step k + 1 - L, counts
    every message it publishes and ends each step with ``/lockstep/tick``. Its services apply requests at the
    step boundary the caller names.
    Sets ~world_hash, ~world_name and ~world_dir (cache folder with objects.json and world.ply).
    Any other private parameter stops the node (exit code 2, docs/architecture.md).

Threading: every GL call and all publishing of sensor data happen in the main loop's
thread; the service callback only queues a request and waits for the loop to apply it.

Publishers: in causal lockstep every topic but ``/clock`` is counted and never drops (an unbounded queue).
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rospy
import tf2_ros
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import ColorRGBA
from vision_msgs.msg import Detection2DArray
from visualization_msgs.msg import Marker

from uav_common.config import ConfigError, config_errors_as, deep_merge, load_yaml_mapping
from uav_common.detection_classes import DetectionClasses, load_detection_classes
from uav_common.geo import GeoPoint
from uav_common.lockstep.protocol import BoundaryQueue
from uav_common.paths import config_file
from uav_common.pointcloud import DepthImagePacker
from uav_common.robot import load_robot_description
from uav_common.ros.arrays import depth_cloud_msg, image_msg
from uav_common.ros.lockstep import APPLY_AFTER_HEADER, StepMaster, causal_enabled
from uav_common.ros.node import run_node
from uav_common.ros.params import node_params
from uav_msgs.msg import Collision, DetectionArray, ObjectStateArray, SimState
from uav_msgs.srv import (
    SetCameraFault,
    SetCameraFaultRequest,
    SetCameraFaultResponse,
    SetObjectPose,
    SetObjectPoseRequest,
    SetObjectPoseResponse,
)
from uav_sim_bridge.config import SimBridgeConfig, bridge_config, resolve_environment
from uav_sim_bridge.core import visualize
from uav_sim_bridge.core.schedule import LockstepRole, RateSchedule
from uav_sim_bridge.core.transforms import OPTICAL_FROM_FLU, RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import load_world_config
from uav_sim_bridge.engine import BridgeEngine, CameraOutput, StepOutput
from uav_sim_bridge.errors import CameraFaultError, SimBridgeConfigError, SimBridgeError
from uav_sim_bridge.render import Renderer
from uav_sim_bridge.ros import conversions as conv
from uav_sim_bridge.shell.simlink import SIM_STEP, LinkCounters, SimLinkClient, SimLinkTracker
from uav_sim_bridge.shell.world_io import export_mesh, export_objects_json
from uav_sim_bridge.shell.world_store import cache_slot, load_or_generate

__all__ = ["SimBridgeNode", "load_node_config", "main"]

_ACCEPTED = 0
_SIMPLE_PARAMS = {
    "world": ("world",),
    "world_cache_dir": ("world_cache_dir",),
    "sim_host": ("sim_link", "host"),
    "sim_port": ("sim_link", "port"),
    "local_port": ("sim_link", "local_port"),
    "lockstep_role": ("lockstep", "role"),
}


@dataclass(frozen=True)
class BridgeParams:
    """The node's private parameters (empty strings keep the configuration file's value)."""

    config_file: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    world: str = ""
    world_cache_dir: str = ""
    cameras: str = ""
    robot_description: str = ""
    publish_pose_tf: bool = True
    publish_camera_tf: bool = True
    sim_host: str = ""
    sim_port: int | str = ""
    local_port: int | str = ""
    lockstep_role: str = ""
    # Written by the node itself (read by the scorer and the depth evaluator); present on a respawn.
    world_hash: str = ""
    world_name: str = ""
    world_dir: str = ""

    def __post_init__(self) -> None:
        for name in ("sim_port", "local_port"):
            value = getattr(self, name)
            if isinstance(value, str) and value != "":
                msg = f"~{name} must be a port number or empty (the file's), got {value!r}"
                raise ValueError(msg)


def load_node_config(params: BridgeParams) -> SimBridgeConfig:
    """File + ``~overrides`` + the convenience parameters -> :class:`SimBridgeConfig`.

    Raises:
        SimBridgeConfigError: missing file, bad YAML, unknown key, bad value.
    """
    with config_errors_as(SimBridgeConfigError):
        path = Path(params.config_file).expanduser() if params.config_file else config_file("sim_bridge.yaml")
        data: dict[str, Any] = deep_merge(load_yaml_mapping(path), params.overrides)
        for name, keys in _SIMPLE_PARAMS.items():
            value = getattr(params, name)
            if value in ("", None):
                continue
            data = deep_merge(data, _nested(keys, value))
        wanted = params.cameras.strip()
        if wanted:
            names = [n.strip() for n in wanted.split(",") if n.strip()]
            cams = data.get("cameras", {})
            missing = [n for n in names if n not in cams]
            if missing:
                msg = f"~cameras names unknown camera(s) {missing}; configured: {sorted(cams)}"
                raise SimBridgeConfigError(msg)
            data["cameras"] = {n: cams[n] for n in names}
            det = dict(data.get("detections", {}))
            det["cameras"] = [c for c in det.get("cameras", ["forward", "nadir"]) if c in names]
            data["detections"] = det
            env = resolve_environment(data.get("environment"))
            if isinstance(env.get("cameras"), dict):
                env["cameras"] = {c: v for c, v in env["cameras"].items() if c in names or c == "default"}
                data["environment"] = env
        robot_path = Path(params.robot_description).expanduser() if params.robot_description else None
        robot = load_robot_description(robot_path or config_file("robot.yaml"))
        return bridge_config(data, robot, source=f"{path} (+ ~params)")


def _detection_classes(cfg: SimBridgeConfig) -> DetectionClasses:
    """The class map of the ground truth's boxes; every detection class must be in it.

    Raises:
        SimBridgeConfigError: missing or bad class map, or a detection class it lacks.
    """
    path = cfg.detections.class_map or config_file("detection_classes.yaml")
    try:
        classes = load_detection_classes(Path(path).expanduser())
    except ConfigError as err:
        raise SimBridgeConfigError(str(err)) from err
    missing = [c for c in cfg.detections.classes if c not in classes.classes]
    if missing:
        msg = f"detections.classes {missing} are not in the class map {path} (it has {sorted(classes.classes)})"
        raise SimBridgeConfigError(msg)
    return classes


def _nested(keys: tuple[str, ...], value: Any) -> dict[str, Any]:
    out: Any = value
    for k in reversed(keys):
        out = {k: out}
    return dict(out)


@dataclass
class _CameraPubs:
    """One camera's publishers (rospy's, or the step master's counted ones: the same interface)."""

    color: Any
    color_info: Any
    depth: Any
    depth_info: Any
    instance: Any
    klass: Any
    points: Any

    def all(self) -> list[Any]:
        return [self.color, self.color_info, self.depth, self.depth_info, self.instance, self.klass, self.points]

    def pixels(self) -> list[Any]:
        """The topics that need the camera rendered (camera_info does not: it goes out with detections too)."""
        return [self.color, self.depth, self.instance, self.klass, self.points]


@dataclass
class _MoveRequest:
    req: SetObjectPoseRequest
    done: threading.Event
    response: SetObjectPoseResponse | None = None
    abandoned: bool = False
    lock: threading.Lock = field(default_factory=threading.Lock)


@dataclass
class _FaultRequest:
    req: SetCameraFaultRequest
    done: threading.Event
    response: SetCameraFaultResponse | None = None
    #: The caller gave up waiting: the loop must not apply it (its answer said it was not applied).
    abandoned: bool = False
    lock: threading.Lock = field(default_factory=threading.Lock)


#: How long (wall seconds) a service waits for the main loop to apply its request (free or plain lockstep time;
#: in causal lockstep the request waits for its step boundary, however long the run takes to get there).
_ANSWER_S = 30.0


class SimBridgeNode:
    """The node (see module docstring). Create and spin it in the same thread."""

    def __init__(self, cfg: SimBridgeConfig, params: BridgeParams) -> None:  # noqa: PLR0915 - start-up, step by step
        self.cfg = cfg
        t0 = time.monotonic()
        world_cfg = load_world_config(cfg.world_yaml())
        self.world: World = load_or_generate(world_cfg, cfg.cache_dir())
        self.world_dir = cache_slot(world_cfg, cfg.cache_dir())
        rospy.loginfo(
            "world %s (%s...): %d objects, %d triangles, ready in %.1f s",
            world_cfg.name,
            self.world.hash[:12],
            len(self.world.objects),
            len(self.world.mesh.faces),
            time.monotonic() - t0,
        )
        self.classes = _detection_classes(cfg)
        self.renderer = Renderer(self.world, cfg.render)
        rospy.loginfo("renderer: %s", self.renderer.gl_renderer)
        try:
            self.engine = BridgeEngine(cfg, self.world, self.renderer)
        except (SimBridgeConfigError, ValueError) as err:
            source = params.config_file or "config/sim_bridge.yaml"
            msg = f"{source} (+ ~overrides): {err}"
            raise SimBridgeConfigError(msg) from err
        env, light = cfg.environment, self.engine.lighting
        rospy.loginfo(
            "environment %s: sun azimuth %.0f, elevation %.1f deg, shadows %s, overcast %.2f, visibility %s; "
            "camera effects on %s; %d moving objects",
            env.preset,
            light.azimuth_deg,
            light.elevation_deg,
            light.shadows,
            env.overcast,
            f"{env.visibility_m:.0f} m" if env.visibility_m is not None else "clear",
            sorted(self.engine.effects) or "none",
            len(self.engine.motion.movers),
        )
        self.counters = LinkCounters()
        sl = cfg.sim_link
        self.link = SimLinkClient(
            sl.host,
            sl.port,
            local_port=sl.local_port,
            system_id=sl.system_id,
            component_id=sl.component_id,
            counters=self.counters,
        )
        self.tracker = SimLinkTracker(sitl_system_id=1, counters=self.counters)
        rospy.loginfo("sim link: local UDP %d -> %s:%d", self.link.local_port, sl.host, sl.port)
        # Causal lockstep (docs/lockstep.md): the bridge is the run's step master.
        self.master: StepMaster | None = None
        if causal_enabled():
            if cfg.lockstep.role != LockstepRole.MASTER:
                msg = (
                    f"/lockstep/causal is true but lockstep.role is {cfg.lockstep.role!r}: the causal lockstep needs "
                    "the bridge as its step master (lockstep.role: master)"
                )
                raise SimBridgeConfigError(msg)
            expected = rospy.get_param("/lockstep/participants", []) or []
            if not isinstance(expected, list) or not all(isinstance(n, str) for n in expected):
                msg = f"/lockstep/participants must be a list of node names, got {expected!r}"
                raise SimBridgeConfigError(msg)
            self.master = StepMaster(step_s=0.0, expected=expected)
            rospy.loginfo("lockstep: causal; the bridge is the step master of %d participants", len(expected))
        self._make_publishers()
        self.publish_pose_tf = params.publish_pose_tf
        if params.publish_camera_tf:
            self._publish_static()
        self._requests: BoundaryQueue[_MoveRequest | _FaultRequest] = BoundaryQueue()
        self._requests_lock = threading.Lock()
        self._service = rospy.Service("~set_object_pose", SetObjectPose, self._on_set_object_pose)
        self._fault_service = rospy.Service("~set_camera_fault", SetCameraFault, self._on_set_camera_fault)
        rospy.set_param("~world_hash", self.world.hash)
        rospy.set_param("~world_name", world_cfg.name)
        rospy.set_param("~world_dir", str(self.world_dir))
        self._processed_serial = 0
        self._processed_t = 0.0  # simulation time of the last state processed
        self._terrain_schedule = RateSchedule(sl.terrain_report_rate_hz)
        self._last_heartbeat = -math.inf
        self._last_state_wall = time.monotonic()
        self._rtf = 0.0
        self._rtf_ref: tuple[float, float] | None = None
        # lockstep master bookkeeping
        self._awaiting_ack = False
        self._grant_sent_at = 0.0
        self._lockstep_denied = False
        self._lockstep_confirmed = False
        self._wall_start: float | None = None
        self._sim_start: float | None = None
        self.grants = 0
        self.frames = 0
        self._packers: dict[str, DepthImagePacker] = {}  # per camera: reused cloud buffers
        self._last_bad = 0
        self._last_state_t: float | None = None
        self._frozen_listeners: dict[str, bool] | None = None  # causal lockstep: see _listened

    # ------------------------------------------------------------------ setup
    def _pub(self, topic: str, msg_class: Any, queue_size: int, *, latch: bool = False) -> Any:
        """A publisher: counted and lossless in causal lockstep (the master's), plain rospy otherwise."""
        if self.master is not None:
            return self.master.publisher(topic, msg_class, latch=latch)
        return rospy.Publisher(topic, msg_class, queue_size=queue_size, latch=latch)

    def _make_publishers(self) -> None:
        pub = self._pub
        self.pub_clock = rospy.Publisher("/clock", Clock, queue_size=10)  # never a lockstep input: not counted
        self.pub_odom = pub("/uav/ground_truth/odom", Odometry, 10)
        self.pub_state = pub("/uav/sim_state", SimState, 10)
        self.pub_det = pub(self.cfg.detections.topic, DetectionArray, 10)
        # The ground truth as one more box-only detector (vision_msgs), per detection camera.
        self.pub_boxes = {
            cam: pub(self.cfg.detections.boxes_topic.format(camera=cam), Detection2DArray, 10)
            for cam in self.cfg.detections.cameras
            if cam in self.engine.cameras
        }
        self.pub_collision = pub("/sim/collision", Collision, 10, latch=True)
        self.pub_objects = pub("/sim/object_states", ObjectStateArray, 10)
        if self.master is not None:
            self.tf: Any = self.master.tf_broadcaster()
            self.tf_static: Any = self.master.tf_broadcaster(static=True)
        else:
            self.tf = tf2_ros.TransformBroadcaster()
            self.tf_static = tf2_ros.StaticTransformBroadcaster()
        self.cam_pubs: dict[str, _CameraPubs] = {}
        q = self.cfg.publish.queue_size  # a recorder must not lose frames: see PublishConfig.queue_size
        for name in self.engine.cameras:
            ns = f"/cameras/{name}"
            self.cam_pubs[name] = _CameraPubs(
                color=pub(f"{ns}/color/image_raw", Image, q),
                color_info=pub(f"{ns}/color/camera_info", CameraInfo, q),
                depth=pub(f"{ns}/depth/image_raw", Image, q),
                depth_info=pub(f"{ns}/depth/camera_info", CameraInfo, q),
                instance=pub(f"{ns}/instance/image_raw", Image, q),
                klass=pub(f"{ns}/class/image_color", Image, q),
                points=pub(f"{ns}/points", PointCloud2, q),
            )
        if self.cfg.publish.world_mesh_marker:
            self.pub_mesh = pub("/sim/world_mesh", Marker, 1, latch=True)
            self._publish_mesh_marker()

    def _publish_static(self) -> None:
        cfg = self.cfg
        msgs = []
        for cam in self.engine.cameras.values():
            msgs.append(conv.transform_stamped(0.0, cfg.base_frame, cam.frame_id, cam.t_base_camera))
            optical = RigidTransform(OPTICAL_FROM_FLU, np.zeros(3))
            msgs.append(conv.transform_stamped(0.0, cam.frame_id, cam.optical_frame_id, optical))
        self.tf_static.sendTransform(msgs)

    def _publish_mesh_marker(self) -> None:
        ply = self.world_dir / "world.ply"
        try:
            if not ply.is_file():
                export_mesh(self.world, ply)
            objects = self.world_dir / "objects.json"
            if not objects.is_file():
                export_objects_json(self.world, objects)
        except SimBridgeError as err:
            rospy.logwarn("cannot export the world mesh for rviz: %s", err)
            return
        m = Marker(header=conv.header(0.0, self.cfg.map_frame), ns="world", id=0, type=Marker.MESH_RESOURCE)
        m.action = Marker.ADD
        m.pose.orientation.w = 1.0
        m.scale.x = m.scale.y = m.scale.z = 1.0
        m.color = ColorRGBA(0.0, 0.0, 0.0, 0.0)  # use the mesh's vertex colors
        m.mesh_resource = f"file://{ply}"
        m.mesh_use_embedded_materials = True
        self.pub_mesh.publish(m)

    # ------------------------------------------------------------------ service (any thread)
    def _boundary(self, req: Any) -> int:
        """The step boundary a request applies at: the caller's (causal lockstep, docs/lockstep.md), else the next
        one (free or plain lockstep time: -1, at once)."""
        if self.master is None:
            return -1
        header = getattr(req, "_connection_header", None) or {}
        raw = header.get(APPLY_AFTER_HEADER)
        return self.master.step if raw is None else int(raw)

    def _queue(self, item: _MoveRequest | _FaultRequest) -> None:
        with self._requests_lock:
            self._requests.put(self._boundary(item.req), item)

    def _wait_answer(self, item: _MoveRequest | _FaultRequest) -> bool:
        """Wait for the loop to apply ``item``: at its boundary in causal lockstep (as long as the run takes to
        get there), within :data:`_ANSWER_S` otherwise. False (and never applied): too late."""
        while not item.done.wait(1.0 if self.master is not None else _ANSWER_S):
            if self.master is None or rospy.is_shutdown():
                break
        with item.lock:
            if item.response is None:
                item.abandoned = True
                return False
        return True

    def _on_set_object_pose(self, req: SetObjectPoseRequest) -> SetObjectPoseResponse:
        item = _MoveRequest(req, threading.Event())
        self._queue(item)
        if not self._wait_answer(item):
            text = f"the bridge loop did not answer within {_ANSWER_S:.0f} s"
            return SetObjectPoseResponse(success=False, message=text)
        assert item.response is not None
        return item.response

    def _on_set_camera_fault(self, req: SetCameraFaultRequest) -> SetCameraFaultResponse:
        item = _FaultRequest(req, threading.Event())
        self._queue(item)
        if not self._wait_answer(item):
            detail = f"the bridge loop did not take it within {_ANSWER_S:.0f} s: not applied"
            return SetCameraFaultResponse(result="DENIED", detail=detail, applied_s=math.nan)
        assert item.response is not None
        return item.response

    def _apply_camera_fault_locked(self, item: _FaultRequest) -> None:
        r = item.req
        applied_s = self._processed_t  # frames of the states processed after it carry the fault
        try:
            self.engine.set_camera_fault(str(r.camera), str(r.type))
        except CameraFaultError as err:
            rospy.logerr("camera fault %s %s refused: %s", r.camera, r.type, err)
            item.response = SetCameraFaultResponse(result="DENIED", detail=str(err), applied_s=math.nan)
        else:
            rospy.logwarn("camera %s: fault %s from %.2f s (simulation time)", r.camera, r.type, applied_s)
            item.response = SetCameraFaultResponse(result="ACCEPTED", detail="", applied_s=applied_s)

    def _drain_requests(self) -> None:
        """Apply the service requests due now: all of them, or in causal lockstep those whose boundary has come
        (the master has published the step they apply after)."""
        finished = self.master.step if self.master is not None else 0
        with self._requests_lock:
            due = self._requests.due(finished)
        for item in due:
            with item.lock:
                if item.abandoned:
                    continue
                if isinstance(item, _FaultRequest):
                    self._apply_camera_fault_locked(item)
                else:
                    self._apply_move_locked(item)
            item.done.set()

    def _apply_move_locked(self, item: _MoveRequest) -> None:
        r = item.req
        key: str | int = int(r.instance_id) if r.instance_id else str(r.name)
        try:
            obj = self.engine.move_object(key, r.position.x, r.position.y, r.position.z, r.yaw_rad)
            item.response = SetObjectPoseResponse(
                success=True, message=f"moved {obj.name} to {obj.pose.position_m}", instance_id=obj.instance_id
            )
        except (KeyError, ValueError) as err:
            item.response = SetObjectPoseResponse(success=False, message=str(err).strip("'\""))

    # ------------------------------------------------------------------ main loop
    def spin(self) -> None:
        role = self.cfg.lockstep.role
        rospy.loginfo("lockstep role: %s", role)
        while not rospy.is_shutdown():
            wake = self.master.wake_fd if self.master is not None else None
            msgs = self.link.receive(0.02, wake_fd=wake)
            if self.master is not None:
                self.master.drain_wake()
            for m in msgs:
                self.tracker.update(m)
            self._drain_requests()
            now = time.monotonic()
            if now - self._last_heartbeat >= self.cfg.sim_link.heartbeat_period_s:
                self.link.send_heartbeat()
                self._last_heartbeat = now
            snap = self.tracker.snapshot
            if snap.state_serial != self._processed_serial and snap.state is not None:
                self._processed_serial = snap.state_serial
                self._process(now)
            acks, snap.acks = snap.acks, []
            for command, result in acks:
                if command == SIM_STEP:
                    self._on_grant_ack(result)
            if role == LockstepRole.MASTER and not self._lockstep_denied:
                if self.master is not None:
                    self._maybe_grant_causal(now)
                else:
                    self._maybe_grant(now)
            self._warn_if_unwell(now)
        rospy.loginfo(
            "sim link: rx %d datagrams (%d bad, %d foreign, %d invalid states), tx %d (%d errors); "
            "%d frames, %d grants",
            self.counters.rx_datagrams,
            self.counters.rx_bad,
            self.counters.rx_foreign,
            self.counters.rx_invalid_state,
            self.counters.tx_messages,
            self.counters.tx_errors,
            self.frames,
            self.grants,
        )
        if self.master is not None:
            rospy.loginfo("lockstep: %s", self.master.summary())

    def _on_grant_ack(self, result: int) -> None:
        self._awaiting_ack = False
        if result == _ACCEPTED:
            if not self._lockstep_confirmed:
                rospy.loginfo("lockstep: the SITL accepted our SIM_STEP grants; the bridge is the step master")
            self._lockstep_confirmed = True
        else:
            self._lockstep_denied = True
            rospy.logwarn("lockstep: SIM_STEP refused (result %d): the SITL runs free; not granting any more", result)

    def _maybe_grant(self, now: float) -> None:
        snap = self.tracker.snapshot
        if snap.heartbeats == 0 and snap.state is None:
            return  # nothing heard from the SITL yet
        lk = self.cfg.lockstep
        if self._awaiting_ack:
            if now - self._grant_sent_at > lk.grant_timeout_s:
                rospy.logwarn_throttle(
                    5.0, "lockstep: no COMMAND_ACK for SIM_STEP within %.1f s; granting again", lk.grant_timeout_s
                )
                self._send_grant(now)
            return
        if lk.max_real_time_factor > 0 and snap.state is not None:
            if self._wall_start is None or self._sim_start is None:
                self._wall_start, self._sim_start = now, snap.state.sim_time_s
            earliest = self._wall_start + (snap.state.sim_time_s - self._sim_start) / lk.max_real_time_factor
            if now < earliest:
                return
        if snap.state is not None:
            report = self.engine.terrain_report(snap.state, self._home())
            if report is not None:
                self.link.send_terrain_report(
                    report.lat_deg, report.lon_deg, report.terrain_amsl_m, report.above_terrain_m
                )
        self._send_grant(now)

    def _maybe_grant_causal(self, now: float) -> None:
        """Causal lockstep: grant step k + 1 once every participant is done with step k + 1 - L (docs/lockstep.md).

        A late COMMAND_ACK means a busy SITL, not a lost grant: granting again would run extra steps, so it waits
        (and says so). Nothing here lets a step through on a timeout.

        Raises:
            LockstepError: a participant reported an error, broke the protocol or made no progress for
                ``/lockstep/watchdog_s`` (the run stops: the bridge is required).
        """
        master = self.master
        assert master is not None
        snap = self.tracker.snapshot
        if snap.heartbeats == 0 and snap.state is None:
            return  # nothing heard from the SITL yet
        if self._awaiting_ack:
            if now - self._grant_sent_at > 10.0 * self.cfg.lockstep.grant_timeout_s:
                rospy.logwarn_throttle(10.0, "lockstep: still waiting for the SITL's COMMAND_ACK for SIM_STEP")
            return
        if self.grants > master.step:
            return  # the state of our last grant has not been processed yet
        if not master.try_start():
            return
        if self._frozen_listeners is None:
            self._freeze_listeners()
        if not master.can_grant():
            master.check_watchdog()
            return
        if snap.state is not None:
            report = self.engine.terrain_report(snap.state, self._home())
            if report is not None:
                self.link.send_terrain_report(
                    report.lat_deg, report.lon_deg, report.terrain_amsl_m, report.above_terrain_m
                )
        self._send_grant(now)

    def _send_grant(self, now: float) -> None:
        self.link.send_sim_step(self.cfg.lockstep.steps_per_grant, step=self.grants + 1)
        self._awaiting_ack = True
        self._grant_sent_at = now
        self.grants += 1

    def _home(self) -> GeoPoint | None:
        h = self.cfg.home
        if h is not None:
            return GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m)
        return self.tracker.snapshot.home

    def _wanted(self, name: str) -> bool:
        if not self.cfg.publish.only_when_subscribed:
            return True
        return any(self._listened(p) for p in self.cam_pubs[name].pixels())

    def _listened(self, pub: Any) -> bool:
        """Does anyone subscribe to ``pub``? In the causal lockstep, as it was when the run started: what is
        rendered (and so every seeded draw of the cameras' noise and effects) must not depend on a viewer that
        comes and goes (rviz, ``rostopic hz``, the scorer's report snapshots)."""
        frozen = self._frozen_listeners
        if frozen is not None:
            return frozen.get(pub.name, False)
        return bool(pub.get_num_connections() > 0)

    def _freeze_listeners(self) -> None:
        pubs = [self.pub_det, *self.pub_boxes.values()]
        for cam in self.cam_pubs.values():
            pubs.extend(cam.all())
        self._frozen_listeners = {p.name: p.get_num_connections() > 0 for p in pubs}
        listened = sorted(n for n, on in self._frozen_listeners.items() if on)
        rospy.loginfo("lockstep: published for the whole run (subscribed at the start): %s", ", ".join(listened))

    def _process(self, now: float) -> None:
        snap = self.tracker.snapshot
        state = snap.state
        assert state is not None
        t = state.sim_time_s
        self._processed_t = t
        self._update_rtf(now, t)
        self._last_state_wall = now
        self.pub_clock.publish(conv.clock(t))
        want_det = (
            not self.cfg.publish.only_when_subscribed
            or self._listened(self.pub_det)
            or any(self._listened(p) for p in self.pub_boxes.values())
        )
        out = self.engine.step(state, home=self._home(), wanted=self._wanted, want_detections=want_det)
        cfg = self.cfg
        if self.publish_pose_tf:
            self.tf.sendTransform(conv.transform_stamped(t, cfg.map_frame, cfg.base_frame, out.published_pose))
        self.pub_odom.publish(conv.odometry(state, cfg.map_frame, cfg.base_frame))
        for cam_out in out.cameras:
            self._publish_camera(cam_out.t_capture_s, cam_out)
        if out.objects is not None:
            self.pub_objects.publish(conv.object_states_msg(t, cfg.map_frame, out.objects))
        self._publish_contacts(out)
        if out.terrain is not None:
            participant = cfg.lockstep.role == LockstepRole.PARTICIPANT
            if participant or (not self._lockstep_confirmed and self._terrain_schedule.due(t)):
                r = out.terrain
                self.link.send_terrain_report(r.lat_deg, r.lon_deg, r.terrain_amsl_m, r.above_terrain_m)
        self.pub_state.publish(
            conv.sim_state(
                t,
                cfg.map_frame,
                rtf=self._rtf,
                armed=snap.armed,
                crashed=snap.crashed,
                lockstep=snap.lockstep,
                motors=snap.motor_outputs,
            )
        )
        if self.master is not None:
            if self._last_state_t is not None and self.master.step_s == 0.0:
                self.master.step_s = t - self._last_state_t
            self.master.publish_tick(t)
        self._last_state_t = t

    def _publish_camera(self, t: float, out: CameraOutput) -> None:
        hdr = conv.header(t, out.camera.optical_frame_id)
        pubs = self.cam_pubs[out.camera.name]
        every = not self.cfg.publish.only_when_subscribed

        def on(p: Any) -> bool:
            return every or self._listened(p)

        info = conv.camera_info(out.camera, hdr)
        # Intrinsics go out with every frame the camera delivers, rendered or detection-only (a consumer of the
        # detections, e.g. the geolocator, needs them; they cost no render), before the detections; once a frame
        # (a delayed frame's went out with its detections at capture time).
        send_info = out.delivered and not out.info_sent
        if send_info and on(pubs.color_info):
            pubs.color_info.publish(info)
        if send_info and on(pubs.depth_info):
            pubs.depth_info.publish(info)
        if out.detections is not None:
            self.pub_det.publish(conv.detection_array(hdr, out.camera.name, out.detections))  # the scene's truth
            boxes = self.pub_boxes.get(out.camera.name)
            found = out.detector_boxes  # what a detector on the delivered image finds (faults included)
            if boxes is not None and found is not None and on(boxes):
                boxes.publish(conv.ground_truth_boxes(hdr, found, self.classes))
        frame = out.frame
        if frame is None or out.depth_m is None:
            return  # only the detections were wanted
        if on(pubs.color):
            pubs.color.publish(image_msg(frame.color_rgb, "rgb8", hdr))
        if on(pubs.depth):
            pubs.depth.publish(image_msg(out.depth_m, "32FC1", hdr))
        if on(pubs.instance):
            pubs.instance.publish(image_msg(frame.instance_id, "16UC1", hdr))
        if self.cfg.publish.class_image and on(pubs.klass):
            rgb = visualize.class_image(frame.instance_id, self.world.instance_class)
            pubs.klass.publish(image_msg(rgb, "rgb8", hdr))
        if self.cfg.publish.points and on(pubs.points):
            stride = self.cfg.publish.points_stride
            packer = self._packers.setdefault(out.camera.name, DepthImagePacker())
            cloud = depth_cloud_msg(packer, hdr, out.depth_m, frame.color_rgb, out.camera.k, stride=stride)
            pubs.points.publish(cloud)
        self.frames += 1

    def _publish_contacts(self, out: StepOutput) -> None:
        speed = float(np.linalg.norm(out.state.velocity_body_mps))
        for c in out.new_contacts:
            obj = self.engine.lookup(c.instance_id)
            rospy.logwarn(
                "collision with %s (%s, id %d) at %.1f m/s", obj.name, c.object_class.label, c.instance_id, speed
            )
            self.link.send_collision(c.instance_id)
            self.pub_collision.publish(
                conv.collision_msg(
                    out.state.sim_time_s,
                    self.cfg.map_frame,
                    instance_id=c.instance_id,
                    class_name=c.object_class.label,
                    point_m=c.point_m,
                    speed_mps=speed,
                )
            )

    def _update_rtf(self, now: float, sim_t: float) -> None:
        if self._rtf_ref is None or sim_t < self._rtf_ref[1]:
            self._rtf_ref = (now, sim_t)
            return
        dw = now - self._rtf_ref[0]
        if dw >= 1.0:
            self._rtf = float((sim_t - self._rtf_ref[1]) / dw)
            self._rtf_ref = (now, sim_t)

    def _warn_if_unwell(self, now: float) -> None:
        if now - self._last_state_wall > self.cfg.sim_link.stale_warning_s:
            rospy.logwarn_throttle(
                10.0,
                "no ground truth from the SITL at %s:%d for %.0f s (is uav-sitl running with its sim link?)",
                self.cfg.sim_link.host,
                self.cfg.sim_link.port,
                now - self._last_state_wall,
            )
        if self.counters.rx_bad > self._last_bad:
            rospy.logwarn_throttle(10.0, "sim link: %d malformed datagrams dropped so far", self.counters.rx_bad)
            self._last_bad = self.counters.rx_bad

    def close(self) -> None:
        self.link.close()
        self.engine.close()
        self.renderer.close()


def main() -> None:
    run_node("sim_bridge", _run, errors=(SimBridgeError,))


def _run() -> None:
    params = node_params(BridgeParams, "sim_bridge")
    node = SimBridgeNode(load_node_config(params), params)
    try:
        node.spin()
    finally:
        node.close()
