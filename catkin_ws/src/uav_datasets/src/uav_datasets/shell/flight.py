"""A flight as a sequence: the frames a bridge camera rendered along a recorded run, re-rendered and labelled.

From a run's bag (``rosbags``, no ROS needed) this reads the effective scenario (``/scenario/config``,
or the run folder's ``scenario.yaml``) and the ground-truth trajectory (``/uav/ground_truth/odom``,
one message per simulation state). From the scenario it rebuilds what the bridge had: the world
(``world_config_for``), its camera configuration (``config/sim_bridge.yaml`` with the scenario's
``node_params.sim_bridge`` merged, as the launch files do) and the objects the scenario moved (the
search-and-rescue person's seeded placement). Frames fall where the bridge rendered them: at the first
state at or after each instant of the camera's rate grid (``RateSchedule``), so the re-rendered frames
are the run's frames (those of the camera at least ``min_altitude_agl_m`` above the terrain). Object
identities are the world's instance ids, the same in every frame. People and vehicles that walk or drive
(the scenario's or world's ``actors``) are placed where the bridge had them at each frame's simulation time
(``MotionPlan.states_at``, a pure function of it); walkers keep the body pose the world generated (the
bridge animates their gait), so their masks and boxes differ from the run's by a limb (docs/datasets.md).

``flight.scenario`` instead flies the scenario first with ``uav-run`` (lockstep, ``replay``
recording) into ``<dataset>/source_run`` and converts that run.
"""

from __future__ import annotations

import math
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uav_common.config import ConfigError
from uav_datasets.core.config import DatasetConfig, FlightSpec
from uav_datasets.core.plan import FramePlan
from uav_datasets.errors import DatasetConfigError, FlightError
from uav_scenarios.core.config import Scenario, load_scenario
from uav_scenarios.core.params import RunContext, needs_person, node_params
from uav_scenarios.core.world import place_person, world_config_for
from uav_scenarios.errors import ScenarioError
from uav_scenarios.ros.records import pose_from_odometry
from uav_sim_bridge.config import SimBridgeConfig, shipped_bridge_config
from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.motion import plan_motion
from uav_sim_bridge.core.objects import ObjectPose
from uav_sim_bridge.core.schedule import RateSchedule
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import WorldConfig
from uav_sim_bridge.errors import SimBridgeError

__all__ = ["Flight", "fly_scenario", "load_flight", "read_trajectory"]

_ODOM = "/uav/ground_truth/odom"
_CONFIG = "/scenario/config"


@dataclass(frozen=True)
class Flight:
    """A flight ready to render: the world, the camera, the frames (poses, times, object poses)."""

    bag: Path
    scenario: Scenario
    world_config: WorldConfig
    camera: CameraModel
    rate_hz: float
    sequence: str
    frames: tuple[FramePlan, ...]


def _bag_and_folder(run: Path) -> tuple[Path, Path | None]:
    if run.is_dir():
        bag = run / "run.bag"
        if not bag.is_file():
            msg = f"{run}: no run.bag in the run folder (was the run recorded? uav-run --record replay)"
            raise FlightError(msg)
        return bag, run
    if run.is_file():
        return run, None
    active = run.with_name(run.name + ".active")
    hint = f" ({active} exists: the recording was cut short; run `rosbag reindex` on it)" if active.exists() else ""
    msg = f"{run}: no such run folder or bag{hint}"
    raise FlightError(msg)


def read_trajectory(bag: Path) -> tuple[str, list[tuple[float, RigidTransform]]]:
    """The scenario YAML recorded on ``/scenario/config`` ("" if none) and the odometry ``(t_s, T_map_base)``.

    Raises:
        FlightError: the bag cannot be read, or holds no ground-truth odometry.
    """
    from rosbags.highlevel import AnyReader  # noqa: PLC0415 - heavy import, only for flights

    if bag.suffix != ".bag":
        msg = f"{bag}: not a finished ROS 1 bag (rosbag record writes .bag.active until it closes the file)"
        raise FlightError(msg)
    scenario_yaml = ""
    states: list[tuple[float, RigidTransform]] = []
    try:
        with AnyReader([bag]) as reader:
            conns = [c for c in reader.connections if c.topic in (_ODOM, _CONFIG)]
            for conn, _t, raw in reader.messages(connections=conns):
                message: Any = reader.deserialize(raw, conn.msgtype)
                if conn.topic == _CONFIG:
                    scenario_yaml = str(message.data)
                    continue
                p = pose_from_odometry(message)
                qx, qy, qz, qw = p.quat_xyzw
                states.append((p.t_s, RigidTransform.from_quat([qw, qx, qy, qz], p.position_m)))
    except FlightError:
        raise
    except Exception as err:  # rosbags raises its own types for damaged bags
        msg = (
            f"{bag}: cannot read the bag ({type(err).__name__}: {err}); if the run was interrupted, "
            "run `rosbag reindex` on it"
        )
        raise FlightError(msg) from err
    if not states:
        msg = f"{bag}: no {_ODOM} messages; record the run with the report or replay preset"
        raise FlightError(msg)
    states.sort(key=lambda s: s[0])
    return scenario_yaml, states


def _scenario(bag: Path, folder: Path | None, recorded_yaml: str) -> Scenario:
    if folder is not None and (folder / "scenario.yaml").is_file():
        return load_scenario(folder / "scenario.yaml")
    if not recorded_yaml:
        msg = f"{bag}: no {_CONFIG} message and no scenario.yaml beside it: cannot tell the world and the cameras"
        raise FlightError(msg)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scenario.yaml"
        path.write_text(recorded_yaml, encoding="utf-8")
        return load_scenario(path)


def _sequence_name(spec: FlightSpec, bag: Path, folder: Path | None) -> str:
    if spec.sequence:
        return spec.sequence
    stem = (folder.name if folder is not None else bag.stem) + f"-{spec.camera}"
    return re.sub(r"[^A-Za-z0-9_-]", "_", stem)


def _moved_objects(bridge: SimBridgeConfig, world: World) -> list[tuple[int, ObjectPose]]:
    """The objects the run's bridge moved at start-up (``object_poses``), stood on the ground as the bridge does."""
    by_name = {o.name: o for o in world.objects}
    moved: list[tuple[int, ObjectPose]] = []
    for name, (x, y, yaw_deg) in bridge.object_poses.items():
        if name not in by_name:
            msg = (
                f"the run's sim_bridge object_poses names {name!r}, which is not an object of world {world.config.name}"
            )
            raise DatasetConfigError(msg)
        z = world.ground_height_at(x, y)[0]  # engine.move_object: z None -> on the ground
        moved.append((by_name[name].instance_id, ObjectPose((float(x), float(y), float(z)), math.radians(yaw_deg))))
    return moved


def load_flight(cfg: DatasetConfig, run: Path, world_loader: Any) -> tuple[Flight, World]:
    """The sequence ``cfg.flight`` asks for along the run at ``run`` (folder or bag).

    Args:
        world_loader: ``WorldConfig -> World`` (the dataset's world cache).

    Raises:
        FlightError: the run cannot be read.
        DatasetConfigError: the camera is not one of the run's, or the scenario or its world is invalid.
    """
    spec = cfg.flight
    assert spec is not None  # DatasetConfig checks source: flight has a flight section
    bag, folder = _bag_and_folder(run)
    recorded, states = read_trajectory(bag)
    try:
        scenario = _scenario(bag, folder, recorded)
        world_cfg = world_config_for(scenario)
        world = world_loader(world_cfg)
        person = (
            place_person(scenario.search.person, world).as_dict()
            if needs_person(scenario) and scenario.search
            else None
        )
        overrides = node_params(scenario, "sim_bridge", RunContext(person=person))
        bridge = shipped_bridge_config(overrides, source=f"{bag} (scenario {scenario.name})")
    except (ConfigError, ScenarioError, SimBridgeError) as err:
        msg = f"flight {bag}: {err}"
        raise DatasetConfigError(msg) from err
    if spec.camera not in bridge.cameras:
        cams = ", ".join(sorted(bridge.cameras))
        msg = f"flight.camera {spec.camera!r} is not a camera of the run; its cameras: {cams}"
        raise DatasetConfigError(msg)
    cam_cfg = bridge.cameras[spec.camera]
    camera = CameraModel.from_config(spec.camera, cam_cfg)
    rate = spec.rate_hz or cam_cfg.rate_hz
    moved = _moved_objects(bridge, world)
    moved_ids = {iid for iid, _ in moved}
    # people who walk and vehicles that drive: where the bridge had them at each frame's simulation time
    motion = plan_motion(world.objects, world.roads, world.terrain.bounds_m, world.config, bridge.actors)
    schedule = RateSchedule(rate)
    t0 = states[0][0]
    sequence = _sequence_name(spec, bag, folder)
    frames: list[FramePlan] = []
    limit = cfg.frame_limit
    for t, t_map_base in states:
        if not schedule.due(t):
            continue
        rel = t - t0
        if rel < spec.start_s - 1e-9 or (spec.end_s is not None and rel > spec.end_s + 1e-9):
            continue
        t_map_optical = camera.optical_pose(t_map_base)
        eye = t_map_optical.translation_m
        if float(eye[2]) - float(world.height_at(float(eye[0]), float(eye[1]))) < spec.min_altitude_agl_m:
            continue  # on the ground (or about to land)
        if limit is not None and len(frames) >= limit:
            break
        k = len(frames)
        frames.append(
            FramePlan(
                index=k,
                name=f"{k:06d}",
                split=spec.split,
                world_seed=world_cfg.seed,
                t_map_optical=t_map_optical,
                timestamp_s=t,
                sequence=sequence,
                sequence_frame=k + 1,
                object_poses=(
                    *moved,
                    *(
                        (st.instance_id, st.pose)
                        for st in motion.states_at(t, world.terrain)
                        if st.instance_id not in moved_ids
                    ),
                ),
            )
        )
    if not frames:
        msg = f"flight {bag}: no {spec.camera} frame between start_s {spec.start_s} and end_s {spec.end_s}"
        raise DatasetConfigError(msg)
    return Flight(bag, scenario, world_cfg, camera, rate, sequence, tuple(frames)), world


def fly_scenario(spec: FlightSpec, run_dir: Path, log: Path) -> Path:
    """Fly ``spec.scenario`` with ``uav-run`` (lockstep, replay recording) into ``run_dir``; returns it.

    A ``run_dir`` that already holds a finished run (``metrics.json`` and ``run.bag``) is reused.

    Raises:
        FlightError: uav-run is missing or the run failed (its output is in ``log``).
    """
    assert spec.scenario is not None
    if (run_dir / "run.bag").is_file() and (run_dir / "metrics.json").is_file():
        return run_dir
    exe = shutil.which("uav-run")
    if exe is None:
        msg = (
            "uav-run is not on PATH; run inside the project environment (scripts/in_env or catkin_ws/devel/setup.bash)"
        )
        raise FlightError(msg)
    shutil.rmtree(run_dir, ignore_errors=True)
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    argv = [exe, str(spec.scenario), "--lockstep", "--record", "replay", "--time-limit", f"{spec.time_limit_s:g}"]
    argv += ["--run-dir", str(run_dir), "--quiet"]
    with log.open("w") as fh:
        rc = subprocess.run(argv, stdout=fh, stderr=subprocess.STDOUT, check=False).returncode
    if rc != 0 or not (run_dir / "run.bag").is_file():
        tail = log.read_text(errors="replace")[-1500:]
        msg = f"flying {spec.scenario} with uav-run failed (exit {rc}); its output is in {log}:\n{tail}"
        raise FlightError(msg)
    return run_dir
