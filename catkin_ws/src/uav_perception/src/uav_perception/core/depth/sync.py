"""A small stamp-keyed buffer to pair messages of the same instant.

The evaluator needs the ground-truth depth (and instance image) of the very
instant an estimate refers to. Estimates arrive late (processing time), so the
ground truth is kept in a bounded buffer keyed by stamp and looked up by the
closest stamp within a tolerance. The estimator, when it takes poses from
odometry rather than tf, interpolates them at the image stamp with
:class:`PoseHistory`.
"""

from __future__ import annotations

import bisect
import math
from typing import Generic, TypeVar

import numpy as np

from uav_common.rotations import matrix_from_quat, quat_from_matrix
from uav_perception.core.depth.types import CameraPose, FloatArray

__all__ = ["PoseHistory", "StampBuffer"]

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

    def at_or_before(self, stamp_ns: int) -> tuple[int, T] | None:
        """The newest item with a stamp <= ``stamp_ns``."""
        i = bisect.bisect_right(self._stamps, stamp_ns) - 1
        return (self._stamps[i], self._items[i]) if i >= 0 else None

    def at_or_after(self, stamp_ns: int) -> tuple[int, T] | None:
        """The oldest item with a stamp >= ``stamp_ns``."""
        i = bisect.bisect_left(self._stamps, stamp_ns)
        return (self._stamps[i], self._items[i]) if i < len(self._stamps) else None

    def oldest_stamp_ns(self) -> int | None:
        """Stamp of the oldest item, or None when empty."""
        return self._stamps[0] if self._stamps else None

    def newest_stamp_ns(self) -> int | None:
        """Stamp of the newest item, or None when empty."""
        return self._stamps[-1] if self._stamps else None


def _slerp(q0: FloatArray, q1: FloatArray, frac: float) -> FloatArray:
    dot = float(q0 @ q1)
    if dot < 0.0:
        q1, dot = -q1, -dot
    if dot > 0.9995:
        q = q0 + frac * (q1 - q0)
        return np.asarray(q / np.linalg.norm(q), dtype=np.float64)
    theta = math.acos(dot)
    s = math.sin(theta)
    q = (math.sin((1.0 - frac) * theta) * q0 + math.sin(frac * theta) * q1) / s
    return np.asarray(q, dtype=np.float64)


class PoseHistory:
    """Stamped poses (e.g. odometry of ``base_link``), interpolated at any stamp in between.

    Position is interpolated linearly, rotation by slerp. A stamp outside the
    stored span is answered only within ``max_extrapolation_ns`` of its end (with
    the end pose); a gap between the two neighbours longer than ``max_gap_ns``
    gives None, as does an invalid (NaN) neighbour.
    """

    def __init__(self, capacity: int, *, max_gap_ns: int, max_extrapolation_ns: int) -> None:
        self._buf: StampBuffer[CameraPose] = StampBuffer(capacity)
        self.max_gap_ns = max_gap_ns
        self.max_extrapolation_ns = max_extrapolation_ns

    def __len__(self) -> int:
        return len(self._buf)

    def add(self, stamp_ns: int, pose: CameraPose) -> None:
        """Store a pose."""
        self._buf.put(stamp_ns, pose)

    def at(self, stamp_ns: int) -> CameraPose | None:
        """The pose at ``stamp_ns``, or None when it cannot be known."""
        before = self._buf.at_or_before(stamp_ns)
        after = self._buf.at_or_after(stamp_ns)
        if before is not None and before[0] == stamp_ns:
            return before[1] if before[1].is_valid else None
        if before is None or after is None:
            edge = before if before is not None else after
            if edge is None or abs(edge[0] - stamp_ns) > self.max_extrapolation_ns:
                return None
            return edge[1] if edge[1].is_valid else None
        (t0, p0), (t1, p1) = before, after
        if t1 - t0 > self.max_gap_ns or not (p0.is_valid and p1.is_valid):
            return None
        frac = (stamp_ns - t0) / (t1 - t0)
        q = _slerp(quat_from_matrix(p0.rotation_map_optical), quat_from_matrix(p1.rotation_map_optical), frac)
        pos = p0.position_map_m + frac * (p1.position_map_m - p0.position_map_m)
        return CameraPose(matrix_from_quat(q), pos)
