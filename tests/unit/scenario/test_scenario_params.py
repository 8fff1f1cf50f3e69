"""Scenario -> component settings, validated by the components' own strict loaders."""

from __future__ import annotations

from pathlib import Path

import pytest

from uav_autonomy.core.controller import ControllerConfig
from uav_autonomy.core.features import FeatureConfig
from uav_autonomy.core.mcdm import GoalSelectorConfig
from uav_autonomy.core.planning import PlannerConfig
from uav_autonomy.core.scenario_config import load_scenario
from uav_autonomy.core.scenario_errors import ScenarioError
from uav_autonomy.core.scenario_params import node_params, scripted_request
from uav_autonomy.ros.autonomy_params import load_section

REPO = Path(__file__).resolve().parents[3]
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
    mower = scripted_request(load_scenario(REPO / "config/scenarios/sar_lawnmower.yaml"))
    assert mower["pattern"] == "lawnmower"
    assert len(mower["points"]) == 4
    square = scripted_request(load_scenario(REPO / "config/scenarios/sar_expanding_square.yaml"))
    assert square["pattern"] == "expanding_square"
    assert square["points"] == [(0.0, -400.0, 0.0)]
    assert square["max_radius_m"] == pytest.approx((250.0**2 + 350.0**2) ** 0.5)
    with pytest.raises(ScenarioError, match="not a scripted baseline"):
        scripted_request(load_scenario(REPO / "config/scenarios/loiter.yaml"))


def test_unknown_node_is_an_error() -> None:
    with pytest.raises(ScenarioError, match="no settings for node 'nope'"):
        node_params(load_scenario(REPO / "config/scenarios/loiter.yaml"), "nope")
