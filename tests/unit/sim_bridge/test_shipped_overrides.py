"""Every shipped or test YAML that overrides the sim bridge's settings (``node_params.sim_bridge`` of a scenario,
a campaign variant or a dataset's flight) gives a configuration the bridge accepts.

Those overrides reach the bridge only when a run starts it; a key the bridge refuses (for example a camera
``mount``, which belongs in config/robot.yaml) used to surface as every run of a campaign dying at start.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml
from helpers.paths import REPO

from uav_common.robot import load_robot_description
from uav_sim_bridge.config import mounted_cameras, shipped_bridge_config


def _sim_bridge_overrides(node: Any, where: str) -> list[tuple[str, dict[str, Any]]]:
    """Every ``node_params: {sim_bridge: {...}}`` mapping anywhere in a YAML document."""
    found: list[tuple[str, dict[str, Any]]] = []
    if isinstance(node, dict):
        params = node.get("node_params")
        if isinstance(params, dict) and isinstance(params.get("sim_bridge"), dict):
            found.append((f"{where}node_params.sim_bridge", params["sim_bridge"]))
        for key, value in node.items():
            found += _sim_bridge_overrides(value, f"{where}{key}.")
    elif isinstance(node, list):
        for i, value in enumerate(node):
            found += _sim_bridge_overrides(value, f"{where}{i}.")
    return found


def _cases() -> list[tuple[str, dict[str, Any]]]:
    cases: list[tuple[str, dict[str, Any]]] = []
    for folder in (REPO / "config", REPO / "tests"):
        for path in sorted(folder.rglob("*.yaml")):
            try:
                doc = yaml.safe_load(path.read_text(encoding="utf-8"))
            except yaml.YAMLError:
                continue  # deliberately broken fixtures are other tests' business
            for where, overrides in _sim_bridge_overrides(doc, ""):
                cases.append((f"{path.relative_to(REPO)}:{where}", overrides))
    return cases


CASES = _cases()


def test_the_search_finds_the_shipped_overrides() -> None:
    assert any(name.startswith("config/campaigns/") for name, _ in CASES), [n for n, _ in CASES]
    assert len(CASES) >= 3


@pytest.mark.parametrize(("where", "overrides"), CASES, ids=[c[0] for c in CASES])
def test_the_bridge_accepts_the_overrides(where: str, overrides: dict[str, Any]) -> None:
    cfg = shipped_bridge_config(overrides, source=where)
    robot = load_robot_description(REPO / "config" / "robot.yaml")
    assert set(cfg.cameras) <= set(robot.cameras), where


def test_a_mount_in_the_overrides_is_refused_naming_the_place() -> None:
    robot = load_robot_description(REPO / "config" / "robot.yaml")
    with pytest.raises(Exception, match=r"x\.yaml: cameras\.nadir\.mount: .*config/robot\.yaml"):
        mounted_cameras({"nadir": {"mount": {"xyz_m": [0, 0, 0], "rpy_deg": [0, 90, 0]}}}, robot, source="x.yaml")


def test_paths_are_repo_relative() -> None:
    assert all(not Path(name.split(":")[0]).is_absolute() for name, _ in CASES)
