"""Which frames a dataset has: their index, name, split, world and (for flights) pose and time (pure).

Sampled viewpoints: the frames are shared among the splits in proportion to their ``fraction``
(largest remainder), in the config's split order; within a split, frame ``j`` goes to world
``world_seeds[j % len(world_seeds)]``. Each frame's viewpoint is drawn later from its own generator
(:func:`uav_datasets.core.sampling.frame_rng`), so the plan, and the dataset, do not depend on how the
frames are shared among workers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from uav_datasets.core.config import DatasetConfig
from uav_sim_bridge.core.objects import ObjectPose
from uav_sim_bridge.core.transforms import RigidTransform

__all__ = ["FramePlan", "allocate", "plan_viewpoints", "shard"]


@dataclass(frozen=True)
class FramePlan:
    """One frame to make.

    Attributes:
        index, name, split, world_seed: see :class:`~uav_datasets.core.records.FrameRecord`.
        t_map_optical: the camera pose (flights); None for a sampled viewpoint (drawn by the worker).
        timestamp_s: simulation time of the world state.
        sequence, sequence_frame: sequence name and 1-based frame number (flights).
        object_poses: poses of the objects that are not where the world generated them, at this instant.
    """

    index: int
    name: str
    split: str
    world_seed: int
    t_map_optical: RigidTransform | None = None
    timestamp_s: float = 0.0
    sequence: str = ""
    sequence_frame: int = 0
    object_poses: tuple[tuple[int, ObjectPose], ...] = ()


def allocate(total: int, weights: list[float]) -> list[int]:
    """``total`` split in proportion to ``weights`` (largest remainder; ties to the earlier entry)."""
    s = sum(weights)
    exact = [total * w / s for w in weights]
    out = [math.floor(e) for e in exact]
    rest = total - sum(out)
    order = sorted(range(len(weights)), key=lambda i: (-(exact[i] - out[i]), i))
    for i in order[:rest]:
        out[i] += 1
    return out


def plan_viewpoints(cfg: DatasetConfig, frames: int) -> list[FramePlan]:
    """The frames of a sampled-viewpoint dataset of ``frames`` frames."""
    names = list(cfg.splits)
    counts = allocate(frames, [cfg.splits[n].fraction for n in names])
    out: list[FramePlan] = []
    index = 0
    for split, count in zip(names, counts, strict=True):
        seeds = cfg.splits[split].world_seeds
        for j in range(count):
            out.append(FramePlan(index, f"{index:06d}", split, seeds[j % len(seeds)]))
            index += 1
    return out


def shard(frames: list[FramePlan], workers: int) -> list[list[FramePlan]]:
    """Frames shared among ``workers`` in contiguous runs of equal length, grouped by world so each worker
    loads as few worlds as possible. The dataset does not depend on the sharing."""
    ordered = sorted(frames, key=lambda f: (f.world_seed, f.index))
    n = max(1, min(workers, len(ordered)))
    size = math.ceil(len(ordered) / n) if ordered else 0
    return [ordered[k * size : (k + 1) * size] for k in range(n) if ordered[k * size : (k + 1) * size]]
