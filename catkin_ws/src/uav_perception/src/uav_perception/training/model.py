"""The range's baseline detector: a small CenterNet-style CNN (torch), and its ONNX export in the node's format.

One output scale, stride 4: per cell a class heatmap (sigmoid: "an object's centre is here"), a sub-cell
offset of the centre and the box's log size in pixels. A backbone of 3x3 conv-BN-ReLU blocks down to stride
16 and a two-step top-down path back to stride 4 (~0.2 M parameters). Fully convolutional: trained on crops,
run on whole frames. :class:`Decoded` wraps it for export: the peaks of the heatmap (3x3 max-pool) become
the candidates of ``uav_perception.core.detection.learned``'s format ``[1, 4 + C, N]``.
"""

from __future__ import annotations

import json
from pathlib import Path

import torch
from torch import nn
from torch.nn import functional as F  # noqa: N812

from uav_perception.training.targets import STRIDE

__all__ = ["STRIDE", "Decoded", "TinyCenterNet", "export_onnx"]


def _block(c_in: int, c_out: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False), nn.BatchNorm2d(c_out), nn.ReLU(inplace=True))


class TinyCenterNet(nn.Module):
    """Input ``[B, 3, H, W]`` RGB in [0, 1] (H, W multiples of 16); outputs at ``H/4 x W/4``: heatmap logits
    ``[B, C, h, w]``, offsets ``[B, 2, h, w]`` (cells), log sizes ``[B, 2, h, w]`` (log pixels)."""

    def __init__(self, num_classes: int = 2, width: int = 16) -> None:
        super().__init__()
        w = width
        self.num_classes = num_classes
        self.stem = nn.Sequential(_block(3, w, 2), _block(w, w * 2, 2), _block(w * 2, w * 2))  # /4
        self.down8 = nn.Sequential(_block(w * 2, w * 3, 2), _block(w * 3, w * 3))  # /8
        self.down16 = nn.Sequential(_block(w * 3, w * 6, 2), _block(w * 6, w * 6), _block(w * 6, w * 6))  # /16
        self.lat8 = nn.Conv2d(w * 3, w * 3, 1)
        self.top16 = nn.Conv2d(w * 6, w * 3, 1)
        self.smooth8 = _block(w * 3, w * 3)
        self.lat4 = nn.Conv2d(w * 2, w * 2, 1)
        self.top8 = nn.Conv2d(w * 3, w * 2, 1)
        self.smooth4 = _block(w * 2, w * 2)
        self.heat = nn.Conv2d(w * 2, num_classes, 1)
        self.offset = nn.Conv2d(w * 2, 2, 1)
        self.size = nn.Conv2d(w * 2, 2, 1)
        assert self.heat.bias is not None  # a Conv2d made with bias=True
        nn.init.constant_(self.heat.bias, -4.6)  # a prior of 1 % "centre here": focal loss starts stable

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        c4 = self.stem(x)
        c8 = self.down8(c4)
        c16 = self.down16(c8)
        p8 = self.smooth8(self.lat8(c8) + F.interpolate(self.top16(c16), scale_factor=2.0, mode="nearest"))
        p4 = self.smooth4(self.lat4(c4) + F.interpolate(self.top8(p8), scale_factor=2.0, mode="nearest"))
        return self.heat(p4), self.offset(p4), self.size(p4)


class Decoded(nn.Module):
    """The network with its decoding, for export: ``[1, 3, H, W]`` -> ``[1, 4 + C, (H/4)(W/4)]``.

    A candidate per cell: ``cx = (col + offset_x) * 4`` (pixel edges), ``w = exp(log size)``, class scores the
    heatmap's sigmoid where the cell is a 3x3 peak of its class, else 0.
    """

    def __init__(self, net: TinyCenterNet, height: int, width: int) -> None:
        super().__init__()
        self.net = net
        h, w = height // STRIDE, width // STRIDE
        ys, xs = torch.meshgrid(
            torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij"
        )
        self.register_buffer("grid", torch.stack([xs, ys]).reshape(1, 2, h * w))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        heat, offset, size = self.net(x)
        prob = torch.sigmoid(heat)
        peak = (F.max_pool2d(prob, 3, 1, 1) == prob).to(prob.dtype)
        scores = (prob * peak).flatten(2)
        centre = (self.grid + offset.flatten(2)) * float(STRIDE)
        wh = torch.exp(size.flatten(2).clamp(-2.0, 7.0))
        return torch.cat([centre, wh, scores], dim=1)


def export_onnx(  # noqa: PLR0917 (positional: uav-train-detector's first model was exported with this call)
    net: TinyCenterNet, path: Path, classes: tuple[str, ...], height: int, width: int, meta: dict[str, str]
) -> None:
    """Write ``net`` with its decoding as ONNX (opset 17, fixed input ``[1, 3, height, width]``), with the class
    names in the metadata ``uav_classes`` and ``meta`` beside them."""
    import onnx  # noqa: PLC0415 (training-only dependency)

    net = net.eval()
    model = Decoded(net, height, width).eval()
    dummy = torch.zeros(1, 3, height, width)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.onnx")
    torch.onnx.export(
        model, (dummy,), str(tmp), input_names=["images"], output_names=["output0"], opset_version=17, dynamo=False
    )
    proto = onnx.load(str(tmp))
    entries = {"uav_classes": json.dumps(list(classes)), **meta}
    for key, value in entries.items():
        prop = proto.metadata_props.add()
        prop.key, prop.value = key, value
    onnx.save(proto, str(tmp))
    tmp.replace(path)
