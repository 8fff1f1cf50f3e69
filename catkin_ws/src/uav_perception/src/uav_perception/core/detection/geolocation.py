"""Box -> 3D position in ``map`` with an uncertainty: the ray through the box's ground-contact point,
intersected with the depth image, else the elevation layer (over the terrain model), else the terrain.

**Ground-contact point.** A person or vehicle stands on the ground; the box's point that images the
ground contact lies on the box's edge *towards where a falling point moves in the image*. Moving a
point at normalised image coordinates ``(x, y)`` along the world's down direction ``d`` (in the optical
frame) moves its image along ``g = (fx (d_x - x d_z), fy (d_y - y d_z))``. In an oblique forward view
``g`` points straight down the image, so the contact point is the bottom centre of the box (a standing
person's feet). In a nadir view ``g`` points to the principal point (the image of the nadir), so the
contact point is the box's edge nearest the image centre, and a person right under the camera is placed
at the box centre (head and feet image to the same point). :func:`contact_point` intersects the ray from
the box centre along ``g`` with the box's edge.

A lying person (or a car) touches the ground over its whole footprint: the contact point found this way
is the *near* edge of that footprint, up to half a body length (~0.9 m) short of the centre. Each class
has a ``footprint_radius_m`` (``config/detection_classes.yaml``): the point is moved that far further
from the camera, horizontally, scaled by the sine of the ray's off-nadir angle (no shift looking straight
down, where the contact point is already the centre), and the same radius enters the covariance.

**Surfaces, in order.** (1) ``depth``: the median z-depth of the box's pixels next to the contact point
(a window of ``depth_window_rel`` of the box size) back-projected along the contact ray. (2) The map
server's ``elevation`` layer, with the prior terrain model filling the cells the map has not seen: the
ray is marched through both and refined by bisection (:func:`first_hit`); the reported source is the
grid that held the hit (``elevation`` or ``terrain``). (3) ``terrain`` alone when there is no elevation
layer. A box whose ray meets none of them within ``max_range_m`` is not placed (``no_surface``).

**Uncertainty.** The covariance (map, m²) sums independent terms, each pushed through the same
intersection by finite differences: the contact pixel (``pixel_sigma_px`` plus ``pixel_sigma_rel`` of the
box's extent along ``g`` plus the camera attitude's ``attitude_sigma_deg`` in pixels, along u and v), the
surface height (``elevation_sigma_m`` or ``terrain_sigma_m``) or the depth (``depth_sigma_rel`` of z, along
the ray), and the footprint radius (horizontal). At a shallow ray a height error becomes a long
horizontal error (``sigma_h / tan(depression)``), which is exactly what the finite difference gives. A
``nearest`` grid (the elevation layer: one height per cell) adds half its cell to the height sigma and its
cell's quantisation (``res / sqrt(12)``) horizontally.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_perception.core.depth.types import CameraPose, PinholeCamera
from uav_perception.core.detection.boxes import Box
from uav_perception.core.detection.heightfield import HeightGrid, first_hit
from uav_perception.errors import DetectionInputError

__all__ = [
    "PLACEMENT_SOURCES",
    "UNPLACED_REASONS",
    "GeolocationConfig",
    "Placement",
    "Surfaces",
    "contact_point",
    "place",
]

FloatArray = npt.NDArray[np.float64]

#: Where a placement came from (``uav_msgs/Detection.position_source``).
PLACEMENT_SOURCES = ("depth", "elevation", "terrain")
#: Why a detection could not be placed.
UNPLACED_REASONS = ("no_camera_info", "no_pose", "no_surface_model", "no_surface")

_DOWN = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class GeolocationConfig:
    """How boxes are placed and how uncertain the placements are (the geolocator's ``~`` parameters)."""

    #: Farthest intersection searched along a ray, metres.
    max_range_m: float = 1000.0
    #: Nearest: closer than this the ray is still inside the camera's own surroundings.
    min_range_m: float = 0.5
    #: Ray-marching step; 0 = half the finest grid's resolution.
    step_m: float = 0.0
    #: Contact-pixel uncertainty: a fixed part, a part relative to the box's extent along the vertical's
    #: image direction, and the camera attitude's uncertainty (converted to pixels).
    pixel_sigma_px: float = 1.0
    pixel_sigma_rel: float = 0.05
    attitude_sigma_deg: float = 0.5
    #: Depth: relative (1 sigma) error of the depth image; window around the contact point (fraction of the box).
    depth_sigma_rel: float = 0.02
    depth_window_rel: float = 0.15
    #: Height uncertainty (1 sigma) of the map server's elevation layer and of the prior terrain model.
    elevation_sigma_m: float = 0.5
    terrain_sigma_m: float = 1.0

    def __post_init__(self) -> None:
        positive = ("max_range_m", "min_range_m", "depth_sigma_rel", "elevation_sigma_m", "terrain_sigma_m")
        non_negative = ("step_m", "pixel_sigma_px", "pixel_sigma_rel", "attitude_sigma_deg", "depth_window_rel")
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                msg = f"{name} must be finite and > 0, got {value}"
                raise ValueError(msg)
        for name in non_negative:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                msg = f"{name} must be finite and >= 0, got {value}"
                raise ValueError(msg)
        if self.min_range_m >= self.max_range_m:
            msg = f"min_range_m ({self.min_range_m}) must be below max_range_m ({self.max_range_m})"
            raise ValueError(msg)


@dataclass(frozen=True, eq=False)
class Surfaces:
    """What a ray can be intersected with for one image; any of them may be missing."""

    #: z-depth image of the same camera and stamp (metres, NaN = none), ``(H, W)``.
    depth_m: npt.NDArray[np.floating[Any]] | None = None
    #: The map server's elevation layer (``nearest``).
    elevation: HeightGrid | None = None
    #: The prior terrain model (``bilinear``).
    terrain: HeightGrid | None = None

    @property
    def any(self) -> bool:
        return self.depth_m is not None or self.elevation is not None or self.terrain is not None


@dataclass(frozen=True, eq=False)
class Placement:
    """Where a box was placed, or why not (``reason``; then every number is NaN)."""

    position_m: tuple[float, float, float]
    #: Row-major 3x3 covariance of ``position_m`` (map, m²).
    covariance_m2: tuple[float, ...]
    #: ``depth`` | ``elevation`` | ``terrain``; "" when not placed.
    source: str
    range_m: float
    contact_px: tuple[float, float]
    reason: str = ""
    sigma_terms_m: dict[str, float] = field(default_factory=dict)

    @property
    def placed(self) -> bool:
        return bool(self.source)

    @staticmethod
    def unplaced(reason: str, contact_px: tuple[float, float] = (math.nan, math.nan)) -> Placement:
        nan = math.nan
        return Placement((nan, nan, nan), (nan,) * 9, "", nan, contact_px, reason)


def _down_image_direction(camera: PinholeCamera, pose: CameraPose, u: float, v: float) -> tuple[float, float]:
    """Image direction in which a point seen at ``(u, v)`` moves when it moves down in the world."""
    d = pose.rotation_map_optical.T @ _DOWN
    x = (u - camera.cx_px) / camera.fx_px
    y = (v - camera.cy_px) / camera.fy_px
    return (camera.fx_px * (d[0] - x * d[2]), camera.fy_px * (d[1] - y * d[2]))


def contact_point(box: Box, camera: PinholeCamera, pose: CameraPose) -> tuple[float, float]:
    """The box's ground-contact pixel: from the centre along the vertical's image direction to the edge."""
    cu, cv = box.center
    gu, gv = _down_image_direction(camera, pose, cu, cv)
    norm = math.hypot(gu, gv)
    if norm < 1e-9:
        return (cu, cv)
    gu, gv = gu / norm, gv / norm
    half_u, half_v = 0.5 * (box.u1 - box.u0), 0.5 * (box.v1 - box.v0)
    reach = min(half_u / abs(gu) if abs(gu) > 1e-12 else math.inf, half_v / abs(gv) if abs(gv) > 1e-12 else math.inf)
    # A standing person seen from above: the vertical's image is short; never step past the box's edge.
    return (cu + reach * gu, cv + reach * gv)


def _ray(camera: PinholeCamera, pose: CameraPose, u: float, v: float) -> FloatArray:
    r = pose.rotation_map_optical @ np.array(
        [(u - camera.cx_px) / camera.fx_px, (v - camera.cy_px) / camera.fy_px, 1.0]
    )
    return np.asarray(r / np.linalg.norm(r), dtype=np.float64)


def _depth_at(depth_m: npt.NDArray[np.floating[Any]], box: Box, u: float, v: float, window_rel: float) -> float:
    """Median finite z-depth of the box's pixels within the window around ``(u, v)``; NaN if none."""
    rows, cols = depth_m.shape
    su, sv = box.size
    radius = max(1.0, window_rel * min(su, sv))
    c0 = max(0, math.floor(max(box.u0 + 0.5, u - radius) + 0.5))
    c1 = min(cols - 1, math.floor(min(box.u1 - 0.5, u + radius) + 0.5))
    r0 = max(0, math.floor(max(box.v0 + 0.5, v - radius) + 0.5))
    r1 = min(rows - 1, math.floor(min(box.v1 - 0.5, v + radius) + 0.5))
    if c1 < c0 or r1 < r0:
        return math.nan
    patch = np.asarray(depth_m[r0 : r1 + 1, c0 : c1 + 1], dtype=np.float64)
    finite = patch[np.isfinite(patch) & (patch > 0)]
    return float(np.median(finite)) if finite.size else math.nan


def _pixel_sigma(box: Box, camera: PinholeCamera, pose: CameraPose, cfg: GeolocationConfig) -> float:
    cu, cv = box.center
    gu, gv = _down_image_direction(camera, pose, cu, cv)
    norm = math.hypot(gu, gv)
    su, sv = box.size
    extent = abs(gu / norm) * su + abs(gv / norm) * sv if norm > 1e-9 else max(su, sv)
    attitude_px = camera.fx_px * math.tan(math.radians(cfg.attitude_sigma_deg))
    return math.sqrt(cfg.pixel_sigma_px**2 + (cfg.pixel_sigma_rel * extent) ** 2 + attitude_px**2)


def _sensitivity(fn: Callable[[float], FloatArray | None], base: FloatArray, sigma: float) -> FloatArray | None:
    """``sigma * d fn / d x`` at 0 by a one-sided difference (the other side if one misses)."""
    if sigma <= 0:
        return np.zeros(3)
    for step in (sigma, -sigma):
        p = fn(step)
        if p is not None:
            return np.asarray((p - base) * (sigma / step), dtype=np.float64)
    return None


def _on_depth(
    depth_m: npt.NDArray[np.floating[Any]],
    box: Box,
    camera: PinholeCamera,
    pose: CameraPose,
    *,
    uv: tuple[float, float],
    sigma_px: float,
    cfg: GeolocationConfig,
) -> tuple[FloatArray, list[FloatArray]] | None:
    """The contact ray's point at the depth image's median depth near the contact pixel, with the
    sensitivities to the pixel (u, v) and to the depth; ``None`` where the depth has no value."""
    u, v = uv
    z = _depth_at(depth_m, box, u, v, cfg.depth_window_rel)
    if not math.isfinite(z):
        return None
    origin = pose.position_map_m

    def at(du: float, dv: float, dz: float) -> FloatArray:
        r = np.array([(u + du - camera.cx_px) / camera.fx_px, (v + dv - camera.cy_px) / camera.fy_px, 1.0])
        return np.asarray(origin + pose.rotation_map_optical @ (r * (z + dz)), dtype=np.float64)

    point = at(0.0, 0.0, 0.0)
    terms = [
        at(sigma_px, 0.0, 0.0) - point,
        at(0.0, sigma_px, 0.0) - point,
        at(0.0, 0.0, cfg.depth_sigma_rel * z) - point,
    ]
    return point, terms


def _on_grids(
    surfaces: Surfaces,
    camera: PinholeCamera,
    pose: CameraPose,
    *,
    uv: tuple[float, float],
    sigma_px: float,
    cfg: GeolocationConfig,
) -> tuple[FloatArray, list[FloatArray], str] | None:
    """The contact ray's first hit on the elevation layer over the terrain model, with its sensitivities to the
    pixel (u, v) and to the surface height, and which grid held the hit; ``None`` if it hits nothing."""
    grids = [g for g in (surfaces.elevation, surfaces.terrain) if g is not None]
    if not grids:
        return None
    u, v = uv
    origin = pose.position_map_m
    step = cfg.step_m or 0.5 * min(g.resolution_m for g in grids)

    def march(du: float, dv: float, dh: float) -> tuple[FloatArray, int] | None:
        hit = first_hit(
            origin,
            _ray(camera, pose, u + du, v + dv),
            grids,
            step_m=step,
            max_range_m=cfg.max_range_m,
            min_range_m=cfg.min_range_m,
            offset_m=dh,
        )
        return None if hit is None else (np.asarray(hit.point_m, dtype=np.float64), hit.grid)

    hit0 = march(0.0, 0.0, 0.0)
    if hit0 is None:
        return None
    point, grid = hit0
    hit_grid = grids[grid]
    source = "elevation" if hit_grid is surfaces.elevation else "terrain"
    sigma_h = cfg.elevation_sigma_m if source == "elevation" else cfg.terrain_sigma_m
    if hit_grid.interpolation == "nearest":
        # A column's height holds over its whole cell: up to half a cell too high where the surface slopes or
        # an object stands in it.
        sigma_h = math.hypot(sigma_h, 0.5 * hit_grid.resolution_m)

    def point_of(hit: tuple[FloatArray, int] | None) -> FloatArray | None:
        return None if hit is None else hit[0]

    sens = [
        _sensitivity(lambda s: point_of(march(s, 0.0, 0.0)), point, sigma_px),
        _sensitivity(lambda s: point_of(march(0.0, s, 0.0)), point, sigma_px),
        _sensitivity(lambda s: point_of(march(0.0, 0.0, s)), point, sigma_h),
    ]
    # A perturbation that misses every surface (a grazing ray): count it as the whole range.
    far = float(np.linalg.norm(point - origin))
    terms = [j if j is not None else np.array([far, far, 0.0]) for j in sens]
    if hit_grid.interpolation == "nearest":
        # and where the ray meets a column's wall is known to a cell (uniform: res / sqrt(12) each way)
        q = hit_grid.resolution_m / math.sqrt(12.0)
        terms += [np.array([q, 0.0, 0.0]), np.array([0.0, q, 0.0])]
    return point, terms, source


def place(
    box: Box,
    camera: PinholeCamera | None,
    pose: CameraPose | None,
    surfaces: Surfaces,
    cfg: GeolocationConfig,
    *,
    footprint_radius_m: float = 0.0,
) -> Placement:
    """Place one box in ``map`` (see the module docstring), or say why it cannot be placed."""
    if camera is None:
        return Placement.unplaced("no_camera_info")
    if pose is None or not pose.is_valid:
        return Placement.unplaced("no_pose")
    if not surfaces.any:
        return Placement.unplaced("no_surface_model")
    if surfaces.depth_m is not None and surfaces.depth_m.shape != camera.shape:
        msg = f"depth image is {surfaces.depth_m.shape[::-1]} but camera_info says {camera.width_px}x{camera.height_px}"
        raise DetectionInputError(msg)
    uv = contact_point(box, camera, pose)
    sigma_px = _pixel_sigma(box, camera, pose, cfg)
    found = (
        _on_depth(surfaces.depth_m, box, camera, pose, uv=uv, sigma_px=sigma_px, cfg=cfg)
        if surfaces.depth_m is not None
        else None
    )
    if found is not None:
        point, terms = found
        source = "depth"
    else:
        on_grid = _on_grids(surfaces, camera, pose, uv=uv, sigma_px=sigma_px, cfg=cfg)
        if on_grid is None:
            return Placement.unplaced("no_surface", uv)
        point, terms, source = on_grid
    names = {
        "pixel_m": float(math.hypot(np.linalg.norm(terms[0]), np.linalg.norm(terms[1]))),
        "surface_m": float(np.linalg.norm(terms[2])),
    }
    cov = np.zeros((3, 3))
    for j in terms:
        cov += np.outer(j, j)
    if footprint_radius_m > 0:
        ray = _ray(camera, pose, *uv)
        horizontal = math.hypot(ray[0], ray[1])  # sin(off-nadir) of the unit ray
        if horizontal > 1e-9:
            point = point + np.array([ray[0], ray[1], 0.0]) / horizontal * (footprint_radius_m * horizontal)
        cov += np.diag([footprint_radius_m**2, footprint_radius_m**2, 0.0])
        names["footprint_m"] = footprint_radius_m
    return Placement(
        position_m=(float(point[0]), float(point[1]), float(point[2])),
        covariance_m2=tuple(float(c) for c in cov.ravel()),
        source=source,
        range_m=float(np.linalg.norm(point - pose.position_map_m)),
        contact_px=uv,
        sigma_terms_m=names,
    )
