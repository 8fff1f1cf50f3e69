"""The one exception hierarchy of :mod:`sitl`.

Library code raises these and never prints or exits; only :func:`sitl.cli.main`
turns them into a message and an exit status.
"""

from __future__ import annotations

from uav_common.errors import ConfigError, ResourceError


class SitlError(Exception):
    """Root of every error raised by :mod:`sitl`."""


class SitlConfigError(SitlError, ConfigError):
    """The configuration (file, command line) is invalid (also a :class:`uav_common.errors.ConfigError`).

    The message names the source, the key and what was expected, so it can be
    shown to a user as it is.
    """


class ParamFileError(SitlError):
    """The persisted parameter file cannot be read or written."""


class LinkError(SitlError, ResourceError):
    """A MAVLink link cannot be opened (port busy, bad address, bad signing key)."""


class FdmError(SitlError):
    """JSBSim could not load the aircraft or produced a non-finite state."""


class LockstepError(SitlError):
    """The lockstep's MAVLink step markers broke (docs/lockstep.md): a count that does not balance (a lost or
    duplicated message), a marker for an unexpected step, a malformed marker. The run is no longer
    reproducible; the SITL stops with exit status 1 and this message names the peer and the counts."""
