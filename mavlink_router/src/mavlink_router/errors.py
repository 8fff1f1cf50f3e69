"""Exception hierarchy of :mod:`mavlink_router`.

Every error the package raises derives from :class:`RouterError`; only the CLI's
``main()`` turns them into a log line and an exit status.
"""

from __future__ import annotations


class RouterError(Exception):
    """Root of every error raised by :mod:`mavlink_router`."""


class ConfigError(RouterError):
    """A configuration file, a command-line option or a key file is invalid.

    The message names the source (file and line, or the option), the section and
    key, what was wrong and what to do, so it can be shown to a user as-is.
    """


class DialectError(RouterError):
    """The MAVLink message table could not be built from the requested dialect."""


class EndpointError(RouterError):
    """An endpoint could not be opened (socket, bind, serial device)."""


class SerialUnavailableError(EndpointError):
    """A serial endpoint was configured but pyserial is not installed."""
