"""Scenario files (``config/scenarios/*.yaml``) as frozen dataclasses.

A scenario says which world to fly in, how the map and the autonomy are set up,
what the mission is (loiter or search and rescue, autonomous or a scripted
baseline), when the run stops, how time runs and what is recorded.  It is parsed
once, strictly (:func:`uav_common.config.load_config`: an unknown key or a wrong
type fails with the file and key), and every process of a run reads its settings
from the same file.

Relative paths inside a scenario file are relative to the file's own folder.
Positions are metres in the ``map`` frame (ENU, origin = home on the ground).

Stress presets (``config/stress/*.yaml``) are partial scenarios laid over a scenario before it is
parsed: ``stress: [lossy_link]`` in the file (or ``uav-run --stress lossy_link``) merges each preset
over it, key by key, in order; the effective scenario records them under ``stress_applied``.
"""

from __future__ import annotations

import enum
import itertools
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from mavlink_router.core.impairment import ImpairmentConfig
from uav_common.config import config_errors_as, deep_merge, from_mapping, load_yaml_mapping
from uav_common.validate import require_in_range
from uav_scenarios.core.faults import camera_name, not_simulated
from uav_scenarios.errors import ScenarioConfigError
from uav_sim_bridge.core.motion import ActorsConfig

__all__ = [
    "LINK_ENDPOINTS",
    "LOCKSTEP_PARTICIPANTS",
    "LOCKSTEP_WALL_FLOOR_S",
    "AutonomySpec",
    "AutopilotKind",
    "DepthSource",
    "DetectorKind",
    "FaultSpec",
    "GeolocationSpec",
    "LinkImpairmentSpec",
    "LinkSpec",
    "MapBackend",
    "MapSpec",
    "MissionKind",
    "PerceptionSpec",
    "PersonSpec",
    "PoseSource",
    "RecordingSpec",
    "Scenario",
    "ScoringSpec",
    "SearchSpec",
    "StopCriteria",
    "Strategy",
    "TargetSpec",
    "TimeMode",
    "TimeSpec",
    "WindSpec",
    "WorldSpec",
    "effective_yaml",
    "estimate_topic",
    "load_scenario",
    "played_topics",
    "recorded_topics",
    "replay_inputs",
]

Point2 = tuple[float, float]

#: Feature names the goal selector knows plus ``origin`` (distance from home).
FEATURE_NAMES = ("age", "frontier", "target", "drone", "origin")


class MissionKind(enum.Enum):
    LOITER = "loiter"
    SEARCH_AND_RESCUE = "search_and_rescue"


class Strategy(enum.Enum):
    """Who decides where to fly: the MCDM autonomy, or a scripted baseline pattern."""

    AUTONOMOUS = "autonomous"
    LAWNMOWER = "lawnmower"
    EXPANDING_SQUARE = "expanding_square"


#: In lockstep a timeout (link, position, pose, estimate, the SITL's offboard stream) also needs this many wall
#: seconds: a lockstep run goes several times faster than real time, so a process starved of CPU for half a
#: wall second on a busy machine would otherwise read as seconds of silence. ``node_params`` overrides it.
LOCKSTEP_WALL_FLOOR_S = 2.0


#: The ROS nodes that can take part in the causal lockstep (docs/lockstep.md) besides the step master (the sim
#: bridge); a run's participants are those of them it starts.
LOCKSTEP_PARTICIPANTS = (
    "robot_description",
    "map_server",
    "feature_evaluator",
    "goal_selector",
    "path_planner",
    "waypoint_controller",
    "autopilot_odometry",
    "depth_estimator",
    "depth_evaluator",
    "degraded_detector",
    "detector",
    "geolocator",
    "tracker",
    "mission_manager",
    "scorer",
)


class TimeMode(enum.Enum):
    FREE = "free"
    LOCKSTEP = "lockstep"


class AutopilotKind(enum.Enum):
    """Which autopilot the simulated vehicle is (``uav-sitl --autopilot``); the controller adapts by itself."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"


class MapBackend(enum.Enum):
    OCTOMAP = "octomap"
    OPENVDB = "openvdb"


class DepthSource(enum.Enum):
    GROUND_TRUTH = "ground_truth"
    ESTIMATED = "estimated"


class PoseSource(enum.Enum):
    """Where the map, features, planner and depth estimator take the vehicle's pose from."""

    #: The simulator's exact pose (``/uav/ground_truth/odom`` and its ``map -> base_link`` tf).
    GROUND_TRUTH = "ground_truth"
    #: The autopilot's own estimate over MAVLink (``autopilot_odometry``: ``/uav/autopilot/odom`` and
    #: ``map -> odom -> base_link``), as on a real vehicle.
    AUTOPILOT = "autopilot"


#: The odometry topic of each pose source.
POSE_TOPICS = {PoseSource.GROUND_TRUTH: "/uav/ground_truth/odom", PoseSource.AUTOPILOT: "/uav/autopilot/odom"}
#: The autopilot_odometry node's status topic.
ESTIMATE_STATUS_TOPIC = "/autopilot_odometry/status"
#: The autopilot's own position target (autopilot_odometry), for the scorer's ``autopilot_tracking``.
TARGET_TOPIC = "/autopilot_odometry/target"


def _check_polygon(name: str, polygon: tuple[Point2, ...]) -> None:
    if polygon and len(polygon) < 3:
        msg = f"{name} needs at least 3 vertices, got {len(polygon)}"
        raise ValueError(msg)


def polygon_area_m2(polygon: tuple[Point2, ...]) -> float:
    """Unsigned shoelace area of a simple polygon, m²."""
    total = 0.0
    for (x0, y0), (x1, y1) in zip(polygon, polygon[1:] + polygon[:1], strict=True):
        total += x0 * y1 - x1 * y0
    return abs(total) / 2.0


@dataclass(frozen=True)
class WorldSpec:
    """The world: a world-generator config and its seed (same seed, same world)."""

    config: Path = Path("../worlds/default.yaml")
    #: World seed; ``None`` keeps the world file's own seed. A different seed gives a
    #: different world (the launchers write a derived world file with this seed).
    seed: int | None = None
    #: Size of the square scene used as the "% mapped" denominator when the world's
    #: own bounds are unknown; the world's ground truth wins when it is available.
    size_m: float = 1000.0

    def __post_init__(self) -> None:
        if self.size_m <= 0:
            msg = f"size_m must be > 0, got {self.size_m}"
            raise ValueError(msg)


@dataclass(frozen=True)
class MapSpec:
    backend: MapBackend = MapBackend.OCTOMAP
    resolution_m: float = 0.5
    #: The camera whose depth (ground truth or estimated) feeds the map.
    camera: str = "nadir"
    #: Extra private parameters for the map server, passed through untouched.
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not 0.05 <= self.resolution_m <= 10.0:
            msg = f"resolution_m must be within [0.05, 10] m, got {self.resolution_m}"
            raise ValueError(msg)


@dataclass(frozen=True)
class TargetSpec:
    """The goal selector's target: a point, or a polygon (its nearest point counts)."""

    point_m: Point2 | None = (0.0, 0.0)
    polygon_m: tuple[Point2, ...] = ()

    def __post_init__(self) -> None:
        _check_polygon("polygon_m", self.polygon_m)
        if self.point_m is None and not self.polygon_m:
            msg = "give a target point_m or a polygon_m"
            raise ValueError(msg)


@dataclass(frozen=True)
class AutonomySpec:
    #: Feature weights of the MCDM score (0 = feature off; negative = avoid: e.g. ``age: -1`` sends the
    #: drone to cells seen long ago, since the age feature is 1 for a cell seen just now).
    weights: dict[str, float] = field(
        default_factory=lambda: {"age": 1.0, "frontier": 1.0, "target": 1.0, "drone": 1.0}
    )
    target: TargetSpec = field(default_factory=TargetSpec)
    #: Cruise altitude = highest known elevation along the path + this buffer.
    cruise_buffer_m: float = 50.0
    cruise_speed_mps: float = 8.0
    takeoff_alt_m: float = 30.0
    age_half_life_s: float = 60.0
    #: Path planner algorithm: ``straight`` (climb, cruise, descend) or ``astar`` (3D over the voxel map).
    planner: Literal["straight", "astar"] = "straight"

    def __post_init__(self) -> None:
        unknown = sorted(set(self.weights) - set(FEATURE_NAMES))
        if unknown:
            msg = f"unknown feature weight(s) {unknown}; known: {', '.join(FEATURE_NAMES)}"
            raise ValueError(msg)
        if not all(math.isfinite(w) for w in self.weights.values()):
            msg = f"weights must be finite, got {self.weights}"
            raise ValueError(msg)
        if not any(w != 0 for w in self.weights.values()):
            msg = "at least one feature weight must be non-zero"
            raise ValueError(msg)
        for name in ("cruise_buffer_m", "cruise_speed_mps", "takeoff_alt_m", "age_half_life_s"):
            if getattr(self, name) <= 0:
                msg = f"{name} must be > 0, got {getattr(self, name)}"
                raise ValueError(msg)


@dataclass(frozen=True)
class PersonSpec:
    """The person of interest (search and rescue): placed at random, seeded, inside a region."""

    #: Which person of the world's object list is the person of interest (moved into place).
    name: str = "person_0000"
    placement_seed: int = 1
    #: Where the person may be; a polygon in map metres.
    region_m: tuple[Point2, ...] = ((-100.0, -400.0), (100.0, -400.0), (100.0, -250.0), (-100.0, -250.0))
    #: Keep the person this far from any obstacle and from home.
    clearance_m: float = 5.0
    #: Fixed position instead of a random one (overrides the seed).
    position_m: Point2 | None = None
    #: The person's pose (``standing``, ``sitting``, ``lying``: a victim is often lying); null keeps the
    #: world's. The person of interest never walks (it is put in place and stays).
    pose: Literal["standing", "sitting", "lying"] | None = None

    def __post_init__(self) -> None:
        _check_polygon("region_m", self.region_m)
        if not self.region_m and self.position_m is None:
            msg = "give the person a region_m or a position_m"
            raise ValueError(msg)


@dataclass(frozen=True)
class SearchSpec:
    """Search and rescue: prior knowledge, detection, confirmation and the search area."""

    person: PersonSpec = field(default_factory=PersonSpec)
    #: Moved: the detector and its camera are ``perception.detector`` and ``perception.camera`` (any run,
    #: not only search and rescue, has a detector under test). Setting these is an error saying so.
    detection_topic: str | None = None
    camera: str | None = None
    #: The ground truth's detection range (the bridge registers people and vehicles this close).
    detection_range_m: float = 100.0
    #: A person is confirmed after this many detections within ``confirm_window_s``.
    confirm_detections: int = 3
    confirm_window_s: float = 3.0
    #: Where the scripted baselines search, and the only place a person is confirmed (a person seen elsewhere is
    #: not the one searched for).
    area_m: tuple[Point2, ...] = ((-250.0, -450.0), (250.0, -450.0), (250.0, -50.0), (-250.0, -50.0))
    #: Lane spacing of the lawnmower / leg increment of the expanding square.
    track_spacing_m: float = 80.0
    #: Altitude of the scripted baselines, metres above ``scripted_alt_reference``.
    scripted_alt_m: float = 40.0
    #: ``terrain``: the pattern is flown ``scripted_alt_m`` above the ground under it, planned on the world's
    #: terrain as a prior DEM (a ground station's terrain-frame survey); ``home``: at one altitude above home
    #: (it flies into any hill higher than that, which is a collision).
    scripted_alt_reference: Literal["terrain", "home"] = "terrain"
    #: Hold (stop and stare) distance from the person once confirmed.
    hold_alt_m: float = 25.0
    #: ``operator``: a candidate (``confirm_detections`` at one place) is checked as an operator looking through
    #: the camera would, knowing who is missing: a bystander is turned down and the search goes on. ``none``: the
    #: first candidate ends the search, right or wrong (the scorer says which: ``search.correct``).
    verify: Literal["operator", "none"] = "operator"

    def __post_init__(self) -> None:
        if self.detection_topic is not None or self.camera is not None:
            msg = (
                "search.detection_topic and search.camera have moved: set perception.detector "
                "(ground_truth | degraded_truth | learned | external, with perception.detector_topic) and "
                "perception.camera "
                "(docs/scenarios.md); the detector's output is vision_msgs/Detection2DArray"
            )
            raise ValueError(msg)
        _check_polygon("area_m", self.area_m)
        if self.detection_range_m <= 0 or self.track_spacing_m <= 0 or self.scripted_alt_m <= 0:
            msg = "detection_range_m, track_spacing_m and scripted_alt_m must be > 0"
            raise ValueError(msg)
        if self.confirm_detections < 1 or self.confirm_window_s <= 0:
            msg = "confirm_detections must be >= 1 and confirm_window_s > 0"
            raise ValueError(msg)


class DetectorKind(enum.Enum):
    """Who publishes the boxes under test (``vision_msgs/Detection2DArray``)."""

    #: The simulator's ground truth as a box-only detector (``/detections/<camera>/ground_truth``).
    GROUND_TRUTH = "ground_truth"
    #: A test instrument, not a detector: the ground truth's boxes degraded, seeded (``degraded_detector``).
    DEGRADED_TRUTH = "degraded_truth"
    #: A detector you start yourself, publishing on ``perception.detector_topic``.
    EXTERNAL = "external"
    #: The learned detector (``uav_perception``'s ``detector`` node) running ``perception.model`` (an ONNX file;
    #: "" = the shipped ``uav_detector.onnx``, trained here by ``uav-train-detector``) on the camera's images.
    LEARNED = "learned"


@dataclass(frozen=True)
class GeolocationSpec:
    """How the geolocator places boxes (docs/perception.md)."""

    #: Intersect with the detector camera's depth image first. The bridge then renders that camera fully
    #: (color and depth, ~16 ms a frame instead of the instance ids alone): slower runs.
    use_depth: bool = False
    #: Give it the world's terrain as a prior terrain model (DEM), as a ground station has SRTM tiles.
    terrain_model: bool = True
    #: Give it the map server's elevation layer (``/map_server/layers``).
    elevation_layer: bool = True
    #: Further geolocator settings (``uav_perception.core.detection.geolocation.GeolocationConfig`` keys),
    #: validated by the node.
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class PerceptionSpec:
    """The detector under test, its camera and operating point, and how its boxes are placed."""

    detector: DetectorKind = DetectorKind.GROUND_TRUTH
    #: ``external`` only: the ``vision_msgs/Detection2DArray`` topic of your detector.
    detector_topic: str = ""
    #: The camera the detector looks through; the tracker and the confirmation follow it.
    camera: str = "forward"
    #: Operating point: detections scoring lower are scored (AP, PR curves) but neither tracked nor confirmed.
    score_threshold: float = 0.5
    #: ``degraded_truth`` only: ``uav_perception.core.detection.degrade.DegradeConfig`` keys (seed, miss rates...).
    degraded: dict[str, Any] = field(default_factory=dict)
    #: ``learned`` only: the ONNX model file ("" = the shipped one; a relative path is relative to the scenario
    #: file's folder). ``uav-run`` loads and checks it before anything starts.
    model: str = ""
    geolocation: GeolocationSpec = field(default_factory=GeolocationSpec)

    def __post_init__(self) -> None:
        if not 0.0 <= self.score_threshold <= 1.0:
            msg = f"score_threshold must be within [0, 1], got {self.score_threshold}"
            raise ValueError(msg)
        if self.detector is DetectorKind.EXTERNAL and not self.detector_topic.startswith("/"):
            msg = "detector: external needs detector_topic, the absolute topic your detector publishes on"
            raise ValueError(msg)
        if self.detector is not DetectorKind.EXTERNAL and self.detector_topic:
            msg = f"detector_topic is for detector: external; {self.detector.value} has its own topic"
            raise ValueError(msg)
        if self.model and self.detector is not DetectorKind.LEARNED:
            msg = f"model is for detector: learned, not {self.detector.value}"
            raise ValueError(msg)
        if self.degraded and self.detector is not DetectorKind.DEGRADED_TRUTH:
            msg = "degraded settings are for detector: degraded_truth"
            raise ValueError(msg)
        if not self.camera or not all(c.isalnum() or c == "_" for c in self.camera):
            msg = f"camera must be a camera name, got {self.camera!r}"
            raise ValueError(msg)

    @property
    def boxes_topic(self) -> str:
        """The ``vision_msgs/Detection2DArray`` topic under test."""
        if self.detector is DetectorKind.GROUND_TRUTH:
            return f"/detections/{self.camera}/ground_truth"
        if self.detector is DetectorKind.DEGRADED_TRUTH:
            return "/degraded_detector/detections"
        if self.detector is DetectorKind.LEARNED:
            return "/detector/detections"
        return self.detector_topic

    @property
    def source(self) -> str:
        """The detector's name in the geolocated detections (``uav_msgs/DetectionArray.source``)."""
        if self.detector is DetectorKind.EXTERNAL:
            return "external"
        return f"{self.detector.value}_boxes" if self.detector is DetectorKind.GROUND_TRUTH else self.detector.value


#: The geolocator's output: every detector box, placed in map (uav_msgs/DetectionArray).
GEOLOCATED_TOPIC = "/geolocator/detections"


#: Router endpoints of a run whose radio link a scenario can make lossy (docs/mavlink_router.md).
LINK_ENDPOINTS = ("gcs", "controller", "mavsdk", "odometry", "adhoc")


@dataclass(frozen=True)
class LinkImpairmentSpec:
    """One endpoint's link as a telemetry radio (the router's ``LossPercent``... keys, docs/mavlink_router.md)."""

    #: Frames lost, percent (each direction).
    loss_pct: float = 0.0
    #: Mean length of a loss burst in frames (0 = independent losses; fades need >= 1).
    loss_burst: float = 0.0
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    reorder_pct: float = 0.0
    reorder_delay_ms: float = 50.0
    #: ``both``, ``in`` (frames from the endpoint to the vehicle) or ``out`` (frames to the endpoint).
    direction: Literal["both", "in", "out"] = "both"

    def __post_init__(self) -> None:
        # the router's own check, once (its message names the key; the loader adds the path)
        ImpairmentConfig(
            loss_pct=self.loss_pct,
            loss_burst=self.loss_burst,
            delay_ms=self.delay_ms,
            jitter_ms=self.jitter_ms,
            reorder_pct=self.reorder_pct,
            reorder_delay_ms=self.reorder_delay_ms,
        )


@dataclass(frozen=True)
class LinkSpec:
    """Lossy MAVLink links of the run (through the router): per endpoint, seeded."""

    seed: int = 0
    #: Endpoint name (:data:`LINK_ENDPOINTS`) -> its link (``odometry`` exists only with ``pose_source: autopilot``;
    #: without it that entry changes nothing).
    endpoints: dict[str, LinkImpairmentSpec] = field(default_factory=dict)

    def __post_init__(self) -> None:
        unknown = sorted(set(self.endpoints) - set(LINK_ENDPOINTS))
        if unknown:
            msg = f"endpoints: unknown endpoint(s) {unknown}; the run's router has {', '.join(LINK_ENDPOINTS)}"
            raise ValueError(msg)
        if self.seed < 0:
            msg = f"seed must be >= 0, got {self.seed}"
            raise ValueError(msg)


@dataclass(frozen=True)
class WindSpec:
    """Mean wind and turbulence, flown by the SITL (its ``wind.*`` settings, docs/sitl.md "Wind and turbulence")."""

    #: Mean wind speed at ``reference_height_m``.
    speed_mps: float = 0.0
    #: Where the wind blows *from*, degrees clockwise from north (meteorological).
    from_deg: float = 0.0
    reference_height_m: float = 10.0
    #: Power-law exponent of the speed's growth with height (0 = the same at every height; ~0.14 open country).
    shear_exponent: float = 0.0
    #: Turbulence (Dryden, MIL-F-8785C intensities): none, light, moderate or severe.
    turbulence: Literal["none", "light", "moderate", "severe"] = "none"
    seed: int = 0

    def __post_init__(self) -> None:
        require_in_range("speed_mps", self.speed_mps, 0.0, 40.0)
        require_in_range("from_deg", self.from_deg, 0.0, 360.0)
        require_in_range("reference_height_m", self.reference_height_m, 1.0, 500.0)
        require_in_range("shear_exponent", self.shear_exponent, 0.0, 1.0)


#: MAVLink FAILURE_UNIT names (MAV_CMD_INJECT_FAILURE) a fault may name, and the range's cameras (the sim
#: bridge's faults: uav_scenarios.core.faults.CAMERA).
FAULT_UNITS = (
    "gyro", "accel", "mag", "baro", "gps", "optical_flow", "vio", "distance_sensor", "airspeed",
    "battery", "motor", "servo", "avoidance", "rc_signal", "mavlink_signal", "camera_nadir", "camera_forward",
)  # fmt: skip
#: MAVLink FAILURE_TYPE names.
FAULT_TYPES = ("ok", "off", "stuck", "garbage", "wrong", "slow", "delayed", "intermittent")


@dataclass(frozen=True)
class FaultSpec:
    """A fault injected in flight, as PX4's ``MAV_CMD_INJECT_FAILURE`` does: the mission manager sends the command
    to the autopilot at ``at_s`` (simulated seconds since the mission started) and, with ``duration_s``, a
    ``FAILURE_TYPE_OK`` that long after (``uav_scenarios.core.faults``). A camera unit (``camera_nadir``,
    ``camera_forward``: off, stuck, garbage, intermittent) goes to the sim bridge instead (``~set_camera_fault``)."""

    at_s: float
    unit: str
    #: A :data:`FAULT_TYPES` name (YAML reads a bare ``off`` as false: taken as ``off``).
    type: str | bool
    #: Which instance (motor number, 1-based; 0 = all).
    instance: int = 0
    #: Then back to ``ok`` (null: for the rest of the run).
    duration_s: float | None = None

    def __post_init__(self) -> None:
        require_in_range("at_s", self.at_s, 0.0, 1e6)
        if self.type is False:
            object.__setattr__(self, "type", "off")
        if self.unit not in FAULT_UNITS:
            msg = f"unit: unknown fault unit {self.unit!r}; known: {', '.join(FAULT_UNITS)}"
            raise ValueError(msg)
        if self.type not in FAULT_TYPES:
            msg = f"type: unknown fault type {self.type!r}; known: {', '.join(FAULT_TYPES)}"
            raise ValueError(msg)
        if not 0 <= self.instance <= 255:
            msg = f"instance must be in [0, 255], got {self.instance}"
            raise ValueError(msg)
        if camera_name(self.unit) and self.instance != 0:
            msg = f"instance: {self.unit} is one camera: its instance must be 0, got {self.instance}"
            raise ValueError(msg)
        if self.duration_s is not None:
            require_in_range("duration_s", self.duration_s, 0.0, 1e6)
        why = not_simulated(self.unit, str(self.type))
        if why:
            msg = f"type: {why}"
            raise ValueError(msg)


@dataclass(frozen=True)
class StopCriteria:
    """The run stops at the first criterion met. Times are simulation seconds."""

    time_limit_s: float = 300.0
    mapped_pct: float | None = None
    target_found: bool = False
    #: With ``target_found``: keep holding over the person this long before stopping.
    after_target_found_s: float = 5.0
    #: Stop (and the report flags it) when the battery falls to this remaining %.
    battery_reserve_pct: float | None = 20.0
    on_collision: bool = True
    #: Wall-clock guard so a wedged simulation cannot hang a shell forever.
    wall_timeout_s: float = 3600.0

    def __post_init__(self) -> None:
        if self.time_limit_s <= 0 or self.wall_timeout_s <= 0 or self.after_target_found_s < 0:
            msg = "time_limit_s and wall_timeout_s must be > 0, after_target_found_s >= 0"
            raise ValueError(msg)
        if self.mapped_pct is not None and not 0 < self.mapped_pct <= 100:
            msg = f"mapped_pct must be within (0, 100], got {self.mapped_pct}"
            raise ValueError(msg)
        if self.battery_reserve_pct is not None and not 0 <= self.battery_reserve_pct < 100:
            msg = f"battery_reserve_pct must be within [0, 100), got {self.battery_reserve_pct}"
            raise ValueError(msg)


@dataclass(frozen=True)
class TimeSpec:
    mode: TimeMode = TimeMode.FREE
    #: Free-running speed factor (1 = real time); ignored in lockstep.
    speed_factor: float = 1.0
    #: Lockstep: simulation seconds granted per step (one camera frame period).
    step_s: float = 0.1
    #: Lockstep only: the causal lockstep (docs/lockstep.md): every process on the control path reports when it
    #: is done with a step and every message on a lockstep input is counted, so the same scenario and seed give
    #: bit-identical runs whatever the machine's load, at close to plain lockstep's speed.
    deterministic: bool = False
    #: Deterministic lockstep: a node's lookahead in steps, over its default (docs/lockstep.md): what it
    #: publishes in step k is its consumers' input at step k + L. Keys are node names.
    lookahead_steps: dict[str, int] = field(default_factory=dict)
    #: Deterministic lockstep: wall seconds without progress after which the run is declared deadlocked and stops
    #: (the watchdog never lets a step through).
    watchdog_s: float = 120.0

    def __post_init__(self) -> None:
        if self.speed_factor <= 0 or self.step_s <= 0:
            msg = "speed_factor and step_s must be > 0"
            raise ValueError(msg)
        if self.deterministic and self.mode is not TimeMode.LOCKSTEP:
            msg = "deterministic: true needs mode: lockstep"
            raise ValueError(msg)
        unknown = sorted(set(self.lookahead_steps) - set(LOCKSTEP_PARTICIPANTS))
        if unknown:
            msg = f"lookahead_steps names unknown node(s) {unknown}; participants: {sorted(LOCKSTEP_PARTICIPANTS)}"
            raise ValueError(msg)
        bad = sorted(
            n for n, v in self.lookahead_steps.items() if isinstance(v, bool) or not isinstance(v, int) or v < 1
        )
        if bad:
            msg = f"lookahead_steps of {bad} must be whole numbers of steps >= 1"
            raise ValueError(msg)
        if not self.watchdog_s > 0:
            msg = f"watchdog_s must be > 0, got {self.watchdog_s}"
            raise ValueError(msg)


#: Topic sets for ``rosbag record``. ``report`` is what ``uav-report`` needs (small);
#: ``replay`` adds what re-drives the map server, the evaluators and the scorer without
#: the simulator (tf and the map camera's depth input, see :func:`recorded_topics`: big).
RECORDING_PRESETS: dict[str, tuple[str, ...]] = {
    "report": (
        "/uav/ground_truth/odom",
        "/uav/sim_state",
        "/uav/battery",
        "/uav/controller/state",
        "/autonomy/goal",
        "/autonomy/goal_reason",
        "/autonomy/path",
        "/autonomy/target",
        "/autonomy/weights",
        "/autonomy/target_point",
        "/detections/ground_truth",
        GEOLOCATED_TOPIC,
        "/geolocator/status",
        "/sim/collision",
        "/sim/object_states",
        "/map_server/insert_stats",
        "/scenario/config",
        "/scenario/status",
        "/scenario/metrics",
        "/scenario/tracks",
        "/scenario/faults",
        "/scenario/snapshot/layers",
        "/scenario/snapshot/features",
        "/scenario/snapshot/nadir/color",
        "/scenario/snapshot/nadir/depth",
        "/scenario/snapshot/nadir/instance",
        "/scenario/snapshot/forward/color",
        "/scenario/snapshot/forward/depth",
        "/scenario/snapshot/forward/instance",
        "/scenario/snapshot/gallery",
        "/depth_evaluator/metrics",
        "/depth_estimator/status",
    ),
    "replay": ("/tf", "/tf_static"),
}


@dataclass(frozen=True)
class RecordingSpec:
    enabled: bool = True
    #: ``report`` (small: what the report needs) or ``replay`` (adds tf and point clouds).
    preset: str = "report"
    extra_topics: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.preset not in RECORDING_PRESETS:
            msg = f"preset must be one of {sorted(RECORDING_PRESETS)}, got {self.preset!r}"
            raise ValueError(msg)
        bad = [t for t in self.extra_topics if not t.startswith("/")]
        if bad:
            msg = f"extra_topics must be absolute topic names, got {bad}"
            raise ValueError(msg)


@dataclass(frozen=True)
class ScoringSpec:
    metrics_rate_hz: float = 1.0
    #: Altitude above ground below which time is counted as "too low".
    altitude_floor_m: float = 10.0
    #: Simulation times of the report's map snapshots (the paper's 15, 45, 125, 230 s).
    snapshot_times_s: tuple[float, ...] = (15.0, 45.0, 125.0, 230.0)
    #: Tracker association gate and MOT evaluation gate, metres on the ground.
    track_gate_m: float = 5.0
    #: Simulation seconds between map-accuracy evaluations (export of the map's occupied voxels).
    map_accuracy_period_s: float = 10.0
    #: Snapshot grids (elevation, score) are reduced to at most this many cells per side for the report.
    snapshot_max_cells: int = 800
    #: Altitude bands (m above ground) for the context breakdown; edges, ascending.
    altitude_bands_m: tuple[float, ...] = (0.0, 20.0, 40.0, 60.0, 1000.0)
    range_bands_m: tuple[float, ...] = (0.0, 25.0, 50.0, 75.0, 100.0, 1000.0)
    view_angle_bands_deg: tuple[float, ...] = (0.0, 30.0, 60.0, 90.0)
    clutter_bands: tuple[float, ...] = (0.0, 1.0, 3.0, 1000.0)
    #: Pixel size (square root of the box area) bands: TinyPerson's tiny1-3, small and reasonable.
    pixel_size_bands_px: tuple[float, ...] = (1.0, 8.0, 12.0, 20.0, 32.0, 10000.0)
    #: Visible fraction (occlusion) bands: CityPersons' bare (< 0.2), heavy (0.2-0.65) and reasonable.
    visible_fraction_bands: tuple[float, ...] = (0.0, 0.2, 0.65, 1.0)
    #: Worst false positives and worst misses kept (each) for the report's gallery; 0 = none.
    gallery_size: int = 6

    def __post_init__(self) -> None:
        if self.metrics_rate_hz <= 0 or self.map_accuracy_period_s <= 0 or self.snapshot_max_cells < 16:
            msg = "metrics_rate_hz and map_accuracy_period_s must be > 0, snapshot_max_cells >= 16"
            raise ValueError(msg)
        if not 0 <= self.gallery_size <= 50:
            msg = f"gallery_size must be within [0, 50], got {self.gallery_size}"
            raise ValueError(msg)
        for name in (
            "altitude_bands_m",
            "range_bands_m",
            "view_angle_bands_deg",
            "clutter_bands",
            "pixel_size_bands_px",
            "visible_fraction_bands",
        ):
            edges = getattr(self, name)
            if len(edges) < 2 or any(b <= a for a, b in itertools.pairwise(edges)):
                msg = f"{name} must be at least 2 strictly ascending edges, got {edges}"
                raise ValueError(msg)
        if list(self.snapshot_times_s) != sorted(self.snapshot_times_s):
            msg = f"snapshot_times_s must be ascending, got {self.snapshot_times_s}"
            raise ValueError(msg)


@dataclass(frozen=True)
class Scenario:
    name: str
    mission: MissionKind
    strategy: Strategy = Strategy.AUTONOMOUS
    description: str = ""
    #: The simulated autopilot: ``px4`` or ``ardupilot`` (ArduCopter's modes, parameters and GUIDED takeoff).
    autopilot: AutopilotKind = AutopilotKind.PX4
    world: WorldSpec = field(default_factory=WorldSpec)
    map: MapSpec = field(default_factory=MapSpec)
    depth_source: DepthSource = DepthSource.GROUND_TRUTH
    #: Where the map, features, planner and depth estimator take the pose from.
    pose_source: PoseSource = PoseSource.GROUND_TRUTH
    #: Lossy MAVLink links through the router.
    link: LinkSpec = field(default_factory=LinkSpec)
    #: Mean wind and turbulence (passed to the SITL as its ``wind.*`` settings).
    wind: WindSpec | None = None
    #: Faults injected in flight: the mission manager sends each as MAV_CMD_INJECT_FAILURE at its time.
    faults: tuple[FaultSpec, ...] = ()
    #: Stress presets to lay over this scenario when it is loaded (names of config/stress/*.yaml or paths).
    stress: tuple[str, ...] = ()
    #: The presets already laid over it (written into an effective scenario; not applied again).
    stress_applied: tuple[str, ...] = ()
    autonomy: AutonomySpec = field(default_factory=AutonomySpec)
    search: SearchSpec | None = None
    perception: PerceptionSpec = field(default_factory=PerceptionSpec)
    stop: StopCriteria = field(default_factory=StopCriteria)
    time: TimeSpec = field(default_factory=TimeSpec)
    recording: RecordingSpec = field(default_factory=RecordingSpec)
    scoring: ScoringSpec = field(default_factory=ScoringSpec)
    #: Light, weather and camera effects: ``{preset: NAME, <free values>}`` (``config/environments/NAME.yaml``,
    #: keys in docs/sim_bridge.md); empty = the ``clean`` preset. Validated when the run starts
    #: (``uav_scenarios.shell.environment``).
    environment: dict[str, Any] = field(default_factory=dict)
    #: Who moves and how (over the world's ``people``/``vehicles`` motion keys): counts, speeds, named objects.
    actors: ActorsConfig = field(default_factory=ActorsConfig)
    #: Per-node private parameter overrides, e.g. ``{sim_bridge: {cameras: ...}}``.
    node_params: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: The file this scenario came from (set by :func:`load_scenario`).
    source: Path | None = None

    def __post_init__(self) -> None:
        if not self.name or not all(c.isalnum() or c in "-_" for c in self.name):
            msg = f"name must be a non-empty slug (letters, digits, - and _), got {self.name!r}"
            raise ValueError(msg)
        if self.mission is MissionKind.SEARCH_AND_RESCUE and self.search is None:
            msg = "a search_and_rescue mission needs a 'search' section"
            raise ValueError(msg)
        if self.strategy is not Strategy.AUTONOMOUS and self.search is None:
            msg = f"strategy {self.strategy.value} flies over search.area_m: add a 'search' section"
            raise ValueError(msg)
        if self.stop.target_found and self.mission is not MissionKind.SEARCH_AND_RESCUE:
            msg = "stop.target_found only makes sense for a search_and_rescue mission"
            raise ValueError(msg)
        if self.search is not None and self.search.person.name in self.actors.objects:
            motion = self.actors.objects[self.search.person.name].motion
            if motion not in (None, "none"):
                msg = (
                    f"actors.objects.{self.search.person.name}: the person of interest is put in place and stays "
                    f"there; it cannot have motion {motion}"
                )
                raise ValueError(msg)
        if any(not camera_name(f.unit) for f in self.faults) and self.autopilot is not AutopilotKind.PX4:
            msg = (
                f"faults: failure injection is PX4's (MAV_CMD_INJECT_FAILURE); the {self.autopilot.value} "
                "personality answers it UNSUPPORTED, as ArduCopter does: use autopilot: px4 or remove the faults"
            )
            raise ValueError(msg)

    @property
    def world_config_path(self) -> Path:
        """The world config, resolved against the scenario file's folder."""
        if self.world.config.is_absolute() or self.source is None:
            return self.world.config
        return (self.source.parent / self.world.config).resolve()


def estimate_topic(scenario: Scenario) -> str:
    """The odometry topic the map, features, planner and controller use (its ``pose_source``)."""
    return POSE_TOPICS[scenario.pose_source]


def replay_inputs(scenario: Scenario) -> tuple[str, ...]:
    """What the map server (and, with estimated depth, the depth nodes) need in a replay.

    Ground-truth depth: the map camera's depth and color images and the depth camera's info (the map
    server back-projects them itself). Estimated depth: both images and both camera infos, so the
    estimator and the evaluator run again. Every topic listed has a reader in the replay (rosbag play
    waits for one per played topic).
    """
    cam = f"/cameras/{scenario.map.camera}"
    if scenario.depth_source is DepthSource.GROUND_TRUTH:
        return (f"{cam}/depth/image_raw", f"{cam}/color/image_raw", f"{cam}/depth/camera_info")
    return (f"{cam}/color/image_raw", f"{cam}/color/camera_info", f"{cam}/depth/image_raw", f"{cam}/depth/camera_info")


#: Recorded topics that a replay plays back besides :func:`replay_inputs` and tf (everything the
#: scorer, the tracker and the feature evaluator read that the replay does not regenerate).
REPLAYED_TOPICS = (
    "/uav/ground_truth/odom",
    "/uav/battery",
    "/uav/controller/state",
    "/autonomy/goal_reason",
    "/autonomy/target",
    "/autonomy/weights",
    "/detections/ground_truth",
    GEOLOCATED_TOPIC,
    "/sim/collision",
    "/sim/object_states",
    "/scenario/status",
)


def played_topics(scenario: Scenario) -> tuple[str, ...]:
    """What ``rosbag play`` publishes in a replay (the map server, the evaluators, the tracker and the
    scorer regenerate everything else)."""
    topics = list(REPLAYED_TOPICS) + list(RECORDING_PRESETS["replay"]) + list(replay_inputs(scenario))
    if scenario.pose_source is PoseSource.AUTOPILOT:
        topics += [estimate_topic(scenario), ESTIMATE_STATUS_TOPIC, TARGET_TOPIC]
    return tuple(topics)


def recorded_topics(scenario: Scenario) -> tuple[str, ...]:
    """The topic list for ``rosbag record`` (presets are cumulative: replay includes report)."""
    spec = scenario.recording
    topics = list(RECORDING_PRESETS["report"])
    if scenario.pose_source is PoseSource.AUTOPILOT:
        topics += [estimate_topic(scenario), ESTIMATE_STATUS_TOPIC, TARGET_TOPIC]
    if scenario.perception.boxes_topic not in topics:
        topics.append(scenario.perception.boxes_topic)  # the detector's own output, as it came
    if spec.preset == "replay":
        topics += RECORDING_PRESETS["replay"]
        topics += replay_inputs(scenario)
    topics += [t for t in spec.extra_topics if t not in topics]
    return tuple(topics)


def effective_yaml(scenario: Scenario, note: str = "") -> str:
    """The scenario as a self-contained YAML file (absolute world path, no ``source``), loadable anywhere."""
    import yaml  # noqa: PLC0415

    from uav_common.config import to_mapping  # noqa: PLC0415

    data = to_mapping(scenario)
    data.pop("source", None)
    data["world"]["config"] = str(scenario.world_config_path)
    model = scenario.perception.model
    if model and not Path(model).expanduser().is_absolute() and scenario.source is not None:
        data["perception"]["model"] = str(scenario.source.parent / model)  # a run folder's copy loads anywhere
    data["stress"] = []  # already laid over it (stress_applied says which): never twice
    header = f"# Effective scenario of a run (from {scenario.source}{note}).\n"
    return header + yaml.safe_dump(data, sort_keys=False)


#: Keys a stress preset may not set: it stresses a scenario, it does not make another one.
_NOT_IN_STRESS = ("name", "mission", "strategy", "stress", "stress_applied", "source")


def stress_path(name: str, scenario_file: Path, stress_dir: Path | None) -> Path:
    """Where the stress preset ``name`` is: a path (it has a ``/`` or ends in ``.yaml``) relative to the scenario
    file's folder, else ``<stress_dir>/<name>.yaml`` (default: the ``stress`` folder next to the scenario's
    folder, i.e. ``config/stress`` for ``config/scenarios/*.yaml``)."""
    if "/" in name or name.endswith(".yaml"):
        candidate = Path(name).expanduser()
        return candidate if candidate.is_absolute() else scenario_file.parent / candidate
    folder = stress_dir if stress_dir is not None else scenario_file.resolve().parent.parent / "stress"
    return folder / f"{name}.yaml"


def apply_stress(
    data: dict[str, Any], names: tuple[str, ...], scenario_file: Path, stress_dir: Path | None
) -> dict[str, Any]:
    """``data`` (a scenario mapping) with each preset merged over it in order (see the module docstring).

    Raises:
        ScenarioConfigError: a preset is missing, not a mapping, or sets a key a preset may not set.
    """
    out = dict(data)
    for name in names:
        path = stress_path(name, scenario_file, stress_dir)
        if not path.is_file():
            folder = path.parent
            known = sorted(p.stem for p in folder.glob("*.yaml")) if folder.is_dir() else []
            msg = f"{scenario_file}: stress: no preset {name!r} (looked for {path}); presets there: {known or 'none'}"
            raise ScenarioConfigError(msg)
        with config_errors_as(ScenarioConfigError):
            overlay = load_yaml_mapping(path)
        bad = [k for k in _NOT_IN_STRESS if k in overlay]
        if bad:
            msg = f"{path}: a stress preset may not set {bad} (it overlays a scenario)"
            raise ScenarioConfigError(msg)
        out = deep_merge(out, overlay)
    return out


def load_scenario(
    path: Path,
    *,
    overrides: dict[str, Any] | None = None,
    stress: tuple[str, ...] = (),
    stress_dir: Path | None = None,
) -> Scenario:
    """Parse and validate a scenario file, with its stress presets (and ``stress``) laid over it.

    Args:
        path: the YAML file.
        overrides: top-level field replacements applied after parsing
            (e.g. ``{"stop": StopCriteria(time_limit_s=30)}`` from a command line).
        stress: more stress presets, after the file's own (e.g. ``uav-run --stress``).
        stress_dir: where preset names are looked up (default: see :func:`stress_path`).

    Raises:
        ScenarioConfigError: the file or a preset is missing, not YAML, has an unknown key, a wrong type
            or an inconsistent setting; the message names the file and the key.
    """
    with config_errors_as(ScenarioConfigError):
        data = load_yaml_mapping(path)
        names = tuple(_as_names(data.get("stress", ()), path)) + tuple(stress)
        source = str(path)
        if names:
            data = apply_stress(data, names, path, stress_dir)
            data["stress"] = []
            data["stress_applied"] = [*_as_names(data.get("stress_applied", ()), path), *names]
            source = f"{path} with stress {', '.join(names)}"
        scenario = from_mapping(Scenario, data, source=source)
    if scenario.source is not None:
        msg = f"{path}: 'source' is set by the loader, remove it from the file"
        raise ScenarioConfigError(msg)
    scenario = replace(scenario, source=path.resolve())
    if not scenario.world_config_path.is_file():
        msg = (
            f"{path}: world.config {scenario.world.config} does not exist (looked for {scenario.world_config_path}; "
            "relative paths are relative to the scenario file)"
        )
        raise ScenarioConfigError(msg)
    if overrides:
        try:
            scenario = replace(scenario, **overrides)
        except (TypeError, ValueError) as err:
            msg = f"{path}: invalid override {sorted(overrides)}: {err}"
            raise ScenarioConfigError(msg) from err
    return scenario


def _as_names(value: Any, path: Path) -> list[str]:
    """``stress:`` as a list of names (a single name is accepted too)."""
    if isinstance(value, str):
        return [value]
    if isinstance(value, list | tuple) and all(isinstance(v, str) for v in value):
        return list(value)
    msg = f"{path}: stress: expected a preset name or a list of them, got {value!r}"
    raise ScenarioConfigError(msg)
