"""Waiting for a transform with a deadline that belongs to the message, not to the moment it is handled.

A node that handles its messages in a queue (the geolocator) must not wait anew for each one: if the first frames
of a run come before the first transform, each waited its full timeout while a lockstep simulation ran on, the
node fell further behind at every frame, the frames it reached were older than the transforms still buffered, and
it placed nothing for the rest of the run (a CI run of the learned-detector search: 97 of 1671 frames handled,
none placed). So the deadline is the message's arrival plus the timeout, and a stamp older than what the buffer
holds ("extrapolation into the past") fails at once: that transform can no longer arrive.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import tf2_ros

__all__ = ["lookup_until"]

_FAILURES = (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException)


def lookup_until(
    buffer: Any,
    target_frame: str,
    source_frame: str,
    stamp: Any,
    deadline_wall_s: float,
    *,
    stop: Callable[[], bool] = lambda: False,
    poll_s: float = 0.005,
) -> tuple[Any | None, str]:
    """``buffer.lookup_transform(target_frame, source_frame, stamp)``, retried until ``deadline_wall_s``
    (``time.monotonic``) or ``stop()``; returns ``(transform, "")`` or ``(None, why)``.

    A stamp older than the buffer's oldest transform fails at once (waiting cannot help).
    """
    while True:
        try:
            return buffer.lookup_transform(target_frame, source_frame, stamp), ""
        except _FAILURES as err:
            past = isinstance(err, tf2_ros.ExtrapolationException) and "into the past" in str(err)
            if past or time.monotonic() >= deadline_wall_s or stop():
                return None, str(err)
        time.sleep(poll_s)
