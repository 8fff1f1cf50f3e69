"""docs/sitl.md documents every parameter and every configuration key."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from sitl.config import SitlConfig
from sitl.core.params import PARAM_SPECS

DOC = Path(__file__).resolve().parents[3] / "docs" / "sitl.md"


def leaf_keys(cls: type, prefix: str = "") -> list[str]:
    out = []
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default  # type: ignore[misc]
        if dataclasses.is_dataclass(default):
            out += leaf_keys(type(default), f"{prefix}{f.name}.")
        else:
            out.append(f"{prefix}{f.name}")
    return out


def test_every_parameter_is_documented() -> None:
    text = DOC.read_text()
    missing = [s.name for s in PARAM_SPECS if f"`{s.name}`" not in text and f"{s.name}`" not in text]
    assert not missing


def test_every_config_key_is_documented() -> None:
    text = DOC.read_text()
    missing = [key for key in leaf_keys(SitlConfig) if key.rsplit(".", 1)[-1] not in text]
    assert not missing
    sections = {key.split(".")[0] for key in leaf_keys(SitlConfig)}
    assert all(f"`{section}." in text for section in sections)
