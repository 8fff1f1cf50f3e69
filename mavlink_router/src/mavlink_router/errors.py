"""Exception hierarchy of :mod:`mavlink_router`.

Every error the package raises derives from :class:`RouterError`; only the CLI's
``main()`` turns them into a log line and an exit status. A configuration error is also a
:class:`uav_common.errors.ConfigError` and an endpoint that cannot be opened a
:class:`uav_common.errors.ResourceError`, as in every package of the project.
"""

from __future__ import annotations

from uav_common.errors import ConfigError as CommonConfigError
from uav_common.errors import ResourceError


class RouterError(Exception):
    """Root of every error raised by :mod:`mavlink_router`."""


class ConfigError(RouterError, CommonConfigError):
    """A configuration file, a command-line option or a key file is invalid.

    The message names the source (file and line, or the option), the section and
    key, what was wrong and what to do, so it can be shown to a user as-is.
    """


class DialectError(RouterError):
    """The MAVLink message table could not be built from the requested dialect."""


class EndpointError(RouterError, ResourceError):
    """An endpoint could not be opened (socket, bind, serial device)."""


class SerialUnavailableError(EndpointError):
    """A serial endpoint was configured but pyserial is not installed."""


class LockstepError(RouterError):
    """The lockstep's step markers broke (docs/mavlink_router.md, "Lockstep"): a count that does not balance (a
    lost or duplicated message), a marker for an unexpected step, a malformed marker. The router stops with exit
    status 1; the message names the endpoint, the step and the counts."""
