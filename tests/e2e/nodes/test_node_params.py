"""Every Python node refuses an unknown or mistyped private parameter: exit code 2 and a message naming it.

Real ``rosrun`` against a real master; the convention is docs/architecture.md's (exit codes, node parameters).
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from helpers.paths import CONFIG
from helpers.procs import Proc, roscore

SCENARIO = CONFIG / "scenarios" / "loiter.yaml"

#: (package, node, private parameters as rosrun arguments, what the message must say)
CASES = [
    ("uav_autonomy", "feature_evaluator", ["_image_namespace:=/x"], "unknown private parameter(s) ~image_namespace"),
    ("uav_autonomy", "goal_selector", ["_odom:=/odom"], "unknown private parameter(s) ~odom"),
    ("uav_autonomy", "path_planner", ["_config:=42"], "key 'config' expected a string, got int 42"),
    ("uav_autonomy", "waypoint_controller", ["_connection:=udpin:0.0.0.0:1"], "~connection"),
    ("uav_autonomy", "autopilot_odometry", ["_odom:=/odom"], "unknown private parameter(s) ~odom"),
    (
        "uav_autonomy",
        "autopilot_odometry",
        ["__name:=autopilot_odometry_b", "_overrides:={time_sync: gps}"],  # its own name: the master keeps ~odom
        "time_sync must be timesync (a real autopilot) or shared (the SITL), got 'gps'",
    ),
    (
        "uav_autonomy",
        "robot_description",
        ["_file:=/nonexistent/robot.yaml"],
        "/nonexistent/robot.yaml: config file not found",
    ),
    ("uav_perception", "depth_estimator", ["_pose_source:=gps"], "key 'pose_source' expected one of 'tf', 'odom'"),
    ("uav_perception", "depth_evaluator", ["_camera_name:=nadir"], "unknown private parameter(s) ~camera_name"),
    ("uav_scenarios", "tracker", ["_gate:=3.0"], "this node takes: ~camera, ~detections, ~gate_m"),
    ("uav_scenarios", "scorer", [f"_scenario:={SCENARIO}", "_run_directory:=/tmp"], "~run_directory"),
    (
        "uav_scenarios",
        "mission_manager",
        [f"_scenario:={SCENARIO}", "_linger_s:=soon"],
        "key 'linger_s' expected a number",
    ),
    ("uav_sim_bridge", "sim_bridge", ["_sim_port:=abc"], "~sim_port must be a port number or empty"),
]


@pytest.fixture(scope="module")
def master() -> Iterator[dict[str, str]]:
    with roscore("roscore_node_params") as env:
        yield env


@pytest.mark.parametrize(
    ("package", "node", "args", "message"), CASES, ids=[f"{c[1]}-{k}" for k, c in enumerate(CASES)]
)
def test_a_bad_private_parameter_stops_the_node_with_exit_code_2(
    master: dict[str, str], package: str, node: str, args: list[str], message: str
) -> None:
    proc = Proc(f"node_params_{node}", ["rosrun", package, node, *args], env=master)
    try:
        code = proc.wait(60.0)
    finally:
        proc.stop()
    log = proc.log_text()
    assert code == 2, f"{node} exited with {code}:\n{log[-2000:]}"
    assert message in log, log[-2000:]
    assert "Traceback" not in log, log[-2000:]  # one clear line, not a stack dump
