"""Integer voxel keys: three signed voxel indices packed into one int64, in one place.

Voxel ``(i, j, k)`` covers ``[i*res, (i+1)*res)`` on each axis, as OctoMap and OpenVDB
index space, so keys from the map server, the world's ground truth and the scorer align.
Each index takes a 21-bit field, offset by 2^20 so it is non-negative
(``key = (i+2^20) << 42 | (j+2^20) << 21 | (k+2^20)``): indices within ±2^20, ±524 km at
0.5 m. Keys sort by x, then y, then z, so ``key >> 21`` is the (x, y) column.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from uav_common.errors import UavCommonError

__all__ = [
    "KEY_BITS",
    "VoxelKeyError",
    "in_sorted",
    "key_columns",
    "keys_from_points",
    "pack_keys",
    "sorted_unique",
    "unpack_keys",
]

IntArray = npt.NDArray[np.int64]

#: Bits per axis of a voxel key.
KEY_BITS = 21
_OFFSET = 1 << (KEY_BITS - 1)
_MASK = (1 << KEY_BITS) - 1


class VoxelKeyError(UavCommonError, ValueError):
    """Voxel indices of the wrong shape or outside the ±2^20 range a key can hold."""


def pack_keys(ijk: npt.ArrayLike) -> IntArray:
    """Integer voxel indices ``(N, 3)`` -> int64 keys ``(N,)``, in the same order.

    Raises:
        VoxelKeyError: wrong shape, or an index out of the ±2^20 range.
    """
    idx = np.asarray(ijk, dtype=np.int64)
    if idx.size == 0:
        return np.zeros(0, dtype=np.int64)
    if idx.ndim != 2 or idx.shape[1] != 3:
        msg = f"voxel indices must have shape (N, 3), got {idx.shape}"
        raise VoxelKeyError(msg)
    shifted = idx + _OFFSET
    if shifted.min() < 0 or shifted.max() > _MASK:
        msg = f"voxel index out of range ±{_OFFSET}: min {idx.min()}, max {idx.max()}"
        raise VoxelKeyError(msg)
    return np.asarray((shifted[:, 0] << (2 * KEY_BITS)) | (shifted[:, 1] << KEY_BITS) | shifted[:, 2], dtype=np.int64)


def unpack_keys(keys: npt.ArrayLike) -> IntArray:
    """int64 keys ``(N,)`` -> voxel indices ``(N, 3)``."""
    k = np.asarray(keys, dtype=np.int64).ravel()
    return np.asarray(
        np.stack([(k >> (2 * KEY_BITS)) - _OFFSET, ((k >> KEY_BITS) & _MASK) - _OFFSET, (k & _MASK) - _OFFSET], axis=1),
        dtype=np.int64,
    )


def sorted_unique(keys: npt.ArrayLike) -> IntArray:
    """``keys`` sorted and unique (returned as they are when they already are: no sort)."""
    k = np.asarray(keys, dtype=np.int64).ravel()
    if k.size > 1 and not np.all(k[1:] > k[:-1]):
        k = np.unique(k)
    return k


def in_sorted(keys: npt.ArrayLike, sorted_set: IntArray) -> npt.NDArray[np.bool_]:
    """Which of ``keys`` are in ``sorted_set`` (sorted and unique): a binary search per key, ``O(n log m)``
    (``np.isin`` sorts both, ``O((n + m) log (n + m))``: seconds for a few keys against a world's millions)."""
    k = np.asarray(keys, dtype=np.int64).ravel()
    if sorted_set.size == 0 or k.size == 0:
        return np.zeros(k.size, dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_set, k), sorted_set.size - 1)
    return np.asarray(sorted_set[pos] == k)


def keys_from_points(points_m: npt.ArrayLike, resolution_m: float) -> IntArray:
    """Points ``(N, 3)`` in metres -> unique sorted keys of the voxels holding them (non-finite points dropped).

    Raises:
        VoxelKeyError: ``resolution_m`` is not positive, or a point is beyond the keys' range.
    """
    if not resolution_m > 0:
        msg = f"resolution_m must be > 0, got {resolution_m}"
        raise VoxelKeyError(msg)
    pts = np.asarray(points_m, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    return sorted_unique(pack_keys(np.floor(pts / resolution_m).astype(np.int64)))


def key_columns(keys: npt.ArrayLike) -> IntArray:
    """The (x, y) column of each key, as int64 ``(N,)`` (the z field dropped)."""
    return np.asarray(keys, dtype=np.int64) >> KEY_BITS
