"""The one exception hierarchy of :mod:`uav_sim_bridge`.

Every error raised on purpose by this package derives from :class:`SimBridgeError`,
so a caller can catch the package's failures without catching programming errors.
Configuration mistakes are :class:`SimBridgeConfigError` (also a
:class:`uav_common.errors.ConfigError`); a renderer or link that cannot be opened is
also a :class:`uav_common.errors.ResourceError`. Messages name the file, key or frame
involved so they can be shown to a user as-is.
"""

from __future__ import annotations

from uav_common.errors import ConfigError, ResourceError

__all__ = [
    "CameraEffectsError",
    "CameraError",
    "CameraFaultError",
    "RenderError",
    "SimBridgeConfigError",
    "SimBridgeError",
    "SimLinkError",
    "WorldError",
    "WorldFileError",
]


class SimBridgeError(Exception):
    """Root of every error raised by :mod:`uav_sim_bridge`."""


class SimBridgeConfigError(SimBridgeError, ConfigError):
    """The bridge's configuration (file, ``~params``, world config) is invalid."""


class WorldError(SimBridgeError):
    """The world cannot be generated from its configuration (e.g. no room for the villages)."""


class WorldFileError(WorldError):
    """A world file (cache, heightmap image, user mesh) is missing, unreadable or malformed."""


class CameraError(SimBridgeError, ValueError):
    """Invalid camera intrinsics, mount, pose or image shape (a ``ValueError`` too, so config loading reports it)."""


class CameraFaultError(SimBridgeError, ValueError):
    """A camera fault names an unknown camera or type (``uav_sim_bridge.core.camera_faults``)."""


class CameraEffectsError(SimBridgeError, ResourceError):
    """The camera-effects process failed a frame, died or could not be started
    (``uav_sim_bridge.shell.effects_process``)."""


class RenderError(SimBridgeError, ResourceError):
    """The OpenGL renderer could not be created or used (no EGL, wrong thread, ...)."""


class SimLinkError(SimBridgeError, ResourceError):
    """The simulation link to the SITL failed (socket error, protocol violation, timeout)."""
