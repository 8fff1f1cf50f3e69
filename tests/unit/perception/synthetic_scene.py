"""An exactly known textured scene, ray-cast in numpy, for depth-estimation tests.

The scene is a smooth heightfield (sums of sinusoids) with axis-aligned box
"buildings" on it. Every pixel's ray is marched to its first surface hit and the
crossing is refined by bisection, so the ground-truth z-depth is exact to about
1e-5 m. Color is a world-space 3-D value-noise texture (it moves with the
surface, as a real texture does) times a Lambert term, so two views of the same
point see the same texture: the scene is matchable by stereo.

Instance ids: 0 = nothing hit (depth NaN), 1 = terrain, 2.. = the boxes in order.

It is independent of the project's renderer on purpose: it gives tests an exact
reference that no renderer bug can shift.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from uav_perception.core.depth.types import CameraPose, PinholeCamera

FloatArray = npt.NDArray[np.float64]

TERRAIN_ID = 1


@dataclass(frozen=True)
class Box:
    """A box standing on the terrain: footprint ``[x0, x1] x [y0, y1]`` (map, m), top at ``top_m``."""

    x0: float
    x1: float
    y0: float
    y1: float
    top_m: float


@dataclass(frozen=True)
class SceneSpec:
    """Terrain shape, boxes and texture of a synthetic scene."""

    amplitude_m: float = 4.0
    wavelengths_m: tuple[float, float] = (90.0, 140.0)
    boxes: tuple[Box, ...] = ()
    texture_freqs_per_m: tuple[float, ...] = (1.0, 0.25, 0.0625)
    texture_weights: tuple[float, ...] = (0.5, 0.3, 0.2)
    seed: int = 0
    sun_dir: tuple[float, float, float] = (0.3, 0.2, 0.93)


def nadir_rotation(heading_rad: float = 0.0) -> FloatArray:
    """``R_map_optical`` of a camera looking straight down on a vehicle heading ``heading_rad`` (ENU yaw).

    Optical x is the vehicle's right, optical y its backward direction, optical z down.
    """
    fwd = np.array([math.cos(heading_rad), math.sin(heading_rad), 0.0])
    right = np.array([math.sin(heading_rad), -math.cos(heading_rad), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    return np.stack([right, -fwd, down], axis=1)


def rotation_about(axis: npt.ArrayLike, angle_rad: float) -> FloatArray:
    """Rodrigues rotation matrix."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle_rad) * k + (1 - math.cos(angle_rad)) * (k @ k)


def _hash01(ix: npt.NDArray[np.int64], iy: npt.NDArray[np.int64], iz: npt.NDArray[np.int64], seed: int) -> FloatArray:
    h = (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791) ^ (seed * 2654435761)
    h = h & 0xFFFFFFFF
    h = ((h >> 16) ^ h) * 0x45D9F3B & 0xFFFFFFFF
    h = ((h >> 16) ^ h) * 0x45D9F3B & 0xFFFFFFFF
    h = (h >> 16) ^ h
    return (h & 0xFFFFFF).astype(np.float64) / float(0xFFFFFF)


def value_noise(p: FloatArray, seed: int) -> FloatArray:
    """Smooth 3-D value noise in [0, 1] at points ``(N, 3)``."""
    base = np.floor(p)
    f = p - base
    f = f * f * (3.0 - 2.0 * f)
    i = base.astype(np.int64)
    out = np.zeros(len(p))
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1.0 - f[:, 0]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1.0 - f[:, 1]
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1.0 - f[:, 2]
                out += wx * wy * wz * _hash01(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


class SyntheticScene:
    """Ray-cast renderer of a :class:`SceneSpec`."""

    def __init__(self, spec: SceneSpec) -> None:
        self.spec = spec
        rng = np.random.default_rng(spec.seed)
        self._phase = rng.uniform(0, 2 * math.pi, 4)
        self.z_top = spec.amplitude_m * 2.0 + max((b.top_m for b in spec.boxes), default=0.0) + 1.0

    def terrain_height(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """Terrain height (map z, m); 0 at the origin."""
        s = self.spec
        k1, k2 = 2 * math.pi / s.wavelengths_m[0], 2 * math.pi / s.wavelengths_m[1]
        p = self._phase
        h = np.sin(k1 * x + p[0]) * np.cos(k2 * y + p[1]) + 0.5 * np.sin(k2 * (x + y) * 0.7 + p[2])
        h0 = math.sin(p[0]) * math.cos(p[1]) + 0.5 * math.sin(p[2])
        return s.amplitude_m * (h - h0)

    def surface(self, x: FloatArray, y: FloatArray) -> tuple[FloatArray, npt.NDArray[np.int64]]:
        """Height and instance id of the top surface at ``(x, y)``."""
        h = self.terrain_height(x, y)
        inst = np.full(x.shape, TERRAIN_ID, dtype=np.int64)
        for k, b in enumerate(self.spec.boxes):
            inside = (x >= b.x0) & (x <= b.x1) & (y >= b.y0) & (y <= b.y1) & (b.top_m > h)
            h = np.where(inside, b.top_m, h)
            inst = np.where(inside, k + 2, inst)
        return h, inst

    def _march_terrain(self, origin: FloatArray, dirs: FloatArray, max_range_m: float) -> FloatArray:
        """Ray parameter of the first terrain hit (NaN = none).

        Lipschitz-bounded steps: the terrain slope never exceeds ``lip``, so a step of
        ``gap / (|d_z| + lip * |d_xy|)`` cannot cross the surface; iterate until the
        gap is below 1e-6 m.
        """
        s = self.spec
        k1, k2 = 2 * math.pi / s.wavelengths_m[0], 2 * math.pi / s.wavelengths_m[1]
        lip = s.amplitude_m * (k1 + k2 + 0.5 * 0.7 * k2 * math.sqrt(2.0)) * 1.05 + 1e-9
        n = len(dirs)
        bound = 3.0 * s.amplitude_m + 1e-3
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = np.where(dirs[:, 2] < 0, (origin[2] - bound) / -dirs[:, 2], 0.0)
        t = np.clip(np.nan_to_num(t0, nan=0.0, posinf=0.0), 0.0, None)
        speed = np.abs(dirs[:, 2]) + lip * np.hypot(dirs[:, 0], dirs[:, 1])
        out = np.full(n, np.nan)
        active = np.arange(n)
        for _ in range(2000):
            if not active.size:
                break
            p = origin + dirs[active] * t[active, None]
            gap = p[:, 2] - self.terrain_height(p[:, 0], p[:, 1])
            done = gap < 1e-6
            out[active[done]] = t[active[done]]
            t[active] += np.maximum(gap, 0.0) / speed[active]
            keep = ~done & (p[:, 2] > -bound) & (t[active] < max_range_m)
            active = active[keep]
        return out

    def _intersect_boxes(self, origin: FloatArray, dirs: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """First box hit per ray (slab method): ray parameter (NaN = none), instance id, face normal."""
        n = len(dirs)
        t_best = np.full(n, np.inf)
        inst = np.zeros(n)
        normal = np.zeros((n, 3))
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / dirs
        for k, b in enumerate(self.spec.boxes):
            lows = np.array([b.x0, b.y0, -1e6])
            highs = np.array([b.x1, b.y1, b.top_m])
            with np.errstate(invalid="ignore"):
                ta = (lows - origin) * inv
                tb = (highs - origin) * inv
            t_near = np.minimum(ta, tb)
            t_far = np.maximum(ta, tb)
            t_near = np.nan_to_num(t_near, nan=-np.inf)
            t_far = np.nan_to_num(t_far, nan=np.inf)
            entry_axis = np.argmax(t_near, axis=1)
            t_in = t_near.max(axis=1)
            t_out = t_far.min(axis=1)
            ok = (t_in <= t_out) & (t_in > 0) & (t_in < t_best)
            t_best = np.where(ok, t_in, t_best)
            inst = np.where(ok, k + 2, inst)
            face = np.zeros((n, 3))
            face[np.arange(n), entry_axis] = -np.sign(dirs[np.arange(n), entry_axis])
            normal = np.where(ok[:, None], face, normal)
        t_best[~np.isfinite(t_best)] = np.nan
        return t_best, inst, normal

    def render(
        self, camera: PinholeCamera, pose: CameraPose, *, max_range_m: float = 2000.0
    ) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.float32], npt.NDArray[np.uint16]]:
        """Color ``(H, W, 3)`` uint8, z-depth ``(H, W)`` float32 (NaN = no hit) and instance ids uint16."""
        rays_cam = camera.pixel_rays().reshape(-1, 3)
        dirs = rays_cam @ pose.rotation_map_optical.T
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        origin = pose.position_map_m
        n = len(dirs)
        t_terrain = self._march_terrain(origin, dirs, max_range_m)
        t_box, box_inst, box_normal = self._intersect_boxes(origin, dirs)
        use_box = np.isfinite(t_box) & ~(t_terrain < t_box)
        t_hit = np.where(use_box, t_box, t_terrain)
        hit = np.isfinite(t_hit)
        pts = origin + dirs[hit] * t_hit[hit, None]
        inst_hit = np.where(use_box[hit], box_inst[hit], TERRAIN_ID).astype(np.int64)
        eps = 0.05
        x, y = pts[:, 0], pts[:, 1]
        gx = (self.terrain_height(x + eps, y) - self.terrain_height(x - eps, y)) / (2 * eps)
        gy = (self.terrain_height(x, y + eps) - self.terrain_height(x, y - eps)) / (2 * eps)
        normals = np.stack([-gx, -gy, np.ones(len(pts))], axis=1)
        normals = np.where(use_box[hit][:, None], box_normal[hit], normals)
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        s = self.spec
        tex = np.zeros(len(pts))
        for freq, weight in zip(s.texture_freqs_per_m, s.texture_weights, strict=True):
            tex += weight * value_noise(pts * freq, s.seed + int(freq * 1000))
        sun = np.asarray(s.sun_dir) / np.linalg.norm(s.sun_dir)
        light = 0.35 + 0.65 * np.clip(normals @ sun, 0.0, 1.0)
        base = np.where((inst_hit == TERRAIN_ID)[:, None], np.array([0.45, 0.62, 0.32]), np.array([0.75, 0.68, 0.6]))
        color = np.clip(base * (0.35 + 0.9 * tex)[:, None] * light[:, None], 0.0, 1.0)
        rgb = np.zeros((n, 3), dtype=np.uint8)
        rgb[~hit] = (150, 190, 235)
        rgb[hit] = np.rint(color * 255).astype(np.uint8)
        depth = np.full(n, np.nan, dtype=np.float32)
        depth[hit] = (t_hit[hit] * (dirs[hit] @ pose.optical_axis_map)).astype(np.float32)
        inst = np.zeros(n, dtype=np.uint16)
        inst[hit] = inst_hit.astype(np.uint16)
        shape = camera.shape
        return rgb.reshape(*shape, 3), depth.reshape(shape), inst.reshape(shape)


def default_scene(seed: int = 0) -> SyntheticScene:
    """Rolling terrain with a few 6-25 m boxes around the origin."""
    boxes = (
        Box(-20.0, -6.0, 4.0, 16.0, 14.0),
        Box(8.0, 20.0, -18.0, -8.0, 22.0),
        Box(15.0, 24.0, 10.0, 22.0, 8.0),
        Box(-25.0, -15.0, -25.0, -12.0, 6.0),
    )
    return SyntheticScene(SceneSpec(boxes=boxes, seed=seed))
