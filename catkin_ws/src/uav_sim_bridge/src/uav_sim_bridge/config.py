"""Configuration of the bridge node: ``config/sim_bridge.yaml`` (+ ROS parameter overrides).

Loaded once at start-up into :class:`SimBridgeConfig` through
:func:`uav_common.config.from_mapping` (strict: unknown keys are errors).  The node
deep-merges the ``~overrides`` parameter and a few convenience parameters (``~world``,
``~sim_host``...) over the file first (:func:`uav_common.config.deep_merge`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uav_common.config import ConfigError, deep_merge, from_mapping, load_yaml_mapping, to_mapping
from uav_common.paths import config_dir, config_file
from uav_common.robot import RobotDescription, load_robot_description
from uav_sim_bridge.core.camera import CameraConfig, MountConfig
from uav_sim_bridge.core.camera_faults import CameraFaultsConfig
from uav_sim_bridge.core.collision import CollisionConfig
from uav_sim_bridge.core.detections import DetectionConfig
from uav_sim_bridge.core.environment import EnvironmentConfig, merge_environment
from uav_sim_bridge.core.motion import ActorsConfig
from uav_sim_bridge.core.render_settings import RenderSettings
from uav_sim_bridge.core.schedule import LockstepConfig
from uav_sim_bridge.core.sensor_noise import NoiseConfig
from uav_sim_bridge.errors import SimBridgeConfigError

__all__ = [
    "GroundTruthDetectionsConfig",
    "HomeConfig",
    "PublishConfig",
    "SimBridgeConfig",
    "SimLinkConfig",
    "bridge_config",
    "default_cameras",
    "environment_preset_path",
    "environment_presets",
    "load_environment_preset",
    "mounted_cameras",
    "resolve_environment",
    "resolve_world_path",
    "shipped_bridge_config",
]


def default_cameras() -> dict[str, CameraConfig]:
    """The architecture's default cameras: a nadir mapping camera at 5 Hz and a forward camera at 10 Hz
    (config/sim_bridge.yaml says why). Their mounts come from the robot description (config/robot.yaml:
    nadir straight down, forward 25 degrees down); the node fills them in."""
    return {
        "nadir": CameraConfig(hfov_deg=90.0, rate_hz=5.0, mount=MountConfig((0.0, 0.0, -0.08), (0.0, 90.0, 0.0))),
        "forward": CameraConfig(hfov_deg=90.0, rate_hz=10.0, mount=MountConfig((0.12, 0.0, -0.04), (0.0, 25.0, 0.0))),
    }


@dataclass(frozen=True)
class SimLinkConfig:
    """UDP simulation link to the SITL (docs/architecture.md)."""

    host: str = "127.0.0.1"
    port: int = 4560
    local_port: int = 0
    system_id: int = 1
    component_id: int = 200
    heartbeat_period_s: float = 1.0
    terrain_report_rate_hz: float = 10.0
    stale_warning_s: float = 5.0

    def __post_init__(self) -> None:
        if not (0 < self.port < 65536 and 0 <= self.local_port < 65536):
            msg = "port must be in 1..65535 and local_port in 0..65535"
            raise ValueError(msg)
        if self.heartbeat_period_s <= 0 or self.terrain_report_rate_hz < 10.0:
            msg = "heartbeat_period_s must be > 0 and terrain_report_rate_hz >= 10 (contract)"
            raise ValueError(msg)


@dataclass(frozen=True)
class HomeConfig:
    """Geodetic home (the ``map`` origin). Leave ``home`` null to derive it from the sim link."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float


@dataclass(frozen=True)
class PublishConfig:
    """What the node publishes besides the always-on pose, clock and state topics."""

    only_when_subscribed: bool = True
    class_image: bool = True
    points: bool = True
    points_stride: int = 1
    world_mesh_marker: bool = True
    #: Camera topics: messages each subscriber connection may fall behind before its oldest is dropped.
    #: rospy writes every connection from its own thread; a recorder whose writer thread waits for the GIL
    #: while a frame renders needs room for a few frames, or the bag silently lacks some.
    queue_size: int = 10
    #: ``/sim/object_states`` (moving and moved people and vehicles) per simulated second.
    object_states_rate_hz: float = 5.0

    def __post_init__(self) -> None:
        if self.points_stride < 1:
            msg = "points_stride must be >= 1"
            raise ValueError(msg)
        if self.queue_size < 1:
            msg = "queue_size must be >= 1"
            raise ValueError(msg)
        if not self.object_states_rate_hz > 0:
            msg = "object_states_rate_hz must be > 0"
            raise ValueError(msg)


@dataclass(frozen=True)
class GroundTruthDetectionsConfig(DetectionConfig):
    """``detections``: registration rules plus the cameras that produce detections."""

    cameras: tuple[str, ...] = ("forward", "nadir")
    #: The truth for scoring (uav_msgs/DetectionArray: instance ids, true centres, ranges, visible fractions).
    topic: str = "/detections/ground_truth"
    #: The same boxes as a box-only detector (vision_msgs/Detection2DArray), one topic per camera.
    boxes_topic: str = "/detections/{camera}/ground_truth"
    #: The class map for the boxes' class ids (null: config/detection_classes.yaml).
    class_map: Path | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if "{camera}" not in self.boxes_topic:
            msg = f"boxes_topic must contain {{camera}} (one topic per camera), got {self.boxes_topic!r}"
            raise ValueError(msg)


@dataclass(frozen=True)
class SimBridgeConfig:
    """The whole node configuration (see docs/sim_bridge.md for every key)."""

    world: str = "default"
    worlds_dir: Path | None = None
    world_cache_dir: Path | None = None
    object_poses: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    cameras: dict[str, CameraConfig] = field(default_factory=default_cameras)
    sim_link: SimLinkConfig = field(default_factory=SimLinkConfig)
    lockstep: LockstepConfig = field(default_factory=LockstepConfig)
    render: RenderSettings = field(default_factory=RenderSettings)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    detections: GroundTruthDetectionsConfig = field(default_factory=GroundTruthDetectionsConfig)
    collision: CollisionConfig = field(default_factory=CollisionConfig)
    publish: PublishConfig = field(default_factory=PublishConfig)
    #: Light, weather, camera effects and depth noise (a preset plus free values: :func:`resolve_environment`).
    environment: EnvironmentConfig = field(default_factory=EnvironmentConfig)
    #: Who moves and how, over the world's own ``people``/``vehicles`` motion keys.
    actors: ActorsConfig = field(default_factory=ActorsConfig)
    #: Faults injected in flight into the cameras (``~set_camera_fault``): their seed, the intermittent drop rate.
    camera_faults: CameraFaultsConfig = field(default_factory=CameraFaultsConfig)
    home: HomeConfig | None = None
    map_frame: str = "map"
    base_frame: str = "base_link"

    def __post_init__(self) -> None:
        for name in self.cameras:
            if not name.isidentifier():
                msg = f"camera name {name!r} must be a plain identifier (it becomes frame camera_{name})"
                raise ValueError(msg)
        unknown = [c for c in self.detections.cameras if c not in self.cameras]
        if unknown:
            msg = f"detections.cameras names unknown camera(s) {unknown}; cameras: {sorted(self.cameras)}"
            raise ValueError(msg)
        unknown = sorted(set(self.environment.cameras) - set(self.cameras) - {"default"})
        if unknown:
            msg = (
                f"environment.cameras names unknown camera(s) {unknown}; cameras: {sorted(self.cameras)} "
                "(or default, for all of them)"
            )
            raise ValueError(msg)

    def world_yaml(self) -> Path:
        return resolve_world_path(self.world, self.worlds_dir)

    def cache_dir(self) -> Path:
        return self.world_cache_dir or Path("~/.cache/uav_test_range/worlds").expanduser()


def resolve_world_path(world: str, worlds_dir: Path | None = None) -> Path:
    """A world name (``default`` -> ``config/worlds/default.yaml``) or a path to a YAML file.

    A relative path that does not exist from the working directory (ROS nodes run in
    ``~/.ros``) is looked up in the project's configuration folder (``config/worlds/x.yaml``
    and ``worlds/x.yaml`` both name ``<config>/worlds/x.yaml``), found by
    :func:`uav_common.paths.config_dir` in a checkout and in an install space alike.

    Raises:
        ConfigError: a world name with no worlds folder given and no configuration folder found.
    """
    if world.endswith((".yaml", ".yml")) or "/" in world:
        path = Path(world).expanduser()
        if path.is_absolute() or path.exists():
            return path
        base = config_dir()
        inside = Path(*path.parts[1:]) if path.parts[:1] == ("config",) else path
        return base / inside if (base / inside).exists() else path
    return (worlds_dir or config_dir() / "worlds") / f"{world}.yaml"


def environment_presets(presets_dir: Path | None = None) -> list[str]:
    """The names of the environment presets (``config/environments/*.yaml``)."""
    folder = presets_dir or config_dir() / "environments"
    return sorted(p.stem for p in folder.glob("*.yaml"))


def environment_preset_path(name: str, presets_dir: Path | None = None) -> Path:
    """A preset name (``haze`` -> ``config/environments/haze.yaml``) or a path to a YAML file."""
    if name.endswith((".yaml", ".yml")) or "/" in name:
        return Path(name).expanduser()
    return (presets_dir or config_dir() / "environments") / f"{name}.yaml"


def load_environment_preset(name: str, presets_dir: Path | None = None) -> dict[str, Any]:
    """The mapping of an environment preset.

    Raises:
        ConfigError: no such preset (the message lists the known ones) or an unreadable file.
    """
    path = environment_preset_path(name, presets_dir)
    if not path.is_file():
        folder = presets_dir or config_dir() / "environments"
        known = ", ".join(environment_presets(folder)) or "none"
        msg = f"unknown environment preset {name!r}: {path} does not exist (presets: {known})"
        raise ConfigError(msg)
    data = load_yaml_mapping(path)
    if "preset" in data:
        msg = f"{path}: a preset cannot name another preset ('preset' key)"
        raise ConfigError(msg)
    return data


def resolve_environment(raw: Mapping[str, Any] | str | None, presets_dir: Path | None = None) -> dict[str, Any]:
    """An ``environment:`` mapping (or its YAML text) with its preset loaded and its free values merged over it
    (still a mapping: :func:`uav_common.config.from_mapping` validates it as :class:`EnvironmentConfig`).

    Raises:
        ConfigError: unknown preset, or ``environment`` is not a mapping.
    """
    if raw is None:
        raw = {}
    if isinstance(raw, str):  # YAML text: what a ROS parameter carries when the mapping has nulls
        import yaml  # noqa: PLC0415

        try:
            raw = yaml.safe_load(raw) or {}
        except yaml.YAMLError as err:
            msg = f"environment: not valid YAML: {err}"
            raise ConfigError(msg) from err
    if not isinstance(raw, Mapping):
        msg = f"environment must be a mapping (preset: NAME plus keys), got {raw!r}"
        raise ConfigError(msg)
    return merge_environment(raw, lambda name: load_environment_preset(name, presets_dir))


def mounted_cameras(cameras: Any, robot: RobotDescription, *, source: str) -> dict[str, Any]:
    """The bridge's cameras (intrinsics from its config; the defaults if it names none) with each mount taken
    from the robot description, the one file that says where sensors sit on the airframe.

    Raises:
        SimBridgeConfigError: a camera of the bridge's config sets ``mount`` (it belongs in the robot
            description), or the robot description has no such camera.
    """
    if cameras is None:
        cameras = {
            name: {k: v for k, v in to_mapping(cam).items() if k != "mount"} for name, cam in default_cameras().items()
        }
    if not isinstance(cameras, dict):
        return cameras  # from_mapping reports the wrong type with the key
    out: dict[str, Any] = {}
    for name, cam in cameras.items():
        if isinstance(cam, dict) and "mount" in cam:
            msg = (
                f"{source}: cameras.{name}.mount: camera extrinsics live in the robot description "
                f"(config/robot.yaml, cameras.{name}), the file a real airframe edits; remove mount here"
            )
            raise SimBridgeConfigError(msg)
        try:
            mount = robot.mount(str(name))
        except KeyError as err:
            msg = f"{source}: camera {name!r} has no mount: {err.args[0]} (add it to config/robot.yaml)"
            raise SimBridgeConfigError(msg) from err
        out[name] = {**(cam or {}), "mount": {"xyz_m": list(mount.xyz_m), "rpy_deg": list(mount.rpy_deg)}}
    return out


def bridge_config(data: dict[str, Any], robot: RobotDescription, *, source: str) -> SimBridgeConfig:
    """The bridge's configuration from its merged settings (``config/sim_bridge.yaml`` with any overrides) and the
    robot description that places its cameras: what the node runs with, and what anything re-creating a run's
    cameras (the data engine) must use. The ``environment`` preset is resolved here too (:func:`resolve_environment`).

    Raises:
        SimBridgeConfigError: a camera sets ``mount`` or has none in the robot description.
        ConfigError: an unknown key or a wrong value (named with ``source``), an unknown environment preset.
    """
    merged = dict(data)
    merged["cameras"] = mounted_cameras(merged.get("cameras"), robot, source=source)
    merged["environment"] = resolve_environment(merged.get("environment"))  # its preset loaded, free values over it
    return from_mapping(SimBridgeConfig, merged, source=source)


def shipped_bridge_config(overrides: Mapping[str, Any], *, source: str) -> SimBridgeConfig:
    """:func:`bridge_config` of ``config/sim_bridge.yaml`` with ``overrides`` merged over it (a scenario's
    ``node_params.sim_bridge``) and the cameras placed by ``config/robot.yaml``: the bridge a run starts.

    Raises:
        SimBridgeConfigError, ConfigError: as :func:`bridge_config`; a missing or broken file, named.
    """
    data = deep_merge(load_yaml_mapping(config_file("sim_bridge.yaml")), dict(overrides))
    return bridge_config(data, load_robot_description(config_file("robot.yaml")), source=source)
