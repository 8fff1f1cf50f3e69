"""One ``wait_until`` (and its asyncio twin) and one ``hold_for`` instead of ad-hoc polling loops.

The clock and the sleep are injected, so shells can wait in wall time, ROS time
or simulation time, and tests can run them against a fake clock. ``check`` runs at
every poll and may raise to abandon the wait early (a process the wait depends on died).
"""

from __future__ import annotations

import asyncio
import time
from collections.abc import Awaitable, Callable
from typing import TypeVar

from uav_common.errors import WaitTimeoutError

T = TypeVar("T")

__all__ = ["hold_for", "wait_until", "wait_until_async"]


def wait_until(
    probe: Callable[[], T],
    predicate: Callable[[T], bool],
    *,
    timeout_s: float,
    describe: str,
    poll_s: float = 0.05,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    check: Callable[[], None] | None = None,
) -> T:
    """Poll ``probe()`` until ``predicate(value)`` holds; return that value.

    Raises:
        WaitTimeoutError: the predicate did not hold within ``timeout_s``; the
            error carries ``describe`` and the last probed value.
        Exception: whatever ``check`` raises.
    """
    deadline = clock() + timeout_s
    value = probe()
    while not predicate(value):
        if check is not None:
            check()
        if clock() >= deadline:
            raise WaitTimeoutError(describe, timeout_s, value)
        sleep(poll_s)
        value = probe()
    return value


async def wait_until_async(
    probe: Callable[[], Awaitable[T]],
    predicate: Callable[[T], bool],
    *,
    timeout_s: float,
    describe: str,
    poll_s: float = 0.1,
    clock: Callable[[], float] = time.monotonic,
) -> T:
    """:func:`wait_until` for an awaitable probe (a MAVSDK getter), sleeping with ``asyncio.sleep``.

    Raises:
        WaitTimeoutError: the predicate did not hold within ``timeout_s``.
    """
    deadline = clock() + timeout_s
    value = await probe()
    while not predicate(value):
        if clock() >= deadline:
            raise WaitTimeoutError(describe, timeout_s, value)
        await asyncio.sleep(poll_s)
        value = await probe()
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
