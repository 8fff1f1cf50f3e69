"""The worst mistakes of a detector over a run, for the report's gallery.

Worst false positives: the highest-scoring detections (at or above the operating threshold) that match
no truth object. Worst misses: the truth objects no detection matched that should have been easiest, the
largest and least occluded (``pixel size x visible fraction``). :class:`Gallery` keeps the ``size`` worst
of each kind as frames are scored; the scorer node cuts each one's crop from the camera image of that
stamp when it is kept (:meth:`Gallery.take_new`).
"""

from __future__ import annotations

import heapq
import itertools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_scenarios.core.scoring.types import Detection

__all__ = ["TILE_PX", "Gallery", "GalleryItem", "crop_tile", "mosaic"]


@dataclass(frozen=True)
class GalleryItem:
    kind: str  # false_positive | miss
    t_s: float
    camera: str
    class_name: str
    bbox_px: tuple[int, int, int, int]
    #: How bad: the detection's score (false positive) or pixel size x visible fraction (miss).
    badness: float
    score: float
    range_m: float
    key: int

    def as_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "t_s": self.t_s,
            "camera": self.camera,
            "class": self.class_name,
            "bbox_px": list(self.bbox_px),
            "badness": self.badness,
            "score": self.score,
            "range_m": self.range_m,
            "key": self.key,
        }


#: Gallery items of one class this close in time whose boxes overlap this much are views of one object.
SAME_OBJECT_S = 5.0
SAME_OBJECT_IOU = 0.3


def _same_object(a: GalleryItem, b: GalleryItem) -> bool:
    if a.camera != b.camera or a.class_name != b.class_name or abs(a.t_s - b.t_s) > SAME_OBJECT_S:
        return False
    ax0, ay0, ax1, ay1 = a.bbox_px
    bx0, by0, bx1, by1 = b.bbox_px
    iw = min(ax1, bx1) - max(ax0, bx0) + 1
    ih = min(ay1, by1) - max(ay0, by0) + 1
    if iw <= 0 or ih <= 0:
        return False
    inter = iw * ih
    union = (ax1 - ax0 + 1) * (ay1 - ay0 + 1) + (bx1 - bx0 + 1) * (by1 - by0 + 1) - inter
    return inter / union >= SAME_OBJECT_IOU


@dataclass
class Gallery:
    size: int = 6
    _heaps: dict[str, list[tuple[float, int, GalleryItem]]] = field(
        default_factory=lambda: {"false_positive": [], "miss": []}
    )
    _new: list[GalleryItem] = field(default_factory=list)
    _seq: itertools.count[int] = field(default_factory=itertools.count)

    def _offer(self, item: GalleryItem) -> None:
        heap = self._heaps[item.kind]
        entry = (item.badness, item.key, item)
        # One object seen frame after frame is one mistake: keep only its worst view.
        same = [e for e in heap if _same_object(e[2], item)]
        if same:
            if max(e[0] for e in same) >= item.badness:
                return
            heap[:] = [e for e in heap if not _same_object(e[2], item)]
            heapq.heapify(heap)
        if len(heap) < self.size:
            heapq.heappush(heap, entry)
        elif entry[:2] > heap[0][:2]:
            heapq.heapreplace(heap, entry)
        else:
            return
        self._new.append(item)

    def false_positive(self, t_s: float, camera: str, det: Detection) -> None:
        if self.size <= 0 or not math.isfinite(det.score):
            return
        self._offer(
            GalleryItem(
                "false_positive",
                t_s,
                camera,
                det.class_name,
                det.bbox_px,
                det.score,
                det.score,
                det.range_m,
                next(self._seq),
            )
        )

    def miss(self, t_s: float, camera: str, truth: Detection) -> None:
        if self.size <= 0:
            return
        vis = truth.visible_fraction if math.isfinite(truth.visible_fraction) else 1.0
        badness = truth.size_px * vis
        self._offer(
            GalleryItem(
                "miss", t_s, camera, truth.class_name, truth.bbox_px, badness, math.nan, truth.range_m, next(self._seq)
            )
        )

    def take_new(self) -> list[GalleryItem]:
        """Items that entered the gallery since the last call and are still in it (the node crops these)."""
        kept = {item.key for heap in self._heaps.values() for _, _, item in heap}
        new = [item for item in self._new if item.key in kept]
        self._new = []
        return new

    def items(self) -> list[GalleryItem]:
        """The gallery, worst first within each kind (false positives first)."""
        out = []
        for kind in ("false_positive", "miss"):
            out += [item for _, _, item in sorted(self._heaps[kind], key=lambda e: (-e[0], e[1]))]
        return out


#: Side of a gallery tile, pixels.
TILE_PX = 128
_COLORS = {"false_positive": (255, 64, 32), "miss": (32, 200, 255)}


def crop_tile(image_rgb: npt.NDArray[np.uint8], item: GalleryItem) -> npt.NDArray[np.uint8]:
    """A ``TILE_PX`` square tile: the box with context around it (at least 32 px, twice the box), scaled up
    (nearest neighbour: small objects stay pixels, not blur), the box drawn, and a one-line label."""
    import cv2  # noqa: PLC0415

    h, w = image_rgb.shape[:2]
    x0, y0, x1, y1 = item.bbox_px
    side = max(32, 2 * max(x1 - x0 + 1, y1 - y0 + 1))
    cx, cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
    left = round(min(max(cx - side / 2.0, 0), max(0, w - side)))
    top = round(min(max(cy - side / 2.0, 0), max(0, h - side)))
    crop = np.zeros((side, side, 3), dtype=np.uint8)
    part = image_rgb[top : top + side, left : left + side]
    crop[: part.shape[0], : part.shape[1]] = part
    scale = (TILE_PX - 16) / side
    tile = np.zeros((TILE_PX, TILE_PX, 3), dtype=np.uint8)
    body = cv2.resize(crop, (TILE_PX - 16, TILE_PX - 16), interpolation=cv2.INTER_NEAREST)
    tile[16:, 8 : TILE_PX - 8] = body
    color = _COLORS.get(item.kind, (255, 255, 255))
    p0 = (8 + round((x0 - 0.5 - left) * scale), 16 + round((y0 - 0.5 - top) * scale))
    p1 = (8 + round((x1 + 0.5 - left) * scale), 16 + round((y1 + 0.5 - top) * scale))
    cv2.rectangle(tile, p0, p1, color, 1)
    what = (
        f"FP {item.class_name[:3]} {item.score:.2f}" if item.kind == "false_positive" else f"miss {item.class_name[:3]}"
    )
    rng = f" {item.range_m:.0f}m" if math.isfinite(item.range_m) else ""
    cv2.putText(tile, what + rng, (2, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, color, 1, cv2.LINE_AA)
    return tile


def mosaic(tiles: dict[str, list[npt.NDArray[np.uint8]]], columns: int) -> npt.NDArray[np.uint8] | None:
    """Rows of tiles: false positives first, then misses; ``None`` if there is no tile."""
    rows = []
    for kind in ("false_positive", "miss"):
        row_tiles = tiles.get(kind, [])
        if not row_tiles:
            continue
        row = np.zeros((TILE_PX, TILE_PX * columns, 3), dtype=np.uint8)
        for k, tile in enumerate(row_tiles[:columns]):
            row[:, k * TILE_PX : (k + 1) * TILE_PX] = tile
        rows.append(row)
    return np.concatenate(rows, axis=0) if rows else None
