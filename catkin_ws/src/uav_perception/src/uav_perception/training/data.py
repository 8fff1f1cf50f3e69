"""A data engine dataset (``uav-dataset generate``) read for training and evaluation: images and boxes per split.

Reads ``dataset.json`` (the effective config, the worlds), ``annotations/instances_<split>.json`` (COCO:
``bbox`` in pixel-edge coordinates, ``category_id`` the world's class id) and the frames' PNGs.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from uav_perception.errors import DetectionError

__all__ = ["DatasetSplit", "Frame", "TrainDataError", "load_split"]


class TrainDataError(DetectionError):
    """A dataset folder is missing, incomplete or lacks the split or classes asked for (the message names it)."""


@dataclass(frozen=True)
class Frame:
    image_id: int
    file: Path
    width: int
    height: int
    #: ``(n, 4)`` float32 ``[x, y, w, h]`` pixel-edge boxes and ``(n,)`` int64 class columns (index in ``classes``).
    boxes: np.ndarray
    labels: np.ndarray


@dataclass(frozen=True)
class DatasetSplit:
    root: Path
    split: str
    classes: tuple[str, ...]
    frames: tuple[Frame, ...]
    world_seeds: tuple[int, ...]
    coco: dict[str, Any]
    #: COCO category id -> class column.
    category_to_column: dict[int, int]
    fingerprint: str

    def image(self, frame: Frame) -> np.ndarray:
        """The frame's RGB image ``(h, w, 3)`` uint8."""
        bgr = cv2.imread(str(frame.file), cv2.IMREAD_COLOR)
        if bgr is None:
            msg = f"{frame.file}: cannot read the image (missing or corrupt)"
            raise TrainDataError(msg)
        return np.ascontiguousarray(bgr[:, :, ::-1])


def load_split(root: str | Path, split: str, classes: tuple[str, ...] = ("person", "vehicle")) -> DatasetSplit:
    """The split ``split`` of the dataset folder ``root``.

    Raises:
        TrainDataError: no complete dataset there, no such split, or a class it does not label.
    """
    root = Path(root)
    manifest = root / "dataset.json"
    if not manifest.is_file():
        msg = (
            f"{root}: no dataset.json; make one: uav-dataset generate config/datasets/detector_train.yaml --out {root}"
        )
        raise TrainDataError(msg)
    meta = json.loads(manifest.read_text())
    if not meta.get("complete"):
        msg = f"{root}: the dataset is incomplete; run the same uav-dataset generate command again to finish it"
        raise TrainDataError(msg)
    ann = root / "annotations" / f"instances_{split}.json"
    if not ann.is_file():
        splits = sorted(p.stem.removeprefix("instances_") for p in (root / "annotations").glob("instances_*.json"))
        msg = f"{root}: no split {split!r} ({ann} missing); its splits: {splits}"
        raise TrainDataError(msg)
    coco = json.loads(ann.read_text())
    by_name = {c["name"]: int(c["id"]) for c in coco["categories"]}
    missing = [c for c in classes if c not in by_name]
    if missing:
        msg = f"{ann}: no category {missing}; it labels {sorted(by_name)}"
        raise TrainDataError(msg)
    cat_to_col = {by_name[c]: i for i, c in enumerate(classes)}
    per_image: dict[int, list[tuple[list[float], int]]] = {}
    for a in coco["annotations"]:
        col = cat_to_col.get(int(a["category_id"]))
        if col is not None:
            per_image.setdefault(int(a["image_id"]), []).append((list(a["bbox"]), col))
    frames = []
    for im in coco["images"]:
        items = per_image.get(int(im["id"]), [])
        boxes = np.array([b for b, _ in items], dtype=np.float32).reshape(-1, 4)
        labels = np.array([c for _, c in items], dtype=np.int64)
        frames.append(
            Frame(
                int(im["id"]),
                root / im.get("files", {}).get("image", f"images/{im['file_name']}"),
                int(im["width"]),
                int(im["height"]),
                boxes,
                labels,
            )
        )
    seeds = tuple(sorted({int(im["world"]["seed"]) for im in coco["images"] if "world" in im}))
    return DatasetSplit(root, split, classes, tuple(frames), seeds, coco, cat_to_col, str(meta.get("fingerprint", "")))
