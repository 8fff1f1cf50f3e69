"""Reading the map server's outputs without liboctomap: binary octrees and exported voxel cells.

Voxel convention (the same as the map server, OctoMap, OpenVDB and the world's ground truth):
voxel index ``i = floor(p / res)`` per axis, covering ``[i * res, (i + 1) * res)``; an OctoMap key is
``i + 32768``.

* :func:`decode_binary_octree` decodes the ``data`` of an ``octomap_msgs/Octomap`` with
  ``binary = True`` (``id`` ``OcTree``), i.e. OctoMap's ``writeBinaryData`` stream, which is also the
  body of a ``.bt`` file after its header.
* :func:`load_occupied_cells` reads what the map server's ``~export_occupied`` service writes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_autonomy.errors import InvalidInputError

__all__ = ["OctreeLeaves", "VoxelCells", "decode_binary_octree", "load_occupied_cells"]

IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

TREE_DEPTH = 16
KEY_OFFSET = 32768


@dataclass(frozen=True)
class OctreeLeaves:
    """The leaves of a binary octree.

    Attributes:
        resolution_m: edge of the finest voxels.
        index_min: ``(N, 3)`` int64 voxel index of each leaf's lowest corner.
        size_voxels: ``(N,)`` int64 edge of each leaf in voxels (1 at the finest depth, 2**k when pruned).
        occupied: ``(N,)`` bool, True for occupied leaves, False for free ones.
    """

    resolution_m: float
    index_min: IntArray
    size_voxels: IntArray
    occupied: BoolArray

    def occupied_indices(self) -> IntArray:
        """``(M, 3)`` int64 indices of every occupied voxel (pruned leaves expanded), sorted and unique."""
        rows: list[IntArray] = []
        for corner, size in zip(self.index_min[self.occupied], self.size_voxels[self.occupied], strict=True):
            s = int(size)
            if s == 1:
                rows.append(corner.reshape(1, 3))
                continue
            offsets = np.stack(np.meshgrid(np.arange(s), np.arange(s), np.arange(s), indexing="ij"), axis=-1)
            rows.append(corner + offsets.reshape(-1, 3).astype(np.int64))
        if not rows:
            return np.zeros((0, 3), dtype=np.int64)
        return np.unique(np.concatenate(rows), axis=0)

    def voxel_counts(self) -> tuple[int, int]:
        """(occupied, free) voxel counts with pruned leaves counted by their volume."""
        volume = self.size_voxels**3
        return int(volume[self.occupied].sum()), int(volume[~self.occupied].sum())


def decode_binary_octree(data: bytes, resolution_m: float) -> OctreeLeaves:
    """Decodes OctoMap's binary tree stream (``OcTree::writeBinaryData``).

    Each inner node is two bytes holding two bits per child: child ``c``'s code is bits ``2c`` (low) and
    ``2c + 1`` (high) of the 16-bit little-endian word, ``1`` a free leaf, ``2`` an occupied leaf, ``3`` an
    inner node, ``0`` none.
    Inner children follow depth-first in child order; child ``c`` adds ``half`` to x if ``c & 1``, to y if
    ``c & 2`` and to z if ``c & 4``.

    Args:
        data: the serialised tree (an ``octomap_msgs/Octomap.data`` as bytes, or a ``.bt`` body).
        resolution_m: the tree's resolution (the message's ``resolution``).

    Returns:
        Every leaf with its corner, size and occupancy.

    Raises:
        InvalidInputError: the stream is truncated, too deep, or has bytes left over.
    """
    if not resolution_m > 0.0:
        msg = f"resolution_m must be > 0, got {resolution_m}"
        raise InvalidInputError(msg)
    corners: list[tuple[int, int, int]] = []
    sizes: list[int] = []
    occupied: list[bool] = []
    pos = 0
    if len(data) > 0:
        # (depth, key of the node's lowest corner); the root covers keys [0, 65536) on each axis.
        stack: list[tuple[int, int, int, int]] = [(0, 0, 0, 0)]
        while stack:
            depth, kx, ky, kz = stack.pop()
            if pos + 2 > len(data):
                msg = f"binary octree truncated at byte {pos} of {len(data)}"
                raise InvalidInputError(msg)
            bits = data[pos] | (data[pos + 1] << 8)
            pos += 2
            half = 1 << (TREE_DEPTH - depth - 1)
            inner: list[tuple[int, int, int, int]] = []
            for child in range(8):
                code = (bits >> (2 * child)) & 3
                if code == 0:
                    continue
                cx = kx + (half if child & 1 else 0)
                cy = ky + (half if child & 2 else 0)
                cz = kz + (half if child & 4 else 0)
                if code == 3:
                    if depth + 1 >= TREE_DEPTH:
                        msg = "binary octree has inner nodes below the finest depth"
                        raise InvalidInputError(msg)
                    inner.append((depth + 1, cx, cy, cz))
                else:
                    corners.append((cx - KEY_OFFSET, cy - KEY_OFFSET, cz - KEY_OFFSET))
                    sizes.append(half)
                    occupied.append(code == 2)
            stack.extend(reversed(inner))
    if pos != len(data):
        msg = f"binary octree has {len(data) - pos} bytes after its last node"
        raise InvalidInputError(msg)
    return OctreeLeaves(
        resolution_m=float(resolution_m),
        index_min=np.asarray(corners, dtype=np.int64).reshape(-1, 3),
        size_voxels=np.asarray(sizes, dtype=np.int64),
        occupied=np.asarray(occupied, dtype=np.bool_),
    )


@dataclass(frozen=True)
class VoxelCells:
    """Occupied cells exported by the map server (``~export_occupied``).

    Attributes:
        resolution_m: cell edge.
        cells: ``(N, 3)`` int64 cell indices, cell ``(i, j, k)`` = ``[i*res, (i+1)*res) x ...`` in ``frame_id``.
        meta: the JSON sidecar (frame_id, backend, map_resolution_m, count, frames_inserted).
    """

    resolution_m: float
    cells: IntArray
    meta: dict[str, Any]


def load_occupied_cells(path: Path) -> VoxelCells:
    """Reads an ``~export_occupied`` file (``.npy``, int32 ``(N, 3)``) and its ``.json`` sidecar.

    Raises:
        InvalidInputError: missing files, wrong array shape or type, or a sidecar that disagrees.
    """
    sidecar = Path(str(path) + ".json")
    try:
        cells = np.load(path, allow_pickle=False)
        meta = json.loads(sidecar.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        msg = f"{path}: cannot read the exported cells or their sidecar {sidecar.name}: {err}"
        raise InvalidInputError(msg) from err
    if cells.ndim != 2 or cells.shape[1] != 3 or cells.dtype != np.int32:
        msg = f"{path}: expected an int32 array of shape (N, 3), got {cells.dtype} {cells.shape}"
        raise InvalidInputError(msg)
    if int(meta.get("count", -1)) != cells.shape[0]:
        msg = f"{path}: sidecar count {meta.get('count')} != {cells.shape[0]} rows"
        raise InvalidInputError(msg)
    return VoxelCells(resolution_m=float(meta["resolution_m"]), cells=cells.astype(np.int64), meta=meta)
