"""Scenario -> each process's settings: the one place this mapping lives.

Launch files load the result with ``<param name="/NODE/overrides" type="yaml"
command="$(find uav_scenarios)/nodes/scenario_params SCENARIO NODE ..."/>``;
``uav-run`` calls the same functions. Keys are those of each component's own config
(``config/autonomy.yaml`` sections, ``config/sim_bridge.yaml``, the map server's
parameters), which validate them again strictly. Settings that depend on the
world (the person's placement, its instance id) come in a :class:`RunContext`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import yaml

from uav_autonomy.core.patterns import expanding_square, follow_terrain, lawnmower
from uav_autonomy.errors import InvalidInputError
from uav_common.config import deep_merge, to_mapping
from uav_common.robot import RobotDescription
from uav_scenarios.core.config import (
    FEATURE_NAMES,
    GEOLOCATED_TOPIC,
    LOCKSTEP_WALL_FLOOR_S,
    DepthSource,
    DetectorKind,
    MissionKind,
    PoseSource,
    Scenario,
    Strategy,
    TimeMode,
)
from uav_scenarios.errors import ScenarioError
from uav_sim_bridge.core.motion import ActorsConfig

#: Terrain height above home at (x, y), vectorised (e.g. the world's ``height_at``).
GroundModel = Callable[[npt.NDArray[np.float64], npt.NDArray[np.float64]], npt.ArrayLike]

__all__ = ["NODE_PARAMS", "RunContext", "node_params", "scripted_request"]


@dataclass(frozen=True)
class RunContext:
    """What a run knows beyond the scenario file (filled in by the launchers).

    Attributes:
        run_dir: the run folder ("" = none).
        world_yaml: the world file the bridge loads (the scenario's, or one derived with its seed).
        person: the person of interest: ``{name, instance_id, x_m, y_m}``; empty if none.
        battery_capacity_mah: the SITL pack's capacity (for BatteryState charge).
        lockstep_role: the bridge's role in lockstep runs (``master`` or ``participant``).
        map_server_base: the map server's configuration file contents (``config/map_server.yaml``).
        cameras: the bridge's cameras for this run: name -> ``{pitch_deg, hfov_deg}``.
        scripted: a scripted baseline's controller request planned over the world's terrain
            (:func:`scripted_request`); None when not needed.
        terrain_dem: the world's terrain model file for the geolocator ("" = none).
    """

    run_dir: str = ""
    world_yaml: str = ""
    person: Mapping[str, Any] | None = None
    battery_capacity_mah: float | None = None
    lockstep_role: str = "master"
    map_server_base: Mapping[str, Any] = field(default_factory=dict)
    cameras: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    scripted: Mapping[str, Any] | None = None
    terrain_dem: str = ""


def _target_xy(scenario: Scenario) -> list[list[float]]:
    target = scenario.autonomy.target
    if target.polygon_m:
        return [[x, y] for x, y in target.polygon_m]
    assert target.point_m is not None  # guaranteed by TargetSpec
    return [[target.point_m[0], target.point_m[1]]]


def goal_selector(scenario: Scenario, _ctx: RunContext) -> dict[str, Any]:
    weights = {name: float(scenario.autonomy.weights.get(name, 0.0)) for name in FEATURE_NAMES}
    return {"weights": weights, "target_xy_m": _target_xy(scenario)}


def features(scenario: Scenario, _ctx: RunContext) -> dict[str, Any]:
    return {"age_half_life_s": scenario.autonomy.age_half_life_s}


def planner(scenario: Scenario, _ctx: RunContext) -> dict[str, Any]:
    return {"algorithm": scenario.autonomy.planner, "cruise_buffer_m": scenario.autonomy.cruise_buffer_m}


def wall_floor_s(scenario: Scenario) -> float | None:
    """The wall-clock floor under the MAVLink nodes' timeouts: none in free time (the default applies), 0 in
    deterministic lockstep (simulated time only: every process keeps step, so silence is never starvation),
    :data:`LOCKSTEP_WALL_FLOOR_S` in plain lockstep."""
    if scenario.time.mode is not TimeMode.LOCKSTEP:
        return None
    return 0.0 if scenario.time.deterministic else LOCKSTEP_WALL_FLOOR_S


def lockstep(scenario: Scenario, _ctx: RunContext) -> dict[str, Any]:
    """The ``/lockstep`` parameters (docs/lockstep.md); the launch file adds the participants it starts."""
    return {
        "causal": bool(scenario.time.deterministic),
        "lookahead_steps": dict(scenario.time.lookahead_steps),
        "watchdog_s": float(scenario.time.watchdog_s),
    }


def controller(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    out: dict[str, Any] = {"takeoff_height_m": scenario.autonomy.takeoff_alt_m}
    floor = wall_floor_s(scenario)
    if floor is not None:
        out["wall_floor_s"] = floor
    if scenario.search is not None:
        out["scripted_altitude_m"] = scenario.search.scripted_alt_m
    if ctx.battery_capacity_mah is not None:
        out["battery_capacity_mah"] = ctx.battery_capacity_mah
    return out


def map_server(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """The scenario's map server settings, merged over ``ctx.map_server_base`` (its config file).

    The launch files set the result as the node's whole private namespace, so it must be
    complete: the base is ``config/map_server.yaml``.
    """
    out: dict[str, Any] = {"backend": scenario.map.backend.value, "resolution": scenario.map.resolution_m}
    # perception.launch wires the inputs: ground truth -> the map camera's depth and color images (the node
    # back-projects them), estimated depth -> the depth estimator's cloud.
    out["input"] = "rgbd" if scenario.depth_source is DepthSource.GROUND_TRUTH else "cloud"
    if scenario.pose_source is PoseSource.AUTOPILOT:
        # The autopilot's estimate (and so the image's transform) reaches the map server after the image: a
        # median 0.1 simulated s, up to 2 s, in lockstep at ~8x on 2 loaded cores. Room for 2 s of nadir frames
        # at 5 Hz while they wait (each waits at most tf_wait_s), so they are not dropped as queue_full.
        out["queue_size"] = 10
    if ctx.run_dir:
        # Each run autosaves into its own folder (parallel runs never share a map file).
        suffix = "ot" if scenario.map.backend.value == "octomap" else "vdb"
        out["autosave"] = {"path": f"{ctx.run_dir}/map_autosave.{suffix}", "resume": False}
    return deep_merge(deep_merge(dict(ctx.map_server_base), out), scenario.map.params)


def sim_bridge(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if ctx.world_yaml:
        out["world"] = ctx.world_yaml
    if scenario.time.mode is TimeMode.LOCKSTEP:
        out["lockstep"] = {"role": ctx.lockstep_role, "steps_per_grant": lockstep_steps(scenario)}
    else:
        out["lockstep"] = {"role": "off"}
    if scenario.search is not None:
        out["detections"] = {"max_range_m": scenario.search.detection_range_m}
    if ctx.person:
        p = ctx.person
        out["object_poses"] = {str(p["name"]): [float(p["x_m"]), float(p["y_m"]), 0.0]}
    if scenario.environment:
        # as YAML text: ROS parameters (XML-RPC) cannot hold the nulls an environment may have
        out["environment"] = yaml.safe_dump(dict(scenario.environment), sort_keys=True)
    # None in actors means "the world's": left out (ROS parameters cannot hold it)
    actors = _without_none(to_mapping(scenario.actors)) if scenario.actors != ActorsConfig() else {}
    if scenario.search is not None and scenario.search.person.pose is not None:
        name = scenario.search.person.name
        objects = actors.setdefault("objects", {})
        objects[name] = {**objects.get(name, {}), "pose": scenario.search.person.pose}
    if actors:
        out["actors"] = actors
    return out


def _without_none(data: Any) -> Any:
    """A mapping without its ``None`` values, at every depth (empty sections are kept)."""
    if isinstance(data, Mapping):
        return {k: _without_none(v) for k, v in data.items() if v is not None}
    if isinstance(data, list):
        return [_without_none(v) for v in data]
    return data


def lockstep_steps(scenario: Scenario) -> int:
    """Physics steps per lockstep grant: ``time.step_s`` at the SITL's physics rate.

    Raises:
        ScenarioError: ``step_s`` is not a whole number of physics steps.
    """
    physics = scenario.node_params.get("sitl", {}).get("physics", {})
    rate = float(physics.get("rate_hz", 250.0)) if isinstance(physics, Mapping) else 250.0
    steps = scenario.time.step_s * rate
    if abs(steps - round(steps)) > 1e-6 or round(steps) < 1:
        msg = f"time.step_s {scenario.time.step_s} s is not a whole number of {rate:g} Hz physics steps"
        raise ScenarioError(msg)
    return round(steps)


def mission_manager(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    out: dict[str, Any] = {"person": dict(ctx.person or {})}
    if ctx.scripted is not None:
        req = dict(ctx.scripted)
        req["points"] = [[float(v) for v in p] for p in req["points"]]
        out["scripted"] = req
    return out


def scorer(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    cams = ctx.cameras
    return {
        "person": dict(ctx.person or {}),
        "map_camera": scenario.map.camera,
        "camera_pitch_deg": {name: float(c["pitch_deg"]) for name, c in cams.items()},
        "map_camera_hfov_deg": float(cams[scenario.map.camera]["hfov_deg"]) if scenario.map.camera in cams else 90.0,
        "map_camera_aspect": float(cams[scenario.map.camera]["aspect"]) if scenario.map.camera in cams else 0.75,
    }


def autopilot_odometry(scenario: Scenario, _ctx: RunContext) -> dict[str, Any]:
    """The autopilot odometry node: config/autonomy.yaml's settings, with the SITL's clock shared.

    The SITL's time since boot (ODOMETRY's ``time_usec``) *is* the simulation time ``/clock`` carries, so the
    stamps need no mapping (``time_sync: shared``). TIMESYNC still runs and its offset is reported: in lockstep
    ROS time moves in ``time.step_s`` jumps, so TIMESYNC there is only as good as half a step (the rostest of the
    node checks TIMESYNC against an autopilot whose clock is 1000 s off). ``node_params.autopilot_odometry``
    overrides this.
    """
    out: dict[str, Any] = {"time_sync": "shared"}
    floor = wall_floor_s(scenario)
    if floor is not None:
        out["wall_floor_s"] = floor
    return out


def tracker(scenario: Scenario, _ctx: RunContext) -> dict[str, Any]:
    perception = scenario.perception
    return {
        "camera": perception.camera,
        "detections": GEOLOCATED_TOPIC,
        "gate_m": scenario.scoring.track_gate_m,
        "min_score": perception.score_threshold,
    }


def geolocator(scenario: Scenario, ctx: RunContext) -> dict[str, Any]:
    """The geolocator places the detector's boxes: its camera, input, depth, elevation layer and terrain model."""
    perception = scenario.perception
    geo = perception.geolocation
    return {
        "camera": perception.camera,
        "detections": perception.boxes_topic,
        "detector": perception.source,
        "depth": f"/cameras/{perception.camera}/depth/image_raw" if geo.use_depth else "",
        "elevation": "/map_server/layers" if geo.elevation_layer else "",
        "terrain_dem": ctx.terrain_dem if geo.terrain_model else "",
        "geolocation": dict(geo.params),
    }


def degraded_detector(scenario: Scenario, _ctx: RunContext) -> dict[str, Any]:
    """The stand-in (a test instrument): the ground truth's boxes of the detector camera, degraded."""
    perception = scenario.perception
    return {
        "camera": perception.camera,
        "input": f"/detections/{perception.camera}/ground_truth",
        "degrade": dict(perception.degraded),
    }


def detector(scenario: Scenario, _ctx: RunContext) -> dict[str, Any]:
    """The learned detector on the detector camera's colour images: the scenario's model ("" = the shipped one;
    relative to the scenario file's folder). It passes on boxes scoring at least 0.2, at most 30 a frame (the
    node's defaults, 0.05 and 100, sent ~90 boxes a frame of the shipped model to the geolocator, which placed
    each one and fell behind: a run scores AP over what is passed on, so the PR curve ends at 0.2)."""
    perception = scenario.perception
    model = perception.model
    if model and not model.startswith(("/", "~")) and scenario.source is not None:
        model = str(scenario.source.parent / model)
    return {
        "camera": perception.camera,
        "image": f"/cameras/{perception.camera}/color/image_raw",
        "model": model,
        "decode": {"score_threshold": min(0.2, perception.score_threshold), "max_detections": 30},
    }


#: Node name -> settings function. ``node_params`` merges ``scenario.node_params[name]`` over it.
NODE_PARAMS: dict[str, Callable[[Scenario, RunContext], dict[str, Any]]] = {
    "goal_selector": goal_selector,
    "feature_evaluator": features,
    "path_planner": planner,
    "waypoint_controller": controller,
    "autopilot_odometry": autopilot_odometry,
    "map_server": map_server,
    "sim_bridge": sim_bridge,
    "mission_manager": mission_manager,
    "scorer": scorer,
    "tracker": tracker,
    "geolocator": geolocator,
    "degraded_detector": degraded_detector,
    "detector": detector,
    "lockstep": lockstep,
}


def node_params(scenario: Scenario, node: str, ctx: RunContext | None = None) -> dict[str, Any]:
    """The settings of ``node`` for this scenario (``node_params.<node>`` merged last, key by key).

    Raises:
        ScenarioError: a node this module does not know and the scenario does not mention.
    """
    base = NODE_PARAMS[node](scenario, ctx or RunContext()) if node in NODE_PARAMS else None
    extra = scenario.node_params.get(node)
    if base is None and extra is None:
        known = ", ".join(sorted(set(NODE_PARAMS) | set(scenario.node_params)))
        msg = f"no settings for node {node!r}; known: {known}"
        raise ScenarioError(msg)
    return deep_merge(base or {}, extra or {})


def needs_terrain_model(scenario: Scenario) -> bool:
    """The geolocator gets the world's terrain as its prior terrain model."""
    return scenario.perception.geolocation.terrain_model


def uses_stand_in(scenario: Scenario) -> bool:
    """The run starts the stand-in detector (``degraded_detector``)."""
    return scenario.perception.detector is DetectorKind.DEGRADED_TRUTH


def needs_person(scenario: Scenario) -> bool:
    return scenario.mission is MissionKind.SEARCH_AND_RESCUE and scenario.search is not None


def needs_terrain(scenario: Scenario) -> bool:
    """A scripted baseline flown above the terrain: its pattern is planned over the world's terrain."""
    search = scenario.search
    scripted = scenario.strategy is not Strategy.AUTONOMOUS
    return scripted and search is not None and search.scripted_alt_reference == "terrain"


def scripted_request(scenario: Scenario, ground_m: GroundModel | None = None) -> dict[str, Any]:
    """The controller's SCRIPTED request (``uav_msgs/SetControllerState`` fields) for a baseline.

    Lawnmower: the search area polygon at ``track_spacing_m``. Expanding square: from the
    search target (the prior datum) out to the farthest corner of the search area. With
    ``scripted_alt_reference: terrain`` the pattern is expanded here into explicit waypoints
    ``scripted_alt_m`` above ``ground_m`` (the world's terrain as a prior DEM; pattern
    ``waypoints``); with ``home`` the controller builds it at ``scripted_alt_m`` above home.

    Args:
        scenario: a scripted baseline.
        ground_m: terrain height above home at ``(x, y)`` (vectorised); needed for ``terrain``.

    Raises:
        ScenarioError: the scenario is autonomous or has no search section, the terrain model is
            missing, or the pattern cannot be built over it.
    """
    search = scenario.search
    if scenario.strategy is Strategy.AUTONOMOUS or search is None:
        msg = f"scenario {scenario.name} is not a scripted baseline"
        raise ScenarioError(msg)
    if scenario.strategy is Strategy.LAWNMOWER:
        points = [(x, y, 0.0) for x, y in search.area_m]
        radius = 0.0
    else:
        datum = _target_xy(scenario)[0]
        points = [(datum[0], datum[1], 0.0)]
        radius = max(((x - datum[0]) ** 2 + (y - datum[1]) ** 2) ** 0.5 for x, y in search.area_m)
    request = {
        "state": "SCRIPTED",
        "pattern": scenario.strategy.value,
        "points": points,
        "spacing_m": search.track_spacing_m,
        "altitude_m": search.scripted_alt_m,
        "max_radius_m": radius,
    }
    if search.scripted_alt_reference == "home":
        return request
    if ground_m is None:
        msg = (
            f"scenario {scenario.name}: search.scripted_alt_reference is terrain, which needs the world's terrain "
            "to plan the pattern over (or set it to home)"
        )
        raise ScenarioError(msg)
    try:
        if scenario.strategy is Strategy.LAWNMOWER:
            track = lawnmower([(x, y) for x, y, _ in points], search.track_spacing_m, 1.0)
        else:
            track = expanding_square(points[0][:2], search.track_spacing_m, 1.0, max_radius_m=radius)
        flown = follow_terrain(track, ground_m, search.scripted_alt_m)
    except InvalidInputError as err:
        msg = f"scenario {scenario.name}: cannot plan the {scenario.strategy.value} over the terrain: {err}"
        raise ScenarioError(msg) from err
    request["pattern"] = "waypoints"
    request["points"] = [(float(x), float(y), float(z)) for x, y, z in flown]
    return request


def sitl_capacity_mah(scenario: Scenario, sitl_config: Path) -> float:
    """The SITL pack's capacity for this run: ``node_params.sitl`` > ``config/sitl.yaml`` > 4000 mAh."""
    import yaml  # noqa: PLC0415

    over = scenario.node_params.get("sitl", {}).get("battery", {})
    if isinstance(over, Mapping) and isinstance(over.get("capacity_mah"), int | float):
        return float(over["capacity_mah"])
    try:
        data = yaml.safe_load(sitl_config.read_text())
    except (OSError, yaml.YAMLError):
        data = None
    battery = data.get("battery") if isinstance(data, dict) else None
    value = battery.get("capacity_mah") if isinstance(battery, dict) else None
    return float(value) if isinstance(value, int | float) else 4000.0


def bridge_cameras(
    bridge_config: Mapping[str, Any], scenario: Scenario, robot: RobotDescription | None = None
) -> dict[str, dict[str, float]]:
    """The bridge's cameras for this scenario (its config file with ``node_params.sim_bridge`` merged), placed by
    the robot description (``config/robot.yaml``).

    Returns name -> ``{pitch_deg, hfov_deg}`` (mount pitch: 90 = nadir; hfov from ``hfov_deg``, or from
    ``fx`` and ``width`` when the intrinsics are given instead).
    """
    import math  # noqa: PLC0415

    merged = deep_merge(bridge_config, scenario.node_params.get("sim_bridge", {}))
    cams = merged.get("cameras") or {"nadir": {}, "forward": {}}
    out: dict[str, dict[str, float]] = {}
    for name, raw in cams.items():
        cam = raw or {}
        mount = robot.cameras.get(str(name)) if robot is not None else None
        rpy = list(mount.rpy_deg) if mount is not None else [0.0, 90.0 if name == "nadir" else 25.0, 0.0]
        hfov = cam.get("hfov_deg")
        if hfov is None and cam.get("fx"):
            hfov = math.degrees(2.0 * math.atan(float(cam.get("width", 640)) / 2.0 / float(cam["fx"])))
        aspect = float(cam.get("height", 480)) / float(cam.get("width", 640))
        out[str(name)] = {
            "pitch_deg": float(rpy[1]),
            "hfov_deg": float(hfov if hfov is not None else 90.0),
            "aspect": aspect,
        }
    return out
