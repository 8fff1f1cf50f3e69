"""A node's private parameters (``~params``) and its config-file section, parsed once, strictly.

Every Python node of the project declares its private parameters as a frozen dataclass and
calls :func:`node_params` once at start-up. An unknown private parameter (a typo, a
parameter of another node) or a value of the wrong type stops the node with a message
naming the parameter and what was expected, as the C++ map server does.

Nodes whose settings live in a section of a YAML file (``config/autonomy.yaml``,
``config/depth.yaml``) take the file from their ``~config`` parameter and merge the
``~overrides`` mapping over the section with :func:`load_section`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

from uav_common.config import ConfigError, deep_merge, from_mapping, load_yaml_mapping

__all__ = ["load_section", "node_params", "parse_node_params"]

T = TypeVar("T")


def parse_node_params(cls: type[T], raw: Mapping[str, Any], *, node: str) -> T:
    """Build ``cls`` from the private parameters ``raw`` of ``node`` (pure; :func:`node_params` reads them).

    Raises:
        ConfigError: an unknown parameter, a wrong type or a failed validation; the message names
            the node, the parameter (``~name``) and what was expected.
    """
    fields = {f.name for f in dataclasses.fields(cls) if f.init}  # type: ignore[arg-type]
    unknown = sorted(str(k) for k in raw if k not in fields)
    if unknown:
        known = ", ".join(f"~{name}" for name in sorted(fields)) or "none"
        msg = (
            f"{node}: unknown private parameter(s) {', '.join('~' + u for u in unknown)}; "
            f"this node takes: {known} (a typo, or a parameter meant for another node?)"
        )
        raise ConfigError(msg)
    return from_mapping(cls, dict(raw), source=f"{node} private parameters (~)")


def node_params(cls: type[T], node: str) -> T:
    """Read every private parameter of this (already initialised) node and build ``cls`` from them.

    Raises:
        ConfigError: see :func:`parse_node_params`.
    """
    import rospy  # noqa: PLC0415 - the pure parser above is importable without ROS

    raw = rospy.get_param("~", {}) or {}
    if not isinstance(raw, Mapping):
        msg = f"{node}: private parameters must form a namespace, got {raw!r}"
        raise ConfigError(msg)
    return parse_node_params(cls, raw, node=node)


def load_section(cls: type[T], path: Path, section: str, overrides: Mapping[str, Any] | None = None) -> T:
    """Build ``cls`` from ``section`` of the YAML file ``path`` with ``overrides`` merged over it.

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
    merged = deep_merge(data[section], overrides or {})
    source = f"{path} (+ ~overrides)" if overrides else str(path)
    return from_mapping(cls, merged, source=source, prefix=section)
