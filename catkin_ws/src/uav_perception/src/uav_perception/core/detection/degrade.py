"""A test instrument, not a detector: the ground truth's boxes made worse, seeded.

It exists to exercise the detector contract end to end (geolocation, tracking, confirmation, scoring)
with boxes only, before a real detector is in the loop: it takes the ground truth's box-only
``Detection2DArray`` (no instance ids, no 3D positions: the simulator publishes those on another topic,
for scoring) and

* misses objects, more often the smaller they are (``miss_rate_large`` at ``large_size_px`` and above,
  ``miss_rate_small`` at ``small_size_px`` and below, linear between; size = sqrt of the box area);
* moves every edge of a kept box by Gaussian noise (``jitter_px`` + ``jitter_rel`` of the box's size);
* mislabels a kept box as another class with probability ``confusion_rate``;
* scores kept boxes around ``score_true`` and adds Poisson(``false_positives_per_frame``) false boxes
  (log-uniform size in ``false_positive_size_px``, person-like or car-like shape, anywhere in the image)
  scored around ``score_false``.

What it cannot do is what makes a real detector hard: it never sees the image, so it cannot be fooled
by a shadow or a rock, and its errors are independent from frame to frame. Its scores say nothing about
the image. Never report its numbers as a detector's.

Every frame draws from its own generator seeded by ``(seed, stamp, camera)``, so a frame degrades the
same way whatever came before it (a replay, a dropped frame, another order).
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from uav_perception.core.detection.boxes import Box, RawDetection

__all__ = ["DegradeConfig", "degrade", "frame_rng"]


@dataclass(frozen=True)
class DegradeConfig:
    """How much worse than the ground truth (the stand-in detector's ``~`` parameters)."""

    seed: int = 0
    miss_rate_small: float = 0.6
    miss_rate_large: float = 0.05
    small_size_px: float = 6.0
    large_size_px: float = 24.0
    jitter_px: float = 0.5
    jitter_rel: float = 0.06
    confusion_rate: float = 0.02
    false_positives_per_frame: float = 0.3
    false_positive_size_px: tuple[float, float] = (5.0, 40.0)
    score_true: tuple[float, float] = (0.8, 0.12)
    score_false: tuple[float, float] = (0.45, 0.15)
    #: Relative frequency of each class among false positives (names from the class map).
    false_positive_classes: dict[str, float] = field(default_factory=lambda: {"person": 1.0, "vehicle": 1.0})

    def __post_init__(self) -> None:
        for name in ("miss_rate_small", "miss_rate_large", "confusion_rate"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                msg = f"{name} must be within [0, 1], got {value}"
                raise ValueError(msg)
        if not 0 < self.small_size_px < self.large_size_px:
            msg = f"need 0 < small_size_px < large_size_px, got {self.small_size_px} and {self.large_size_px}"
            raise ValueError(msg)
        for name in ("jitter_px", "jitter_rel", "false_positives_per_frame"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                msg = f"{name} must be finite and >= 0, got {value}"
                raise ValueError(msg)
        lo, hi = self.false_positive_size_px
        if not 0 < lo <= hi:
            msg = f"false_positive_size_px must be 0 < low <= high, got {self.false_positive_size_px}"
            raise ValueError(msg)
        for name in ("score_true", "score_false"):
            mean, sd = getattr(self, name)
            if not (0 <= mean <= 1 and sd >= 0):
                msg = f"{name} must be (mean in [0, 1], sd >= 0), got {getattr(self, name)}"
                raise ValueError(msg)
        weights = self.false_positive_classes
        if not weights or any(w < 0 for w in weights.values()) or sum(weights.values()) <= 0:
            msg = f"false_positive_classes needs non-negative weights with a positive sum, got {weights}"
            raise ValueError(msg)

    def miss_probability(self, size_px: float) -> float:
        s = (size_px - self.small_size_px) / (self.large_size_px - self.small_size_px)
        s = min(1.0, max(0.0, s))
        return self.miss_rate_small + s * (self.miss_rate_large - self.miss_rate_small)


def frame_rng(seed: int, stamp_ns: int, camera: str) -> np.random.Generator:
    """The generator of one frame: the same frame always degrades the same way."""
    return np.random.default_rng([seed & 0xFFFFFFFF, stamp_ns & 0xFFFFFFFFFFFFFFFF, zlib.crc32(camera.encode())])


def _score(rng: np.random.Generator, mean_sd: tuple[float, float]) -> float:
    mean, sd = mean_sd
    return float(np.clip(rng.normal(mean, sd), 0.01, 1.0))


def degrade(
    truth: Sequence[Box],
    *,
    width_px: int,
    height_px: int,
    class_ids: dict[str, int],
    cfg: DegradeConfig,
    rng: np.random.Generator,
) -> list[RawDetection]:
    """One frame of the stand-in's output from the ground truth's boxes of that frame.

    Args:
        truth: the ground truth's boxes (class and edges; nothing else is used).
        class_ids: class name -> the id to publish (the class map).
    """
    out: list[RawDetection] = []
    names = sorted(class_ids)
    for box in truth:
        su, sv = box.size
        size = math.sqrt(max(su * sv, 0.0))
        if rng.random() < cfg.miss_probability(size):
            continue
        u0, v0, u1, v1 = (
            edge + rng.normal(0.0, cfg.jitter_px + cfg.jitter_rel * extent)
            for edge, extent in ((box.u0, su), (box.v0, sv), (box.u1, su), (box.v1, sv))
        )
        u0, u1 = max(-0.5, min(u0, u1)), min(width_px - 0.5, max(u0, u1))
        v0, v1 = max(-0.5, min(v0, v1)), min(height_px - 0.5, max(v0, v1))
        if u1 - u0 < 1.0 or v1 - v0 < 1.0:
            continue  # jittered to nothing
        name = box.class_name
        if len(names) > 1 and rng.random() < cfg.confusion_rate:
            name = str(rng.choice([n for n in names if n != box.class_name]))
        out.append(
            RawDetection(
                0.5 * (u0 + u1), 0.5 * (v0 + v1), u1 - u0, v1 - v0, ((class_ids[name], _score(rng, cfg.score_true)),)
            )
        )
    fp_names = [n for n in sorted(cfg.false_positive_classes) if n in class_ids and cfg.false_positive_classes[n] > 0]
    if fp_names:
        weights = np.array([cfg.false_positive_classes[n] for n in fp_names], dtype=np.float64)
        weights /= weights.sum()
        lo, hi = cfg.false_positive_size_px
        for _ in range(int(rng.poisson(cfg.false_positives_per_frame))):
            name = str(rng.choice(fp_names, p=weights))
            size = math.exp(rng.uniform(math.log(lo), math.log(hi)))
            aspect = rng.uniform(1.8, 3.0) if name == "person" else rng.uniform(0.4, 0.7)  # height / width
            su, sv = size / math.sqrt(aspect), size * math.sqrt(aspect)
            su, sv = min(su, width_px - 1.0), min(sv, height_px - 1.0)
            cu = rng.uniform(-0.5 + su / 2, width_px - 0.5 - su / 2)
            cv = rng.uniform(-0.5 + sv / 2, height_px - 0.5 - sv / 2)
            out.append(RawDetection(cu, cv, su, sv, ((class_ids[name], _score(rng, cfg.score_false)),)))
    return out
