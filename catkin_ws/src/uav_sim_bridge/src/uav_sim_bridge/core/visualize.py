"""False-color images for people: class colors, instance colors, depth (pure numpy)."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.world_config import ObjectClass

__all__ = ["CLASS_COLORS_RGB", "class_image", "depth_image", "instance_image"]

# Color of each class id in the colorised class image (index = ObjectClass value).
CLASS_COLORS_RGB: npt.NDArray[np.uint8] = np.array(
    [
        [135, 190, 235],  # sky
        [120, 150, 80],  # terrain
        [90, 90, 95],  # road
        [200, 70, 50],  # building
        [30, 110, 40],  # tree
        [255, 0, 200],  # person
        [255, 200, 0],  # vehicle
    ],
    dtype=np.uint8,
)
assert len(CLASS_COLORS_RGB) == len(ObjectClass)


def class_image(instance_id: npt.ArrayLike, instance_class: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """``(H, W, 3)`` uint8 class colors from an instance image and the instance -> class table.

    Ids beyond the table (unknown instances) are drawn as sky.
    """
    ids = np.asarray(instance_id)
    lut = np.asarray(instance_class, dtype=np.uint8)
    cls = np.where(ids < len(lut), lut[np.minimum(ids, len(lut) - 1)], 0)
    return np.asarray(CLASS_COLORS_RGB[cls], dtype=np.uint8)


def instance_image(instance_id: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    """``(H, W, 3)`` uint8 pseudo-random color per instance id (0 = black)."""
    ids = np.asarray(instance_id).astype(np.uint64)
    h = (ids * np.uint64(2654435761)) & np.uint64(0xFFFFFF)
    rgb = np.stack(
        [(h >> np.uint64(16)) & np.uint64(255), (h >> np.uint64(8)) & np.uint64(255), h & np.uint64(255)], -1
    )
    out = np.asarray((64 + (rgb.astype(np.uint16) * 191) // 255), dtype=np.uint8)
    out[ids == 0] = 0
    return out


def depth_image(depth_m: npt.ArrayLike, max_m: float = 300.0) -> npt.NDArray[np.uint8]:
    """``(H, W)`` uint8: near = bright, far = dark (square-root scale), no return = 0."""
    d = np.asarray(depth_m, dtype=np.float32)
    valid = np.isfinite(d)
    scaled = np.sqrt(np.clip(np.where(valid, d, max_m) / max_m, 0.0, 1.0))
    out = (255.0 * (1.0 - scaled)).astype(np.uint8)
    out[~valid] = 0
    return out
