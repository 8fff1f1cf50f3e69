"""A run's node settings checked before anything starts.

A scenario's ``node_params.sim_bridge`` and ``node_params.sitl`` reach those programs only when a run starts
them; a key they refuse used to show as the run (or every run of a campaign) dying seconds into its launch.
``uav-run`` and ``uav-campaign`` call :func:`check_node_settings` first, so the same mistake is a configuration
error (exit 2) naming the scenario file, the node and the key, and nothing is started or written. A learned
detector's model file is loaded and checked the same way.

The bridge's settings are assembled exactly as the node assembles them (``uav_sim_bridge.config.shipped_bridge_config``
with ``config/robot.yaml``); the SITL's by ``uav-sitl --print-config`` with the run's ``--set`` overrides (the
SITL is a program of its own, not a library of this package).
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterable

from uav_common.config import ConfigError
from uav_perception.errors import ModelFileError
from uav_perception.shell.models import resolve_model
from uav_perception.shell.onnx_detector import OnnxDetector
from uav_scenarios.core.config import DetectorKind, Scenario
from uav_scenarios.core.launch import flatten_settings, yaml_scalar
from uav_scenarios.core.params import node_params
from uav_scenarios.errors import ScenarioConfigError, ScenarioError
from uav_sim_bridge.config import shipped_bridge_config
from uav_sim_bridge.errors import SimBridgeError

__all__ = ["check_node_settings", "check_runs"]

#: How long ``uav-sitl --print-config`` may take (it imports JSBSim's bindings; about a second).
SITL_CHECK_TIMEOUT_S = 60.0


def check_node_settings(scenario: Scenario, *, where: str = "") -> None:
    """Raise :class:`ScenarioConfigError` if the bridge or the SITL would refuse this scenario's settings.

    Args:
        scenario: the effective scenario (overrides, stress presets and seeds applied).
        where: what to name in the message (default: the scenario's file).
    """
    label = where or str(scenario.source)
    _check_bridge(scenario, label)
    _check_sitl(scenario, label)
    _check_detector(scenario, label)


def check_runs(scenarios: Iterable[tuple[str, Scenario]]) -> int:
    """:func:`check_node_settings` for many runs, each distinct node setting checked once.

    Args:
        scenarios: ``(label, scenario)`` pairs; the label names the run in an error (e.g. the campaign arm).

    Returns:
        How many distinct settings were checked.
    """
    seen: set[str] = set()
    for label, scenario in scenarios:
        key = repr(
            (
                scenario.autopilot,
                scenario.node_params.get("sim_bridge"),
                scenario.node_params.get("sitl"),
                scenario.perception.detector,
                node_params(scenario, "detector"),
            )
        )
        if key in seen:
            continue
        seen.add(key)
        check_node_settings(scenario, where=label)
    return len(seen)


def _check_bridge(scenario: Scenario, label: str) -> None:
    source = f"{label}: node_params.sim_bridge over config/sim_bridge.yaml"
    try:
        shipped_bridge_config(node_params(scenario, "sim_bridge"), source=source)
    except (ConfigError, SimBridgeError, ScenarioError, ValueError) as err:
        msg = f"the sim bridge would refuse this run's settings: {err}"
        raise ScenarioConfigError(msg) from err


def _check_detector(scenario: Scenario, label: str) -> None:
    """A learned detector's model is loaded and checked as the node will (a missing, corrupt or wrong-format
    file names the file and what was expected)."""
    if scenario.perception.detector is not DetectorKind.LEARNED:
        return
    model = str(node_params(scenario, "detector").get("model", ""))
    try:
        OnnxDetector(resolve_model(model), threads=1)
    except ModelFileError as err:
        msg = f"{label}: perception.detector learned: {err}"
        raise ScenarioConfigError(msg) from err


def _check_sitl(scenario: Scenario, label: str) -> None:
    argv = ["uav-sitl", "--print-config", "--autopilot", scenario.autopilot.value]
    for key, value in flatten_settings(scenario.node_params.get("sitl", {})):
        argv += ["--set", f"{key}={yaml_scalar(value)}"]
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=SITL_CHECK_TIMEOUT_S, check=False)
    except FileNotFoundError as err:
        msg = "uav-sitl is not on PATH: run inside the project's environment (scripts/in_env) after make setup"
        raise ScenarioConfigError(msg) from err
    except subprocess.TimeoutExpired as err:
        msg = f"checking the SITL's settings (uav-sitl --print-config) took over {SITL_CHECK_TIMEOUT_S:g} s"
        raise ScenarioConfigError(msg) from err
    if proc.returncode != 0:
        detail = (proc.stderr.strip() or proc.stdout.strip()).splitlines()
        msg = f"{label}: node_params.sitl: the SITL would refuse this run's settings: {detail[-1] if detail else ''}"
        raise ScenarioConfigError(msg)
