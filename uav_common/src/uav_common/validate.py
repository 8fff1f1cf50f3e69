"""Validators for configuration dataclasses and algorithm inputs, written once.

Each raises ``error`` (default :class:`ValueError`, which :func:`uav_common.config.from_mapping`
turns into a :class:`~uav_common.errors.ConfigError` naming the file and key) with a message
that names the value and what was expected. Pure: no I/O.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "require",
    "require_finite",
    "require_finite_vector",
    "require_in_range",
    "require_non_negative",
    "require_port",
    "require_positive",
]


def require(condition: bool, message: str, *, error: type[Exception] = ValueError) -> None:
    """Raise ``error(message)`` unless ``condition`` holds."""
    if not condition:
        raise error(message)


def require_finite(name: str, value: float, *, error: type[Exception] = ValueError) -> float:
    """``value`` as a float; it must be finite (not NaN or infinite)."""
    if not math.isfinite(value):
        msg = f"{name} must be finite, got {value}"
        raise error(msg)
    return float(value)


def require_positive(name: str, value: float, *, error: type[Exception] = ValueError) -> float:
    """``value`` as a float; it must be finite and > 0."""
    if not (math.isfinite(value) and value > 0.0):
        msg = f"{name} must be a finite number > 0, got {value}"
        raise error(msg)
    return float(value)


def require_non_negative(name: str, value: float, *, error: type[Exception] = ValueError) -> float:
    """``value`` as a float; it must be finite and >= 0."""
    if not (math.isfinite(value) and value >= 0.0):
        msg = f"{name} must be a finite number >= 0, got {value}"
        raise error(msg)
    return float(value)


def require_in_range(name: str, value: float, low: float, high: float, *, error: type[Exception] = ValueError) -> float:
    """``value`` as a float; it must lie in ``[low, high]``."""
    if not (math.isfinite(value) and low <= value <= high):
        msg = f"{name} must be in [{low:g}, {high:g}], got {value}"
        raise error(msg)
    return float(value)


def require_finite_vector(
    name: str, value: object, size: int, *, error: type[Exception] = ValueError
) -> tuple[float, ...]:
    """``value`` (a list, tuple or array of any shape) as a tuple of ``size`` finite floats."""
    try:
        arr = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as err:
        msg = f"{name}: expected {size} numbers, got {value!r}"
        raise error(msg) from err
    if arr.size != size or not np.isfinite(arr).all():
        msg = f"{name}: expected {size} finite numbers, got {arr.tolist()}"
        raise error(msg)
    return tuple(float(v) for v in arr)


def require_port(name: str, port: int, *, allow_zero: bool = False, error: type[Exception] = ValueError) -> int:
    """A TCP/UDP port number: 1..65535 (0 too with ``allow_zero``: "any free port")."""
    low = 0 if allow_zero else 1
    if not low <= port <= 65535:
        msg = f"'{name}' must be a port in [{low}, 65535], got {port}"
        raise error(msg)
    return port
