"""Benchmark of the learned detector (the shipped ONNX model run as the ``detector`` node runs it).

Held-out frames: ``config/datasets/detector_heldout.yaml`` (400 frames of the forward camera's point of view in the
default world, seed 7, and seed 31, neither of them a training world), generated on first use into
``datasets/detector_heldout`` (``uav-dataset generate``; resumed or reused after).

Speed. ``OnnxDetector.detect`` on those 640x480 frames with one onnxruntime thread: letterbox, the model, decoding
and NMS, as the node does per frame (image conversion from the ROS message excluded).

* ``detector.rate_hz_1thread`` (target >= 10 Hz; baseline: the model alone, ``session.run`` on the same frames, so
  the ratio is the share of the frame time spent in the model)

Accuracy. pycocotools AP50 of the detections against the frames' labels, by class and TinyPerson pixel-size bin
(``sqrt(w h)`` of the tight box), every bin reported; baseline: the stand-in ``degraded_detector`` (the ground
truth's boxes degraded, seeded; docs/perception.md) on the same frames, scored the same way.

* ``detector.ap50.<class>.ge12px`` (target >= 0.6 for person and vehicle), ``detector.ap50.<class>.<bin>``,
  ``detector.ap.<class>.ge12px`` (COCO AP .5:.95)

Usage: ``scripts/in_env python bench/bench_detector.py [--model PATH] [--frames N]``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from typing import Any

import numpy as np
from benchlib import REPO, record

from uav_perception.core.detection.boxes import Box
from uav_perception.core.detection.degrade import DegradeConfig, degrade, frame_rng
from uav_perception.core.detection.learned import letterbox
from uav_perception.shell.models import resolve_model
from uav_perception.shell.onnx_detector import OnnxDetector
from uav_perception.training.data import DatasetSplit, load_split
from uav_perception.training.evaluate import SIZE_BINS, coco_detection, coco_scores, detect_split

DATASET = REPO / "datasets" / "detector_heldout"
CONFIG = REPO / "config" / "datasets" / "detector_heldout.yaml"


def heldout() -> DatasetSplit:
    if not (DATASET / "dataset.json").is_file() or '"complete": true' not in (DATASET / "dataset.json").read_text():
        print(f"generating {DATASET} ({CONFIG.name})", flush=True)
        subprocess.run(
            ["uav-dataset", "generate", str(CONFIG), "--out", str(DATASET), "--workers", "2", "--quiet"], check=True
        )
    return load_split(DATASET, "test")


def degraded_detections(data: DatasetSplit) -> list[dict[str, Any]]:
    """The stand-in's boxes on the ground truth of each frame (COCO format, the dataset's category ids)."""
    cfg = DegradeConfig(seed=0)
    ids = {name: k for k, name in enumerate(data.classes)}
    col_to_cat = {col: cat for cat, col in data.category_to_column.items()}
    out = []
    for f in data.frames:
        truth = [
            Box(
                data.classes[int(c)],
                int(c),
                1.0,
                float(x) - 0.5,
                float(y) - 0.5,
                float(x + w) - 0.5,
                float(y + h) - 0.5,
            )
            for (x, y, w, h), c in zip(f.boxes, f.labels, strict=True)
        ]
        rng = frame_rng(cfg.seed, f.image_id, "camera_forward_optical")
        dets = degrade(truth, width_px=f.width, height_px=f.height, class_ids=ids, cfg=cfg, rng=rng)
        out += [coco_detection(f.image_id, d, col_to_cat) for d in dets]
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--model", default="", help="ONNX model ('' = the shipped one)")
    ap.add_argument("--frames", type=int, default=0, help="score only the first N frames (0 = all)")
    args = ap.parse_args()
    data = heldout()
    if args.frames:
        data = DatasetSplit(
            data.root,
            data.split,
            data.classes,
            data.frames[: args.frames],
            data.world_seeds,
            data.coco,
            data.category_to_column,
            data.fingerprint,
        )
    model_path = resolve_model(args.model)
    model = OnnxDetector(model_path, threads=1)
    images = [data.image(f) for f in data.frames]
    print(f"{model_path}: {len(images)} held-out frames of worlds {list(data.world_seeds)}", flush=True)

    # speed: the node's per-frame path against the model alone, interleaved in chunks (the same machine load)
    sess, name = model.session, model.spec.input_name
    tensors = [letterbox(img, model.spec.input_hw)[0] for img in images[:50]]
    full, bare = [], []
    for _ in range(4):
        t0 = time.perf_counter()
        for img in images[:50]:
            model.detect(img, [0, 2])
        full.append((time.perf_counter() - t0) / len(tensors))
        t0 = time.perf_counter()
        for x in tensors:
            sess.run(None, {name: x})
        bare.append((time.perf_counter() - t0) / len(tensors))
    rate, rate_bare = 1.0 / float(np.median(full)), 1.0 / float(np.median(bare))
    record(
        "detector.rate_hz_1thread",
        rate,
        "Hz",
        rate_bare,
        target=">= 10",
        met=rate >= 10.0,
        notes="640x480, one onnxruntime thread, letterbox+model+decode+NMS; baseline: the model alone",
    )

    # accuracy on held-out worlds against the stand-in on the same frames
    dets, _ = detect_split(model, data, images)
    ours = coco_scores(data, dets)
    theirs = coco_scores(data, degraded_detections(data))
    for cls in data.classes:
        for bin_name in SIZE_BINS:
            mine, base = ours[cls][bin_name], theirs[cls][bin_name]
            label = "ge12px" if bin_name == ">=12" else bin_name.replace(">", "gt")
            gt = int(mine["gt"])
            if gt == 0:
                print(f"detector.ap50.{cls}.{label}: no labelled {cls} of this size in the held-out frames")
                continue
            target = bin_name == ">=12"
            record(
                f"detector.ap50.{cls}.{label}",
                mine["AP50"],
                "AP50",
                base["AP50"],
                target=">= 0.6" if target else "",
                met=mine["AP50"] >= 0.6 if target else None,
                notes=f"{gt} labelled {cls}s in {len(data.frames)} held-out frames (worlds {list(data.world_seeds)}); "
                "baseline: the degraded_detector stand-in on the ground truth",
            )
        record(
            f"detector.ap.{cls}.ge12px",
            ours[cls][">=12"]["AP"],
            "AP",
            theirs[cls][">=12"]["AP"],
            notes="COCO AP .5:.95; baseline: the stand-in",
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
