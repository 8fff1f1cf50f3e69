"""Exception hierarchy of :mod:`uav_common`."""

from __future__ import annotations


class UavCommonError(Exception):
    """Root of every error raised by :mod:`uav_common`."""


class ConfigError(UavCommonError):
    """A configuration file or mapping is missing, malformed or invalid.

    The message always names the source (file or parameter namespace), the key
    and what was expected, so it can be shown to a user as-is.
    """


class WaitTimeoutError(UavCommonError):
    """A :func:`uav_common.waiting.wait_until` condition did not hold in time."""

    def __init__(self, describe: str, timeout_s: float, last_value: object) -> None:
        super().__init__(f"timed out after {timeout_s:.1f} s waiting for {describe}; last value: {last_value!r}")
        self.describe = describe
        self.timeout_s = timeout_s
        self.last_value = last_value
