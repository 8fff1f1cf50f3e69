"""Default locations that the code derives from its own path point into the checkout."""

from __future__ import annotations

from helpers.procs import REPO

from uav_autonomy.ros import scenario_run
from uav_autonomy.ros.autonomy_params import default_config_path


def test_uav_run_writes_runs_and_caches_under_the_checkout() -> None:
    assert scenario_run.REPO_ROOT == REPO
    assert (scenario_run.REPO_ROOT / "Makefile").is_file()
    args = scenario_run._parse(["config/scenarios/loiter.yaml"])
    assert args.runs_dir == REPO / "runs"


def test_node_configs_default_to_the_checkout() -> None:
    assert default_config_path() == REPO / "config" / "autonomy.yaml"
