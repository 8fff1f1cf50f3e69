"""Node configuration: one section of ``config/autonomy.yaml`` plus ``~overrides``, loaded strictly.

Each node reads the file named by its private ``~config`` parameter (default: the
repository's ``config/autonomy.yaml``), takes its section, merges the optional
``~overrides`` dictionary over it (nested mappings merge key by key) and builds the
section's frozen dataclass with :func:`uav_common.config.from_mapping`, so a typo
in a key fails at start-up with the file and key in the message.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from uav_common.config import ConfigError, from_mapping, load_yaml_mapping

__all__ = ["default_config_path", "load_section", "merge"]

T = TypeVar("T")


def default_config_path() -> Path:
    """``<repo>/config/autonomy.yaml`` (this file is ``<repo>/catkin_ws/src/uav_autonomy/src/uav_autonomy/ros/``)."""
    return Path(__file__).resolve().parents[6] / "config" / "autonomy.yaml"


def merge(base: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Recursive dict merge; ``overrides`` wins, nested mappings merge."""
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def load_section(cls: type[T], path: Path, section: str, overrides: Mapping[str, Any] | None = None) -> T:
    """Build ``cls`` from ``section`` of ``path`` with ``overrides`` merged over it.

    Raises:
        ConfigError: missing file or section, unknown key, wrong type, failed validation.
    """
    data = load_yaml_mapping(path)
    if section not in data:
        msg = f"{path}: missing section '{section}'"
        raise ConfigError(msg)
    if not isinstance(data[section], Mapping):
        msg = f"{path}: section '{section}' must be a mapping"
        raise ConfigError(msg)
    if overrides is not None and not isinstance(overrides, Mapping):
        msg = f"~overrides must be a mapping, got {overrides!r}"
        raise ConfigError(msg)
    merged = merge(data[section], overrides or {})
    source = f"{path} (+ ~overrides)" if overrides else str(path)
    return from_mapping(cls, merged, source=source, prefix=section)
