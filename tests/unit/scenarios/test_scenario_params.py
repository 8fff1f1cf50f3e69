"""Scenario -> component settings, validated by the components' own strict loaders."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.paths import REPO

from uav_autonomy.core.controller import ControllerConfig
from uav_autonomy.core.features import FeatureConfig
from uav_autonomy.core.mcdm import GoalSelectorConfig
from uav_autonomy.core.planning import PlannerConfig
from uav_common.config import load_yaml_mapping
from uav_common.ros.params import load_section
from uav_scenarios.core.config import DepthSource, TimeMode, TimeSpec, load_scenario
from uav_scenarios.core.params import (
    RunContext,
    bridge_cameras,
    lockstep_steps,
    node_params,
    scripted_request,
    sitl_capacity_mah,
)
from uav_scenarios.errors import ScenarioError

SCENARIOS = sorted((REPO / "config" / "scenarios").glob("*.yaml"))
AUTONOMY = REPO / "config" / "autonomy.yaml"
SECTIONS = {
    "goal_selector": (GoalSelectorConfig, "goal_selector"),
    "feature_evaluator": (FeatureConfig, "features"),
    "path_planner": (PlannerConfig, "planner"),
    "waypoint_controller": (ControllerConfig, "controller"),
}


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.stem for p in SCENARIOS])
@pytest.mark.parametrize("node", sorted(SECTIONS))
def test_autonomy_nodes_accept_every_scenario(path: Path, node: str) -> None:
    cls, section = SECTIONS[node]
    config = load_section(cls, AUTONOMY, section, node_params(load_scenario(path), node))
    assert config is not None


def test_sar_weights_and_target_reach_the_goal_selector() -> None:
    sar = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    params = node_params(sar, "goal_selector")
    assert params["weights"] == {"age": 0.0, "frontier": 1.0, "target": 2.0, "drone": 1.0, "origin": 0.0}
    assert params["target_xy_m"] == [[0.0, -400.0]]
    assert node_params(sar, "waypoint_controller")["takeoff_height_m"] == sar.autonomy.takeoff_alt_m


def test_scripted_requests() -> None:
    mower_scenario = load_scenario(REPO / "config/scenarios/sar_lawnmower.yaml")
    assert mower_scenario.search is not None
    assert mower_scenario.search.scripted_alt_reference == "terrain"
    with pytest.raises(ScenarioError, match="needs the world's terrain"):
        scripted_request(mower_scenario)
    # Above home: the controller builds the pattern itself.
    home = replace(mower_scenario, search=replace(mower_scenario.search, scripted_alt_reference="home"))
    mower = scripted_request(home)
    assert mower["pattern"] == "lawnmower"
    assert len(mower["points"]) == 4
    # Above the terrain: explicit waypoints, 40 m over a ground that rises 1 m per 10 m eastwards.
    slope = lambda x, y: 0.1 * (np.asarray(x) + 250.0)  # noqa: E731
    planned = scripted_request(mower_scenario, slope)
    assert planned["pattern"] == "waypoints"
    pts = np.asarray(planned["points"])
    assert len(pts) > 20
    assert np.all(np.linalg.norm(np.diff(pts[:, :2], axis=0), axis=1) <= 25.0 + 1e-9)
    assert pts[:, 2].min() == pytest.approx(40.0, abs=3.0)
    assert pts[:, 2].max() == pytest.approx(90.0, abs=3.0)
    assert np.all(pts[:, 2] >= slope(pts[:, 0], pts[:, 1]) + 40.0 - 1e-9)
    square_scenario = load_scenario(REPO / "config/scenarios/sar_expanding_square.yaml")
    assert square_scenario.search is not None
    square = scripted_request(
        replace(square_scenario, search=replace(square_scenario.search, scripted_alt_reference="home"))
    )
    assert square["pattern"] == "expanding_square"
    assert square["points"] == [(0.0, -400.0, 0.0)]
    assert square["max_radius_m"] == pytest.approx((250.0**2 + 350.0**2) ** 0.5)
    assert scripted_request(square_scenario, slope)["points"][0][:2] == (0.0, -400.0)
    with pytest.raises(ScenarioError, match="not a scripted baseline"):
        scripted_request(load_scenario(REPO / "config/scenarios/loiter.yaml"))


def test_unknown_node_is_an_error() -> None:
    with pytest.raises(ScenarioError, match="no settings for node 'nope'"):
        node_params(load_scenario(REPO / "config/scenarios/loiter.yaml"), "nope")


def test_bridge_map_server_and_lockstep_settings(tmp_path: Path) -> None:
    sar = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    person = {"name": "person_0000", "instance_id": 77, "x_m": 10.0, "y_m": -200.0}
    ctx = RunContext(run_dir=str(tmp_path), world_yaml="/w.yaml", person=person)
    bridge = node_params(sar, "sim_bridge", ctx)
    assert bridge["object_poses"] == {"person_0000": [10.0, -200.0, 0.0]}
    assert bridge["detections"]["max_range_m"] == 100.0
    assert bridge["lockstep"] == {"role": "off"}
    assert bridge["world"] == "/w.yaml"
    lock = replace(sar, time=TimeSpec(mode=TimeMode.LOCKSTEP, step_s=0.1))
    assert node_params(lock, "sim_bridge", ctx)["lockstep"] == {"role": "master", "steps_per_grant": 25}
    assert lockstep_steps(replace(sar, time=TimeSpec(mode=TimeMode.LOCKSTEP, step_s=0.02))) == 5
    with pytest.raises(ScenarioError, match="whole number"):
        lockstep_steps(replace(sar, time=TimeSpec(mode=TimeMode.LOCKSTEP, step_s=0.003)))
    assert node_params(sar, "mission_manager", ctx) == {"person": person}
    base = load_yaml_mapping(REPO / "config" / "map_server.yaml")
    ms = node_params(sar, "map_server", replace(ctx, map_server_base=base))
    assert set(base) <= set(ms)  # the launch file sets this as the node's whole namespace
    assert ms["autosave"]["path"] == f"{tmp_path}/map_autosave.ot"
    assert ms["autosave"]["interval_s"] == base["autosave"]["interval_s"]
    assert ms["resolution"] == sar.map.resolution_m
    assert ms["input"] == "rgbd"  # ground-truth depth: the map camera's images, back-projected by the node
    estimated = replace(sar, depth_source=DepthSource.ESTIMATED)
    assert node_params(estimated, "map_server", replace(ctx, map_server_base=base))["input"] == "cloud"
    cams = bridge_cameras(load_yaml_mapping(REPO / "config" / "sim_bridge.yaml"), sar)
    assert cams["nadir"]["pitch_deg"] == 90.0
    assert cams["forward"]["pitch_deg"] == 25.0
    assert cams["nadir"]["aspect"] == pytest.approx(0.75)
    assert (
        sitl_capacity_mah(sar, REPO / "config" / "sitl.yaml")
        == load_yaml_mapping(REPO / "config" / "sitl.yaml")["battery"]["capacity_mah"]
    )
    assert sitl_capacity_mah(sar, tmp_path / "missing.yaml") == 4000.0


def test_scenario_params_cli_prints_yaml_or_fails(tmp_path: Path) -> None:
    cmd = [sys.executable, str(REPO / "catkin_ws/src/uav_scenarios/nodes/scenario_params")]
    ok = subprocess.run(
        [*cmd, str(REPO / "config/scenarios/loiter.yaml"), "goal_selector", "__name:=x"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert ok.returncode == 0, ok.stderr
    assert yaml.safe_load(ok.stdout)["weights"]["frontier"] == 1.0
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: x\nmission: loiter\nstop: {time_limt_s: 3}\n")
    fail = subprocess.run([*cmd, str(bad), "goal_selector"], capture_output=True, text=True, check=False)
    assert fail.returncode == 2  # a configuration error (docs/architecture.md, exit codes)
    assert "time_limt_s" in fail.stderr


def test_detector_geolocator_and_tracker_settings(tmp_path: Path) -> None:
    from uav_common.ros.params import parse_node_params  # noqa: PLC0415
    from uav_perception.ros.params import DegradedDetectorParams, DetectorParams, GeolocatorParams  # noqa: PLC0415
    from uav_scenarios.ros.params import TrackerParams  # noqa: PLC0415

    sar = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    ctx = RunContext(terrain_dem="/cache/terrain/abc-2m.npz")
    geo = node_params(sar, "geolocator", ctx)
    assert geo["detections"] == "/detections/forward/ground_truth"
    assert geo["terrain_dem"] == "/cache/terrain/abc-2m.npz"
    assert geo["elevation"] == "/map_server/layers"
    assert geo["depth"] == ""  # the forward camera is rendered for depth only when asked (use_depth)
    parse_node_params(GeolocatorParams, geo, node="geolocator")  # the node's own strict parser takes them
    tracker = node_params(sar, "tracker", ctx)
    assert tracker["detections"] == "/geolocator/detections"
    assert tracker["min_score"] == 0.5
    parse_node_params(TrackerParams, tracker, node="tracker")
    text = (REPO / "config/scenarios/search_and_rescue.yaml").read_text()
    text = text.replace("../worlds/default.yaml", str(REPO / "config/worlds/default.yaml"))
    path = tmp_path / "depth.yaml"
    path.write_text(
        text.replace("detector: ground_truth", "detector: degraded_truth\n  degraded: {seed: 9, jitter_px: 1.0}")
        .replace("use_depth: false", "use_depth: true")
        .replace("terrain_model: true", "terrain_model: false")
    )
    stand_in = load_scenario(path)
    geo = node_params(stand_in, "geolocator", ctx)
    assert geo["depth"] == "/cameras/forward/depth/image_raw"
    assert geo["terrain_dem"] == ""
    assert geo["detections"] == "/degraded_detector/detections"
    assert geo["detector"] == "degraded_truth"
    degraded = parse_node_params(DegradedDetectorParams, node_params(stand_in, "degraded_detector"), node="x")
    assert (degraded.degrade.seed, degraded.degrade.jitter_px) == (9, 1.0)
    path.write_text(text.replace("detector: ground_truth", "detector: learned\n  model: mine/m.onnx"))
    learned = load_scenario(path)
    assert node_params(learned, "geolocator", ctx)["detections"] == "/detector/detections"
    det = parse_node_params(DetectorParams, node_params(learned, "detector", ctx), node="detector")
    assert (det.model, det.image, det.threads) == (str(tmp_path / "mine/m.onnx"), "/cameras/forward/color/image_raw", 1)


def test_lockstep_runs_give_every_timeout_a_wall_clock_floor(tmp_path: Path) -> None:
    """A lockstep run goes several times faster than real time: its link, pose and offboard-stream timeouts need
    2 s of wall-clock silence too, whatever the scenario file says (a test scenario without it lost the link
    for 0.1 s on a busy machine); real-time runs keep the configured floor; node_params still win."""
    from uav_scenarios.core.launch import RunPorts, sitl_argv  # noqa: PLC0415

    data = yaml.safe_load((REPO / "config/scenarios/loiter.yaml").read_text())
    data["node_params"].pop("waypoint_controller", None)
    data["node_params"]["sitl"].pop("time", None)
    data["world"]["config"] = str(REPO / "config/worlds/default.yaml")
    data["time"] = {"mode": "lockstep"}
    path = tmp_path / "plain.yaml"
    path.write_text(yaml.safe_dump(data))
    lockstep = load_scenario(path)
    assert lockstep.time.mode is TimeMode.LOCKSTEP
    assert node_params(lockstep, "waypoint_controller")["wall_floor_s"] == 2.0
    assert node_params(lockstep, "autopilot_odometry")["wall_floor_s"] == 2.0
    ports = RunPorts()
    argv = sitl_argv(lockstep, ports, params_file=tmp_path / "p.json")
    assert "time.stream_wall_floor_s=2" in argv
    realtime = replace(lockstep, time=replace(lockstep.time, mode=TimeMode.FREE))
    assert "wall_floor_s" not in node_params(realtime, "waypoint_controller")
    assert "time.stream_wall_floor_s=2" not in sitl_argv(realtime, ports, params_file=tmp_path / "p.json")
    data["node_params"]["waypoint_controller"] = {"wall_floor_s": 0.25}
    path.write_text(yaml.safe_dump(data))
    assert node_params(load_scenario(path), "waypoint_controller")["wall_floor_s"] == 0.25
