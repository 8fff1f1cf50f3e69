"""scenario_params SCENARIO NODE [options]: print NODE's settings for a scenario as YAML.

Used by the scenario launch files as ``<param name="/NODE/overrides" type="yaml"
command="$(find uav_scenarios)/nodes/scenario_params $(arg scenario) NODE --run-dir ..."/>``
so every node of a run takes its settings from the one scenario file. ``NODE`` may also be
``scenario`` (the whole parsed scenario), ``scripted`` (the controller's SCRIPTED request) or
``lockstep`` (the ``/lockstep`` parameters of the causal lockstep, docs/lockstep.md).

Options: ``--run-dir DIR`` (the run folder), ``--world-cache-dir DIR`` (the bridge's world
cache), ``--lockstep-role master|participant``. For search and rescue the person of
interest's placement (seeded, clear of obstacles) is computed from the world here, so the
bridge, the mission manager and the scorer agree on it. A broken scenario file or a
missing world makes it exit non-zero with the file and key, which stops roslaunch.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import yaml

from uav_common.config import ConfigError, load_yaml_mapping, to_mapping
from uav_common.exit_codes import exit_code_for
from uav_common.paths import config_file
from uav_common.robot import load_robot_description
from uav_scenarios.core.config import Scenario, load_scenario
from uav_scenarios.core.params import (
    RunContext,
    bridge_cameras,
    needs_person,
    needs_terrain,
    needs_terrain_model,
    node_params,
    scripted_request,
    sitl_capacity_mah,
)
from uav_scenarios.core.world import place_person
from uav_scenarios.errors import ScenarioError
from uav_scenarios.shell.world_store import DEFAULT_CACHE_DIR, derived_world_yaml, load_world, terrain_dem


def run_context(
    scenario: Scenario, node: str, *, run_dir: str, cache_dir: Path | None, lockstep_role: str
) -> RunContext:
    """The world-dependent part of a node's settings (loads the world only when needed)."""
    person: dict[str, Any] | None = None
    scripted: dict[str, Any] | None = None
    world = None
    if needs_person(scenario) and node in ("sim_bridge", "mission_manager", "scorer"):
        assert scenario.search is not None
        world = load_world(scenario, cache_dir)
        person = place_person(scenario.search.person, world).as_dict()
    if needs_terrain(scenario) and node == "mission_manager":
        world = world or load_world(scenario, cache_dir)
        scripted = scripted_request(scenario, world.height_at)
    dem = ""
    if needs_terrain_model(scenario) and node == "geolocator":
        world = world or load_world(scenario, cache_dir)
        dem = str(terrain_dem(world, cache_dir))
    world_yaml = ""
    if node == "sim_bridge":
        world_yaml = str(derived_world_yaml(scenario, (cache_dir or DEFAULT_CACHE_DIR).parent / "scenario_worlds"))
    capacity = sitl_capacity_mah(scenario, config_file("sitl.yaml"))
    base = load_yaml_mapping(config_file("map_server.yaml")) if node == "map_server" else {}
    cameras = (
        bridge_cameras(
            load_yaml_mapping(config_file("sim_bridge.yaml")),
            scenario,
            load_robot_description(config_file("robot.yaml")),
        )
        if node == "scorer"
        else {}
    )
    return RunContext(
        map_server_base=base,
        cameras=cameras,
        run_dir=run_dir,
        world_yaml=world_yaml,
        person=person,
        battery_capacity_mah=capacity,
        lockstep_role=lockstep_role,
        scripted=scripted,
        terrain_dem=dem,
    )


def main() -> None:
    argv = [a for a in sys.argv[1:] if not a.startswith("__")]  # roslaunch adds __name:= etc.
    parser = argparse.ArgumentParser(prog="scenario_params", description="a node's settings for a scenario, as YAML")
    parser.add_argument("scenario", type=Path)
    parser.add_argument("node")
    parser.add_argument("--run-dir", default="")
    parser.add_argument("--world-cache-dir", default="")
    parser.add_argument("--lockstep-role", default="master", choices=("master", "participant"))
    args = parser.parse_args(argv)
    try:
        scenario = load_scenario(args.scenario)
        if args.node == "scenario":
            data: Any = to_mapping(scenario)
        elif args.node == "scripted":
            cache = Path(args.world_cache_dir).expanduser() if args.world_cache_dir else None
            ground = load_world(scenario, cache).height_at if needs_terrain(scenario) else None
            data = to_mapping(scripted_request(scenario, ground))
        else:
            cache = Path(args.world_cache_dir).expanduser() if args.world_cache_dir else None
            ctx = run_context(
                scenario, args.node, run_dir=args.run_dir, cache_dir=cache, lockstep_role=args.lockstep_role
            )
            data = node_params(scenario, args.node, ctx)
    except (ConfigError, ScenarioError) as err:
        sys.stderr.write(f"scenario_params: {err}\n")
        sys.exit(int(exit_code_for(err)))
    sys.stdout.write(yaml.safe_dump(data, sort_keys=True, default_flow_style=True))
