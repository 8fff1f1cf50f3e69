"""An ONNX detector scored on a data engine split (held-out worlds): COCO AP and AP50 by class and pixel size.

The model runs exactly as the ``detector`` node runs it (:class:`~uav_perception.shell.onnx_detector.OnnxDetector`,
the same letterbox, decoding and NMS) on each frame; pycocotools scores the detections against the split's
labels. Pixel-size bins are TinyPerson's on ``sqrt(w h)`` of the tight box (``1-8``, ``8-12``, ``12-20``,
``20-32``, ``>32``) plus ``>=12`` (the issue's target) and ``all``; COCO's area ranges are set to those bins
(pycocotools ignores ground truth outside a range, and detections outside it that match nothing).
"""

from __future__ import annotations

import contextlib
import io
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from uav_perception.core.detection.boxes import RawDetection, center_to_edges
from uav_perception.shell.onnx_detector import OnnxDetector
from uav_perception.training.data import DatasetSplit

__all__ = ["SIZE_BINS", "coco_detection", "coco_scores", "detect_split"]

#: ``name -> (min px, max px)`` of ``sqrt(w h)``, half-open.
SIZE_BINS: dict[str, tuple[float, float]] = {
    "all": (0.0, 1e5),
    "1-8": (1.0, 8.0),
    "8-12": (8.0, 12.0),
    "12-20": (12.0, 20.0),
    "20-32": (20.0, 32.0),
    ">32": (32.0, 1e5),
    ">=12": (12.0, 1e5),
}


def coco_detection(image_id: int, d: RawDetection, col_to_cat: dict[int, int]) -> dict[str, Any]:
    """A contract detection (its best hypothesis) as a COCO result: box in pixel-edge coordinates."""
    u0, v0, u1, v1 = center_to_edges(d.center_u, d.center_v, d.size_u, d.size_v)
    col, score = d.hypotheses[0]
    # contract convention (pixel centres) -> COCO pixel edges
    return {
        "image_id": image_id,
        "category_id": col_to_cat[col],
        "bbox": [u0 + 0.5, v0 + 0.5, u1 - u0, v1 - v0],
        "score": score,
    }


def detect_split(
    model: OnnxDetector,
    data: DatasetSplit,
    images: list[np.ndarray] | None = None,
    progress: Callable[[int], None] | None = None,
) -> tuple[list[dict[str, Any]], float]:
    """COCO-style detections of ``model`` on every frame of ``data`` (category ids the dataset's), and the mean
    seconds per frame spent in :meth:`OnnxDetector.detect`."""
    col_to_cat = {col: cat for cat, col in data.category_to_column.items()}
    out: list[dict[str, Any]] = []
    spent = 0.0
    for k, frame in enumerate(data.frames):
        image = images[k] if images is not None else data.image(frame)
        t0 = time.perf_counter()
        dets, _ = model.detect(image, list(range(model.num_classes)))
        spent += time.perf_counter() - t0
        out += [coco_detection(frame.image_id, d, col_to_cat) for d in dets]
        if progress is not None:
            progress(k + 1)
    return out, spent / max(1, len(data.frames))


def coco_scores(data: DatasetSplit, detections: list[dict[str, Any]]) -> dict[str, dict[str, dict[str, float]]]:
    """``{class: {bin: {"AP", "AP50", "AR100", "gt"}}}`` for each class of ``data`` and ``"all"`` classes.

    A bin without ground truth reports ``gt`` 0 and NaN scores (pycocotools' -1).
    """
    annotations: list[dict[str, Any]] = []
    gt: dict[str, Any] = {
        "images": [{"id": f.image_id, "width": f.width, "height": f.height} for f in data.frames],
        "categories": [{"id": cat, "name": data.classes[col]} for cat, col in data.category_to_column.items()],
        "annotations": annotations,
    }
    n = 0
    for f in data.frames:
        for box, col in zip(f.boxes, f.labels, strict=False):
            n += 1
            cat = next(c for c, k in data.category_to_column.items() if k == col)
            w, h = float(box[2]), float(box[3])
            annotations.append(
                {
                    "id": n,
                    "image_id": f.image_id,
                    "category_id": cat,
                    "bbox": [float(v) for v in box],
                    "area": w * h,
                    "iscrowd": 0,
                }
            )
    with contextlib.redirect_stdout(io.StringIO()):
        coco_gt = COCO()
        coco_gt.dataset = gt
        coco_gt.createIndex()
        coco_dt = coco_gt.loadRes(detections) if detections else None
    sizes = {a["id"]: np.sqrt(a["area"]) for a in annotations}
    out: dict[str, dict[str, dict[str, float]]] = {}
    targets = [("all", list(data.category_to_column))] + [
        (data.classes[col], [cat]) for cat, col in data.category_to_column.items()
    ]
    for name, cats in targets:
        out[name] = {}
        for bin_name, (lo, hi) in SIZE_BINS.items():
            count = sum(1 for a in annotations if a["category_id"] in cats and lo <= sizes[a["id"]] < hi)
            row = {"gt": float(count), "AP": float("nan"), "AP50": float("nan"), "AR100": float("nan")}
            if count and coco_dt is not None:
                with contextlib.redirect_stdout(io.StringIO()):
                    ev = COCOeval(coco_gt, coco_dt, "bbox")
                    ev.params.catIds = cats
                    ev.params.areaRng = [[lo * lo, hi * hi]]
                    ev.params.areaRngLbl = ["all"]  # summarize() reads the "all" range
                    ev.params.maxDets = [1, 10, 100]
                    ev.evaluate()
                    ev.accumulate()
                    ev.summarize()
                stats = ev.stats
                row.update({"AP": _nan(stats[0]), "AP50": _nan(stats[1]), "AR100": _nan(stats[8])})
            elif count:
                row.update({"AP": 0.0, "AP50": 0.0, "AR100": 0.0})
            out[name][bin_name] = row
    return out


def _nan(v: float) -> float:
    return float("nan") if v < 0 else float(v)
