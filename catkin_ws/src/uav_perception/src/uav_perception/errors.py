"""The one exception hierarchy of :mod:`uav_perception`.

Every error raised on purpose by the package derives from :class:`PerceptionError`.
Configuration mistakes are :class:`PerceptionConfigError`, also a
:class:`uav_common.errors.ConfigError`. :class:`DepthError` lets callers catch everything
the depth estimation and evaluation code raises at once.
"""

from __future__ import annotations

from uav_common.errors import ConfigError

__all__ = ["DepthError", "DepthGeometryError", "DepthInputError", "PerceptionConfigError", "PerceptionError"]


class PerceptionError(Exception):
    """Root of every error raised on purpose by :mod:`uav_perception`."""


class PerceptionConfigError(PerceptionError, ConfigError):
    """A settings file, section, key or private parameter of a perception node is wrong."""


class DepthError(PerceptionError):
    """Root of every error raised by the depth estimation and evaluation code."""


class DepthInputError(DepthError):
    """An input is malformed: wrong image shape or dtype, mismatched sizes, bad intrinsics."""


class DepthGeometryError(DepthError):
    """A camera pose or a stereo geometry is unusable (NaN pose, degenerate baseline)."""
