"""A scenario's ``environment:`` (presets from ``config/environments/``) and ``actors:``, checked before a run.

* :func:`scenario_environment` — the preset loaded and the scenario's free values merged over it, validated
  (an unknown preset or key, a time of day out of range, a night-time sun: an error naming the scenario
  file and the key);
* :func:`with_environment` — the same scenario under another preset (``uav-run --environment``);
* :func:`check_actors` — the scenario's ``actors:`` against its world (a named object that is not there, a
  vehicle told to drive with no road, a path missing: the file and the key).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from uav_common.config import ConfigError, from_mapping
from uav_scenarios.core.config import Scenario
from uav_scenarios.errors import ScenarioConfigError
from uav_sim_bridge.config import environment_presets, resolve_environment
from uav_sim_bridge.core.environment import EnvironmentConfig
from uav_sim_bridge.core.lighting import lighting_for
from uav_sim_bridge.core.motion import MotionPlan, plan_motion
from uav_sim_bridge.core.world import World
from uav_sim_bridge.errors import SimBridgeConfigError

__all__ = ["check_actors", "environment_presets", "scenario_environment", "with_environment"]


def scenario_environment(
    scenario: Scenario, latitude_deg: float | None = None
) -> tuple[dict[str, Any], EnvironmentConfig]:
    """The resolved ``environment`` mapping (preset + free values) and its parsed form.

    Args:
        scenario: the scenario (its ``source`` names it in errors).
        latitude_deg: the world's latitude, to check that the sun is up at the time of day (skipped if None).

    Raises:
        ScenarioConfigError: unknown preset or key, bad value, or the sun below civil twilight.
    """
    where = str(scenario.source or scenario.name)
    try:
        merged = resolve_environment(scenario.environment)
    except ConfigError as err:
        msg = f"{where}: 'environment.preset': {err}"
        raise ScenarioConfigError(msg) from err
    try:
        env = from_mapping(EnvironmentConfig, merged, source=where, prefix="environment")
    except ConfigError as err:
        raise ScenarioConfigError(str(err)) from err
    if latitude_deg is not None:
        try:
            lighting_for(env, latitude_deg)
        except ValueError as err:
            msg = f"{where}: 'environment.time_of_day_h': {err}"
            raise ScenarioConfigError(msg) from err
    return merged, env


def with_environment(scenario: Scenario, preset: str) -> Scenario:
    """The scenario under preset ``preset`` (its own free values, if any, still apply over it)."""
    raw = dict(scenario.environment)
    raw["preset"] = preset
    return replace(scenario, environment=raw)


def check_actors(scenario: Scenario, world: World) -> MotionPlan:
    """The scenario's movers in its world (what the bridge will do), or an error naming the file and key.

    Raises:
        ScenarioConfigError: the ``actors`` section cannot be carried out in this world.
    """
    try:
        return plan_motion(world.objects, world.roads, world.terrain.bounds_m, world.config, scenario.actors)
    except SimBridgeConfigError as err:
        msg = f"{scenario.source or scenario.name}: {err}"
        raise ScenarioConfigError(msg) from err
