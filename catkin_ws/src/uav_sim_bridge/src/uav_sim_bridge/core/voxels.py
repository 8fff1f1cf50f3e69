"""Ground-truth voxel set of the world's *observable surfaces* at any resolution.

A voxel key is ``floor(p / resolution_m)`` per axis (int64), for a point ``p`` in
``map``; its centre is ``(key + 0.5) * resolution_m``.  The set holds every voxel
that a world surface passes through:

* terrain: for each x-y column of the grid, the voxels between the lowest and the
  highest terrain height over that column (exact for the piecewise-linear mesh up to
  the sub-sampling below), except where a building footprint or a road covers it;
* objects: every voxel hit by dense samples (spacing ``resolution_m / 2``) of their
  triangles, except samples below the terrain (foundations, buried trunk bases).

The volume under the terrain and inside objects is never included.  Dynamic objects
(people, vehicles) are included at their generated poses.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import numpy.typing as npt

from uav_common.voxel_keys import pack_keys, unpack_keys
from uav_sim_bridge.core.terrain import Heightfield

__all__ = ["object_surface_voxels", "terrain_surface_voxels", "union_keys", "voxel_centres"]

IntArray = npt.NDArray[np.int64]
FloatArray = npt.NDArray[np.float64]


def voxel_centres(keys: IntArray, resolution_m: float) -> FloatArray:
    """``(N, 3)`` centres of voxel keys."""
    return (np.asarray(keys, dtype=np.float64) + 0.5) * resolution_m


def union_keys(*parts: IntArray) -> IntArray:
    """Sorted (x, y, z lexicographic) unique union of ``(N, 3)`` key arrays."""
    if not parts:
        return np.zeros((0, 3), np.int64)
    packed = np.concatenate([pack_keys(p) for p in parts])
    return unpack_keys(np.unique(packed))


def terrain_surface_voxels(
    terrain: Heightfield, resolution_m: float, covered_xy_polys: list[FloatArray] | None = None
) -> IntArray:
    """Voxels of the terrain surface (see module docstring); ``covered_xy_polys`` are ``(K, 2)`` polygons to skip."""
    res = float(resolution_m)
    x_min, y_min, x_max, y_max = terrain.bounds_m
    c0 = math.floor(x_min / res)
    c1 = math.ceil(x_max / res) - 1
    r0 = math.floor(y_min / res)
    r1 = math.ceil(y_max / res) - 1
    cols = c1 - c0 + 1
    rows = r1 - r0 + 1
    # Sub-sample each column so that terrain nodes inside it are (nearly) hit.
    sub = max(1, math.ceil(res / terrain.resolution_m) * 2)
    covered = np.zeros((rows, cols), dtype=np.uint8)
    if covered_xy_polys:
        # raster pixel (row, col) is the column [c0 + col, c0 + col + 1) * res; cv2 puts pixel centres at integers
        polys = [np.round((np.asarray(p) / res - [c0 + 0.5, r0 + 0.5]) * 16).astype(np.int32) for p in covered_xy_polys]
        cv2.fillPoly(covered, polys, color=(1,), shift=4)
    out: list[IntArray] = []
    chunk = max(1, 2_000_000 // max(1, cols * (sub + 1) * (sub + 1) // 4))
    u = np.arange(cols * sub + 1) / sub
    xs = (c0 + u) * res
    for start in range(0, rows, chunk):
        stop = min(rows, start + chunk)
        v = start + np.arange((stop - start) * sub + 1) / sub
        ys = (r0 + v) * res
        h = terrain.height_at(xs[None, :], ys[:, None])  # samples at column corners and sub-points
        nr, nc = stop - start, cols
        # min / max over each column's (sub+1)^2 samples, via sliding windows
        blocks = np.lib.stride_tricks.sliding_window_view(h, (sub + 1, sub + 1))[::sub, ::sub]
        hmin = blocks.min(axis=(2, 3)).reshape(nr, nc)
        hmax = blocks.max(axis=(2, 3)).reshape(nr, nc)
        inside_x = ((c0 + np.arange(nc) + 0.5) * res >= x_min) & ((c0 + np.arange(nc) + 0.5) * res <= x_max)
        inside_y = ((r0 + start + np.arange(nr) + 0.5) * res >= y_min) & (
            (r0 + start + np.arange(nr) + 0.5) * res <= y_max
        )
        keep = inside_y[:, None] & inside_x[None, :] & (covered[start:stop] == 0)
        k_lo = np.floor(hmin / res).astype(np.int64)[keep]
        k_hi = np.floor(hmax / res).astype(np.int64)[keep]
        rr, cc = np.nonzero(keep)
        count = k_hi - k_lo + 1
        kz = np.repeat(k_lo, count) + (np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count))
        out.append(
            np.stack([np.repeat(cc + c0, count), np.repeat(rr + start + r0, count), kz], axis=1).astype(np.int64)
        )
    return union_keys(*out)


def object_surface_voxels(
    triangles_m: FloatArray, resolution_m: float, terrain: Heightfield | None = None, chunk: int = 4096
) -> IntArray:
    """Voxels hit by dense samples of ``(N, 3, 3)`` triangles, skipping samples below ``terrain``."""
    res = float(resolution_m)
    spacing = res / 2.0
    tri = np.asarray(triangles_m, dtype=np.float64).reshape(-1, 3, 3)
    if len(tri) == 0:
        return np.zeros((0, 3), dtype=np.int64)
    edge = np.max(
        np.stack(
            [np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1), np.linalg.norm(tri[:, 2] - tri[:, 1], axis=1),
             np.linalg.norm(tri[:, 0] - tri[:, 2], axis=1)],
            axis=1,
        ),
        axis=1,
    )  # fmt: skip
    steps = np.maximum(1, np.ceil(edge / spacing).astype(np.int64))
    # Only triangles reaching down near the terrain need their samples tested against it.
    if terrain is not None:
        clearance = tri[:, :, 2] - terrain.height_at(tri[:, :, 0], tri[:, :, 1])
        near_ground = clearance.min(axis=1) < 1.0 + res
    else:
        near_ground = np.zeros(len(tri), dtype=bool)
    out: list[IntArray] = []
    normal_z = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2]
    for n, low in sorted({(int(a), bool(b)) for a, b in zip(steps, near_ground, strict=True)}):
        sel = (steps == n) & (near_ground == low)
        group = tri[sel]
        facing_down = normal_z[sel] < 0
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        mask = i + j <= n
        bary_b = (i[mask] / n).astype(np.float64)
        bary_c = (j[mask] / n).astype(np.float64)
        per = max(1, chunk * 64 // len(bary_b))
        for s in range(0, len(group), per):
            g = group[s : s + per]
            # a + b (B - A) + c (C - A): exact on axis-aligned faces (no 7.999... for a roof at 8)
            pts = (
                g[:, None, 0, :]
                + bary_b[None, :, None] * (g[:, None, 1, :] - g[:, None, 0, :])
                + bary_c[None, :, None] * (g[:, None, 2, :] - g[:, None, 0, :])
            ).reshape(-1, 3)
            if terrain is not None and low:
                ground = terrain.height_at(pts[:, 0], pts[:, 1])
                down = np.repeat(facing_down[s : s + per], len(bary_b))
                # below ground, or a downward face lying on the ground: not observable
                pts = pts[(pts[:, 2] >= ground - 0.25 * res) & ~(down & (pts[:, 2] < ground + 0.25 * res))]
            out.append(unpack_keys(np.unique(pack_keys(np.floor(pts / res).astype(np.int64)))))
    return union_keys(*out)
