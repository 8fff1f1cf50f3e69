"""Triangle queries against the world mesh: surface height under a point, sphere contacts.

:class:`TriangleGrid` buckets triangles into square ``cell_m`` columns of the x-y
plane (compressed sparse rows), so a query only tests the few triangles near it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["SphereContact", "TriangleGrid", "closest_points_on_triangles"]

FloatArray = npt.NDArray[np.float64]


def closest_points_on_triangles(p: FloatArray, a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """Closest point to ``p`` (3,) on each triangle ``(a, b, c)`` (each ``(N, 3)``) — Ericson, RTCD 5.1.5."""
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v_in = vb * denom
        w_in = vc * denom
        out = a + ab * v_in[:, None] + ac * w_in[:, None]
        # edge regions (later assignments take precedence, so go from generic to specific)
        v_ab = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        out = np.where(m[:, None], a + ab * v_ab[:, None], out)
        w_ac = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        out = np.where(m[:, None], a + ac * w_ac[:, None], out)
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        out = np.where(m[:, None], b + (c - b) * w_bc[:, None], out)
    # vertex regions
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    return np.asarray(out, dtype=np.float64)


@dataclass(frozen=True)
class SphereContact:
    """A triangle touched by a sphere: instance id, closest point and the triangle's unit normal."""

    instance_id: int
    point_m: tuple[float, float, float]
    distance_m: float
    normal: tuple[float, float, float]


class TriangleGrid:
    """Triangles bucketed by x-y cell.

    Args:
        triangles_m: ``(N, 3, 3)`` vertex positions.
        instance_ids: ``(N,)`` instance id of each triangle.
        cell_m: bucket size.
    """

    def __init__(self, triangles_m: npt.ArrayLike, instance_ids: npt.ArrayLike, cell_m: float = 8.0) -> None:
        tri = np.asarray(triangles_m, dtype=np.float64).reshape(-1, 3, 3)
        self.triangles_m = tri
        self.instance_ids = np.asarray(instance_ids, dtype=np.int64).reshape(-1)
        self.cell_m = float(cell_m)
        n = len(tri)
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        self.normals = normal / (np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12)
        if n == 0:
            self._origin = np.zeros(2)
            self._shape = (1, 1)
            self._start = np.zeros(2, dtype=np.int64)
            self._items = np.zeros(0, dtype=np.int64)
            return
        lo = tri[:, :, :2].min(axis=1)
        hi = tri[:, :, :2].max(axis=1)
        self._origin = lo.min(axis=0)
        cells_lo = np.floor((lo - self._origin) / self.cell_m).astype(np.int64)
        cells_hi = np.floor((hi - self._origin) / self.cell_m).astype(np.int64)
        ncols, nrows = (cells_hi.max(axis=0) + 1).tolist()
        self._shape = (int(nrows), int(ncols))
        span = cells_hi - cells_lo + 1
        counts = span[:, 0] * span[:, 1]
        tri_idx = np.repeat(np.arange(n), counts)
        offset = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
        sx = np.repeat(span[:, 0], counts)
        cx = np.repeat(cells_lo[:, 0], counts) + offset % sx
        cy = np.repeat(cells_lo[:, 1], counts) + offset // sx
        cell = cy * ncols + cx
        order = np.argsort(cell, kind="stable")
        self._items = tri_idx[order]
        self._start = np.searchsorted(cell[order], np.arange(nrows * ncols + 1))

    def _candidates(self, x_lo: float, y_lo: float, x_hi: float, y_hi: float) -> npt.NDArray[np.int64]:
        rows, cols = self._shape
        c0 = max(0, math.floor((x_lo - self._origin[0]) / self.cell_m))
        c1 = min(cols - 1, math.floor((x_hi - self._origin[0]) / self.cell_m))
        r0 = max(0, math.floor((y_lo - self._origin[1]) / self.cell_m))
        r1 = min(rows - 1, math.floor((y_hi - self._origin[1]) / self.cell_m))
        if c0 > c1 or r0 > r1 or len(self._items) == 0:
            return np.zeros(0, dtype=np.int64)
        parts = [self._items[self._start[r * cols + c0] : self._start[r * cols + c1 + 1]] for r in range(r0, r1 + 1)]
        return np.asarray(np.unique(np.concatenate(parts)), dtype=np.int64)

    def highest_surface(self, x_m: float, y_m: float, below_z_m: float = math.inf) -> tuple[float, int]:
        """Highest triangle crossing the vertical at ``(x, y)`` not above ``below_z_m``.

        Returns:
            ``(z_m, instance_id)``, or ``(-inf, 0)`` if there is none.
        """
        idx = self._candidates(x_m, y_m, x_m, y_m)
        if len(idx) == 0:
            return -math.inf, 0
        t = self.triangles_m[idx]
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        v0 = b[:, :2] - a[:, :2]
        v1 = c[:, :2] - a[:, :2]
        v2 = np.array([x_m, y_m]) - a[:, :2]
        den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
        ok = np.abs(den) > 1e-12
        safe = np.where(ok, den, 1.0)
        v = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / safe
        w = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / safe
        u = 1.0 - v - w
        eps = -1e-9
        hit = ok & (u >= eps) & (v >= eps) & (w >= eps)
        if not np.any(hit):
            return -math.inf, 0
        z = u * a[:, 2] + v * b[:, 2] + w * c[:, 2]
        z = np.where(hit & (z <= below_z_m), z, -np.inf)
        k = int(np.argmax(z))
        if not np.isfinite(z[k]):
            return -math.inf, 0
        return float(z[k]), int(self.instance_ids[idx[k]])

    def sphere_contacts(self, center_m: npt.ArrayLike, radius_m: float) -> list[SphereContact]:
        """Triangles within ``radius_m`` of ``center_m``, nearest first (at most one per instance)."""
        p = np.asarray(center_m, dtype=np.float64)
        idx = self._candidates(p[0] - radius_m, p[1] - radius_m, p[0] + radius_m, p[1] + radius_m)
        if len(idx) == 0:
            return []
        t = self.triangles_m[idx]
        zmin = t[:, :, 2].min(axis=1)
        zmax = t[:, :, 2].max(axis=1)
        near_z = (zmin <= p[2] + radius_m) & (zmax >= p[2] - radius_m)
        idx, t = idx[near_z], t[near_z]
        if len(idx) == 0:
            return []
        q = closest_points_on_triangles(p, t[:, 0], t[:, 1], t[:, 2])
        d = np.linalg.norm(q - p, axis=1)
        inside = d <= radius_m
        contacts: dict[int, SphereContact] = {}
        for k in np.argsort(d[inside]):
            j = int(np.flatnonzero(inside)[k])
            iid = int(self.instance_ids[idx[j]])
            if iid in contacts:
                continue
            n = self.normals[idx[j]]
            contacts[iid] = SphereContact(
                iid,
                (float(q[j, 0]), float(q[j, 1]), float(q[j, 2])),
                float(d[j]),
                (float(n[0]), float(n[1]), float(n[2])),
            )
        return list(contacts.values())
