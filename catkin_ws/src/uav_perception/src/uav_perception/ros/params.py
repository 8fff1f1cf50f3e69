"""The depth nodes' private parameters and their sections of ``config/depth.yaml``.

Parsed once at start-up by :func:`uav_common.ros.params.node_params`; an unknown or mistyped
private parameter stops the node. ``~config`` names the settings file (empty: the project's
``config/depth.yaml``), ``~overrides`` is merged over the node's section.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

from uav_common.config import config_errors_as
from uav_common.paths import config_file
from uav_common.ros.params import load_section
from uav_perception.errors import PerceptionConfigError

__all__ = ["EstimatorParams", "EvaluatorParams", "depth_section"]

T = TypeVar("T")


def depth_section(cls: type[T], section: str, config: str, overrides: Mapping[str, Any]) -> T:
    """``section`` of the settings file ``config`` (empty: ``config/depth.yaml``) with ``overrides`` over it.

    Raises:
        PerceptionConfigError: missing file or section, unknown key, wrong type, failed validation.
    """
    with config_errors_as(PerceptionConfigError):
        path = Path(config).expanduser() if config else config_file("depth.yaml")
        return load_section(cls, path, section, overrides)


@dataclass(frozen=True)
class EstimatorParams:
    """``depth_estimator``'s private parameters."""

    config: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    camera: str = "nadir"
    pose_source: Literal["tf", "odom"] = "tf"
    map_frame: str = "map"
    base_frame: str = "base_link"
    odom_topic: str = "/uav/ground_truth/odom"
    tf_timeout_s: float = 0.3

    def __post_init__(self) -> None:
        if not self.tf_timeout_s > 0.0:
            msg = f"~tf_timeout_s must be > 0, got {self.tf_timeout_s}"
            raise ValueError(msg)


@dataclass(frozen=True)
class EvaluatorParams:
    """``depth_evaluator``'s private parameters."""

    config: str = ""
    overrides: dict[str, Any] = field(default_factory=dict)
    camera: str = "nadir"
    estimate_topic: str = "/depth_estimator/depth/image_raw"
    objects_file: str = ""
    world_dir_param: str = "/sim_bridge/world_dir"
    run_dir: str = ""
