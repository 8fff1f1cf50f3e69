"""Exception hierarchy of :mod:`uav_autonomy`.

Every error raised on purpose by the package derives from :class:`UavAutonomyError`.
Other components of the package may add subclasses here. Configuration files are
loaded by :mod:`uav_common.config`, whose :class:`uav_common.errors.ConfigError` is
re-used as-is rather than duplicated.
"""

from __future__ import annotations


class UavAutonomyError(Exception):
    """Root of every error raised on purpose by :mod:`uav_autonomy`."""


class InvalidInputError(UavAutonomyError, ValueError):
    """An input is malformed: NaN/inf coordinates, mismatched layer shapes, empty grids.

    The message says which input and what was expected; nothing the caller held
    has been changed when it is raised.
    """


class PlanningError(UavAutonomyError):
    """The path planner cannot produce a path."""


class NoPathError(PlanningError):
    """No collision-free path exists under the planner's constraints."""


class ControllerError(UavAutonomyError):
    """The waypoint controller cannot do what was asked."""


class InvalidTransitionError(ControllerError):
    """A requested controller state change is not allowed from the current state."""


class MavlinkLinkError(ControllerError):
    """The MAVLink connection cannot be opened or used."""
