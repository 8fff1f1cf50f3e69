"""One launch argument switches what feeds the map server (real roslaunch, roscore and map server)."""

from __future__ import annotations

import subprocess
import time
from pathlib import Path

import pytest
import rosgraph
from helpers.procs import REPO, Proc, roscore

LAUNCH = REPO / "catkin_ws" / "src" / "uav_perception" / "launch" / "perception.launch"
# roslaunch escalates SIGINT -> SIGTERM -> SIGKILL on its nodes within ~17 s; it must live that
# long, or a node stuck in rospy's shutdown (a SIGINT during its start-up can deadlock it) is orphaned.
ROSLAUNCH_STOP_S = 20.0


def graph() -> tuple[dict[str, set[str]], set[str]]:
    """``(topic -> subscriber nodes, every node the master knows)``."""
    pubs, subs, srvs = rosgraph.Master("/depth_switch_check").getSystemState()
    nodes = {n for group in (pubs, subs, srvs) for _name, ns in group for n in ns}
    return {t: set(ns) for t, ns in subs}, nodes


def planned_nodes(source: str) -> set[str]:
    """The nodes the launch file starts for ``source``, from roslaunch itself (no master, no timing)."""
    out = subprocess.run(
        ["roslaunch", "--nodes", str(LAUNCH), f"depth_source:={source}"],
        capture_output=True,
        text=True,
        check=True,
        timeout=60,
    )
    return {line.strip() for line in out.stdout.splitlines() if line.startswith("/")}


def wait_running(expected: set[str], proc: Proc, timeout_s: float = 30.0) -> set[str]:
    """Wait until every expected node is registered; return the launch's nodes then running."""
    deadline = time.monotonic() + timeout_s
    nodes: set[str] = set()
    while time.monotonic() < deadline:
        assert proc.alive(), proc.tail()
        _, nodes = graph()
        if expected <= nodes:
            return nodes - {"/rosout"}
        time.sleep(0.2)
    raise AssertionError(f"nodes {sorted(expected - nodes)} never came up\n{proc.tail()}")


def wait_subscribed(topic: str, node: str, proc: Proc, timeout_s: float = 30.0) -> dict[str, set[str]]:
    deadline = time.monotonic() + timeout_s
    subs: dict[str, set[str]] = {}
    while time.monotonic() < deadline:
        assert proc.alive(), proc.tail()
        subs, _ = graph()
        if node in subs.get(topic, set()):
            return subs
        time.sleep(0.2)
    raise AssertionError(f"{node} never subscribed to {topic}; subscriptions: {subs}\n{proc.tail()}")


@pytest.mark.parametrize(
    ("source", "cloud", "depth_nodes"),
    [
        ("ground_truth", "/cameras/nadir/depth/image_raw", False),
        ("estimated", "/depth_estimator/points", True),
    ],
)
def test_depth_source_switches_the_map_input(source: str, cloud: str, depth_nodes: bool, tmp_path: Path) -> None:
    planned = planned_nodes(source)
    depth = {"/depth_estimator", "/depth_evaluator"}
    assert planned == ({"/map_server"} | depth if depth_nodes else {"/map_server"})
    with roscore(f"roscore_switch_{source}") as env:
        proc = Proc(
            f"perception_switch_{source}",
            ["roslaunch", str(LAUNCH), f"depth_source:={source}", f"autosave_path:={tmp_path / 'map.bt'}"],
            env=env,
        )
        try:
            subs = wait_subscribed(cloud, "/map_server", proc)
            if source == "ground_truth":  # rgbd input: depth, color and the depth camera's info, no cloud
                for topic in ("/cameras/nadir/color/image_raw", "/cameras/nadir/depth/camera_info"):
                    subs = wait_subscribed(topic, "/map_server", proc)
                others = ["/depth_estimator/points", "/cameras/nadir/points"]
            else:
                others = ["/cameras/nadir/points", "/cameras/nadir/depth/image_raw"]
            assert not [t for t in others if "/map_server" in subs.get(t, set())]
            # Every node the launch planned is up, and nothing else: with ground truth no depth node runs.
            assert wait_running(planned, proc) == planned
            if depth_nodes:
                wait_subscribed("/cameras/nadir/color/image_raw", "/depth_estimator", proc)
                wait_subscribed("/depth_estimator/depth/image_raw", "/depth_evaluator", proc)
        finally:
            proc.stop(timeout_s=ROSLAUNCH_STOP_S)


def test_a_bad_depth_source_fails_the_launch() -> None:
    with roscore("roscore_switch_bad") as env:
        proc = Proc("perception_switch_bad", ["roslaunch", str(LAUNCH), "depth_source:=lidar"], env=env)
        try:
            assert proc.wait(30.0) != 0
        finally:
            proc.stop(timeout_s=ROSLAUNCH_STOP_S)
        assert "lidar" in proc.log_text()
