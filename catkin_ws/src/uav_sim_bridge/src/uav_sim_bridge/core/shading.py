"""Finishing a shadowed frame's colour on the CPU: the sun's share taken away where the shadow pass found shade.

The renderer's camera pass writes each pixel's lit colour (RGB) and the sun's share of it (alpha, 0-255); its
shadow pass writes the lit fraction of every ``step`` x ``step`` block at low resolution. The final colour is

    rgb * (1 - (1 - lit) * share)

with ``lit`` brought back to full resolution (each block's value at its centre pixel, linear in between). It is
kept apart from the GL pass because it is plain OpenCV work (~0.5 ms at 640x480) that any thread or process can
do: the bridge does it in its camera-effects process, beside the next render.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

__all__ = ["UnshadedColor"]


@dataclass(frozen=True)
class UnshadedColor:
    """A frame's colour before its shadows are applied.

    Attributes:
        rgba: ``(H, W, 4)`` uint8, top row first: lit RGB and the sun's share in alpha.
        lit_low: ``(ceil(H / step), ceil(W / step))`` uint8, the lit fraction (255: in full sun) of each block.
    """

    rgba: npt.NDArray[np.uint8]
    lit_low: npt.NDArray[np.uint8]

    def __post_init__(self) -> None:
        if self.rgba.ndim != 3 or self.rgba.shape[2] != 4 or self.rgba.dtype != np.uint8:
            msg = f"rgba must be (H, W, 4) uint8, got {self.rgba.shape} {self.rgba.dtype}"
            raise ValueError(msg)
        if self.lit_low.ndim != 2 or self.lit_low.dtype != np.uint8:
            msg = f"lit_low must be 2-D uint8, got {self.lit_low.shape} {self.lit_low.dtype}"
            raise ValueError(msg)

    def finish(self) -> npt.NDArray[np.uint8]:
        """The shadowed RGB image (a new array)."""
        h, w = self.rgba.shape[:2]
        lit = cv2.resize(self.lit_low, (w, h), interpolation=cv2.INTER_LINEAR)
        # factor = 1 - (1 - lit) * sun_share, in 1/255 units: 255 - (255 - lit) * share / 255
        share = cv2.extractChannel(self.rgba, 3)
        factor = cv2.bitwise_not(cv2.multiply(cv2.bitwise_not(lit), share, scale=1.0 / 255.0))
        out = cv2.multiply(self.rgba, cv2.cvtColor(factor, cv2.COLOR_GRAY2RGBA), scale=1.0 / 255.0)
        # ~60x faster than a numpy slice copy (640x480: 0.025 vs 1.5 ms), same bytes
        return np.asarray(cv2.cvtColor(out, cv2.COLOR_RGBA2RGB), dtype=np.uint8)
