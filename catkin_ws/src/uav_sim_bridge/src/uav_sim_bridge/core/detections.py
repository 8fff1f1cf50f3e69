"""Ground-truth detections from rendered instance images (pure numpy).

An object registers in a camera image when (1) at least ``min_pixels`` of its pixels
are visible in the instance image (so it is in the frame and not fully occluded) and
(2) its centre is within ``max_range_m`` of the camera.  Its visible fraction is the
number of visible pixels over the number it would cover with nothing else in the
scene (the renderer draws each candidate alone in an occlusion query), both counted
inside the frame.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.objects import WorldObject
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world_config import ObjectClass

__all__ = ["DetectionConfig", "GroundTruthDetection", "ground_truth_detections", "visible_candidates"]


@dataclass(frozen=True)
class DetectionConfig:
    """``detections`` section of ``config/sim_bridge.yaml``."""

    classes: tuple[str, ...] = ("person", "vehicle")
    max_range_m: float = 100.0
    min_pixels: int = 4

    def __post_init__(self) -> None:
        for c in self.classes:
            ObjectClass.from_label(c)
        if self.max_range_m <= 0 or self.min_pixels < 1:
            msg = "max_range_m must be > 0 and min_pixels >= 1"
            raise ValueError(msg)

    @cached_property
    def class_ids(self) -> frozenset[ObjectClass]:
        return frozenset(ObjectClass.from_label(c) for c in self.classes)


@dataclass(frozen=True)
class GroundTruthDetection:
    """One registered object; the box is in pixels, inclusive."""

    instance_id: int
    object_class: ObjectClass
    x_min: int
    y_min: int
    x_max: int
    y_max: int
    range_m: float
    visible_fraction: float
    visible_pixels: int
    position_m: tuple[float, float, float]


def visible_candidates(
    instance_id: npt.NDArray[np.integer[Any]],
    t_map_optical: RigidTransform,
    objects: Mapping[int, WorldObject] | Iterable[WorldObject],
    cfg: DetectionConfig,
) -> list[int]:
    """Ids of the objects of ``cfg.classes`` with at least ``min_pixels`` visible pixels and within range.

    Exactly the objects :func:`ground_truth_detections` reports (same tests), found from the ids present
    in the image: detections need only be computed for these.
    """
    objs = objects if isinstance(objects, Mapping) else {o.instance_id: o for o in objects}
    ids = np.asarray(instance_id)
    counts = np.bincount(ids.ravel(), minlength=1)
    eye = t_map_optical.translation_m
    wanted = cfg.class_ids
    out = []
    for iid in np.flatnonzero(counts >= cfg.min_pixels):  # the few ids in the image, not every object
        o = objs.get(int(iid))
        if o is not None and o.object_class in wanted and float(np.linalg.norm(o.center_m - eye)) <= cfg.max_range_m:
            out.append(int(iid))
    return out


def ground_truth_detections(
    instance_id: npt.NDArray[np.integer[Any]],
    t_map_optical: RigidTransform,
    objects: Mapping[int, WorldObject] | Iterable[WorldObject],
    cfg: DetectionConfig,
    unoccluded_pixels: Mapping[int, int] | None = None,
) -> list[GroundTruthDetection]:
    """Detections of the objects of ``cfg.classes`` in one image, sorted by instance id.

    Args:
        instance_id: ``(H, W)`` rendered instance image.
        t_map_optical: camera pose (its translation is the camera centre).
        objects: the candidate objects *at their current poses*, keyed by instance id.
        cfg: classes, range limit and minimum pixel count.
        unoccluded_pixels: pixels each object would cover alone in this frame
            (:meth:`Renderer.unoccluded_pixel_counts`); None = visible fraction 1.
    """
    objs = objects if isinstance(objects, Mapping) else {o.instance_id: o for o in objects}
    wanted = cfg.class_ids
    ids = np.asarray(instance_id)
    candidates = {iid: o for iid, o in objs.items() if o.object_class in wanted}
    if not candidates:
        return []
    top = max(int(ids.max(initial=0)), *candidates) + 1
    lut = np.zeros(top, dtype=bool)
    lut[list(candidates)] = True
    mask = lut[ids]
    if not mask.any():
        return []
    rows, cols = np.nonzero(mask)
    hit = ids[rows, cols].astype(np.int64)
    counts = np.bincount(hit, minlength=top)
    big = np.iinfo(np.int64).max
    x_min = np.full(top, big, np.int64)
    y_min = np.full(top, big, np.int64)
    x_max = np.full(top, -1, np.int64)
    y_max = np.full(top, -1, np.int64)
    np.minimum.at(x_min, hit, cols)
    np.minimum.at(y_min, hit, rows)
    np.maximum.at(x_max, hit, cols)
    np.maximum.at(y_max, hit, rows)
    eye = t_map_optical.translation_m
    out = []
    for iid in np.flatnonzero(counts >= cfg.min_pixels):
        obj = candidates[int(iid)]
        centre = obj.center_m
        rng_m = float(np.linalg.norm(centre - eye))
        if rng_m > cfg.max_range_m:
            continue
        visible = int(counts[iid])
        full = int(unoccluded_pixels.get(int(iid), visible)) if unoccluded_pixels is not None else visible
        fraction = min(1.0, visible / full) if full > 0 else 1.0
        out.append(
            GroundTruthDetection(
                instance_id=int(iid),
                object_class=obj.object_class,
                x_min=int(x_min[iid]),
                y_min=int(y_min[iid]),
                x_max=int(x_max[iid]),
                y_max=int(y_max[iid]),
                range_m=rng_m,
                visible_fraction=fraction,
                visible_pixels=visible,
                position_m=(float(centre[0]), float(centre[1]), float(centre[2])),
            )
        )
    return out
