"""The one exception hierarchy of :mod:`uav_perception`.

Every error raised on purpose by the package derives from :class:`PerceptionError`.
Configuration mistakes are :class:`PerceptionConfigError`, also a
:class:`uav_common.errors.ConfigError`. :class:`DepthError` lets callers catch everything
the depth estimation and evaluation code raises at once, :class:`DetectionError` what the
detection contract, the geolocation and the stand-in detector raise.
"""

from __future__ import annotations

from uav_common.errors import ConfigError, ResourceError

__all__ = [
    "DepthError",
    "DepthGeometryError",
    "DepthInputError",
    "DetectionError",
    "DetectionInputError",
    "ModelFileError",
    "ModelFormatError",
    "PerceptionConfigError",
    "PerceptionError",
    "TerrainFileError",
]


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


class DetectionError(PerceptionError):
    """Root of every error raised by the detection contract, geolocation and the stand-in detector."""


class DetectionInputError(DetectionError):
    """A detection input is malformed: intrinsics, image sizes, a depth image that does not match."""


class TerrainFileError(DetectionError, ResourceError):
    """A terrain model (DEM) file is missing, unreadable or malformed (the message names it)."""


class ModelFileError(DetectionError, ResourceError):
    """A detector model file is missing, unreadable or not a model the runtime can load (the message names it)."""


class ModelFormatError(ModelFileError):
    """A detector model loads but its inputs or outputs are not the documented format (docs/detector.md)."""
