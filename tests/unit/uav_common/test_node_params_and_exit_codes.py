"""A node's ~params are parsed strictly (uav_common.ros.params); the exit code follows the error kind."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import pytest

from uav_common.config import ConfigError
from uav_common.errors import ResourceError, UavCommonError
from uav_common.exit_codes import ExitCode, exit_code_for
from uav_common.ros.params import parse_node_params


@dataclass(frozen=True)
class Run:
    person: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Params:
    scenario: str
    gate_m: float = 5.0
    min_hits: int = 2
    pose_source: Literal["tf", "odom"] = "tf"
    cameras: tuple[str, ...] = ("nadir",)
    run: Run = field(default_factory=Run)


def test_parameters_become_a_frozen_dataclass() -> None:
    p = parse_node_params(
        Params, {"scenario": "s.yaml", "gate_m": 3, "cameras": ["a", "b"], "run": {"person": {"id": 7}}}, node="n"
    )
    assert p == Params("s.yaml", 3.0, 2, "tf", ("a", "b"), Run({"id": 7}))


@pytest.mark.parametrize(
    ("raw", "match"),
    [
        ({"scenario": "s", "gate": 3}, r"tracker: unknown private parameter\(s\) ~gate; this node takes: ~cameras, "),
        ({"scenario": "s", "gate_m": "5"}, r"key 'gate_m' expected a number, got str '5'"),
        ({"scenario": "s", "min_hits": 2.5}, r"key 'min_hits' expected an integer"),
        ({"scenario": "s", "pose_source": "gps"}, r"key 'pose_source' expected one of 'tf', 'odom'"),
        ({"scenario": "s", "run": {"persn": {}}}, r"'run' has unknown key\(s\) 'persn'"),
        ({}, r"required key 'scenario' is missing"),
    ],
)
def test_unknown_or_mistyped_parameters_stop_the_node_naming_them(raw: dict[str, Any], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        parse_node_params(Params, raw, node="tracker")


def test_exit_codes_follow_the_error_kind() -> None:
    assert exit_code_for(ConfigError("x")) is ExitCode.CONFIG == 2
    assert exit_code_for(ResourceError("port busy")) is ExitCode.RESOURCE == 3
    assert exit_code_for(UavCommonError("x")) is ExitCode.FAILURE == 1
    assert exit_code_for(RuntimeError("x")) is ExitCode.FAILURE
