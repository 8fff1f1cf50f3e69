"""``uav-dataset preview``: a contact sheet of a dataset's frames with masks and boxes drawn (OpenCV).

Each tile is one frame: its image, each labelled instance's mask tinted in a colour of its track,
its tight box (the visible pixels' extent) as a rectangle in that colour (and a ring around it when it
is only a few pixels on the sheet), its loose box (the projected 3D box, clipped to the image) as a thin
white one, and a caption (frame, split, camera
altitude and pitch, label count). Frames are picked evenly over the dataset, frames with labels first.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt

from uav_datasets.core import rle
from uav_datasets.core.records import FrameRecord
from uav_datasets.errors import DatasetError
from uav_datasets.shell.folder import read_records
from uav_datasets.shell.writers import atomic_write

__all__ = ["contact_sheet", "pick_frames", "write_preview"]

_LOOSE_BGR = (255, 255, 255)
_TEXT_BGR = (255, 255, 255)


def _track_colour(track_id: int) -> tuple[int, int, int]:
    """A bright, stable BGR colour per track (golden-angle hue)."""
    hue = int((track_id * 137.508) % 180)
    hsv = np.array([[[hue, 220, 255]]], dtype=np.uint8)
    b, g, r = (int(v) for v in cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0])
    return b, g, r


def pick_frames(frames: Sequence[FrameRecord], count: int) -> list[FrameRecord]:
    """Up to ``count`` frames spread evenly over the dataset, from the frames with labels when enough have some."""
    labelled = [f for f in frames if f.labels]
    pool = labelled if len(labelled) >= count else list(frames)
    if len(pool) <= count:
        return list(pool)
    step = len(pool) / count
    return [pool[math.floor(k * step)] for k in range(count)]


def _tile(folder: Path, rec: FrameRecord, width: int) -> npt.NDArray[np.uint8]:
    image_path = folder / rec.files["image"] if "image" in rec.files else None
    img = cv2.imread(str(image_path)) if image_path is not None else None
    if img is None:
        img = np.full((rec.height, rec.width, 3), 60, np.uint8)
    overlay = img.copy()
    for lab in rec.labels:
        mask = rle.decode(lab.segmentation)
        overlay[mask] = _track_colour(lab.track_id)
    img = cv2.addWeighted(overlay, 0.55, img, 0.45, 0.0)
    scale = width / rec.width
    height = round(rec.height * scale)
    img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    for lab in rec.labels:
        lx, ly, lw, lh = lab.bbox_loose
        cv2.rectangle(
            img,
            (round(lx * scale), round(ly * scale)),
            (round((lx + lw) * scale), round((ly + lh) * scale)),
            _LOOSE_BGR,
            1,
        )
        x, y, w, h = lab.bbox
        x0, y0 = math.floor(x * scale), math.floor(y * scale)
        x1, y1 = math.ceil((x + w) * scale) - 1, math.ceil((y + h) * scale) - 1
        cv2.rectangle(img, (x0 - 1, y0 - 1), (x1 + 1, y1 + 1), _track_colour(lab.track_id), 1)
        if max(x1 - x0, y1 - y0) < 8:  # a tiny object: ring it so the eye finds it on the sheet
            centre = ((x0 + x1) // 2, (y0 + y1) // 2)
            cv2.circle(img, centre, 10, _track_colour(lab.track_id), 1, cv2.LINE_AA)
        if lab.size_px >= 12:
            cv2.putText(
                img, lab.class_name, (x0, max(10, y0 - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.35, _TEXT_BGR, 1, cv2.LINE_AA
            )
    caption = (
        f"{rec.name} {rec.split}  alt {rec.altitude_agl_m:.0f} m  pitch {rec.pitch_deg:.0f}  {len(rec.labels)} labels"
    )
    bar = np.zeros((18, width, 3), np.uint8)
    cv2.putText(bar, caption, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, _TEXT_BGR, 1, cv2.LINE_AA)
    return np.vstack([bar, img])


def contact_sheet(
    folder: Path, frames: Sequence[FrameRecord], *, columns: int = 4, tile_width: int = 480
) -> npt.NDArray[np.uint8]:
    """The contact sheet (BGR) of ``frames``: ``columns`` tiles per row, with a legend on top."""
    if not frames:
        msg = f"{folder}: no frames to preview"
        raise DatasetError(msg)
    tiles = [_tile(folder, rec, tile_width) for rec in frames]
    th, tw = tiles[0].shape[:2]
    rows = math.ceil(len(tiles) / columns)
    cols = min(columns, len(tiles))
    gap = 4
    sheet = np.full((rows * (th + gap) + gap + 22, cols * (tw + gap) + gap, 3), 25, np.uint8)
    legend = (
        "tint: instance mask (visible pixels)   box in the tint colour: tight box   white: loose box (projected 3D box)"
    )
    cv2.putText(sheet, legend, (gap, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, _TEXT_BGR, 1, cv2.LINE_AA)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, columns)
        y = 22 + gap + r * (th + gap)
        x = gap + c * (tw + gap)
        sheet[y : y + tile.shape[0], x : x + tile.shape[1]] = tile
    return sheet


def write_preview(
    folder: Path, out: Path | None = None, *, count: int = 16, columns: int = 4, tile_width: int = 480
) -> Path:
    """Write the contact sheet of a finished dataset (default ``<folder>/preview.png``); returns its path.

    Raises:
        DatasetFolderError, IncompleteDatasetError: not a finished dataset.
    """
    frames = pick_frames(read_records(folder), count)
    sheet = contact_sheet(folder, frames, columns=columns, tile_width=tile_width)
    path = out or folder / "preview.png"
    ok, buf = cv2.imencode(".png", sheet)
    if not ok:  # pragma: no cover
        msg = f"could not encode the contact sheet for {path}"
        raise DatasetError(msg)
    atomic_write(path, bytes(buf.tobytes()))
    return path
