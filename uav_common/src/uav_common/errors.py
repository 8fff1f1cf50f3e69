"""Exception hierarchy of :mod:`uav_common`, and the two error kinds every package shares.

Every package has one root error (``SitlError``, ``SimBridgeError``, ``UavAutonomyError``,
``PerceptionError``, ``ScenarioError``...). Two kinds of failure cut across them, and each
package's own class for them derives from both its root and the shared kind, so a caller
can catch either (``except ScenarioError`` or ``except ConfigError``):

* :class:`ConfigError`: a configuration file, parameter or argument is wrong. The user fixes
  the input; programs exit with :attr:`uav_common.exit_codes.ExitCode.CONFIG`.
* :class:`ResourceError`: something the program needs is not available (a port in use, no
  EGL/GL, a missing build product). Programs exit with ``ExitCode.RESOURCE``.
"""

from __future__ import annotations

__all__ = ["ConfigError", "ResourceError", "StopRequestedError", "UavCommonError", "WaitTimeoutError"]


class UavCommonError(Exception):
    """Root of every error raised by :mod:`uav_common`."""


class ConfigError(UavCommonError):
    """A configuration file, mapping, parameter or argument is missing, malformed or invalid.

    The message always names the source (file or parameter namespace), the key
    and what was expected, so it can be shown to a user as-is.
    """


class ResourceError(UavCommonError):
    """A resource the program needs is unavailable: a port in use, no GL context, a missing build product.

    The message names the resource and what to do (free the port, install the package, ``make build``).
    """


class WaitTimeoutError(UavCommonError):
    """A :func:`uav_common.waiting.wait_until` condition did not hold in time."""

    def __init__(self, describe: str, timeout_s: float, last_value: object) -> None:
        super().__init__(f"timed out after {timeout_s:.1f} s waiting for {describe}; last value: {last_value!r}")
        self.describe = describe
        self.timeout_s = timeout_s
        self.last_value = last_value


class StopRequestedError(UavCommonError):
    """A wait ended because the program is shutting down (e.g. a node's SIGINT), not because of a failure."""
