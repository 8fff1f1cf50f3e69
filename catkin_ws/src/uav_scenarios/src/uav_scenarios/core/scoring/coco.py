"""COCO-style detection scores with pycocotools, over a run's frames and by context.

Every scored image (a detector frame paired with the ground truth of the same camera and stamp) adds its
truth boxes and the detector's boxes with their scores. :meth:`CocoScores.evaluate` runs pycocotools'
``COCOeval`` (box IoU, IoU 0.50:0.05:0.95, 101 recall points, up to 100 detections per image; the matching
image by image as the run goes, :meth:`CocoScores.update`) and gives

* ``AP`` (mean over IoU 0.50:0.95 and classes), ``AP50`` (IoU 0.5), ``AR`` (max recall, 100 detections);
* the precision-recall curve at IoU 0.5 (precision at recall 0, 0.01, ..., 1, mean over classes);
* the same per class, and per band of each context.

Contexts of an *object* (range, view angle, pixel size, visible fraction) use COCO's own area-range
mechanism with the context value in place of the area: a truth object outside the band is ignored, a
detection matched to it is ignored, and an unmatched detection counts in the band its own value falls
in. A detection whose value is unknown (no visible fraction; no range when it was not placed) counts as a
false positive in every band, as CityPersons scores occlusion subsets. Contexts of a *frame* (altitude,
clutter) evaluate the frames in the band. A band with no truth object has no AP (NaN), and says so with
its counts; every band is reported.

pycocotools prints progress; its output is swallowed here. Boxes are whole pixels, converted to COCO's
``[x, y, w, h]`` on pixel edges (:attr:`Detection.box_xywh`).
"""

from __future__ import annotations

import contextlib
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from uav_scenarios.core.scoring.metrics import band_label
from uav_scenarios.core.scoring.types import Detection

__all__ = ["RECALL_POINTS", "CocoScores", "ContextBands"]

#: Recall points of the precision-recall curves (COCO's 101).
RECALL_POINTS = tuple(round(r, 2) for r in np.linspace(0.0, 1.0, 101))
_ALL = (-1e12, 1e12)


@dataclass(frozen=True)
class ContextBands:
    """A context's band edges (ascending) and unit, for labels."""

    edges: tuple[float, ...]
    unit: str = ""

    def ranges(self) -> list[tuple[float, float]]:
        """``[lo, hi)`` of each band as COCO's closed area ranges (the last band closed on the right)."""
        out = []
        n = len(self.edges) - 1
        for k in range(n):
            lo, hi = self.edges[k], self.edges[k + 1]
            out.append((lo, hi if k == n - 1 else math.nextafter(hi, -math.inf)))
        return out

    def labels(self) -> list[str]:
        return [band_label(k, self.edges, self.unit) for k in range(len(self.edges) - 1)]

    def index(self, value: float) -> int:
        """The band of ``value`` (-1 outside or NaN)."""
        if not math.isfinite(value):
            return -1
        for k, (lo, hi) in enumerate(self.ranges()):
            if lo <= value <= hi:
                return k
        return -1


@dataclass
class CocoScores:
    """Accumulates scored images and scores them with pycocotools.

    pycocotools' per-image matching (``COCOeval.evaluateImg``, nearly all of its time) depends on one image only,
    so :meth:`update` runs it on the images added since the last call, once per object context, and keeps the
    results; :meth:`evaluate` matches the rest and only accumulates (cheap), so a long run's final summary does
    not redo the whole run. Frame contexts need no matching of their own: they accumulate subsets of the images.
    """

    classes: tuple[str, ...] = ("person", "vehicle")
    object_contexts: dict[str, ContextBands] = field(default_factory=dict)
    frame_contexts: dict[str, ContextBands] = field(default_factory=dict)
    _images: list[dict[str, float]] = field(default_factory=list)
    _truth: list[dict[str, Any]] = field(default_factory=list)
    _dets: list[dict[str, Any]] = field(default_factory=list)
    #: Per evaluation (None: overall; else an object context), image id -> its evaluateImg results, in
    #: pycocotools' (category, area range) order.
    _matched: dict[str | None, dict[int, list[Any]]] = field(default_factory=dict)
    _next: int = 1

    @property
    def images(self) -> int:
        return len(self._images)

    def add_image(
        self,
        truth: Sequence[Detection],
        truth_context: Sequence[Mapping[str, float]],
        detections: Sequence[Detection],
        detection_context: Sequence[Mapping[str, float]],
        frame_context: Mapping[str, float],
    ) -> None:
        """One scored image: its truth objects and detections (each with its object-context values, NaN
        when unknown) and the frame's context values. Objects of classes not in ``classes`` are left out."""
        image_id = len(self._images) + 1
        self._images.append(dict(frame_context))
        for det, ctx in zip(truth, truth_context, strict=True):
            if det.class_name in self.classes:
                self._truth.append({"image_id": image_id, "det": det, "ctx": dict(ctx)})
        for det, ctx in zip(detections, detection_context, strict=True):
            if det.class_name in self.classes and math.isfinite(det.score):
                self._dets.append({"image_id": image_id, "det": det, "ctx": dict(ctx)})

    # ---- matching, image by image ------------------------------------------------------

    def _annotations(self, context: str | None, first_image: int) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
        cat = {name: k + 1 for k, name in enumerate(self.classes)}
        gts, dts = [], []
        for k, item in enumerate(self._truth, start=1):
            if item["image_id"] < first_image:
                continue
            det: Detection = item["det"]
            value = item["ctx"].get(context, math.nan) if context else det.size_px**2
            gts.append(
                {
                    "id": k,
                    "image_id": item["image_id"],
                    "category_id": cat[det.class_name],
                    "bbox": list(det.box_xywh),
                    # unknown context: outside every band (a truth object is then scored in none of them)
                    "area": value if math.isfinite(value) else -1e30,
                    "iscrowd": 0,
                }
            )
        for k, item in enumerate(self._dets, start=1):
            if item["image_id"] < first_image:
                continue
            det = item["det"]
            value = item["ctx"].get(context, math.nan) if context else det.size_px**2
            dts.append(
                {
                    "id": k,
                    "image_id": item["image_id"],
                    "category_id": cat[det.class_name],
                    "bbox": list(det.box_xywh),
                    "score": float(det.score),
                    # unknown context (NaN): never outside a band, so an unmatched one counts in each
                    "area": value,
                    "iscrowd": 0,
                }
            )
        return gts, dts

    def _ranges(self, context: str | None) -> list[tuple[float, float]]:
        return [_ALL] if context is None else self.object_contexts[context].ranges()

    def update(self) -> None:
        """Match the images added since the last call (every evaluation), keeping the per-image results."""
        from pycocotools.coco import COCO  # noqa: PLC0415 - deferred: only the summaries need it
        from pycocotools.cocoeval import COCOeval  # noqa: PLC0415

        first = self._next
        self._next = len(self._images) + 1
        busy = self._busy_images(set(range(first, self._next)))
        if not busy:
            return
        images = [{"id": i} for i in busy]
        categories = [{"id": k + 1, "name": n} for k, n in enumerate(self.classes)]
        for context in (None, *self.object_contexts):
            gts, dts = self._annotations(context, first)
            ranges = self._ranges(context)
            with contextlib.redirect_stdout(io.StringIO()):
                coco_gt = COCO()
                coco_gt.dataset = {"images": images, "annotations": gts, "categories": categories}
                coco_gt.createIndex()
                coco_dt = COCO()
                coco_dt.dataset = {"images": images, "annotations": dts, "categories": categories}
                coco_dt.createIndex()
                ev = COCOeval(coco_gt, coco_dt, iouType="bbox")
                ev.params.imgIds = busy
                ev.params.areaRng = [list(r) for r in ranges]
                ev.params.areaRngLbl = [str(k) for k in range(len(ranges))]
                ev.evaluate()
            store = self._matched.setdefault(context, {})
            n_img, n_area = len(busy), len(ranges)
            for i, image_id in enumerate(busy):  # evalImgs is ordered category, area range, image
                store[image_id] = [
                    ev.evalImgs[(k * n_area + a) * n_img + i] for k in range(len(categories)) for a in range(n_area)
                ]

    def _accumulate(self, context: str | None, image_ids: list[int]) -> Any:
        """pycocotools' accumulation over already matched images."""
        import copy  # noqa: PLC0415

        from pycocotools.cocoeval import COCOeval  # noqa: PLC0415

        ranges = self._ranges(context)
        store = self._matched[context]
        with contextlib.redirect_stdout(io.StringIO()):
            ev = COCOeval(iouType="bbox")
            p = ev.params
            p.imgIds = image_ids
            p.catIds = list(range(1, len(self.classes) + 1))
            p.areaRng = [list(r) for r in ranges]
            p.areaRngLbl = [str(k) for k in range(len(ranges))]
            n_area = len(ranges)
            ev.evalImgs = [
                store[i][k * n_area + a] for k in range(len(p.catIds)) for a in range(n_area) for i in image_ids
            ]
            ev._paramsEval = copy.deepcopy(p)
            ev.accumulate()
        return ev

    def _busy_images(self, subset: set[int] | None = None) -> list[int]:
        ids = {t["image_id"] for t in self._truth} | {d["image_id"] for d in self._dets}
        if subset is not None:
            ids &= subset
        return sorted(ids)

    def _slice(self, ev: Any, a: int, class_index: int | None = None) -> dict[str, Any]:
        """AP, AP50, AR and the IoU-0.5 curve of area range ``a`` (one class, or the mean over classes)."""
        prec = np.asarray(ev.eval["precision"])  # [T, R, K, A, M]
        rec = np.asarray(ev.eval["recall"])  # [T, K, A, M]
        ks = [class_index] if class_index is not None else list(range(prec.shape[2]))
        p = prec[:, :, ks, a, -1]
        r = rec[:, ks, a, -1]
        ap = float(p[p > -1].mean()) if (p > -1).any() else math.nan
        p50 = p[0]
        ap50 = float(p50[p50 > -1].mean()) if (p50 > -1).any() else math.nan
        ar = float(r[r > -1].mean()) if (r > -1).any() else math.nan
        valid = [k for k in range(p50.shape[1]) if (p50[:, k] > -1).all()]
        curve = [float(v) for v in p50[:, valid].mean(axis=1)] if valid else []
        return {"AP": ap, "AP50": ap50, "AR": ar, "pr_curve": curve}

    def _counts(self, keep_truth: Any, keep_det: Any) -> dict[str, int]:
        return {
            "truths": sum(1 for t in self._truth if keep_truth(t)),
            "detections": sum(1 for d in self._dets if keep_det(d)),
        }

    def evaluate(self) -> dict[str, Any]:
        """Every score: overall, per class, and per band of every context (see the module docstring)."""
        out: dict[str, Any] = {"images": len(self._images), "truths": len(self._truth), "detections": len(self._dets)}
        self.update()
        busy = self._busy_images()
        if not busy:
            return {**out, "AP": math.nan, "AP50": math.nan, "AR": math.nan, "pr_curve": [], "per_class": {}}
        ev = self._accumulate(None, busy)
        out.update(self._slice(ev, 0))
        out["per_class"] = {
            name: {
                **self._slice(ev, 0, k),
                **self._counts(lambda t, n=name: t["det"].class_name == n, lambda d, n=name: d["det"].class_name == n),
            }
            for k, name in enumerate(self.classes)
        }
        by_context: dict[str, dict[str, Any]] = {}
        for name, bands in self.object_contexts.items():
            ev = self._accumulate(name, busy)
            per: dict[str, Any] = {}
            for a, label in enumerate(bands.labels()):
                lo, hi = bands.ranges()[a]

                def in_band(item: dict[str, Any], lo: float = lo, hi: float = hi, ctx: str = name) -> bool:
                    v = float(item["ctx"].get(ctx, math.nan))
                    return lo <= v <= hi

                def det_counts(item: dict[str, Any], lo: float = lo, hi: float = hi, ctx: str = name) -> bool:
                    v = float(item["ctx"].get(ctx, math.nan))
                    return not math.isfinite(v) or lo <= v <= hi

                per[label] = {**self._slice(ev, a), **self._counts(in_band, det_counts)}
            by_context[name] = per
        for name, bands in self.frame_contexts.items():
            per = {}
            for k, label in enumerate(bands.labels()):
                frames = {i + 1 for i, ctx in enumerate(self._images) if bands.index(ctx.get(name, math.nan)) == k}
                ids = self._busy_images(frames)
                counts = self._counts(lambda t, f=frames: t["image_id"] in f, lambda d, f=frames: d["image_id"] in f)
                if not ids:
                    per[label] = {"AP": math.nan, "AP50": math.nan, "AR": math.nan, "pr_curve": [], **counts}
                    continue
                per[label] = {**self._slice(self._accumulate(None, ids), 0), **counts}
            by_context[name] = per
        out["by_context"] = by_context
        return out
