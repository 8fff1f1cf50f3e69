"""Exception hierarchy of :mod:`uav_sim_bridge`.

Every error raised on purpose by this package derives from :class:`SimBridgeError`,
so a caller can catch the package's failures without catching programming errors.
Messages name the file, key or frame involved so they can be shown to a user as-is.
"""

from __future__ import annotations

from uav_common.errors import ConfigError

__all__ = [
    "CameraError",
    "ConfigError",
    "PointCloudLayoutError",
    "RenderError",
    "SimBridgeError",
    "SimLinkError",
    "WorldError",
    "WorldFileError",
]


class SimBridgeError(Exception):
    """Root of every error raised by :mod:`uav_sim_bridge`."""


class WorldError(SimBridgeError):
    """The world cannot be generated from its configuration (e.g. no room for the villages)."""


class WorldFileError(WorldError):
    """A world file (cache, heightmap image, user mesh) is missing, unreadable or malformed."""


class CameraError(SimBridgeError):
    """Invalid camera intrinsics, mount or image shape."""


class RenderError(SimBridgeError):
    """The OpenGL renderer could not be created or used (no EGL, wrong thread, ...)."""


class SimLinkError(SimBridgeError):
    """The simulation link to the SITL failed (socket error, protocol violation, timeout)."""


class PointCloudLayoutError(SimBridgeError):
    """A PointCloud2 does not have the project's x, y, z, rgb float32 layout."""
