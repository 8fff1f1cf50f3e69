"""One ``wait_until`` and one ``hold_for`` instead of ad-hoc polling loops.

The clock and the sleep are injected, so shells can wait in wall time, ROS time
or simulation time, and tests can run them against a fake clock.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

from uav_common.errors import WaitTimeoutError

T = TypeVar("T")

__all__ = ["hold_for", "wait_until"]


def wait_until(
    probe: Callable[[], T],
    predicate: Callable[[T], bool],
    *,
    timeout_s: float,
    describe: str,
    poll_s: float = 0.05,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> T:
    """Poll ``probe()`` until ``predicate(value)`` holds; return that value.

    Raises:
        WaitTimeoutError: the predicate did not hold within ``timeout_s``; the
            error carries ``describe`` and the last probed value.
    """
    deadline = clock() + timeout_s
    value = probe()
    while not predicate(value):
        if clock() >= deadline:
            raise WaitTimeoutError(describe, timeout_s, value)
        sleep(poll_s)
        value = probe()
    return value


def hold_for(
    probe: Callable[[], T],
    predicate: Callable[[T], bool],
    *,
    duration_s: float,
    describe: str,
    poll_s: float = 0.05,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> T:
    """Require ``predicate(probe())`` to hold continuously for ``duration_s``.

    Raises:
        WaitTimeoutError: the predicate failed at some point; ``last_value`` is the
            offending value.
    """
    end = clock() + duration_s
    value = probe()
    while True:
        if not predicate(value):
            msg = f"{describe} (stopped holding)"
            raise WaitTimeoutError(msg, duration_s, value)
        if clock() >= end:
            return value
        sleep(poll_s)
        value = probe()
