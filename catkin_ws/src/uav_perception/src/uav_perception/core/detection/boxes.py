"""The detector contract's boxes: what a detector says, what is kept, and why the rest is discarded.

A detector publishes ``vision_msgs/Detection2DArray``: per object a box (centre and size in pixels)
and one or more class hypotheses (id, score). This module is the pure half of reading that:

* :class:`RawDetection` is one ``Detection2D`` as sent (no checks);
* :func:`screen` keeps the detections a consumer can use (:class:`Box`) and counts the others by
  reason (:data:`DISCARD_REASONS`): a NaN or infinite box or score, an empty box, a box outside
  the image, a class id that is not a class of the range, a score outside [0, 1], no hypothesis.

Pixel convention (as ``sensor_msgs/CameraInfo`` and OpenCV): pixel ``[row, col]`` has its centre at
``(u, v) = (col, row)``, so the image spans ``[-0.5, W - 0.5] x [-0.5, H - 0.5]`` and a box that
covers pixel columns ``x_min .. x_max`` (inclusive) has centre ``(x_min + x_max) / 2`` and width
``x_max - x_min + 1``. :func:`inclusive_to_center` and :meth:`Box.inclusive` convert both ways
(exactly, for whole-pixel boxes).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

from uav_common.detection_classes import DetectionClasses

__all__ = [
    "DISCARD_REASONS",
    "Box",
    "RawDetection",
    "center_to_edges",
    "inclusive_to_center",
    "screen",
]

#: Why a detection was discarded (the counters' keys, in this order in messages and metrics).
DISCARD_REASONS = ("nan_box", "empty_box", "out_of_image", "no_hypothesis", "unknown_class", "bad_score")


@dataclass(frozen=True)
class RawDetection:
    """One ``vision_msgs/Detection2D`` as received: box centre and size (pixels) and its hypotheses."""

    center_u: float
    center_v: float
    size_u: float
    size_v: float
    #: ``(class id, score)`` per ``ObjectHypothesisWithPose``.
    hypotheses: tuple[tuple[int, float], ...]


@dataclass(frozen=True)
class Box:
    """A kept detection: its class, score and box edges ``[u0, u1] x [v0, v1]`` in pixels (clipped to the image)."""

    class_name: str
    class_id: int
    score: float
    u0: float
    v0: float
    u1: float
    v1: float

    @property
    def center(self) -> tuple[float, float]:
        return (0.5 * (self.u0 + self.u1), 0.5 * (self.v0 + self.v1))

    @property
    def size(self) -> tuple[float, float]:
        return (self.u1 - self.u0, self.v1 - self.v0)

    def inclusive(self) -> tuple[int, int, int, int]:
        """``(x_min, y_min, x_max, y_max)``: the pixels the box covers most of (at least one)."""
        x_min = math.floor(self.u0 + 1.0)
        y_min = math.floor(self.v0 + 1.0)
        x_max = max(x_min, math.floor(self.u1))
        y_max = max(y_min, math.floor(self.v1))
        return (x_min, y_min, x_max, y_max)


def inclusive_to_center(x_min: int, y_min: int, x_max: int, y_max: int) -> tuple[float, float, float, float]:
    """Inclusive pixel box -> ``(center_u, center_v, size_u, size_v)`` (the ``BoundingBox2D`` fields)."""
    return (0.5 * (x_min + x_max), 0.5 * (y_min + y_max), float(x_max - x_min + 1), float(y_max - y_min + 1))


def center_to_edges(cu: float, cv: float, su: float, sv: float) -> tuple[float, float, float, float]:
    """``(u0, v0, u1, v1)`` of a box given by centre and size."""
    return (cu - 0.5 * su, cv - 0.5 * sv, cu + 0.5 * su, cv + 0.5 * sv)


def _hypothesis(det: RawDetection, classes: DetectionClasses) -> tuple[str, tuple[str, int, float] | None]:
    """The best-scoring hypothesis of a known class, or why there is none."""
    if not det.hypotheses:
        return "no_hypothesis", None
    if not all(math.isfinite(s) for _, s in det.hypotheses):
        return "nan_box", None
    known = [(name, i, s) for i, s in det.hypotheses if (name := classes.name_of(i)) is not None]
    if not known:
        return "unknown_class", None
    best = max(known, key=lambda k: k[2])
    if not 0.0 <= best[2] <= 1.0:
        return "bad_score", None
    return "", best


def _edges(
    det: RawDetection, width_px: int | None, height_px: int | None, margin_px: float
) -> tuple[str, tuple[float, float, float, float] | None]:
    """The box's edges clipped to the image, or why it has none."""
    geometry = (det.center_u, det.center_v, det.size_u, det.size_v)
    if not all(math.isfinite(v) for v in geometry):
        return "nan_box", None
    if det.size_u <= 0.0 or det.size_v <= 0.0:
        return "empty_box", None
    u0, v0, u1, v1 = center_to_edges(*geometry)
    if width_px is None or height_px is None:
        return "", (u0, v0, u1, v1)
    lo, hi_u, hi_v = -0.5 - margin_px, width_px - 0.5 + margin_px, height_px - 0.5 + margin_px
    if u0 < lo or v0 < lo or u1 > hi_u or v1 > hi_v:
        return "out_of_image", None
    u0, v0 = max(u0, -0.5), max(v0, -0.5)
    u1, v1 = min(u1, width_px - 0.5), min(v1, height_px - 0.5)
    if u1 <= u0 or v1 <= v0:
        return "out_of_image", None
    return "", (u0, v0, u1, v1)


def screen(
    detections: Sequence[RawDetection],
    classes: DetectionClasses,
    *,
    width_px: int | None,
    height_px: int | None,
    margin_px: float = 2.0,
) -> tuple[list[Box], Counter[str]]:
    """The detections a consumer can use, and how many of the others were discarded, by reason.

    A box is out of the image when it reaches more than ``margin_px`` beyond the image's edges (a
    detector's rounding is tolerated; a box of garbage coordinates is not); kept boxes are clipped to
    the image. Without the image size (no ``camera_info`` yet) the extent is not checked. Among several
    hypotheses the best-scoring one of a known class decides the class.

    Returns:
        ``(kept, discarded)``: kept boxes in input order; ``discarded[reason]`` for the others.
    """
    kept: list[Box] = []
    discarded: Counter[str] = Counter()
    for det in detections:
        reason, edges = _edges(det, width_px, height_px, margin_px)
        if edges is None:
            discarded[reason] += 1
            continue
        reason, best = _hypothesis(det, classes)
        if best is None:
            discarded[reason] += 1
            continue
        name, _, score = best
        kept.append(Box(name, classes.id_of(name), float(score), *edges))
    return kept, discarded
