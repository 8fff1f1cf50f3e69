"""scenario_params SCENARIO NODE: print NODE's settings for a scenario as YAML.

Used by the scenario launch files as ``<param name="overrides" type="yaml"
command="$(find uav_autonomy)/nodes/scenario_params $(arg scenario) goal_selector"/>``
so every node of a run takes its settings from the one scenario file. ``NODE`` may also be
``scenario`` (the whole parsed scenario) or ``scripted`` (the controller's SCRIPTED request).
A broken scenario file makes it exit non-zero with the file and key, which stops roslaunch.
"""

from __future__ import annotations

import sys
from pathlib import Path

import yaml

from uav_autonomy.core.scenario_config import load_scenario
from uav_autonomy.core.scenario_errors import ScenarioError
from uav_autonomy.core.scenario_params import node_params, scripted_request
from uav_common.config import ConfigError, to_mapping


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("__")]  # roslaunch adds __name:= etc.
    if len(args) != 2:
        sys.stderr.write("usage: scenario_params SCENARIO.yaml NODE|scenario|scripted\n")
        sys.exit(2)
    try:
        scenario = load_scenario(Path(args[0]))
        if args[1] == "scenario":
            data = to_mapping(scenario)
        elif args[1] == "scripted":
            data = to_mapping(scripted_request(scenario))
        else:
            data = node_params(scenario, args[1])
    except (ConfigError, ScenarioError) as err:
        sys.stderr.write(f"scenario_params: {err}\n")
        sys.exit(1)
    sys.stdout.write(yaml.safe_dump(data, sort_keys=True, default_flow_style=True))
