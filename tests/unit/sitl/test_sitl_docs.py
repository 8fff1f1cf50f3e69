"""docs/sitl.md's parameter and configuration tables match the code, row by row, both ways.

Each table is parsed: a row names one or more keys (``a.b``, ``.c`` continues the last prefix,
``{x,y}`` expands, ``links.gcs.*`` covers a section) and their defaults in the same order. Every
parameter and every configuration key must be in a row, every documented name must exist, and
where a default is written as a value it must be the code's.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import re
from pathlib import Path
from typing import Any

import pytest
from helpers.paths import REPO

from sitl.config import SitlConfig
from sitl.core.params import PARAM_SPECS, ParamSpec
from sitl.core.params_ardupilot import ARDUCOPTER_PARAM_SPECS

DOC = REPO / "docs" / "sitl.md"


def leaf_defaults(cls: type, prefix: str = "") -> dict[str, Any]:
    """Every leaf key of the config dataclasses and its default."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default  # type: ignore[misc]
        if dataclasses.is_dataclass(default):
            out |= leaf_defaults(type(default), f"{prefix}{f.name}.")
        else:
            out[f"{prefix}{f.name}"] = default
    return out


def table(text: str, header: str) -> list[list[str]]:
    """The rows (cells, stripped) of the markdown table whose header row starts with ``header``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {header} |"))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows


def expand_keys(cell: str) -> list[str]:
    """``\\`a.b\\`, \\`.c\\``` -> ``a.b, a.c``; ``\\`x.{p,q}.r\\``` -> ``x.p.r, x.q.r``."""
    out: list[str] = []
    prefixes = [""]
    for raw in re.findall(r"`([^`]+)`", cell):
        name = raw.split(":")[0].strip()  # `time.mode: lockstep` style cells
        names = [p + name[1:] for p in prefixes] if name.startswith(".") else [name]
        expanded = []
        for n in names:
            m = re.match(r"^(.*)\{([^}]+)\}(.*)$", n)
            expanded += [f"{m.group(1)}{alt}{m.group(3)}" for alt in m.group(2).split(",")] if m else [n]
        out += expanded
        prefixes = [n.rsplit(".", 1)[0] + "." if "." in n else "" for n in expanded]
    return out


def as_value(text: str) -> Any:
    """A documented default as a Python value, or ``...`` when it is prose ("LiPo table")."""
    t = text.strip().strip("`")
    if t in ("null", "none"):
        return None
    if t in ("true", "false"):
        return t == "true"
    try:
        return float(t)
    except ValueError:
        return t if re.fullmatch(r"[a-z_]+", t) else ...


def same(doc: Any, code: Any) -> bool:
    if doc is ...:
        return True
    if isinstance(code, enum.Enum):
        code = code.value
        if doc is None and code == "none":  # an enum member named none (wind.turbulence)
            return True
    if isinstance(code, bool) and doc in ("enabled", "disabled"):
        return code == (doc == "enabled")
    if isinstance(code, Path):
        return True  # written relative to the file in the doc
    if isinstance(doc, float) and isinstance(code, int | float) and not isinstance(code, bool):
        return math.isclose(doc, float(code), rel_tol=1e-9, abs_tol=1e-12)
    return doc == code


TEXT = DOC.read_text()
CONFIG = leaf_defaults(SitlConfig)
CONFIG_ROWS = table(TEXT, "Key")
PARAM_ROWS = table(TEXT, "Parameter")
ARDUPILOT_PARAM_ROWS = table(TEXT, "ArduPilot parameter")


def documented_config_keys() -> dict[str, str]:
    """Documented key -> the default cell's part for it ("" when the row gives none per key)."""
    out: dict[str, str] = {}
    for cells in CONFIG_ROWS:
        keys = expand_keys(cells[0])
        defaults = [d.strip() for d in cells[1].split(",")] if len(keys) > 1 else [cells[1]]
        for i, key in enumerate(keys):
            out[key] = defaults[i] if len(defaults) == len(keys) else ""
    return out


def test_every_config_key_is_in_the_table() -> None:
    documented = documented_config_keys()
    sections = [k[:-2] for k in documented if k.endswith(".*")]
    missing = [k for k in CONFIG if k not in documented and not any(k.startswith(s + ".") for s in sections)]
    assert not missing, f"docs/sitl.md has no row for {missing}"


def test_every_documented_config_key_exists() -> None:
    stale = [k for k in documented_config_keys() if not k.endswith(".*") and k not in CONFIG]
    assert not stale, f"docs/sitl.md documents keys the configuration does not have: {stale}"


def test_documented_config_defaults_are_the_code_defaults() -> None:
    wrong = {
        key: (cell, CONFIG[key])
        for key, cell in documented_config_keys().items()
        if key in CONFIG and cell and not same(as_value(cell), CONFIG[key])
    }
    assert not wrong, f"documented default (doc, code) differs: {wrong}"


def documented_params(rows: list[list[str]] | None = None) -> dict[str, tuple[str, str, str]]:
    """Parameter -> (type, default, range) cells, one per name of a row (PX4's table unless ``rows``)."""
    out: dict[str, tuple[str, str, str]] = {}
    for cells in PARAM_ROWS if rows is None else rows:
        names = re.findall(r"`([A-Z0-9_]+)`", cells[0])
        defaults = [d.strip() for d in cells[2].split(",")]
        for i, name in enumerate(names):
            assert name not in out, f"{name} is documented twice"
            out[name] = (cells[1], defaults[i] if len(defaults) == len(names) else cells[2], cells[3])
    return out


@pytest.mark.parametrize(
    ("spec", "personality"),
    [(s, "px4") for s in PARAM_SPECS] + [(s, "ardupilot") for s in ARDUCOPTER_PARAM_SPECS],
    ids=[s.name for s in PARAM_SPECS] + [f"ardupilot-{s.name}" for s in ARDUCOPTER_PARAM_SPECS],
)
def test_each_parameter_row_matches_the_parameter(spec: ParamSpec, personality: str) -> None:
    rows = documented_params(ARDUPILOT_PARAM_ROWS if personality == "ardupilot" else None)
    assert spec.name in rows, f"docs/sitl.md has no row for {spec.name}"
    ptype, default, rng = rows[spec.name]
    assert ptype == spec.type.name, f"{spec.name}: documented as {ptype}, is {spec.type.name}"
    assert float(default) == pytest.approx(spec.default), f"{spec.name}: documented default {default}"
    span = re.fullmatch(r"(-?[\d.]+) \.\. (-?[\d.]+)", rng)
    if span:
        assert (float(span.group(1)), float(span.group(2))) == pytest.approx((spec.min, spec.max)), spec.name
    elif rng:
        assert spec.choices is not None, f"{spec.name}: documented choices {rng}, but it takes a range"
        assert tuple(int(c) for c in rng.split(",")) == spec.choices, spec.name


def test_every_documented_parameter_exists() -> None:
    names = {s.name for s in PARAM_SPECS}
    stale = sorted(set(documented_params()) - names)
    assert not stale, f"docs/sitl.md documents parameters the autopilot does not have: {stale}"
    ardupilot = {s.name for s in ARDUCOPTER_PARAM_SPECS}
    stale = sorted(set(documented_params(ARDUPILOT_PARAM_ROWS)) - ardupilot)
    assert not stale, f"docs/sitl.md documents ArduPilot parameters the personality does not have: {stale}"


def test_the_parser_sees_mistakes() -> None:
    """The checks above are only as good as the parsing: a wrong row must be caught."""
    assert expand_keys("`links.{gcs,api}.enabled`, `.remote_host`") == [
        "links.gcs.enabled",
        "links.api.enabled",
        "links.gcs.remote_host",
        "links.api.remote_host",
    ]
    assert expand_keys("`home.lat_deg`, `home.lon_deg`") == ["home.lat_deg", "home.lon_deg"]
    assert expand_keys("`estimator.horizontal_noise_m`, `.vertical_noise_m`")[1] == "estimator.vertical_noise_m"
    assert not same(as_value("250"), 200)
    assert not same(as_value("free"), "lockstep")
    assert same(as_value("LiPo table"), ((0.0, 3.27),))
