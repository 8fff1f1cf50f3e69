"""Exception hierarchy of :mod:`uav_autonomy`.

Every error raised on purpose by the package derives from :class:`UavAutonomyError`.
Configuration mistakes are :class:`AutonomyConfigError`, which is also a
:class:`uav_common.errors.ConfigError`; a link that cannot be opened is also a
:class:`uav_common.errors.ResourceError` (the exit codes of ``uav_common.exit_codes``).
"""

from __future__ import annotations

from uav_common.errors import ConfigError, ResourceError


class UavAutonomyError(Exception):
    """Root of every error raised on purpose by :mod:`uav_autonomy`."""


class AutonomyConfigError(UavAutonomyError, ConfigError):
    """A settings file, section, key or private parameter of an autonomy node is wrong."""


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


class MavlinkLinkError(ControllerError, ResourceError):
    """The MAVLink connection cannot be opened or used."""
