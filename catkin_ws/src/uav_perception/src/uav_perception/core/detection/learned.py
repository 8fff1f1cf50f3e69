"""The learned detector's pure half: the model's format, pre-processing, decoding and NMS (numpy only).

**The model format** (docs/detector.md) is the one YOLOv8/YOLO11 ONNX exports use, so such a model runs
unchanged next to the range's own (``uav-train-detector``):

* one input, ``float32 [1, 3, H, W]``: RGB in [0, 1]; ``H`` and ``W`` fixed (the image is letterboxed into
  them: scaled to fit, keeping its aspect, padded with grey 114/255) or dynamic (the image is padded at the
  bottom and right to a multiple of :data:`DYNAMIC_STRIDE`);
* its first output, ``float32 [1, 4 + C, N]``: for each of ``N`` candidates the box centre and size
  ``(cx, cy, w, h)`` in the input's pixels (pixel-edge coordinates, COCO's: a box over columns 10..19 is
  ``cx = 15, w = 10``), then ``C`` class scores in [0, 1] (no objectness; already sigmoid);
* the classes: the model's metadata ``uav_classes`` (a JSON list of the range's class names, column by
  column) or, without it, column ``k`` is class id ``k`` (COCO-80 as YOLO numbers it: person 0, car 2).

:func:`validate_io` checks a model's declared inputs and outputs against that; :func:`check_output` the
array a model actually returned. :func:`decode` turns the output into ``RawDetection`` in the camera's pixel
convention (``boxes.py``), after class-wise NMS; candidates with a NaN or infinite value, an empty box or a
box reaching more than ``margin_px`` past the image are counted by reason and discarded.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_perception.core.detection.boxes import RawDetection
from uav_perception.errors import ModelFormatError

__all__ = [
    "DYNAMIC_STRIDE",
    "LETTERBOX_FILL",
    "DecodeConfig",
    "Letterbox",
    "ModelSpec",
    "TensorInfo",
    "check_output",
    "decode",
    "letterbox",
    "nms",
    "validate_io",
]

#: A dynamic input is padded to a multiple of this (the deepest stride of common detectors).
DYNAMIC_STRIDE = 32
#: The letterbox's padding (YOLO's grey).
LETTERBOX_FILL = 114


@dataclass(frozen=True)
class TensorInfo:
    """A model input or output as its file declares it (``None`` or a string for a dynamic dimension)."""

    name: str
    shape: tuple[int | str | None, ...]
    dtype: str


@dataclass(frozen=True)
class ModelSpec:
    """What the node needs to know about a validated model."""

    input_name: str
    #: ``(H, W)`` of a fixed input; ``None`` for a dynamic one.
    input_hw: tuple[int, int] | None
    #: Number of class columns ``C`` (``None`` if the file leaves it dynamic: known after the first run).
    num_classes: int | None


@dataclass(frozen=True)
class DecodeConfig:
    """How candidates become detections (the ``detector`` node's ``~`` parameters)."""

    #: Candidates scoring below this are dropped before NMS (keep it low: the scorer's AP needs the low scores;
    #: the scenario's ``score_threshold`` is the operating point).
    score_threshold: float = 0.05
    #: Two boxes of one class overlapping more than this (IoU) are one object: the lower-scoring one goes.
    iou_threshold: float = 0.5
    max_detections: int = 100
    #: Boxes reaching farther than this past the image's edges are discarded (``out_of_image``).
    margin_px: float = 2.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.score_threshold <= 1.0:
            msg = f"score_threshold must be within [0, 1], got {self.score_threshold}"
            raise ValueError(msg)
        if not 0.0 < self.iou_threshold <= 1.0:
            msg = f"iou_threshold must be within (0, 1], got {self.iou_threshold}"
            raise ValueError(msg)
        if self.max_detections < 1:
            msg = f"max_detections must be >= 1, got {self.max_detections}"
            raise ValueError(msg)
        if not (math.isfinite(self.margin_px) and self.margin_px >= 0.0):
            msg = f"margin_px must be finite and >= 0, got {self.margin_px}"
            raise ValueError(msg)


_EXPECTED = (
    "one input float32 [1, 3, H, W] (RGB in [0, 1]) and a first output float32 [1, 4 + C, N] "
    "(cx, cy, w, h, C class scores)"
)


def _static(dim: int | str | None) -> int | None:
    return dim if isinstance(dim, int) and dim > 0 else None


def validate_io(path: str, inputs: Sequence[TensorInfo], outputs: Sequence[TensorInfo]) -> ModelSpec:
    """Check a model's declared inputs and outputs against the format.

    Raises:
        ModelFormatError: naming ``path``, what it has and what was expected.
    """
    if len(inputs) != 1:
        msg = f"{path}: the model has {len(inputs)} inputs; expected {_EXPECTED}"
        raise ModelFormatError(msg)
    if not outputs:
        msg = f"{path}: the model has no output; expected {_EXPECTED}"
        raise ModelFormatError(msg)
    inp, out = inputs[0], outputs[0]
    if "float" not in inp.dtype or "16" in inp.dtype or len(inp.shape) != 4 or inp.shape[1] != 3:
        msg = f"{path}: input {inp.name!r} is {inp.dtype} {list(inp.shape)}; expected {_EXPECTED}"
        raise ModelFormatError(msg)
    if _static(inp.shape[0]) not in (None, 1):
        msg = f"{path}: input {inp.name!r} has batch {inp.shape[0]}; expected 1 (or dynamic)"
        raise ModelFormatError(msg)
    h, w = _static(inp.shape[2]), _static(inp.shape[3])
    if (h is None) != (w is None):
        msg = f"{path}: input {inp.name!r} {list(inp.shape)} fixes one of H, W but not the other; expected both or none"
        raise ModelFormatError(msg)
    if "float" not in out.dtype or "16" in out.dtype or len(out.shape) != 3:
        msg = f"{path}: output {out.name!r} is {out.dtype} {list(out.shape)}; expected {_EXPECTED}"
        raise ModelFormatError(msg)
    if _static(out.shape[0]) not in (None, 1):
        msg = f"{path}: output {out.name!r} has batch {out.shape[0]}; expected 1"
        raise ModelFormatError(msg)
    rows = _static(out.shape[1])
    if rows is not None and rows < 5:
        msg = f"{path}: output {out.name!r} is {list(out.shape)}: {rows} rows per candidate; expected {_EXPECTED}"
        raise ModelFormatError(msg)
    return ModelSpec(inp.name, None if h is None or w is None else (h, w), None if rows is None else rows - 4)


def check_output(path: str, output: npt.NDArray[Any], spec: ModelSpec, num_names: int | None) -> int:
    """Check an array the model returned; the number of classes ``C``.

    ``num_names``: the number of class names the model's metadata gives (``None``: none given).

    Raises:
        ModelFormatError: naming ``path``: wrong rank, batch, dtype, or a class count that differs from the
        declared one or from the metadata's names.
    """
    if output.ndim != 3 or output.shape[0] != 1 or output.shape[1] < 5 or not np.issubdtype(output.dtype, np.floating):
        msg = f"{path}: the model returned {output.dtype} {list(output.shape)}; expected {_EXPECTED}"
        raise ModelFormatError(msg)
    classes = int(output.shape[1]) - 4
    if spec.num_classes is not None and classes != spec.num_classes:
        msg = f"{path}: the model returned {classes} class columns but declares {spec.num_classes}"
        raise ModelFormatError(msg)
    if num_names is not None and classes != num_names:
        msg = f"{path}: the model returned {classes} class columns but its metadata uav_classes names {num_names}"
        raise ModelFormatError(msg)
    return classes


@dataclass(frozen=True)
class Letterbox:
    """How an image was put into the model's input: ``input = image * scale + (pad_x, pad_y)``."""

    scale: float
    pad_x: float
    pad_y: float


def _resize_bilinear(image: npt.NDArray[Any], out_h: int, out_w: int) -> npt.NDArray[Any]:
    """Bilinear resize (half-pixel centres, as OpenCV's INTER_LINEAR) of an ``(h, w, 3)`` uint8 image, float32."""
    h, w = image.shape[:2]
    ys = np.clip((np.arange(out_h, dtype=np.float32) + 0.5) * (h / out_h) - 0.5, 0, h - 1)
    xs = np.clip((np.arange(out_w, dtype=np.float32) + 0.5) * (w / out_w) - 0.5, 0, w - 1)
    y0 = np.floor(ys).astype(np.intp)
    x0 = np.floor(xs).astype(np.intp)
    y1 = np.minimum(y0 + 1, h - 1)
    x1 = np.minimum(x0 + 1, w - 1)
    fy = (ys - y0)[:, None, None]
    fx = (xs - x0)[None, :, None]
    img = image.astype(np.float32)
    top = img[y0][:, x0] * (1 - fx) + img[y0][:, x1] * fx
    bottom = img[y1][:, x0] * (1 - fx) + img[y1][:, x1] * fx
    out: npt.NDArray[Any] = top * (1 - fy) + bottom * fy
    return out


def letterbox(image_rgb: npt.NDArray[Any], input_hw: tuple[int, int] | None) -> tuple[npt.NDArray[Any], Letterbox]:
    """The model's input tensor ``float32 [1, 3, H, W]`` for an ``(h, w, 3)`` uint8 RGB image.

    Fixed ``input_hw``: scaled to fit (the aspect kept), centred, padded with :data:`LETTERBOX_FILL`; an image
    of exactly that size is passed as it is. ``None``: padded at the bottom and right to a multiple of
    :data:`DYNAMIC_STRIDE`.

    Raises:
        ValueError: the image is not ``(h, w, 3)`` uint8 with h, w > 0.
    """
    if image_rgb.ndim != 3 or image_rgb.shape[2] != 3 or image_rgb.dtype != np.uint8 or 0 in image_rgb.shape:
        msg = f"expected an (h, w, 3) uint8 RGB image, got {image_rgb.dtype} {image_rgb.shape}"
        raise ValueError(msg)
    h, w = image_rgb.shape[:2]
    if input_hw is None:
        th = -(-h // DYNAMIC_STRIDE) * DYNAMIC_STRIDE
        tw = -(-w // DYNAMIC_STRIDE) * DYNAMIC_STRIDE
        scale, new_h, new_w, px, py = 1.0, h, w, 0, 0
    else:
        th, tw = input_hw
        scale = min(th / h, tw / w)
        new_h, new_w = max(1, round(h * scale)), max(1, round(w * scale))
        px, py = (tw - new_w) // 2, (th - new_h) // 2
    canvas = np.full((th, tw, 3), LETTERBOX_FILL / 255.0, dtype=np.float32)
    if (new_h, new_w) == (h, w):
        canvas[py : py + h, px : px + w] = image_rgb.astype(np.float32) * (1.0 / 255.0)
    else:
        canvas[py : py + new_h, px : px + new_w] = _resize_bilinear(image_rgb, new_h, new_w) * (1.0 / 255.0)
    tensor = np.ascontiguousarray(canvas.transpose(2, 0, 1)[None])
    sx = new_w / w
    return tensor, Letterbox(scale=sx, pad_x=float(px), pad_y=float(py))


def _iou_one(box: npt.NDArray[Any], others: npt.NDArray[Any]) -> npt.NDArray[Any]:
    x0 = np.maximum(box[0], others[:, 0])
    y0 = np.maximum(box[1], others[:, 1])
    x1 = np.minimum(box[2], others[:, 2])
    y1 = np.minimum(box[3], others[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area = (box[2] - box[0]) * (box[3] - box[1])
    areas = (others[:, 2] - others[:, 0]) * (others[:, 3] - others[:, 1])
    union = area + areas - inter
    out: npt.NDArray[Any] = np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)
    return out


def nms(
    boxes_xyxy: npt.NDArray[Any], scores: npt.NDArray[Any], iou_threshold: float, max_keep: int
) -> npt.NDArray[Any]:
    """Greedy non-maximum suppression: indices of the kept boxes, best score first.

    A box is dropped when it overlaps a kept, higher-scoring box by more than ``iou_threshold`` (IoU); ties
    in score keep the earlier box.
    """
    order = np.argsort(-scores, kind="stable")
    keep: list[int] = []
    while order.size and len(keep) < max_keep:
        i = int(order[0])
        keep.append(i)
        rest = order[1:]
        order = rest[_iou_one(boxes_xyxy[i], boxes_xyxy[rest]) <= iou_threshold]
    return np.asarray(keep, dtype=np.intp)


def decode(
    output: npt.NDArray[Any],
    lb: Letterbox,
    *,
    width_px: int,
    height_px: int,
    class_ids: Sequence[int],
    cfg: DecodeConfig,
) -> tuple[list[RawDetection], Counter[str]]:
    """The model's output ``[1, 4 + C, N]`` -> detections in the image's pixels, and the discards by reason.

    A candidate with a NaN or infinite value anywhere is counted (``nan_box``) and discarded; the others take
    their best class, and those below ``cfg.score_threshold`` are not detections (not counted); of the rest, a
    size <= 0 (``empty_box``) or a box reaching more than ``cfg.margin_px`` past the image (``out_of_image``) are
    counted and discarded; then
    class-wise NMS, at most ``cfg.max_detections``, best first. ``class_ids[k]`` is column ``k``'s class id.
    Boxes kept are clipped to the image and given in the contract's convention (centre of pixel ``(r, c)`` at
    ``(c, r)``).
    """
    pred = np.asarray(output[0], dtype=np.float64).T  # (N, 4 + C)
    num_classes = pred.shape[1] - 4
    if len(class_ids) != num_classes:
        msg = f"{len(class_ids)} class ids for {num_classes} class columns"
        raise ValueError(msg)
    discarded: Counter[str] = Counter()
    if pred.shape[0] == 0:
        return [], discarded
    bad = ~np.all(np.isfinite(pred), axis=1)
    discarded["nan_box"] += int(bad.sum())
    pred = pred[~bad]
    best = np.argmax(pred[:, 4:], axis=1)
    score = pred[np.arange(len(pred)), 4 + best]
    passing = score >= cfg.score_threshold
    pred, best, score = pred[passing], best[passing], score[passing]
    geometry = pred[:, :4]
    empty = (geometry[:, 2] <= 0) | (geometry[:, 3] <= 0)
    discarded["empty_box"] += int(empty.sum())
    pred, best, score, geometry = pred[~empty], best[~empty], score[~empty], geometry[~empty]
    score = np.clip(score, 0.0, 1.0)
    # input pixel-edge coordinates -> image pixel-edge coordinates -> the contract's (centre of pixel at c).
    cx = (geometry[:, 0] - lb.pad_x) / lb.scale
    cy = (geometry[:, 1] - lb.pad_y) / lb.scale
    bw = geometry[:, 2] / lb.scale
    bh = geometry[:, 3] / lb.scale
    x0, y0, x1, y1 = cx - bw / 2 - 0.5, cy - bh / 2 - 0.5, cx + bw / 2 - 0.5, cy + bh / 2 - 0.5
    lo, hi_u, hi_v = -0.5 - cfg.margin_px, width_px - 0.5 + cfg.margin_px, height_px - 0.5 + cfg.margin_px
    outside = (x0 < lo) | (y0 < lo) | (x1 > hi_u) | (y1 > hi_v)
    discarded["out_of_image"] += int(outside.sum())
    keep_in = ~outside
    x0 = np.clip(x0[keep_in], -0.5, width_px - 0.5)
    y0 = np.clip(y0[keep_in], -0.5, height_px - 0.5)
    x1 = np.clip(x1[keep_in], -0.5, width_px - 0.5)
    y1 = np.clip(y1[keep_in], -0.5, height_px - 0.5)
    best, score = best[keep_in], score[keep_in]
    xyxy = np.stack([x0, y0, x1, y1], axis=1)
    # Class-wise NMS in one pass: shift each class's boxes far apart.
    offset = best[:, None].astype(np.float64) * (4.0 * (width_px + height_px) + 8.0)
    kept = nms(xyxy + offset, score, cfg.iou_threshold, cfg.max_detections)
    out = []
    for i in kept:
        u0, v0, u1, v1 = (float(v) for v in xyxy[i])
        out.append(
            RawDetection(
                0.5 * (u0 + u1),
                0.5 * (v0 + v1),
                u1 - u0,
                v1 - v0,
                ((int(class_ids[int(best[i])]), float(score[i])),),
            )
        )
    return out, +discarded  # unary plus drops the zero counts
