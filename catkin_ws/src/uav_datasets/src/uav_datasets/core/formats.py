"""The annotation formats, written and read back (pure: text and dicts, no files).

* COCO instances (:func:`coco_document`): standard keys plus the extra attributes of each image and
  annotation (``docs/datasets.md``); ``category_id`` is the world's class id (person 5, vehicle 6).
* YOLO (:func:`yolo_lines`, :func:`parse_yolo`): ``class cx cy w h``, normalised by the image size;
  ``class`` is the position in ``labels.classes``.
* MOTChallenge (:func:`mot_lines`, :func:`parse_mot`, :func:`seqinfo_ini`): ``frame, id, left, top,
  width, height, conf, class, visibility`` with 1-based frames and pixel coordinates, as MOT17's
  ``gt.txt``; class 1 = pedestrian (person), 3 = car (vehicle).
* KITTI object labels (:func:`kitti_lines`, :func:`parse_kitti`, :func:`kitti_calib`).

Every pixel box is ``[x, y, w, h]`` in pixel-edge coordinates (pixel column ``c`` spans ``[c, c+1)``);
MOT shifts it to 1-based coordinates, KITTI writes ``x1 y1 x2 y2`` = ``x, y, x + w, y + h``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_datasets.core.records import FrameRecord, InstanceLabel

__all__ = [
    "KITTI_TYPES",
    "MOT_CLASSES",
    "coco_annotation",
    "coco_document",
    "coco_image",
    "data_yaml",
    "kitti_calib",
    "kitti_lines",
    "kitti_occluded",
    "mot_lines",
    "parse_kitti",
    "parse_mot",
    "parse_yolo",
    "seqinfo_ini",
    "yolo_lines",
]

#: MOT17 class ids of the world's classes (TrackEval evaluates class 1, pedestrians; 3 is a car).
MOT_CLASSES = {"person": 1, "vehicle": 3}
#: KITTI type names of the world's classes.
KITTI_TYPES = {"person": "Pedestrian", "vehicle": "Car"}
_OTHER_MOT_CLASS = 12  # MOT17 "other"


def coco_image(rec: FrameRecord, file_name: str) -> dict[str, Any]:
    """A COCO ``images`` entry with the frame's metadata."""
    d = rec.to_json()
    return {
        "id": rec.index + 1,
        "file_name": file_name,
        "width": rec.width,
        "height": rec.height,
        "license": 1,
        "frame_index": rec.index,
        "name": rec.name,
        "split": rec.split,
        "world": d["world"],
        "sequence": rec.sequence,
        "sequence_frame": rec.sequence_frame,
        "timestamp_s": d["timestamp_s"],
        "intrinsics": {"fx": rec.fx, "fy": rec.fy, "cx": rec.cx, "cy": rec.cy, "K": rec.k.tolist()},
        "t_map_camera": d["t_map_camera"],
        "altitude_agl_m": d["altitude_agl_m"],
        "pitch_deg": d["pitch_deg"],
        "yaw_deg": d["yaw_deg"],
        "files": d["files"],
    }


def coco_annotation(label: InstanceLabel, ann_id: int, image_id: int) -> dict[str, Any]:
    """A COCO ``annotations`` entry: the standard keys plus every attribute of the label."""
    d = label.to_json()
    return {
        "id": ann_id,
        "image_id": image_id,
        "category_id": label.class_id,
        "bbox": d.pop("bbox"),
        "area": d.pop("area"),
        "segmentation": d.pop("segmentation"),
        "iscrowd": 0,
        **d,
    }


def coco_document(
    frames: Sequence[FrameRecord],
    *,
    classes: Sequence[tuple[int, str]],
    info: dict[str, Any],
    licence: str,
    file_name: Any,
) -> dict[str, Any]:
    """The COCO instances document of ``frames`` (in their order; image id = frame index + 1).

    Args:
        classes: ``(class_id, name)`` of the labelled classes, in the config's order.
        info: the ``info`` section.
        licence: the data licence (the one ``licenses`` entry every image refers to).
        file_name: ``FrameRecord -> str``, the image path relative to ``images/``.
    """
    images = []
    annotations = []
    ann_id = 1
    for rec in frames:
        images.append(coco_image(rec, file_name(rec)))
        for label in rec.labels:
            annotations.append(coco_annotation(label, ann_id, rec.index + 1))
            ann_id += 1
    categories = [
        {"id": cid, "name": name, "supercategory": "object", "yolo_index": k} for k, (cid, name) in enumerate(classes)
    ]
    return {
        "info": info,
        "licenses": [{"id": 1, "name": licence, "url": ""}],
        "images": images,
        "annotations": annotations,
        "categories": categories,
    }


# ---------------------------------------------------------------------------------------------- YOLO


def yolo_lines(labels: Iterable[InstanceLabel], class_index: dict[str, int], width: int, height: int) -> str:
    """YOLO label text: one ``class cx cy w h`` line per label, normalised to [0, 1] (8 decimals)."""
    out = []
    for lab in labels:
        x, y, w, h = lab.bbox
        cx, cy = (x + w / 2) / width, (y + h / 2) / height
        out.append(f"{class_index[lab.class_name]} {cx:.8f} {cy:.8f} {w / width:.8f} {h / height:.8f}")
    return "".join(line + "\n" for line in out)


def parse_yolo(text: str, width: int, height: int) -> list[tuple[int, tuple[float, float, float, float]]]:
    """``(class, [x, y, w, h])`` pixel boxes of a YOLO label text.

    Raises:
        ValueError: a line without 5 numbers.
    """
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != 5:
            msg = f"line {n}: expected 'class cx cy w h', got {line!r}"
            raise ValueError(msg)
        k = int(parts[0])
        cx, cy, w, h = (float(v) for v in parts[1:])
        out.append((k, ((cx - w / 2) * width, (cy - h / 2) * height, w * width, h * height)))
    return out


def data_yaml(splits: Sequence[str], class_names: Sequence[str]) -> str:
    """YOLO ``data.yaml``: split image folders relative to the dataset folder, and the class names."""
    lines = [
        "# YOLO dataset description (written by uav-dataset). Paths are relative to this file's folder;",
        "# labels/<split>/<name>.txt sit beside images/<split>/<name>.png.",
        "path: .",
    ]
    lines += [f"{split}: images/{split}" for split in splits]
    lines.append(f"nc: {len(class_names)}")
    lines.append("names:")
    lines += [f"  {k}: {name}" for k, name in enumerate(class_names)]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------- MOT


def mot_lines(frames: Iterable[FrameRecord]) -> str:
    """MOTChallenge ``gt.txt`` of one sequence: rows by frame, then by track id."""
    rows = []
    for rec in frames:
        for lab in sorted(rec.labels, key=lambda la: la.track_id):
            x, y, w, h = lab.bbox
            cls = MOT_CLASSES.get(lab.class_name, _OTHER_MOT_CLASS)
            rows.append((rec.sequence_frame, lab.track_id, x + 1, y + 1, w, h, 1, cls, lab.visible_fraction))
    rows.sort(key=lambda r: (r[0], r[1]))
    return "".join(f"{f},{t},{x},{y},{w},{h},{c},{k},{v:.6f}\n" for f, t, x, y, w, h, c, k, v in rows)


def parse_mot(text: str) -> list[tuple[int, int, tuple[float, float, float, float], int, float]]:
    """``(frame, track_id, [x, y, w, h] 0-based, class, visibility)`` of each ``gt.txt`` row.

    Raises:
        ValueError: a row with fewer than 9 fields.
    """
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        f = line.split(",")
        if len(f) < 9:
            msg = f"line {n}: expected 9 comma-separated fields, got {line!r}"
            raise ValueError(msg)
        box = (float(f[2]) - 1, float(f[3]) - 1, float(f[4]), float(f[5]))
        out.append((int(f[0]), int(f[1]), box, int(f[7]), float(f[8])))
    return out


def seqinfo_ini(name: str, *, frames: int, rate_hz: float, width: int, height: int, ext: str) -> str:
    """MOTChallenge ``seqinfo.ini`` (images in ``img1/`` as ``000001<ext>``...)."""
    return (
        "[Sequence]\n"
        f"name={name}\n"
        "imDir=img1\n"
        f"frameRate={round(rate_hz) if float(rate_hz).is_integer() else rate_hz}\n"
        f"seqLength={frames}\n"
        f"imWidth={width}\n"
        f"imHeight={height}\n"
        f"imExt={ext}\n"
    )


# ---------------------------------------------------------------------------------------------- KITTI


def kitti_occluded(visible_fraction: float) -> int:
    """KITTI's occlusion level: 0 fully visible (>= 0.9), 1 partly (>= 0.5), 2 largely occluded (< 0.5)."""
    if visible_fraction >= 0.9:
        return 0
    if visible_fraction >= 0.5:
        return 1
    return 2


def kitti_lines(labels: Iterable[InstanceLabel]) -> str:
    """KITTI object label text: ``type truncated occluded alpha x1 y1 x2 y2 h w l x y z ry`` per label.

    The 3D fields are in the camera's optical frame (x right, y down, z forward): the box's bottom
    centre, its size (height, width, length) and its heading about the optical y axis. They match
    KITTI's meaning exactly only for a level camera; the COCO file has the 3D box in ``map``.
    """
    out = []
    for lab in labels:
        x, y, w, h = lab.bbox
        length, width, height = lab.box3d_size_m
        lx, ly, lz = lab.location_camera_m
        kind = KITTI_TYPES.get(lab.class_name, lab.class_name.capitalize())
        out.append(
            f"{kind} {lab.truncation:.4f} {kitti_occluded(lab.visible_fraction)} {lab.alpha_rad:.4f} "
            f"{x:.2f} {y:.2f} {x + w:.2f} {y + h:.2f} {height:.4f} {width:.4f} {length:.4f} "
            f"{lx:.4f} {ly:.4f} {lz:.4f} {lab.rotation_y_rad:.4f}"
        )
    return "".join(line + "\n" for line in out)


def parse_kitti(text: str) -> list[tuple[str, tuple[float, float, float, float]]]:
    """``(type, [x, y, w, h])`` of each KITTI label line.

    Raises:
        ValueError: a line with fewer than 15 fields.
    """
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        f = line.split()
        if len(f) < 15:
            msg = f"line {n}: expected 15 fields, got {line!r}"
            raise ValueError(msg)
        x1, y1, x2, y2 = (float(v) for v in f[4:8])
        out.append((f[0], (x1, y1, x2 - x1, y2 - y1)))
    return out


def kitti_calib(rec: FrameRecord) -> str:
    """KITTI calibration text: ``P0..P3`` = K [I | 0], ``R0_rect`` = I, and ``Tr_velo_to_cam`` = the
    map -> camera transform (there is no lidar: the "velodyne" frame is ``map``)."""
    k = rec.k
    p = np.hstack([k, np.zeros((3, 1))])
    t = np.asarray(rec.t_map_camera, dtype=np.float64)
    rot = t[:3, :3]
    tr = np.hstack([rot.T, (-rot.T @ t[:3, 3]).reshape(3, 1)])

    def row(m: npt.NDArray[np.float64]) -> str:
        return " ".join(f"{v:.12e}" for v in m.reshape(-1))

    lines = [f"P{i}: {row(p)}" for i in range(4)]
    lines += [f"R0_rect: {row(np.eye(3))}", f"Tr_velo_to_cam: {row(tr)}", f"Tr_imu_to_velo: {row(np.eye(4)[:3])}"]
    return "\n".join(lines) + "\n"
