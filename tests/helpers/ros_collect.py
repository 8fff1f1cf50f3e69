"""Every message of a topic, kept for a ROS-tier check to look at (thread-safe; rospy calls back in its threads)."""

from __future__ import annotations

import threading
from typing import Any

import rospy

__all__ = ["Collector"]


class Collector:
    """Subscribes to ``topic`` and keeps every message; :meth:`snapshot` returns a copy of what came so far."""

    def __init__(self, topic: str, cls: type, *, queue_size: int = 500, buff_size: int = 2**25) -> None:
        self.msgs: list[Any] = []
        self._lock = threading.Lock()
        rospy.Subscriber(topic, cls, self._cb, queue_size=queue_size, buff_size=buff_size)

    def _cb(self, msg: object) -> None:
        with self._lock:
            self.msgs.append(msg)

    def snapshot(self) -> list[Any]:
        with self._lock:
            return list(self.msgs)
