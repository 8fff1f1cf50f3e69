"""The records of a dataset: one :class:`FrameRecord` per frame, one :class:`InstanceLabel` per labelled object.

They are what the workers journal (one JSON line per finished frame), what the annotation writers
read, and what ``frames.jsonl`` holds in a finished dataset. Every attribute is defined exactly in
``docs/datasets.md``; the short version:

* pixel boxes are ``[x, y, w, h]`` in pixel-edge coordinates (pixel column ``c`` spans
  ``[c, c + 1)``, as in COCO), so a tight box is exactly its mask's extent;
* ``visible_fraction`` = visible pixels / pixels the object would cover with nothing in front of it,
  both inside the image;
* ``truncation`` = 1 - (area of the projected 3D box inside the image) / (its whole area);
* 3D boxes are in ``map`` (x East, y North, z Up): base centre, size (length along the object's x,
  width, height) and yaw.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["SIZE_BINS", "FrameRecord", "InstanceLabel", "size_bin"]

#: TinyPerson's size bins over sqrt(w * h) of the tight box in pixels: [low, high) and a label.
SIZE_BINS: tuple[tuple[float, float, str], ...] = (
    (0.0, 8.0, "1-8"),
    (8.0, 12.0, "8-12"),
    (12.0, 20.0, "12-20"),
    (20.0, 32.0, "20-32"),
    (32.0, math.inf, ">32"),
)


def size_bin(size_px: float) -> str:
    """TinyPerson bin of an object whose tight box has ``sqrt(w * h) = size_px``."""
    for lo, hi, label in SIZE_BINS:
        if lo <= size_px < hi:
            return label
    return SIZE_BINS[-1][2]


def _r(value: float, digits: int = 6) -> float:
    return round(float(value), digits)


@dataclass(frozen=True)
class InstanceLabel:
    """One labelled object in one frame (see the module docstring and ``docs/datasets.md``)."""

    instance_id: int
    track_id: int
    class_name: str
    class_id: int
    object_name: str
    bbox: tuple[int, int, int, int]
    bbox_loose: tuple[float, float, float, float]
    segmentation: dict[str, Any]
    area: int
    unoccluded_pixels: int
    visible_fraction: float
    truncation: float
    range_m: float
    height_above_ground_m: float
    camera_height_m: float
    view_angle_deg: float
    box3d_position_m: tuple[float, float, float]
    box3d_size_m: tuple[float, float, float]
    box3d_yaw_rad: float
    #: KITTI: the box's bottom centre in the camera's optical frame, its rotation about the optical y axis, and
    #: the observation angle.
    location_camera_m: tuple[float, float, float]
    rotation_y_rad: float
    alpha_rad: float

    @property
    def size_px(self) -> float:
        return math.sqrt(self.bbox[2] * self.bbox[3])

    @property
    def size_bin(self) -> str:
        return size_bin(self.size_px)

    @property
    def box3d_corners_m(self) -> npt.NDArray[np.float64]:
        """``(8, 3)`` corners in ``map``: bottom face then top face, counter-clockwise from (-l/2, -w/2)."""
        length, width, height = self.box3d_size_m
        local = np.array(
            [
                [sx * length / 2, sy * width / 2, z]
                for z in (0.0, height)
                for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))
            ]
        )
        c, s = math.cos(self.box3d_yaw_rad), math.sin(self.box3d_yaw_rad)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return np.asarray(local @ rot.T + np.asarray(self.box3d_position_m))

    def to_json(self) -> dict[str, Any]:
        return {
            "instance_id": self.instance_id,
            "track_id": self.track_id,
            "class_name": self.class_name,
            "class_id": self.class_id,
            "object_name": self.object_name,
            "bbox": list(self.bbox),
            "bbox_loose": [_r(v, 4) for v in self.bbox_loose],
            "segmentation": self.segmentation,
            "area": self.area,
            "unoccluded_pixels": self.unoccluded_pixels,
            "visible_fraction": _r(self.visible_fraction),
            "truncation": _r(self.truncation),
            "range_m": _r(self.range_m, 4),
            "height_above_ground_m": _r(self.height_above_ground_m, 4),
            "camera_height_m": _r(self.camera_height_m, 4),
            "view_angle_deg": _r(self.view_angle_deg, 4),
            "box3d": {
                "position_m": [_r(v, 4) for v in self.box3d_position_m],
                "size_m": [_r(v, 4) for v in self.box3d_size_m],
                "yaw_rad": _r(self.box3d_yaw_rad),
            },
            "location_camera_m": [_r(v, 4) for v in self.location_camera_m],
            "rotation_y_rad": _r(self.rotation_y_rad),
            "alpha_rad": _r(self.alpha_rad),
            "size_px": _r(self.size_px, 4),
            "size_bin": self.size_bin,
        }

    @staticmethod
    def from_json(d: dict[str, Any]) -> InstanceLabel:
        box = d["box3d"]
        x, y, w, h = (int(v) for v in d["bbox"])
        lx, ly, lw, lh = (float(v) for v in d["bbox_loose"])
        px, py, pz = (float(v) for v in box["position_m"])
        sx, sy, sz = (float(v) for v in box["size_m"])
        cx, cy, cz = (float(v) for v in d["location_camera_m"])
        return InstanceLabel(
            instance_id=int(d["instance_id"]),
            track_id=int(d["track_id"]),
            class_name=str(d["class_name"]),
            class_id=int(d["class_id"]),
            object_name=str(d["object_name"]),
            bbox=(x, y, w, h),
            bbox_loose=(lx, ly, lw, lh),
            segmentation=dict(d["segmentation"]),
            area=int(d["area"]),
            unoccluded_pixels=int(d["unoccluded_pixels"]),
            visible_fraction=float(d["visible_fraction"]),
            truncation=float(d["truncation"]),
            range_m=float(d["range_m"]),
            height_above_ground_m=float(d["height_above_ground_m"]),
            camera_height_m=float(d["camera_height_m"]),
            view_angle_deg=float(d["view_angle_deg"]),
            box3d_position_m=(px, py, pz),
            box3d_size_m=(sx, sy, sz),
            box3d_yaw_rad=float(box["yaw_rad"]),
            location_camera_m=(cx, cy, cz),
            rotation_y_rad=float(d["rotation_y_rad"]),
            alpha_rad=float(d["alpha_rad"]),
        )


@dataclass(frozen=True)
class FrameRecord:
    """One frame: where it was taken, what files it has and its labels.

    Attributes:
        index: position in the dataset (0-based; the COCO image id is ``index + 1``).
        name: file stem (``000123``); files are ``images/<split>/<name>.png`` and so on.
        split: the split it belongs to.
        world_seed, world_name, world_hash: the world it was rendered in.
        sequence, sequence_frame: for flights, the sequence name and the 1-based frame number in it.
        timestamp_s: simulation time of the world state (0 for sampled viewpoints of the static world).
        width, height, fx, fy, cx, cy: intrinsics (OpenCV convention: pixel centres at integers).
        t_map_camera: 4x4 pose of the camera's optical frame (x right, y down, z forward) in ``map``.
        altitude_agl_m: camera height above the terrain under it.
        pitch_deg: depression of the optical axis below the horizon (90 = nadir).
        yaw_deg: heading of the view, counter-clockwise from east, in [0, 360).
        files: relative paths of the frame's files (image, depth, instance_mask, class_mask, yolo, kitti, calib).
        labels: the labelled instances.
        attempts: viewpoint draws made for this frame (1 = the first draw was valid).
        position_mode: the viewpoint mode that chose it (``flight`` for flights).
    """

    index: int
    name: str
    split: str
    world_seed: int
    world_name: str
    world_hash: str
    sequence: str
    sequence_frame: int
    timestamp_s: float
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    t_map_camera: tuple[tuple[float, ...], ...]
    altitude_agl_m: float
    pitch_deg: float
    yaw_deg: float
    files: dict[str, str] = field(default_factory=dict)
    labels: tuple[InstanceLabel, ...] = ()
    attempts: int = 1
    position_mode: str = ""

    @property
    def k(self) -> npt.NDArray[np.float64]:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def to_json(self) -> dict[str, Any]:
        return {
            "index": self.index,
            "name": self.name,
            "split": self.split,
            "world": {"seed": self.world_seed, "name": self.world_name, "hash": self.world_hash},
            "sequence": self.sequence,
            "sequence_frame": self.sequence_frame,
            "timestamp_s": _r(self.timestamp_s, 9),
            "camera": {
                "width": self.width,
                "height": self.height,
                "fx": self.fx,
                "fy": self.fy,
                "cx": self.cx,
                "cy": self.cy,
            },
            "t_map_camera": [[_r(v, 9) for v in row] for row in self.t_map_camera],
            "altitude_agl_m": _r(self.altitude_agl_m, 4),
            "pitch_deg": _r(self.pitch_deg, 4),
            "yaw_deg": _r(self.yaw_deg, 4),
            "files": dict(sorted(self.files.items())),
            "attempts": self.attempts,
            "position_mode": self.position_mode,
            "labels": [lab.to_json() for lab in self.labels],
        }

    @staticmethod
    def from_json(d: dict[str, Any]) -> FrameRecord:
        cam = d["camera"]
        world = d["world"]
        return FrameRecord(
            index=int(d["index"]),
            name=str(d["name"]),
            split=str(d["split"]),
            world_seed=int(world["seed"]),
            world_name=str(world["name"]),
            world_hash=str(world["hash"]),
            sequence=str(d["sequence"]),
            sequence_frame=int(d["sequence_frame"]),
            timestamp_s=float(d["timestamp_s"]),
            width=int(cam["width"]),
            height=int(cam["height"]),
            fx=float(cam["fx"]),
            fy=float(cam["fy"]),
            cx=float(cam["cx"]),
            cy=float(cam["cy"]),
            t_map_camera=tuple(tuple(float(v) for v in row) for row in d["t_map_camera"]),
            altitude_agl_m=float(d["altitude_agl_m"]),
            pitch_deg=float(d["pitch_deg"]),
            yaw_deg=float(d["yaw_deg"]),
            files={str(k): str(v) for k, v in d["files"].items()},
            labels=tuple(InstanceLabel.from_json(lab) for lab in d["labels"]),
            attempts=int(d.get("attempts", 1)),
            position_mode=str(d.get("position_mode", "")),
        )
