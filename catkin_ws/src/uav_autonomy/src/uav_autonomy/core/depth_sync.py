"""A small stamp-keyed buffer to pair messages of the same instant.

The evaluator needs the ground-truth depth (and instance image) of the very
instant an estimate refers to. Estimates arrive late (processing time), so the
ground truth is kept in a bounded buffer keyed by stamp and looked up by the
closest stamp within a tolerance.
"""

from __future__ import annotations

import bisect
from typing import Generic, TypeVar

__all__ = ["StampBuffer"]

T = TypeVar("T")


class StampBuffer(Generic[T]):
    """Up to ``capacity`` items ordered by stamp (nanoseconds); the oldest are evicted."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            msg = f"capacity must be >= 1, got {capacity}"
            raise ValueError(msg)
        self.capacity = capacity
        self._stamps: list[int] = []
        self._items: list[T] = []

    def __len__(self) -> int:
        return len(self._stamps)

    def put(self, stamp_ns: int, item: T) -> None:
        """Insert (or replace the item at an identical stamp)."""
        i = bisect.bisect_left(self._stamps, stamp_ns)
        if i < len(self._stamps) and self._stamps[i] == stamp_ns:
            self._items[i] = item
            return
        self._stamps.insert(i, stamp_ns)
        self._items.insert(i, item)
        if len(self._stamps) > self.capacity:
            del self._stamps[0]
            del self._items[0]

    def closest(self, stamp_ns: int, tolerance_ns: int) -> tuple[int, T] | None:
        """The item whose stamp is closest to ``stamp_ns`` and within ``tolerance_ns``, or None."""
        i = bisect.bisect_left(self._stamps, stamp_ns)
        best: tuple[int, int] | None = None
        for j in (i - 1, i):
            if 0 <= j < len(self._stamps):
                diff = abs(self._stamps[j] - stamp_ns)
                if diff <= tolerance_ns and (best is None or diff < best[0]):
                    best = (diff, j)
        if best is None:
            return None
        j = best[1]
        return self._stamps[j], self._items[j]

    def oldest_stamp_ns(self) -> int | None:
        """Stamp of the oldest item, or None when empty."""
        return self._stamps[0] if self._stamps else None

    def newest_stamp_ns(self) -> int | None:
        """Stamp of the newest item, or None when empty."""
        return self._stamps[-1] if self._stamps else None
