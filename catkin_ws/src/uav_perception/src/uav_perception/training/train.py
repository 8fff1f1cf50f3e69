"""Training :class:`~uav_perception.training.model.TinyCenterNet` on a data engine dataset, on the CPU, seeded.

Each step draws a batch of square crops at the frames' native resolution (half of them around a labelled
object, so that small people are not rare), flipped left-right at random and jittered in brightness and
contrast; targets are CenterNet's: a Gaussian peak per object in its class's heatmap (penalty-reduced focal
loss), the centre's sub-cell offset and the log box size at the peak (L1). Everything random comes from one
``numpy.random.Generator`` and torch's generator, both seeded: the same command gives the same weights on
the same machine and thread count. The curve (loss per logged step) and the hyper-parameters are returned
for the run folder.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch.nn import functional as F  # noqa: N812

from uav_perception.training.data import DatasetSplit
from uav_perception.training.model import TinyCenterNet
from uav_perception.training.targets import STRIDE, crop_boxes, make_targets

__all__ = ["TrainConfig", "TrainResult", "train"]


@dataclass(frozen=True)
class TrainConfig:
    """Hyper-parameters (saved with the model)."""

    seed: int = 0
    steps: int = 3000
    batch_size: int = 16
    crop_px: int = 256
    object_crop_fraction: float = 0.6
    lr: float = 3e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    width: int = 16
    min_box_px: float = 2.0
    size_loss_weight: float = 1.0
    offset_loss_weight: float = 1.0
    threads: int = 2
    log_every: int = 25

    def __post_init__(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or self.crop_px % 16 or self.crop_px < 32:
            msg = f"need steps >= 1, batch_size >= 1 and crop_px a multiple of 16 (>= 32); got {self}"
            raise ValueError(msg)
        if not 0.0 <= self.object_crop_fraction <= 1.0:
            msg = f"object_crop_fraction must be within [0, 1], got {self.object_crop_fraction}"
            raise ValueError(msg)

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


@dataclass
class TrainResult:
    net: TinyCenterNet
    curve: list[dict[str, float]]
    seconds: float
    samples: int


def _focal(pred_logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    pred = torch.sigmoid(pred_logits).clamp(1e-4, 1 - 1e-4)
    pos = target.eq(1.0).float()
    neg = 1.0 - pos
    pos_loss = torch.log(pred) * (1 - pred) ** 2 * pos
    neg_loss = torch.log(1 - pred) * pred**2 * (1 - target) ** 4 * neg
    n = pos.sum().clamp(min=1.0)
    return -(pos_loss.sum() + neg_loss.sum()) / n


def _batch(
    data: DatasetSplit,
    images: list[np.ndarray],
    cfg: TrainConfig,
    *,
    rng: np.random.Generator,
    with_objects: list[int],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One batch of augmented crops and their targets."""
    nc = len(data.classes)
    out = cfg.crop_px // STRIDE
    batch = np.empty((cfg.batch_size, cfg.crop_px, cfg.crop_px, 3), np.float32)
    heat = np.empty((cfg.batch_size, nc, out, out), np.float32)
    off = np.empty((cfg.batch_size, 2, out, out), np.float32)
    lsz = np.empty((cfg.batch_size, 2, out, out), np.float32)
    mask = np.empty((cfg.batch_size, out, out), np.float32)
    for b in range(cfg.batch_size):
        around = bool(rng.random() < cfg.object_crop_fraction) and bool(with_objects)
        i = int(rng.choice(with_objects)) if around else int(rng.integers(len(data.frames)))
        f = data.frames[i]
        crop, boxes, labels = crop_boxes(images[i], f.boxes, f.labels, size=cfg.crop_px, rng=rng, around=around)
        img = crop.astype(np.float32) / 255.0
        if rng.random() < 0.5:
            img = img[:, ::-1]
            boxes = boxes.copy()
            boxes[:, 0] = cfg.crop_px - boxes[:, 0] - boxes[:, 2]
        gain, bias = rng.uniform(0.8, 1.2), rng.uniform(-0.08, 0.08)
        batch[b] = np.clip(img * gain + bias, 0.0, 1.0)
        heat[b], off[b], lsz[b], mask[b] = make_targets(
            boxes, labels, nc, out_h=out, out_w=out, min_box_px=cfg.min_box_px
        )
    return batch, heat, off, lsz, mask


def train(
    data: DatasetSplit,
    images: list[np.ndarray],
    cfg: TrainConfig,
    progress: Callable[[dict[str, float]], None] | None = None,
) -> TrainResult:
    """Train from scratch (random initialisation, seeded) on ``data``'s frames (``images`` their RGB arrays)."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed)
    nc = len(data.classes)
    net = TinyCenterNet(nc, cfg.width)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    with_objects = [i for i, f in enumerate(data.frames) if len(f.boxes)]
    curve: list[dict[str, float]] = []
    acc = {"loss": 0.0, "heat": 0.0, "offset": 0.0, "size": 0.0}
    t0 = time.perf_counter()
    net.train()
    for step in range(1, cfg.steps + 1):
        lr = cfg.lr * min(1.0, step / cfg.warmup_steps) * 0.5 * (1 + math.cos(math.pi * step / cfg.steps))
        for g in opt.param_groups:
            g["lr"] = lr
        batch, heat, off, lsz, mask = _batch(data, images, cfg, rng=rng, with_objects=with_objects)
        x = torch.from_numpy(batch).permute(0, 3, 1, 2).contiguous()
        p_heat, p_off, p_size = net(x)
        m = torch.from_numpy(mask).unsqueeze(1)
        n = m.sum().clamp(min=1.0)
        l_heat = _focal(p_heat, torch.from_numpy(heat))
        l_off = (F.l1_loss(p_off, torch.from_numpy(off), reduction="none") * m).sum() / n
        l_size = (F.l1_loss(p_size, torch.from_numpy(lsz), reduction="none") * m).sum() / n
        loss = l_heat + cfg.offset_loss_weight * l_off + cfg.size_loss_weight * l_size
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        for key, v in (("loss", loss), ("heat", l_heat), ("offset", l_off), ("size", l_size)):
            acc[key] += float(v.detach())
        if step % cfg.log_every == 0 or step == cfg.steps:
            k = cfg.log_every if step % cfg.log_every == 0 else step % cfg.log_every
            point = {"step": float(step), "lr": lr, "seconds": time.perf_counter() - t0}
            point.update({name: value / k for name, value in acc.items()})
            curve.append(point)
            acc = dict.fromkeys(acc, 0.0)
            if progress is not None:
                progress(point)
    net.eval()
    return TrainResult(net, curve, time.perf_counter() - t0, cfg.steps * cfg.batch_size)
