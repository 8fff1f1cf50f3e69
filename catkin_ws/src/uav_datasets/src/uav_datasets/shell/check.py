"""``uav-dataset check``: the checks a user can run on a finished dataset, with pycocotools as the referee.

1. ``pycocotools`` loads ``annotations/instances.json``; the ground truth evaluated as detections (score 1)
   gives AP = 1.0 for boxes and for masks;
2. every tight box equals its mask's extent (``pycocotools.mask.toBbox``) and every area its mask's
   pixel count, and each mask is exactly the pixels of its instance id in the instance-mask PNG;
3. YOLO, KITTI and MOTChallenge files read back to the same boxes (and MOT to the same track ids);
4. a track id keeps its class and object in every frame and appears at most once per frame;
5. every file a frame lists exists.
"""

from __future__ import annotations

import contextlib
import io
import json
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from uav_datasets.core.formats import KITTI_TYPES, MOT_CLASSES, parse_kitti, parse_mot, parse_yolo
from uav_datasets.core.records import FrameRecord
from uav_datasets.errors import DatasetError
from uav_datasets.shell.folder import read_manifest, read_records
from uav_datasets.shell.writers import read_ids

__all__ = ["CheckReport", "check_dataset", "coco_ap"]

#: Boxes read back from normalised YOLO text may differ by this much (pixels) from the integers written.
_YOLO_TOLERANCE_PX = 1e-4


@dataclass
class CheckReport:
    """Each check's name, whether it passed, and what was measured or wrong."""

    results: list[tuple[str, bool, str]] = field(default_factory=list)

    def add(self, name: str, ok: bool, detail: str) -> None:
        self.results.append((name, ok, detail))

    @property
    def ok(self) -> bool:
        return all(ok for _, ok, _ in self.results)

    def text(self) -> str:
        return "\n".join(f"{'PASS' if ok else 'FAIL'}  {name}: {detail}" for name, ok, detail in self.results)


def coco_ap(path: Path, iou_type: str = "bbox") -> tuple[float, int]:
    """AP (IoU 0.50:0.95) of the COCO file's ground truth evaluated as detections of score 1, and the annotation count.

    Raises:
        DatasetError: pycocotools is not installed.
    """
    try:
        from pycocotools.coco import COCO  # noqa: PLC0415
        from pycocotools.cocoeval import COCOeval  # noqa: PLC0415
    except ImportError as err:
        msg = "pycocotools is not installed; run make setup (it is pinned in requirements.txt)"
        raise DatasetError(msg) from err
    with contextlib.redirect_stdout(io.StringIO()):  # pycocotools prints its progress
        gt = COCO(str(path))
        anns = gt.loadAnns(gt.getAnnIds())
        if not anns:
            return float("nan"), 0
        dets = [
            {
                "image_id": a["image_id"],
                "category_id": a["category_id"],
                "bbox": a["bbox"],
                "segmentation": a["segmentation"],
                "score": 1.0,
            }
            for a in anns
        ]
        dt = gt.loadRes(dets)
        ev = COCOeval(gt, dt, iou_type)
        per_image = max(len(gt.getAnnIds(imgIds=[i])) for i in gt.getImgIds())
        ev.params.maxDets = [1, 10, max(100, per_image)]
        ev.evaluate()
        ev.accumulate()
    # AP@[0.50:0.95], every area, the largest maxDets (COCOeval.summarize prints maxDets=100 whatever is set)
    precision = ev.eval["precision"][:, :, :, 0, -1]
    valid = precision[precision > -1]
    return (float(valid.mean()) if valid.size else float("nan")), len(anns)


def _coco_labels(doc: dict[str, Any]) -> dict[int, list[dict[str, Any]]]:
    """The COCO file's annotations by frame index (image id - 1), in file order."""
    out: dict[int, list[dict[str, Any]]] = {img["id"] - 1: [] for img in doc["images"]}
    for ann in doc["annotations"]:
        out.setdefault(ann["image_id"] - 1, []).append(ann)
    return out


def _check_coco_matches(doc: dict[str, Any], frames: list[FrameRecord], report: CheckReport) -> None:
    by_frame = _coco_labels(doc)
    bad = [
        rec.name
        for rec in frames
        if [
            (a["instance_id"], a["category_id"], list(a["bbox"]), a["segmentation"])
            for a in by_frame.get(rec.index, [])
        ]
        != [(lab.instance_id, lab.class_id, list(lab.bbox), lab.segmentation) for lab in rec.labels]
    ]
    n = len(doc["annotations"])
    report.add(
        "COCO annotations match the frames' labels",
        len(doc["images"]) == len(frames) and not bad,
        f"{len(doc['images'])} images, {n} annotations" + (f"; frames that differ: {bad[:5]}" if bad else ""),
    )


def _check_masks(folder: Path, frames: list[FrameRecord], doc: dict[str, Any] | None, report: CheckReport) -> None:
    """Each tight box against its mask's extent and area, and each mask against the instance-id PNG (the COCO
    file's annotations when there is one, else the frames' labels)."""
    from pycocotools import mask as mask_utils  # noqa: PLC0415

    by_frame = _coco_labels(doc) if doc is not None else None
    n = bad_box = bad_area = bad_png = 0
    first_bad = ""
    for rec in frames:
        ids = read_ids(folder / rec.files["instance_mask"]) if "instance_mask" in rec.files else None
        if by_frame is not None:
            items = [(a["instance_id"], a["bbox"], a["area"], a["segmentation"]) for a in by_frame.get(rec.index, [])]
        else:
            items = [(lab.instance_id, lab.bbox, lab.area, lab.segmentation) for lab in rec.labels]
        for iid, bbox, area, segmentation in items:
            n += 1
            seg = dict(segmentation)
            seg["counts"] = seg["counts"].encode("ascii")
            box = [int(v) for v in mask_utils.toBbox(seg).tolist()]
            if box != [int(v) for v in bbox]:
                bad_box += 1
                first_bad = first_bad or f"frame {rec.name} instance {iid}: bbox {list(bbox)}, mask {box}"
            if int(mask_utils.area(seg)) != area:
                bad_area += 1
            if ids is not None and not np.array_equal(mask_utils.decode(seg).astype(bool), ids == iid):
                bad_png += 1
                first_bad = first_bad or f"frame {rec.name} instance {iid}: mask differs from the instance PNG"
    ok = bad_box == bad_area == bad_png == 0
    detail = (
        f"{n} masks: {bad_box} tight boxes differ from their mask extent, {bad_area} areas from their pixel "
        f"count, {bad_png} masks from the instance-id PNG"
    )
    report.add("tight boxes equal mask extents", ok, detail + (f" (first: {first_bad})" if first_bad else ""))


def _check_yolo(folder: Path, frames: list[FrameRecord], classes: list[str], report: CheckReport) -> None:
    n = bad = 0
    worst = 0.0
    for rec in frames:
        text = (folder / rec.files["yolo"]).read_text()
        rows = parse_yolo(text, rec.width, rec.height)
        want = [(classes.index(lab.class_name), lab.bbox) for lab in rec.labels]
        if len(rows) != len(want):
            bad += 1
            continue
        for (k, box), (wk, wbox) in zip(rows, want, strict=True):
            n += 1
            err = max(abs(a - b) for a, b in zip(box, wbox, strict=True))
            worst = max(worst, err)
            if k != wk or err > _YOLO_TOLERANCE_PX:
                bad += 1
    report.add("YOLO round trip", bad == 0, f"{n} boxes, {bad} differ; largest difference {worst:.2e} px")


def _check_kitti(folder: Path, frames: list[FrameRecord], report: CheckReport) -> None:
    n = bad = 0
    for rec in frames:
        rows = parse_kitti((folder / rec.files["kitti"]).read_text())
        want = [(KITTI_TYPES.get(lab.class_name, lab.class_name.capitalize()), lab.bbox) for lab in rec.labels]
        n += len(want)
        if len(rows) != len(want) or any(
            t != wt or max(abs(a - b) for a, b in zip(box, wbox, strict=True)) > 0.005
            for (t, box), (wt, wbox) in zip(rows, want, strict=True)
        ):
            bad += 1
    report.add("KITTI round trip", bad == 0, f"{n} boxes, {bad} frames differ")


def _check_mot(folder: Path, frames: list[FrameRecord], report: CheckReport) -> None:
    by_seq: dict[str, list[FrameRecord]] = defaultdict(list)
    for rec in frames:
        if rec.sequence:
            by_seq[rec.sequence].append(rec)
    for seq, recs in sorted(by_seq.items()):
        rows = parse_mot((folder / "mot" / seq / "gt" / "gt.txt").read_text())
        got = sorted((f, t, tuple(box), c) for f, t, box, c, _v in rows)
        want = sorted(
            (rec.sequence_frame, lab.track_id, tuple(float(v) for v in lab.bbox), MOT_CLASSES.get(lab.class_name, 12))
            for rec in recs
            for lab in rec.labels
        )
        ini = (folder / "mot" / seq / "seqinfo.ini").read_text()
        ok = got == want and f"seqLength={len(recs)}" in ini
        report.add(
            f"MOT round trip ({seq})", ok, f"{len(rows)} rows in gt.txt, {len(want)} labels in {len(recs)} frames"
        )


def _check_identities(frames: list[FrameRecord], report: CheckReport) -> None:
    who: dict[tuple[int, int], tuple[str, str]] = {}
    problems: list[str] = []
    tracks: set[tuple[int, int]] = set()
    for rec in frames:
        seen: set[int] = set()
        for lab in rec.labels:
            key = (rec.world_seed, lab.track_id)
            tracks.add(key)
            ident = (lab.class_name, lab.object_name)
            if who.setdefault(key, ident) != ident:
                problems.append(f"track {lab.track_id} is {who[key]} and {ident}")
            if lab.track_id in seen:
                problems.append(f"track {lab.track_id} twice in frame {rec.name}")
            seen.add(lab.track_id)
    detail = f"{len(tracks)} tracks over {len(frames)} frames" + (f"; {problems[:3]}" if problems else "")
    report.add("track identities consistent", not problems, detail)


def check_dataset(folder: Path) -> CheckReport:
    """Run every check on a finished dataset.

    Raises:
        DatasetFolderError: not a dataset folder.
        IncompleteDatasetError: its generation has not finished.
    """
    manifest = read_manifest(folder)
    frames = read_records(folder)
    config = manifest["identity"]["config"]
    classes = list(config["labels"]["classes"])
    report = CheckReport()
    missing = [rel for rec in frames for rel in rec.files.values() if not (folder / rel).is_file()]
    report.add(
        "files present",
        not missing,
        f"{sum(len(r.files) for r in frames)} files" + (f"; missing {missing[:3]}" if missing else ""),
    )
    coco = folder / "annotations" / "instances.json"
    doc = json.loads(coco.read_text()) if coco.is_file() else None
    if doc is not None:
        _check_coco_matches(doc, frames, report)
        for iou in ("bbox", "segm"):
            ap, n = coco_ap(coco, iou)
            report.add(
                f"pycocotools AP ({iou}) of the ground truth as detections",
                ap == 1.0,
                f"AP = {ap:.4f} over {n} annotations",
            )
    _check_masks(folder, frames, doc, report)
    if frames and "yolo" in frames[0].files:
        _check_yolo(folder, frames, classes, report)
    if frames and "kitti" in frames[0].files:
        _check_kitti(folder, frames, report)
    if (folder / "mot").is_dir():
        _check_mot(folder, frames, report)
    _check_identities(frames, report)
    return report
