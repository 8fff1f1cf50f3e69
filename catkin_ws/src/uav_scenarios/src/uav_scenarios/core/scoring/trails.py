"""What the map makes of things that move: voxels people and vehicles occupied and left, kept or cleared.

A moving object leaves a trail of voxels it filled for a while. A map whose update is probabilistic
(OctoMap's hit/miss log-odds with free-space clearing along each ray) clears them once it sees the
ground there again; a map that only adds hits keeps them as ghosts. :class:`TrailTracker` measures
it from the ground-truth object states (``/sim/object_states``) and the map's occupied voxels
(exported every ``scoring.map_accuracy_period_s``):

* *visited*: every voxel whose centre lay inside a moving object's 3D box at some state;
* *left*: visited, not inside any moving object's box now, and not a static surface voxel of the
  world (the road or ground under it);
* *mapped*: visited voxels the map held as occupied at some evaluation;
* *ghosts*: left voxels the map still holds as occupied now;
* *cleared*: mapped voxels that are left and no longer occupied.

Keys are packed int64 voxel keys (:mod:`uav_common.voxel_keys`) at the map's resolution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from uav_common.voxel_keys import pack_keys, sorted_unique

__all__ = ["ObjectStateRecord", "TrailStats", "TrailTracker", "box_voxel_keys"]

IntArray = npt.NDArray[np.int64]


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
    ghosts: int
    cleared: int

    @property
    def cleared_fraction(self) -> float:
        """Of the trail voxels the map once held as occupied and that are now left: the part it cleared."""
        total = self.cleared + self.ghosts
        return self.cleared / total if total else math.nan

    def as_dict(self) -> dict[str, float]:
        return {
            "movers": float(self.movers),
            "distance_m": self.distance_m,
            "visited_voxels": float(self.visited),
            "left_voxels": float(self.left),
            "mapped_voxels": float(self.mapped),
            "ghost_voxels": float(self.ghosts),
            "cleared_voxels": float(self.cleared),
            "cleared_fraction": self.cleared_fraction,
        }


@dataclass
class TrailTracker:
    """Accumulates moving objects' voxels and scores the map against them (see module docstring)."""

    resolution_m: float
    static_keys: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    _visited: IntArray = field(default_factory=lambda: np.zeros(0, np.int64))
    _pending: list[IntArray] = field(default_factory=list)
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
        self._pending.append(self._current)
        if len(self._pending) > 50:
            self._merge()

    def _merge(self) -> None:
        if self._pending:
            self._visited = sorted_unique(np.concatenate([self._visited, *self._pending]))
            self._pending = []

    def evaluate(self, t_s: float, map_keys: npt.ArrayLike) -> TrailStats:
        """Score the map's occupied voxels (packed keys) now."""
        self._merge()
        occupied = sorted_unique(np.asarray(map_keys, dtype=np.int64))
        visited = np.setdiff1d(self._visited, self.static_keys, assume_unique=True)
        left = np.setdiff1d(visited, self._current, assume_unique=True)
        self._mapped = np.union1d(self._mapped, np.intersect1d(visited, occupied, assume_unique=True))
        ghosts = np.intersect1d(left, occupied, assume_unique=True)
        cleared = np.setdiff1d(np.intersect1d(self._mapped, left, assume_unique=True), occupied, assume_unique=True)
        self.last = TrailStats(
            t_s,
            len(self.movers),
            self.distance_m,
            int(visited.size),
            int(left.size),
            int(self._mapped.size),
            int(ghosts.size),
            int(cleared.size),
        )
        return self.last
