"""De-duplication of identical frames within a time window (pure).

Same rule as mavlink-router's ``Dedup`` (``DeduplicationPeriod``): the whole
frame, header and sequence number included, is the key; a frame identical to one
first seen less than ``period_s`` ago is dropped. A repeat does not extend the
window: the entry expires ``period_s`` after its first sighting. This removes the
copies that arrive over redundant links (the same packet, byte for byte), while
a sender that repeats a message gets a new sequence number and is not affected.
"""

from __future__ import annotations

from collections import deque

__all__ = ["Deduplicator"]


class Deduplicator:
    """Remembers frames for ``period_s`` seconds; time is passed in."""

    __slots__ = ("_order", "_period_s", "_seen")

    def __init__(self, period_s: float) -> None:
        if period_s <= 0:
            msg = f"period_s must be > 0, got {period_s}"
            raise ValueError(msg)
        self._period_s = period_s
        self._seen: set[bytes] = set()
        self._order: deque[tuple[float, bytes]] = deque()

    def __len__(self) -> int:
        return len(self._seen)

    def is_new(self, frame: bytes, now_s: float) -> bool:
        """``True`` (and remember it) unless ``frame`` was first seen within the window."""
        order = self._order
        horizon = now_s - self._period_s
        while order and order[0][0] < horizon:
            self._seen.discard(order.popleft()[1])
        if frame in self._seen:
            return False
        self._seen.add(frame)
        order.append((now_s, frame))
        return True
