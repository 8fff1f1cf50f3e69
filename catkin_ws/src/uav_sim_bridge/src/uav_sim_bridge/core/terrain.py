"""Terrain heightfield: generation (valley and hills, or a user heightmap) and exact queries.

The heightfield is a regular grid of nodes ``heights_m[row, col]`` at
``x = origin_x + col * res`` (east) and ``y = origin_y + row * res`` (north).  Each
cell is split into two triangles along its south-west -> north-east diagonal, and
:meth:`Heightfield.height_at` interpolates on exactly those triangles, so queries
agree with the rendered mesh to float precision.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.world_config import TerrainConfig
from uav_sim_bridge.errors import WorldFileError

__all__ = ["Heightfield", "fbm_noise", "generate_terrain", "smoothstep"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Heightfield:
    """Piecewise-linear terrain over a square grid (see module docstring).

    Attributes:
        origin_m: ``(x, y)`` of node ``[0, 0]``, the south-west corner, metres in ``map``.
        resolution_m: node spacing.
        heights_m: ``(rows, cols)`` float64 heights (z up, metres).
    """

    origin_m: tuple[float, float]
    resolution_m: float
    heights_m: FloatArray

    def __post_init__(self) -> None:
        h = np.asarray(self.heights_m, dtype=np.float64)
        if h.ndim != 2 or min(h.shape) < 2:
            msg = f"heights_m must be a 2-D grid of at least 2x2 nodes, got shape {h.shape}"
            raise ValueError(msg)
        if not np.all(np.isfinite(h)):
            msg = "heights_m contains NaN or inf"
            raise ValueError(msg)
        h.setflags(write=False)
        object.__setattr__(self, "heights_m", h)

    @property
    def shape(self) -> tuple[int, int]:
        rows, cols = self.heights_m.shape
        return int(rows), int(cols)

    @property
    def bounds_m(self) -> tuple[float, float, float, float]:
        """``(x_min, y_min, x_max, y_max)`` of the grid."""
        rows, cols = self.shape
        x0, y0 = self.origin_m
        return x0, y0, x0 + (cols - 1) * self.resolution_m, y0 + (rows - 1) * self.resolution_m

    def node_xy(self) -> tuple[FloatArray, FloatArray]:
        """``(X, Y)`` node coordinate grids, each ``(rows, cols)``."""
        rows, cols = self.shape
        x = self.origin_m[0] + np.arange(cols) * self.resolution_m
        y = self.origin_m[1] + np.arange(rows) * self.resolution_m
        gx, gy = np.meshgrid(x, y, indexing="xy")
        return gx, gy

    def height_at(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> FloatArray:
        """Terrain height at ``(x, y)`` (any broadcastable shapes), clamped to the grid edge."""
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        rows, cols = self.shape
        gx = np.clip((x - self.origin_m[0]) / self.resolution_m, 0.0, cols - 1.0)
        gy = np.clip((y - self.origin_m[1]) / self.resolution_m, 0.0, rows - 1.0)
        i = np.minimum(np.floor(gx).astype(np.int64), cols - 2)
        j = np.minimum(np.floor(gy).astype(np.int64), rows - 2)
        fx = gx - i
        fy = gy - j
        h = self.heights_m
        ha = h[j, i]
        hb = h[j, i + 1]
        hc = h[j + 1, i]
        hd = h[j + 1, i + 1]
        lower = fx >= fy
        out = np.where(lower, ha + fx * (hb - ha) + fy * (hd - hb), ha + fy * (hc - ha) + fx * (hd - hc))
        return np.asarray(out, dtype=np.float64)

    def slope_at(self, x_m: npt.ArrayLike, y_m: npt.ArrayLike) -> FloatArray:
        """Gradient magnitude (rise over run) from central differences over one cell."""
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        r = self.resolution_m
        dx = (self.height_at(x + r, y) - self.height_at(x - r, y)) / (2 * r)
        dy = (self.height_at(x, y + r) - self.height_at(x, y - r)) / (2 * r)
        return np.asarray(np.hypot(dx, dy), dtype=np.float64)

    def vertex_normals(self) -> FloatArray:
        """``(rows, cols, 3)`` unit normals from the height gradient."""
        gy, gx = np.gradient(self.heights_m, self.resolution_m)
        n = np.stack([-gx, -gy, np.ones_like(gx)], axis=-1)
        return np.asarray(n / np.linalg.norm(n, axis=-1, keepdims=True), dtype=np.float64)

    def mesh(self) -> tuple[FloatArray, npt.NDArray[np.int64]]:
        """``(vertices (rows*cols, 3), faces (2*(rows-1)*(cols-1), 3))``, CCW seen from above."""
        gx, gy = self.node_xy()
        verts = np.stack([gx, gy, self.heights_m], axis=-1).reshape(-1, 3)
        rows, cols = self.shape
        idx = np.arange(rows * cols, dtype=np.int64).reshape(rows, cols)
        a, b = idx[:-1, :-1], idx[:-1, 1:]
        c, d = idx[1:, :-1], idx[1:, 1:]
        faces = np.concatenate(
            [np.stack([a, b, d], axis=-1).reshape(-1, 3), np.stack([a, d, c], axis=-1).reshape(-1, 3)]
        )
        return verts, faces

    def with_heights(self, heights_m: FloatArray) -> Heightfield:
        return Heightfield(self.origin_m, self.resolution_m, heights_m)


def smoothstep(edge0: float, edge1: float, x: npt.ArrayLike) -> FloatArray:
    """Hermite 0 -> 1 ramp between ``edge0`` and ``edge1``."""
    t = np.clip((np.asarray(x, dtype=np.float64) - edge0) / (edge1 - edge0), 0.0, 1.0)
    return np.asarray(t * t * (3.0 - 2.0 * t), dtype=np.float64)


def _value_noise(x: FloatArray, y: FloatArray, wavelength_m: float, rng: np.random.Generator) -> FloatArray:
    """Smooth value noise in [0, 1] with lattice spacing ``wavelength_m`` over the points' extent."""
    x0, y0 = float(np.min(x)), float(np.min(y))
    gx = (x - x0) / wavelength_m
    gy = (y - y0) / wavelength_m
    nx = math.floor(float(np.max(gx))) + 2
    ny = math.floor(float(np.max(gy))) + 2
    lattice = rng.random((ny + 1, nx + 1))
    i = np.floor(gx).astype(np.int64)
    j = np.floor(gy).astype(np.int64)
    fx = gx - i
    fy = gy - j
    fx = fx * fx * (3.0 - 2.0 * fx)
    fy = fy * fy * (3.0 - 2.0 * fy)
    v00 = lattice[j, i]
    v10 = lattice[j, i + 1]
    v01 = lattice[j + 1, i]
    v11 = lattice[j + 1, i + 1]
    top = v00 + (v10 - v00) * fx
    bot = v01 + (v11 - v01) * fx
    return np.asarray(top + (bot - top) * fy, dtype=np.float64)


def fbm_noise(
    x: npt.ArrayLike, y: npt.ArrayLike, base_wavelength_m: float, octaves: int, rng: np.random.Generator
) -> FloatArray:
    """Fractal value noise in about [-1, 1]: ``octaves`` layers halving wavelength and amplitude."""
    xa = np.asarray(x, dtype=np.float64)
    ya = np.asarray(y, dtype=np.float64)
    total = np.zeros(np.broadcast(xa, ya).shape)
    amp, norm = 1.0, 0.0
    wl = base_wavelength_m
    xb, yb = np.broadcast_arrays(xa, ya)
    for _ in range(octaves):
        total += amp * (2.0 * _value_noise(xb, yb, wl, rng) - 1.0)
        norm += amp
        amp *= 0.5
        wl *= 0.5
    return np.asarray(total / norm, dtype=np.float64)


def _valley_terrain(cfg: TerrainConfig, gx: FloatArray, gy: FloatArray, rng: np.random.Generator) -> FloatArray:
    """Valley-and-hills heights: a meandering valley floor between noisy hills."""
    heading = math.radians(cfg.valley_heading_deg)
    along = gx * math.sin(heading) + gy * math.cos(heading)  # valley runs toward the heading (from north)
    across = gx * math.cos(heading) - gy * math.sin(heading)
    ph1, ph2 = rng.uniform(0.0, 2.0 * math.pi, 2)
    l1, l2 = rng.uniform(550.0, 800.0), rng.uniform(230.0, 330.0)

    def centre(s: FloatArray | float) -> FloatArray:
        s_arr = np.asarray(s, dtype=np.float64)
        return np.asarray(
            cfg.valley_meander_m
            * (0.75 * np.sin(2 * math.pi * s_arr / l1 + ph1) + 0.25 * np.sin(2 * math.pi * s_arr / l2 + ph2)),
            dtype=np.float64,
        )

    # Put home on the valley's flank, a little off its floor.
    offset = float(centre(0.0)) - rng.uniform(-0.25, 0.25) * cfg.valley_width_m
    dist = across - (centre(along) - offset)
    half = cfg.valley_width_m / 2.0
    shape = 1.0 - np.exp(-((dist / half) ** 2))
    ridges = 0.55 + 0.9 * (0.5 + 0.5 * fbm_noise(gx, gy, 420.0, 3, rng))
    hills = cfg.hill_height_m * shape * ridges
    rough = cfg.roughness_m * fbm_noise(gx, gy, 160.0, 5, rng) * (0.35 + 0.65 * shape)
    grade = cfg.valley_grade * along  # the valley floor descends gently along its length
    return np.asarray(hills + rough + grade, dtype=np.float64)


def normalized_heightmap(img: npt.NDArray[np.generic]) -> FloatArray:
    """A decoded heightmap image (8- or 16-bit, grey or colour) as heights in [0, 1], row 0 the north edge.

    Raises:
        WorldFileError: not a 2D grey or 3D colour image.
    """
    if img.ndim == 3:
        img = img[..., :3].mean(axis=2)
    if img.ndim != 2 or img.size == 0:
        msg = f"heightmap image has shape {img.shape}; expected a 2D grey or colour image"
        raise WorldFileError(msg)
    full = {np.dtype(np.uint8): 255.0, np.dtype(np.uint16): 65535.0}.get(img.dtype, 1.0)
    return np.clip(img.astype(np.float64) / full, 0.0, 1.0)


def _heightmap_terrain(cfg: TerrainConfig, norm: FloatArray, rows: int, cols: int) -> FloatArray:
    # Image row 0 is the north edge; grid row 0 is the south edge.
    grid = cv2.resize(norm[::-1].copy(), (cols, rows), interpolation=cv2.INTER_LINEAR)
    return np.asarray(cfg.heightmap_min_m + grid * (cfg.heightmap_max_m - cfg.heightmap_min_m), dtype=np.float64)


def generate_terrain(cfg: TerrainConfig, rng: np.random.Generator, heightmap: FloatArray | None = None) -> Heightfield:
    """Build the heightfield with a flat home pad, shifted so that ``height_at(0, 0) == 0``.

    Args:
        heightmap: the configured heightmap image, :func:`normalized_heightmap` (loaded by the
            shell, ``uav_sim_bridge.shell.world_store.load_world_inputs``).

    Raises:
        WorldFileError: a heightmap image is configured but was not given.
    """
    if cfg.heightmap_image is not None and heightmap is None:
        msg = f"terrain.heightmap_image {cfg.heightmap_image} was not loaded (load_world_inputs reads it)"
        raise WorldFileError(msg)
    n = round(cfg.size_m / cfg.resolution_m) + 1
    origin = (cfg.center_m[0] - cfg.size_m / 2.0, cfg.center_m[1] - cfg.size_m / 2.0)
    x = origin[0] + np.arange(n) * cfg.resolution_m
    y = origin[1] + np.arange(n) * cfg.resolution_m
    gx, gy = np.meshgrid(x, y, indexing="xy")
    heights = _heightmap_terrain(cfg, heightmap, n, n) if heightmap is not None else _valley_terrain(cfg, gx, gy, rng)
    field = Heightfield(origin, cfg.resolution_m, heights)
    if cfg.home_pad_radius_m > 0:
        r = np.hypot(gx, gy)
        inside = r <= cfg.home_pad_radius_m
        pad_h = (
            float(np.mean(field.height_at(gx[inside], gy[inside]))) if np.any(inside) else float(field.height_at(0, 0))
        )
        w = 1.0 - smoothstep(cfg.home_pad_radius_m, 2.5 * cfg.home_pad_radius_m, r)
        heights = heights * (1.0 - w) + pad_h * w
        field = field.with_heights(heights)
    return field.with_heights(field.heights_m - float(field.height_at(0.0, 0.0)))
