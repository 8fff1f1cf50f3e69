"""What the map makes of things that move: voxels people and vehicles occupied and left, kept or cleared.

A moving object leaves a trail of voxels it filled for a while. A map whose update is probabilistic
(OctoMap's hit/miss log-odds with free space cleared along each ray) clears them once it looks at the
ground there again; a map that only adds hits keeps them as ghosts. :class:`TrailTracker` measures it
from the ground-truth object states (``/sim/object_states``), the map's occupied voxels (exported every
``scoring.map_accuracy_period_s``) and the map's ``last_seen_s`` layer:

* *visited*: every voxel whose centre lay inside a moving object's 3D box at some state, with the last
  time one did;
* *left*: visited, not inside any moving object's box now, and not a static surface voxel of the world
  (the road or ground under it);
* *mapped*: visited voxels the map held as occupied at some evaluation;
* *seen again*: mapped, left, and in a map column observed after the object left it (the map had the
  chance to clear it);
* *cleared*: seen again and no longer occupied; *ghosts*: seen again and still occupied. The map's
  clearing rate is ``cleared / (cleared + ghosts)``; *unseen*: mapped and left but not looked at since.

Keys are packed int64 voxel keys (:mod:`uav_common.voxel_keys`) at the map's resolution.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from uav_common.voxel_keys import in_sorted, pack_keys, sorted_unique, unpack_keys

__all__ = ["LastSeen", "ObjectStateRecord", "TrailStats", "TrailTracker", "box_voxel_keys"]

#: The map's ``last_seen_s`` (absolute simulation seconds, NaN where never seen) at ``(x, y)`` arrays.
LastSeen = Callable[[npt.NDArray[np.float64], npt.NDArray[np.float64]], npt.NDArray[np.float64]]

IntArray = npt.NDArray[np.int64]
_AFTER_S = 0.4


@dataclass(frozen=True)
class ObjectStateRecord:
    """The moving (and moved) objects at one instant: rows ``(instance_id, x, y, z, yaw, length, width, height)``
    and whether each follows a path."""

    t_s: float
    rows: npt.NDArray[np.float64]
    moving: npt.NDArray[np.bool_]
    names: tuple[str, ...] = ()
    classes: tuple[str, ...] = ()


def box_voxel_keys(
    position_m: tuple[float, float, float], yaw: float, size: tuple[float, float, float], res: float
) -> IntArray:
    """Packed keys of the voxels whose centres lie inside a box standing at ``position_m`` with heading ``yaw``."""
    x, y, z = position_m
    length, width, height = size
    r = 0.5 * math.hypot(length, width)
    i0, i1 = math.floor((x - r) / res), math.floor((x + r) / res)
    j0, j1 = math.floor((y - r) / res), math.floor((y + r) / res)
    k0, k1 = math.floor(z / res), math.floor((z + height) / res)
    ii, jj, kk = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), np.arange(k0, k1 + 1), indexing="ij")
    c = (np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1) + 0.5) * res
    dx, dy = c[:, 0] - x, c[:, 1] - y
    cs, sn = math.cos(yaw), math.sin(yaw)
    lx, ly = cs * dx + sn * dy, -sn * dx + cs * dy
    inside = (np.abs(lx) <= length / 2) & (np.abs(ly) <= width / 2) & (c[:, 2] >= z) & (c[:, 2] <= z + height)
    ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1)[inside]
    return pack_keys(ijk)


@dataclass(frozen=True)
class TrailStats:
    t_s: float
    movers: int
    distance_m: float  # travelled by all movers
    visited: int
    left: int
    mapped: int
    seen_again: int
    ghosts: int
    cleared: int
    mapped_now_occupied_by_movers: int = 0  # mapped voxels a mover is in right now (neither left nor unseen)

    @property
    def cleared_fraction(self) -> float:
        """Of the trail voxels the map once held as occupied, has looked at again since the object left and so
        could clear: the part it cleared."""
        total = self.cleared + self.ghosts
        return self.cleared / total if total else math.nan

    def as_dict(self) -> dict[str, float]:
        return {
            "movers": float(self.movers),
            "distance_m": self.distance_m,
            "visited_voxels": float(self.visited),
            "left_voxels": float(self.left),
            "mapped_voxels": float(self.mapped),
            "seen_again_voxels": float(self.seen_again),
            "ghost_voxels": float(self.ghosts),
            "cleared_voxels": float(self.cleared),
            "unseen_voxels": float(self.mapped - self.seen_again - self.mapped_now_occupied_by_movers),
            "cleared_fraction": self.cleared_fraction,
        }


@dataclass
class TrailTracker:
    """Accumulates moving objects' voxels and scores the map against them (see module docstring)."""

    resolution_m: float
    static_keys: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    _keys: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))  # visited, sorted
    _left_t: npt.NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))  # last time occupied, per key
    _pending: list[tuple[IntArray, float]] = field(default_factory=list)
    _current: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    _mapped: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    _last: dict[int, tuple[float, float]] = field(default_factory=dict)
    distance_m: float = 0.0
    movers: set[int] = field(default_factory=set)
    last: TrailStats | None = None

    def add(self, record: ObjectStateRecord) -> None:
        """One object-state message: the moving objects' boxes now."""
        current = []
        for row, moving in zip(record.rows, record.moving, strict=True):
            if not moving:
                continue
            iid = int(row[0])
            x, y, z, yaw, length, width, height = (float(v) for v in row[1:8])
            keys = box_voxel_keys((x, y, z), yaw, (length, width, height), self.resolution_m)
            current.append(keys)
            if iid in self._last:
                self.distance_m += math.hypot(x - self._last[iid][0], y - self._last[iid][1])
            self._last[iid] = (x, y)
            self.movers.add(iid)
        self._current = sorted_unique(np.concatenate(current)) if current else np.zeros(0, np.int64)
        self._pending.append((self._current, record.t_s))
        if len(self._pending) > 50:
            self._merge()

    def _merge(self) -> None:
        if not self._pending:
            return
        keys = np.concatenate([self._keys, *(k for k, _ in self._pending)])
        times = np.concatenate([self._left_t, *(np.full(len(k), t) for k, t in self._pending)])
        uniq, inverse = np.unique(keys, return_inverse=True)
        latest = np.full(len(uniq), -np.inf)
        np.maximum.at(latest, inverse, times)
        self._keys, self._left_t = uniq, latest
        self._pending = []

    def evaluate(self, t_s: float, map_keys: npt.ArrayLike, last_seen: LastSeen | None = None) -> TrailStats:
        """Score the map's occupied voxels (packed keys) now; ``last_seen``: the map's ``last_seen_s`` layer
        (without it every voxel counts as seen again)."""
        self._merge()
        occupied = sorted_unique(np.asarray(map_keys, dtype=np.int64))
        # binary searches: the trails are a few thousand keys, the static world and the map millions
        visited = ~in_sorted(self._keys, sorted_unique(self.static_keys))
        left = visited & ~np.isin(self._keys, self._current, assume_unique=True)
        now_occupied = in_sorted(self._keys, occupied)
        self._mapped = np.union1d(self._mapped, self._keys[visited & now_occupied])
        was_mapped = np.isin(self._keys, self._mapped, assume_unique=True)
        candidates = left & was_mapped
        seen_again = candidates.copy()
        if last_seen is not None and candidates.any():
            centres = (unpack_keys(self._keys[candidates]) + 0.5) * self.resolution_m
            seen = np.asarray(last_seen(centres[:, 0], centres[:, 1]), dtype=np.float64)
            with np.errstate(invalid="ignore"):
                # observed after the object left (object states come every 0.2 s: a margin of two)
                seen_again[candidates] = seen > self._left_t[candidates] + _AFTER_S
        ghosts = seen_again & now_occupied
        cleared = seen_again & ~now_occupied
        self.last = TrailStats(
            t_s,
            len(self.movers),
            self.distance_m,
            int(visited.sum()),
            int(left.sum()),
            int(self._mapped.size),
            int(seen_again.sum()),
            int(ghosts.sum()),
            int(cleared.sum()),
            int((was_mapped & visited & ~left).sum()),
        )
        return self.last
