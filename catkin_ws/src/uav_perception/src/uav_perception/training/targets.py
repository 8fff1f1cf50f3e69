"""Training targets without torch: CenterNet heatmaps, offsets and sizes for a crop, and the crops themselves.

The network's output cell ``(row, col)`` covers input pixels ``[4 col, 4 col + 4) x [4 row, 4 row + 4)``
(:data:`STRIDE`); an object's centre ``(cx, cy)`` (pixel edges) falls in cell ``(int(cy / 4), int(cx / 4))``, whose
targets are a heatmap peak of 1 in the object's class, the offset ``(cx / 4 - col, cy / 4 - row)`` in [0, 1) and
the log size ``(log w, log h)``; the export decodes ``cx = (col + offset_x) * 4`` (``model.Decoded``).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["STRIDE", "crop_boxes", "make_targets"]

#: Output stride: one heatmap cell per 4x4 input pixels.
STRIDE = 4


def make_targets(
    boxes: np.ndarray, labels: np.ndarray, num_classes: int, *, out_h: int, out_w: int, min_box_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """CenterNet targets for one crop: heatmap ``[C, h, w]``, offset and log-size ``[2, h, w]``, mask ``[h, w]``.

    ``boxes`` ``[n, 4]`` pixel-edge ``[x, y, w, h]`` in the crop. The Gaussian's sigma follows the box size in
    cells (at least 0.5 cell), so a 12 px person peaks over about one cell and a 60 px car over several.
    """
    heat = np.zeros((num_classes, out_h, out_w), np.float32)
    offset = np.zeros((2, out_h, out_w), np.float32)
    logsize = np.zeros((2, out_h, out_w), np.float32)
    mask = np.zeros((out_h, out_w), np.float32)
    ys, xs = np.mgrid[0:out_h, 0:out_w].astype(np.float32)
    order = np.argsort(-(boxes[:, 2] * boxes[:, 3])) if len(boxes) else np.zeros(0, np.int64)
    for i in order:  # large first: a small object's regression wins its cell
        x, y, w, h = boxes[i]
        if w < min_box_px or h < min_box_px:
            continue
        cx, cy = (x + w / 2) / STRIDE, (y + h / 2) / STRIDE
        col, row = int(cx), int(cy)
        if not (0 <= col < out_w and 0 <= row < out_h):
            continue
        sigma = max(0.5, 0.15 * math.sqrt(w * h) / STRIDE)
        g = np.exp(-((xs - (col + 0.5)) ** 2 + (ys - (row + 0.5)) ** 2) / (2 * sigma * sigma))
        heat[labels[i]] = np.maximum(heat[labels[i]], g)
        heat[labels[i], row, col] = 1.0
        offset[:, row, col] = (cx - col, cy - row)
        logsize[:, row, col] = (math.log(w), math.log(h))
        mask[row, col] = 1.0
    return heat, offset, logsize, mask


def crop_boxes(
    image: np.ndarray, boxes: np.ndarray, labels: np.ndarray, *, size: int, rng: np.random.Generator, around: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    h, w = image.shape[:2]
    if around and len(boxes):
        bx, by, bw, bh = boxes[rng.integers(len(boxes))]
        cx = bx + bw / 2 + rng.uniform(-0.4, 0.4) * size
        cy = by + bh / 2 + rng.uniform(-0.4, 0.4) * size
        x0 = int(np.clip(cx - size / 2, 0, w - size))
        y0 = int(np.clip(cy - size / 2, 0, h - size))
    else:
        x0, y0 = int(rng.integers(0, w - size + 1)), int(rng.integers(0, h - size + 1))
    crop = image[y0 : y0 + size, x0 : x0 + size]
    b = boxes.copy()
    b[:, 0] -= x0
    b[:, 1] -= y0
    # clip to the crop; keep a box whose visible part keeps at least half of it
    x1 = np.clip(b[:, 0] + b[:, 2], 0, size)
    y1 = np.clip(b[:, 1] + b[:, 3], 0, size)
    nx0, ny0 = np.clip(b[:, 0], 0, size), np.clip(b[:, 1], 0, size)
    area = b[:, 2] * b[:, 3]
    new = np.stack([nx0, ny0, x1 - nx0, y1 - ny0], axis=1)
    keep = (new[:, 2] > 0) & (new[:, 3] > 0) & (new[:, 2] * new[:, 3] >= 0.5 * np.maximum(area, 1e-6))
    return crop, new[keep], labels[keep]
