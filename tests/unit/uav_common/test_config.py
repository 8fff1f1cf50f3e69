from __future__ import annotations

import enum
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest

from uav_common.config import (
    ConfigError,
    config_errors_as,
    deep_merge,
    from_mapping,
    load_config,
    set_dotted,
    to_mapping,
)


class Mode(enum.Enum):
    HOLD = "hold"
    RTL = "rtl"


@dataclass(frozen=True)
class Battery:
    capacity_mah: float = 5000.0
    cells: int = 4

    def __post_init__(self) -> None:
        if self.capacity_mah <= 0:
            msg = f"capacity_mah must be > 0, got {self.capacity_mah}"
            raise ValueError(msg)


@dataclass(frozen=True)
class Vehicle:
    name: str
    battery: Battery = field(default_factory=Battery)
    action: Mode = Mode.HOLD
    home: tuple[float, float, float] = (47.0, 8.0, 400.0)
    ports: tuple[int, ...] = ()
    link: Literal["udp", "tcp"] = "udp"
    key_file: Path | None = None
    weights: dict[str, float] = field(default_factory=dict)


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "vehicle.yaml"
    path.write_text(text)
    return path


def test_full_file_loads_into_frozen_dataclasses(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        "name: f450\nbattery: {capacity_mah: 4000, cells: 3}\naction: rtl\nhome: [1, 2, 3]\n"
        "ports: [14550, 14540]\nlink: tcp\nkey_file: /tmp/key\nweights: {age: 1, frontier: 0.5}\n",
    )
    cfg = load_config(Vehicle, path)
    assert cfg.battery == Battery(4000.0, 3)
    assert isinstance(cfg.battery.capacity_mah, float)
    assert cfg.action is Mode.RTL
    assert cfg.home == (1.0, 2.0, 3.0)
    assert cfg.ports == (14550, 14540)
    assert cfg.key_file == Path("/tmp/key")
    assert cfg.weights == {"age": 1.0, "frontier": 0.5}
    with pytest.raises(AttributeError):
        cfg.name = "other"  # type: ignore[misc]
    assert from_mapping(Vehicle, to_mapping(cfg), source="roundtrip") == cfg


def test_defaults_apply_and_enum_accepts_name(tmp_path: Path) -> None:
    cfg = load_config(Vehicle, write(tmp_path, "name: x\naction: RTL\n"))
    assert cfg.battery == Battery()
    assert cfg.action is Mode.RTL


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (
            "name: x\nbatery: {}\n",
            r"vehicle.yaml: top level has unknown key\(s\) 'batery'; known keys: action, battery",
        ),
        ("name: x\nbattery: {capacity: 1}\n", r"'battery' has unknown key\(s\) 'capacity'"),
        ("name: x\nbattery: {cells: 3.5}\n", r"key 'battery.cells' expected an integer, got float 3.5"),
        ("name: x\nbattery: {capacity_mah: big}\n", r"key 'battery.capacity_mah' expected a number, got str 'big'"),
        ("name: x\nbattery: {capacity_mah: -1}\n", r"'battery': capacity_mah must be > 0, got -1.0"),
        ("name: x\naction: land\n", r"key 'action' expected one of 'hold', 'rtl'"),
        ("name: x\nhome: [1, 2]\n", r"key 'home' expected a list of exactly 3 items"),
        ("name: x\nports: [1, a]\n", r"key 'ports\[1\]' expected an integer"),
        ("name: x\nlink: serial\n", r"key 'link' expected one of 'udp', 'tcp'"),
        ("battery: {}\n", r"required key 'name' is missing"),
        ("name: [unclosed\n", r"not valid YAML"),
        ("- a\n- b\n", r"top level must be a mapping"),
        ("name: true\n", r"key 'name' expected a string, got bool True"),
    ],
)
def test_bad_files_name_file_key_and_expectation(tmp_path: Path, text: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_config(Vehicle, write(tmp_path, text))


def test_missing_file_says_what_to_do(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope.yaml: config file not found"):
        load_config(Vehicle, tmp_path / "nope.yaml")


def test_section_loading(tmp_path: Path) -> None:
    path = write(tmp_path, "vehicle:\n  name: a\nother: 1\n")
    assert load_config(Vehicle, path, section="vehicle").name == "a"
    with pytest.raises(ConfigError, match="missing section 'nothing'"):
        load_config(Vehicle, path, section="nothing")


# ---- deep_merge, set_dotted, config_errors_as: the one override merge of every package ----


def test_deep_merge_merges_mappings_at_every_depth_and_replaces_the_rest() -> None:
    base = {"cameras": {"nadir": {"rate_hz": 10, "hfov_deg": 90}}, "list": [1, 2], "x": 1}
    merged = deep_merge(base, {"cameras": {"nadir": {"rate_hz": 5}, "forward": {}}, "list": [3], "x": None})
    assert merged == {"cameras": {"nadir": {"rate_hz": 5, "hfov_deg": 90}, "forward": {}}, "list": [3], "x": None}


def test_deep_merge_never_changes_or_shares_its_inputs() -> None:
    """A copy that drifted mutated the caller's defaults; the result must own every mutable value."""
    base = {"a": {"b": [1, 2]}, "c": {"d": 1}}
    over = {"c": {"e": [9]}}
    merged = deep_merge(base, over)
    merged["a"]["b"].append(3)
    merged["c"]["e"].append(10)
    assert base == {"a": {"b": [1, 2]}, "c": {"d": 1}}
    assert over == {"c": {"e": [9]}}


def test_a_mapping_replaces_a_scalar_and_a_scalar_a_mapping() -> None:
    assert deep_merge({"a": 1}, {"a": {"b": 2}}) == {"a": {"b": 2}}
    assert deep_merge({"a": {"b": 2}}, {"a": 3}) == {"a": 3}


def test_set_dotted_builds_sections_and_refuses_to_descend_into_a_value() -> None:
    data: dict[str, object] = {"links": {"gcs": {"port": 1}}}
    set_dotted(data, "links.gcs.port", 14550)
    set_dotted(data, "links.api.enabled", False)
    assert data == {"links": {"gcs": {"port": 14550}, "api": {"enabled": False}}}
    with pytest.raises(ConfigError, match="'port' is not a section"):
        set_dotted(data, "links.gcs.port.x", 1)
    with pytest.raises(ConfigError, match="empty key part"):
        set_dotted(data, "links..x", 1)


class _PkgError(Exception):
    pass


class _PkgConfigError(_PkgError, ConfigError):
    pass


def test_config_errors_become_the_packages_own_with_the_same_message() -> None:
    with pytest.raises(_PkgConfigError, match="bad key") as caught, config_errors_as(_PkgConfigError):
        raise ConfigError("x.yaml: bad key")
    assert isinstance(caught.value, _PkgError)  # a caller catching the package's root sees it
    assert isinstance(caught.value.__cause__, ConfigError)
    with pytest.raises(ValueError, match="other"), config_errors_as(_PkgConfigError):
        raise ValueError("other")  # other errors pass through untouched
