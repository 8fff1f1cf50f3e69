"""The autonomy nodes' private parameters and their sections of ``config/autonomy.yaml``.

Each node declares its ``~params`` as a frozen dataclass (below), parsed once at start-up by
:func:`uav_common.ros.params.node_params`; an unknown or mistyped parameter stops the node.
``~config`` names the settings file (empty: the project's ``config/autonomy.yaml``, found by
:func:`uav_common.paths.config_file`), ``~overrides`` is merged over the node's section.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, TypeVar

from uav_autonomy.errors import AutonomyConfigError
from uav_common.config import config_errors_as
from uav_common.paths import config_file
from uav_common.ros.params import load_section

__all__ = [
    "AUTOPILOT_ODOM",
    "AutopilotOdometryParams",
    "ControllerParams",
    "FeatureParams",
    "GoalSelectorParams",
    "PlannerParams",
    "RobotDescriptionParams",
    "autonomy_section",
    "mavlink_node_section",
]

T = TypeVar("T")

GROUND_TRUTH_ODOM = "/uav/ground_truth/odom"
#: Where ``autopilot_odometry`` publishes the autopilot's estimate (``pose_source: autopilot``).
AUTOPILOT_ODOM = "/uav/autopilot/odom"


def autonomy_section(cls: type[T], section: str, config: str, overrides: Mapping[str, Any]) -> T:
    """``section`` of the settings file ``config`` (empty: ``config/autonomy.yaml``) with ``overrides`` over it.

    Raises:
        AutonomyConfigError: missing file or section, unknown key, wrong type, failed validation.
    """
    with config_errors_as(AutonomyConfigError):
        path = Path(config).expanduser() if config else config_file("autonomy.yaml")
        return load_section(cls, path, section, overrides)


class _MavlinkNodeParams(Protocol):
    @property
    def config(self) -> str: ...
    @property
    def overrides(self) -> dict[str, Any]: ...
    @property
    def connection_url(self) -> str: ...


def mavlink_node_section(cls: type[T], section: str, params: _MavlinkNodeParams) -> T:
    """:func:`autonomy_section` for a node that talks MAVLink: its ``~connection_url``, when set, wins over the
    section's (and over ``~overrides``)."""
    overrides = dict(params.overrides)
    if params.connection_url:
        overrides["connection_url"] = params.connection_url
    return autonomy_section(cls, section, params.config, overrides)


@dataclass(frozen=True)
class FeatureParams:
    """``feature_evaluator``'s private parameters."""

    config: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    odom_topic: str = GROUND_TRUTH_ODOM
    image_ns: str = "/autonomy/feature_images"


@dataclass(frozen=True)
class GoalSelectorParams:
    """``goal_selector``'s private parameters."""

    config: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    odom_topic: str = GROUND_TRUTH_ODOM


@dataclass(frozen=True)
class PlannerParams:
    """``path_planner``'s private parameters."""

    config: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    odom_topic: str = GROUND_TRUTH_ODOM


@dataclass(frozen=True)
class ControllerParams:
    """``waypoint_controller``'s private parameters (``connection_url``, when set, wins over the file's)."""

    config: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    connection_url: str = ""
    #: The odometry the rest of the autonomy plans on (""= not watched): stale or NaN there stops commanding.
    pose_topic: str = ""


@dataclass(frozen=True)
class AutopilotOdometryParams:
    """``autopilot_odometry``'s private parameters (``connection_url``, when set, wins over the file's)."""

    config: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    connection_url: str = ""
    odom_topic: str = AUTOPILOT_ODOM


@dataclass(frozen=True)
class RobotDescriptionParams:
    """``robot_description``'s private parameters: the robot description file (""= ``config/robot.yaml``)."""

    file: str = ""
