"""Vectorised low-poly primitives and the accumulator that assembles the world mesh.

Every primitive generator makes ``K`` instances at once and returns vertex positions
``(K, n_vertices, 3)`` plus one face template ``(n_faces, 3)`` shared by all
instances (counter-clockwise seen from outside).  :class:`MeshAccumulator` turns
them into one flat-shaded triangle soup with per-vertex color and instance id.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = [
    "LOD_ALWAYS",
    "LOD_FAR",
    "LOD_NEAR",
    "MeshAccumulator",
    "MeshArrays",
    "boxes",
    "cones",
    "cylinders",
    "ellipsoids",
    "gable_roofs",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

# Level-of-detail class of a triangle: drawn always, only near the camera, only far away.
LOD_ALWAYS = 0
LOD_NEAR = 1
LOD_FAR = 2


def _yaw_place(local: FloatArray, centers: FloatArray, yaw_rad: FloatArray) -> FloatArray:
    """Rotate ``(K, n, 3)`` local points by yaw about z and translate by ``(K, 3)`` centres."""
    c = np.cos(yaw_rad)[:, None]
    s = np.sin(yaw_rad)[:, None]
    out = np.empty_like(local)
    out[..., 0] = centers[:, None, 0] + c * local[..., 0] - s * local[..., 1]
    out[..., 1] = centers[:, None, 1] + s * local[..., 0] + c * local[..., 1]
    out[..., 2] = centers[:, None, 2] + local[..., 2]
    return out


_BOX_UNIT = np.array(
    [[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=np.float64
) * np.array([0.5, 0.5, 1.0])
_BOX_FACES = np.array(
    [[4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]],
    dtype=np.int64,
)
_BOX_BOTTOM = np.array([[0, 2, 1], [0, 3, 2]], dtype=np.int64)


def boxes(
    bottom_centers_m: npt.ArrayLike, sizes_m: npt.ArrayLike, yaw_rad: npt.ArrayLike, *, bottom: bool = False
) -> tuple[FloatArray, IntArray]:
    """Boxes standing on their bottom centre; ``sizes_m`` is ``(K, 3)`` (x length, y width, z height)."""
    c = np.atleast_2d(np.asarray(bottom_centers_m, dtype=np.float64))
    size = np.atleast_2d(np.asarray(sizes_m, dtype=np.float64))
    yaw = np.broadcast_to(np.asarray(yaw_rad, dtype=np.float64), (len(c),))
    local = _BOX_UNIT[None, :, :] * size[:, None, :]
    faces = np.concatenate([_BOX_FACES, _BOX_BOTTOM]) if bottom else _BOX_FACES
    return _yaw_place(local, c, yaw), faces


def gable_roofs(
    eave_centers_m: npt.ArrayLike, footprint_m: npt.ArrayLike, roof_height_m: npt.ArrayLike, yaw_rad: npt.ArrayLike
) -> tuple[FloatArray, IntArray]:
    """Gable roofs (ridge along local x) over ``(K, 2)`` footprints, eaves at the given centres."""
    c = np.atleast_2d(np.asarray(eave_centers_m, dtype=np.float64))
    fp = np.atleast_2d(np.asarray(footprint_m, dtype=np.float64))
    k = len(c)
    hr = np.broadcast_to(np.asarray(roof_height_m, dtype=np.float64), (k,))
    yaw = np.broadcast_to(np.asarray(yaw_rad, dtype=np.float64), (k,))
    hx, hy = fp[:, 0] / 2.0, fp[:, 1] / 2.0
    zero = np.zeros(k)
    local = np.stack(
        [
            np.stack([-hx, -hy, zero], -1),
            np.stack([hx, -hy, zero], -1),
            np.stack([hx, hy, zero], -1),
            np.stack([-hx, hy, zero], -1),
            np.stack([-hx, zero, hr], -1),
            np.stack([hx, zero, hr], -1),
        ],
        axis=1,
    )
    faces = np.array(
        [[0, 1, 5], [0, 5, 4], [2, 3, 4], [2, 4, 5], [1, 2, 5], [3, 0, 4], [0, 2, 1], [0, 3, 2]], dtype=np.int64
    )
    return _yaw_place(local, c, yaw), faces


def cones(
    base_centers_m: npt.ArrayLike, radius_m: npt.ArrayLike, height_m: npt.ArrayLike, segments: int, *, base: bool = True
) -> tuple[FloatArray, IntArray]:
    """Upright cones (tree crowns); ``segments`` sides, optional base disc."""
    c = np.atleast_2d(np.asarray(base_centers_m, dtype=np.float64))
    k = len(c)
    r = np.broadcast_to(np.asarray(radius_m, dtype=np.float64), (k,))
    h = np.broadcast_to(np.asarray(height_m, dtype=np.float64), (k,))
    a = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    local = np.zeros((k, segments + 2, 3))
    local[:, :segments, 0] = r[:, None] * np.cos(a)[None, :]
    local[:, :segments, 1] = r[:, None] * np.sin(a)[None, :]
    local[:, segments, 2] = h
    i = np.arange(segments)
    j = (i + 1) % segments
    parts = [np.stack([i, j, np.full(segments, segments)], axis=1)]
    if base:
        parts.append(np.stack([j, i, np.full(segments, segments + 1)], axis=1))
    return local + c[:, None, :], np.concatenate(parts).astype(np.int64)


def cylinders(
    base_centers_m: npt.ArrayLike, radius_m: npt.ArrayLike, height_m: npt.ArrayLike, segments: int
) -> tuple[FloatArray, IntArray]:
    """Open upright cylinders (tree trunks)."""
    c = np.atleast_2d(np.asarray(base_centers_m, dtype=np.float64))
    k = len(c)
    r = np.broadcast_to(np.asarray(radius_m, dtype=np.float64), (k,))
    h = np.broadcast_to(np.asarray(height_m, dtype=np.float64), (k,))
    a = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    local = np.zeros((k, 2 * segments, 3))
    local[:, :segments, 0] = r[:, None] * np.cos(a)
    local[:, :segments, 1] = r[:, None] * np.sin(a)
    local[:, segments:, :2] = local[:, :segments, :2]
    local[:, segments:, 2] = h[:, None]
    i = np.arange(segments)
    j = (i + 1) % segments
    faces = np.concatenate([np.stack([i, j, j + segments], 1), np.stack([i, j + segments, i + segments], 1)])
    return local + c[:, None, :], faces.astype(np.int64)


def icosahedron() -> tuple[FloatArray, IntArray]:
    """The unit icosahedron: 12 vertices and 20 outward faces."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
         [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )  # fmt: skip
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
         [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
         [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )  # fmt: skip
    return v, f


_ICO_V, _ICO_F = icosahedron()
_OCT_V = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)
_OCT_F = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [1, 0, 5], [2, 1, 5], [3, 2, 5], [0, 3, 5]], np.int64)


def ellipsoids(
    centers_m: npt.ArrayLike, radii_m: npt.ArrayLike, *, low_poly: bool = False
) -> tuple[FloatArray, IntArray]:
    """Ellipsoids (deciduous crowns): an icosahedron (20 faces) or an octahedron (8) scaled by ``(K, 3)`` radii."""
    c = np.atleast_2d(np.asarray(centers_m, dtype=np.float64))
    r = np.atleast_2d(np.asarray(radii_m, dtype=np.float64))
    unit, faces = (_OCT_V, _OCT_F) if low_poly else (_ICO_V, _ICO_F)
    return c[:, None, :] + unit[None, :, :] * r[:, None, :], faces


@dataclass(frozen=True)
class MeshArrays:
    """A flat-shaded triangle soup.

    Attributes:
        vertices_m: ``(V, 3)`` float32 positions in ``map``.
        normals: ``(V, 3)`` float32 unit normals.
        colors: ``(V, 3)`` float32 base colors in [0, 1].
        vertex_instance: ``(V,)`` uint32 world instance id of each vertex.
        faces: ``(F, 3)`` uint32 vertex indices.
        face_lod: ``(F,)`` uint8 level-of-detail class (``LOD_*``).
    """

    vertices_m: npt.NDArray[np.float32]
    normals: npt.NDArray[np.float32]
    colors: npt.NDArray[np.float32]
    vertex_instance: npt.NDArray[np.uint32]
    faces: npt.NDArray[np.uint32]
    face_lod: npt.NDArray[np.uint8]


class MeshAccumulator:
    """Collects primitives into one mesh; each call adds ``K`` instances."""

    def __init__(self) -> None:
        self._v: list[FloatArray] = []
        self._n: list[FloatArray] = []
        self._c: list[npt.NDArray[np.float32]] = []
        self._i: list[npt.NDArray[np.uint32]] = []
        self._f: list[IntArray] = []
        self._lod: list[npt.NDArray[np.uint8]] = []
        self._count = 0

    @property
    def vertex_count(self) -> int:
        return self._count

    def add_smooth(
        self,
        vertices_m: FloatArray,
        normals: FloatArray,
        faces: IntArray,
        colors: npt.ArrayLike,
        instance_id: int,
        *,
        lod: int = LOD_ALWAYS,
    ) -> None:
        """One shared-vertex mesh (terrain, roads) with per-vertex normals and colors."""
        n = len(vertices_m)
        self._v.append(np.asarray(vertices_m, dtype=np.float64))
        self._n.append(np.asarray(normals, dtype=np.float64))
        self._c.append(np.ascontiguousarray(np.broadcast_to(np.asarray(colors, np.float32), (n, 3))))
        self._i.append(np.full(n, instance_id, dtype=np.uint32))
        self._f.append(np.asarray(faces, dtype=np.int64) + self._count)
        self._lod.append(np.full(len(faces), lod, dtype=np.uint8))
        self._count += n

    def add_flat(
        self,
        vertices_m: FloatArray,
        faces: IntArray,
        colors: npt.ArrayLike,
        instance_ids: npt.ArrayLike,
        *,
        lod: int = LOD_ALWAYS,
    ) -> None:
        """``K`` instances of one primitive, flat shaded.

        Args:
            vertices_m: ``(K, n_vertices, 3)`` positions.
            faces: ``(n_faces, 3)`` template shared by all instances.
            colors: ``(K, 3)`` or ``(3,)`` color per instance, or ``(K, n_faces, 3)`` per face.
            instance_ids: ``(K,)`` instance id per instance.
            lod: ``LOD_*`` class of all the added faces.
        """
        k = vertices_m.shape[0]
        if k == 0:
            return
        nf = len(faces)
        tri = vertices_m[:, faces, :]  # (K, nf, 3, 3)
        normal = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True) + 1e-12
        verts = tri.reshape(-1, 3)
        normals = np.repeat(normal.reshape(-1, 3), 3, axis=0)
        c = np.asarray(colors, dtype=np.float32)
        ids = np.broadcast_to(np.asarray(instance_ids, dtype=np.uint32).reshape(-1), (k,))
        per = nf * 3
        if c.ndim == 3:  # per face
            vert_colors = np.repeat(np.broadcast_to(c, (k, nf, 3)).reshape(-1, 3), 3, axis=0)
        else:
            vert_colors = np.repeat(np.broadcast_to(c.reshape(-1, 3), (k, 3)), per, axis=0)
        self._v.append(verts)
        self._n.append(normals)
        self._c.append(vert_colors.astype(np.float32))
        self._i.append(np.repeat(ids, per).astype(np.uint32))
        self._f.append(np.arange(k * per, dtype=np.int64).reshape(-1, 3) + self._count)
        self._lod.append(np.full(k * nf, lod, dtype=np.uint8))
        self._count += k * per

    def finish(self) -> MeshArrays:
        if not self._v:
            msg = "empty mesh"
            raise ValueError(msg)
        return MeshArrays(
            vertices_m=np.concatenate(self._v).astype(np.float32),
            normals=np.concatenate(self._n).astype(np.float32),
            colors=np.concatenate(self._c).astype(np.float32),
            vertex_instance=np.concatenate(self._i).astype(np.uint32),
            faces=np.concatenate(self._f).astype(np.uint32),
            face_lod=np.concatenate(self._lod).astype(np.uint8),
        )
