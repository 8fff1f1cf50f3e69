"""Scenario -> each process's settings: the one place this mapping lives.

Launch files load the result with ``<param name="overrides" type="yaml"
command="$(find uav_autonomy)/nodes/scenario_params SCENARIO NODE"/>``; ``uav-run``
calls the same functions. Keys are those of each component's own config section
(``config/autonomy.yaml`` etc.), which validates them again strictly.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from uav_autonomy.core.scenario_config import FEATURE_NAMES, Scenario, Strategy
from uav_autonomy.core.scenario_errors import ScenarioError

__all__ = ["NODE_PARAMS", "node_params", "scripted_request"]


def _target_xy(scenario: Scenario) -> list[list[float]]:
    target = scenario.autonomy.target
    if target.polygon_m:
        return [[x, y] for x, y in target.polygon_m]
    assert target.point_m is not None  # guaranteed by TargetSpec
    return [[target.point_m[0], target.point_m[1]]]


def goal_selector(scenario: Scenario) -> dict[str, Any]:
    weights = {name: float(scenario.autonomy.weights.get(name, 0.0)) for name in FEATURE_NAMES}
    return {"weights": weights, "target_xy_m": _target_xy(scenario)}


def features(scenario: Scenario) -> dict[str, Any]:
    return {"age_half_life_s": scenario.autonomy.age_half_life_s}


def planner(scenario: Scenario) -> dict[str, Any]:
    return {"algorithm": scenario.autonomy.planner, "cruise_buffer_m": scenario.autonomy.cruise_buffer_m}


def controller(scenario: Scenario) -> dict[str, Any]:
    out: dict[str, Any] = {"takeoff_height_m": scenario.autonomy.takeoff_alt_m}
    if scenario.search is not None:
        out["scripted_altitude_m"] = scenario.search.scripted_alt_m
    return out


def map_server(scenario: Scenario) -> dict[str, Any]:
    return {"backend": scenario.map.backend.value, "resolution": scenario.map.resolution_m, **scenario.map.params}


#: Node name -> settings function. ``node_params`` merges ``scenario.node_params[name]`` over it.
NODE_PARAMS: dict[str, Callable[[Scenario], dict[str, Any]]] = {
    "goal_selector": goal_selector,
    "feature_evaluator": features,
    "path_planner": planner,
    "waypoint_controller": controller,
    "map_server": map_server,
}


def node_params(scenario: Scenario, node: str) -> dict[str, Any]:
    """The settings of ``node`` for this scenario (component overrides merged last).

    Raises:
        ScenarioError: a node this module does not know and the scenario does not mention.
    """
    base = NODE_PARAMS[node](scenario) if node in NODE_PARAMS else None
    extra = scenario.node_params.get(node)
    if base is None and extra is None:
        known = ", ".join(sorted(set(NODE_PARAMS) | set(scenario.node_params)))
        msg = f"no settings for node {node!r}; known: {known}"
        raise ScenarioError(msg)
    return {**(base or {}), **(extra or {})}


def scripted_request(scenario: Scenario) -> dict[str, Any]:
    """The controller's SCRIPTED request (``uav_msgs/SetControllerState`` fields) for a baseline.

    Lawnmower: the search area polygon at ``track_spacing_m``. Expanding square: from the
    search target (the prior datum) out to the farthest corner of the search area.

    Raises:
        ScenarioError: the scenario is autonomous or has no search section.
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
    return {
        "state": "SCRIPTED",
        "pattern": scenario.strategy.value,
        "points": points,
        "spacing_m": search.track_spacing_m,
        "altitude_m": search.scripted_alt_m,
        "max_radius_m": radius,
    }
