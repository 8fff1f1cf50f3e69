"""Strict YAML -> frozen dataclass loading, shared by every component.

Config is data: each component describes its settings as ``@dataclass(frozen=True)``
classes with units in the field names (``capacity_mah``, ``rate_hz``) and defaults
next to the fields.  :func:`load_config` parses a YAML file once, at start-up, and
returns an instance; anything wrong fails immediately with a :class:`ConfigError`
that names the file, the key and what was expected.

Rules:

* An unknown key is an error (typos must not be silently ignored).
* Types are checked, not coerced, with two deliberate exceptions: an ``int`` is
  accepted where a ``float`` is expected, and a YAML list is accepted for a
  ``tuple`` field.
* Supported field types: ``bool``, ``int``, ``float``, ``str``, ``pathlib.Path``,
  ``Enum`` subclasses (by value or by name), ``Literal[...]``, ``X | None``,
  ``tuple[X, ...]``, ``tuple[X, Y]``, ``dict[str, X]`` and nested dataclasses.
* A dataclass may validate cross-field rules in ``__post_init__`` by raising
  ``ValueError``; the message is wrapped with the file and section it came from.

Example::

    @dataclass(frozen=True)
    class Battery:
        capacity_mah: float = 5000.0
        cells: int = 4

    cfg = load_config(Battery, Path("config/battery.yaml"))
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import enum
import math
import types
import typing
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any, TypeVar

import yaml

from uav_common.errors import ConfigError

T = TypeVar("T")

__all__ = [
    "ConfigError",
    "config_errors_as",
    "deep_merge",
    "from_mapping",
    "load_config",
    "load_yaml_mapping",
    "set_dotted",
    "to_mapping",
]


def load_yaml_mapping(path: Path) -> dict[str, Any]:
    """Read a YAML file whose top level is a mapping.

    Raises:
        ConfigError: the file is missing, unreadable, not YAML or not a mapping.
    """
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError as err:
        msg = f"{path}: config file not found; pass an existing file (see config/ for examples)"
        raise ConfigError(msg) from err
    except OSError as err:
        msg = f"{path}: cannot read config file: {err.strerror}"
        raise ConfigError(msg) from err
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        msg = f"{path}: not valid YAML: {err}"
        raise ConfigError(msg) from err
    if data is None:
        return {}
    if not isinstance(data, dict):
        msg = f"{path}: top level must be a mapping of settings, got {type(data).__name__}"
        raise ConfigError(msg)
    return data


@contextlib.contextmanager
def config_errors_as(cls: type[ConfigError]) -> Iterator[None]:
    """Re-raise a :class:`ConfigError` from the block as ``cls``, a package's own config error.

    Each package's config error derives from both its root error and :class:`ConfigError`
    (``class ScenarioConfigError(ScenarioError, ConfigError)``), so a caller catching the
    package's root catches configuration mistakes too. The message is kept as it is.
    """
    try:
        yield
    except cls:
        raise
    except ConfigError as err:
        raise cls(str(err)) from err


def deep_merge(base: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``overrides`` merged over ``base``, as a new dict; neither input is changed.

    Mappings merge key by key, at every depth; any other value in ``overrides`` (a list,
    a scalar, ``None``) replaces the one in ``base`` whole. The result shares no mutable
    value with either input, so changing it never changes a caller's defaults.
    """
    out: dict[str, Any] = {str(k): copy.deepcopy(v) for k, v in base.items()}
    for key, value in overrides.items():
        current = out.get(key)
        if isinstance(value, Mapping) and isinstance(current, Mapping):
            out[key] = deep_merge(current, value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def set_dotted(data: dict[str, Any], dotted_key: str, value: Any) -> None:
    """Set ``a.b.c = value`` in a nested dict, creating sections as needed (``--set a.b.c=value``).

    Raises:
        ConfigError: an intermediate key holds a value that is not a mapping.
    """
    parts = dotted_key.split(".")
    if not all(parts):
        msg = f"cannot set {dotted_key!r}: empty key part (use section.key)"
        raise ConfigError(msg)
    node = data
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            msg = f"cannot set '{dotted_key}': '{part}' is not a section"
            raise ConfigError(msg)
        node = child
    node[parts[-1]] = value


def load_config(cls: type[T], path: Path, *, section: str | None = None) -> T:
    """Load ``path`` (optionally one top-level ``section`` of it) into ``cls``.

    Raises:
        ConfigError: on any missing file, syntax error, unknown key, wrong type or
            failed validation, with the file and key in the message.
    """
    data: Any = load_yaml_mapping(path)
    if section is not None:
        if section not in data:
            msg = f"{path}: missing section '{section}'"
            raise ConfigError(msg)
        data = data[section]
    return from_mapping(cls, data, source=str(path), prefix=section or "")


def from_mapping(cls: type[T], data: Any, *, source: str, prefix: str = "") -> T:
    """Build dataclass ``cls`` from a plain mapping (e.g. parsed YAML or rosparams).

    Args:
        cls: a dataclass type.
        data: mapping of field name to value; missing fields take their defaults.
        source: where the data came from, used in error messages (a file path,
            ``"rosparam ~"``, ``"--set"``...).
        prefix: dotted key prefix of ``data`` inside ``source``.

    Raises:
        ConfigError: unknown key, wrong type, missing required field, or a
            ``ValueError`` raised by the dataclass's own validation.
    """
    if not dataclasses.is_dataclass(cls):
        msg = f"{cls!r} is not a dataclass"
        raise TypeError(msg)
    where = f"{source}: '{prefix}'" if prefix else f"{source}: top level"
    if not isinstance(data, Mapping):
        msg = f"{where} must be a mapping, got {_describe(data)}"
        raise ConfigError(msg)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(str(k) for k in data if k not in fields)
    if unknown:
        known = ", ".join(sorted(fields))
        msg = f"{where} has unknown key(s) {', '.join(repr(u) for u in unknown)}; known keys: {known}"
        raise ConfigError(msg)
    kwargs: dict[str, Any] = {}
    for name, field in fields.items():
        key = f"{prefix}.{name}" if prefix else name
        if name in data:
            kwargs[name] = _convert(hints[name], data[name], source=source, key=key)
        elif field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
            msg = f"{source}: required key '{key}' is missing"
            raise ConfigError(msg)
    try:
        return cls(**kwargs)
    except ValueError as err:
        msg = f"{where}: {err}"
        raise ConfigError(msg) from err


def to_mapping(obj: Any) -> Any:
    """Inverse of :func:`from_mapping`: plain YAML-able data (enums by value, tuples as lists)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_mapping(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, enum.Enum):
        return obj.value
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, tuple | list):
        return [to_mapping(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): to_mapping(v) for k, v in obj.items()}
    return obj


def _describe(value: Any) -> str:
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{type(value).__name__} {text}"


def _type_name(tp: Any) -> str:
    if isinstance(tp, type):
        return tp.__name__
    return str(tp).replace("typing.", "")


def _convert(tp: Any, value: Any, *, source: str, key: str) -> Any:  # noqa: PLR0911, PLR0912
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)

    def fail(expected: str) -> ConfigError:
        return ConfigError(f"{source}: key '{key}' expected {expected}, got {_describe(value)}")

    if tp is Any:
        return value
    if origin is typing.Union or origin is types.UnionType:
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        errors = []
        for option in options:
            try:
                return _convert(option, value, source=source, key=key)
            except ConfigError as err:
                errors.append(err)
        if len(options) == 1:
            raise errors[0]
        raise fail(" or ".join(_type_name(o) for o in args))
    if origin is typing.Literal:
        if value in args:
            return value
        raise fail("one of " + ", ".join(repr(a) for a in args))
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return from_mapping(tp, value, source=source, prefix=key)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        for member in tp:
            if value == member.value or (isinstance(value, str) and value.upper() == member.name):
                return member
        raise fail("one of " + ", ".join(repr(m.value) for m in tp))
    if tp in _SCALARS:
        return _convert_scalar(tp, value, fail)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            msg = f"a list ({_type_name(tp)})"
            raise fail(msg)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(args[0], v, source=source, key=f"{key}[{i}]") for i, v in enumerate(value))
        if len(value) != len(args):
            msg = f"a list of exactly {len(args)} items"
            raise fail(msg)
        return tuple(
            _convert(a, v, source=source, key=f"{key}[{i}]") for i, (a, v) in enumerate(zip(args, value, strict=True))
        )
    if origin is dict:
        if not isinstance(value, Mapping):
            msg = "a mapping"
            raise fail(msg)
        key_tp, val_tp = args
        return {
            _convert(key_tp, k, source=source, key=f"{key}.{k}"): _convert(val_tp, v, source=source, key=f"{key}.{k}")
            for k, v in value.items()
        }
    msg = f"unsupported config field type {tp!r} for key '{key}'"
    raise TypeError(msg)


_SCALARS = (bool, int, float, str, Path)


def _convert_scalar(tp: Any, value: Any, fail: Callable[[str], ConfigError]) -> Any:
    if tp is bool:
        if isinstance(value, bool):
            return value
        msg = "true or false"
        raise fail(msg)
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        msg = "an integer"
        raise fail(msg)
    if tp is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            out = float(value)
            if math.isnan(out):
                msg = "a number (not NaN)"
                raise fail(msg)
            return out
        msg = "a number"
        raise fail(msg)
    if tp is str:
        if isinstance(value, str):
            return value
        msg = "a string"
        raise fail(msg)
    if tp is Path:
        if isinstance(value, str) and value:
            return Path(value)
        msg = "a file path string"
        raise fail(msg)
    msg = f"unsupported scalar type {tp!r}"
    raise TypeError(msg)
