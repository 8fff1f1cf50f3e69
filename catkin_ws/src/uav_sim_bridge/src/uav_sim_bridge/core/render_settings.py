"""Look and speed settings of the renderer (``render`` section of ``config/sim_bridge.yaml``)."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["RenderSettings"]


@dataclass(frozen=True)
class RenderSettings:
    """Look and speed knobs of the renderer (``render`` section of ``config/sim_bridge.yaml``)."""

    tile_size_m: float = 50.0
    lod_distance_m: float = 160.0
    texture_gain: float = 0.9
    haze_distance_m: float = 1800.0
    sun_azimuth_deg: float = 135.0
    sun_elevation_deg: float = 55.0
    pad_half_size_m: float = 7.0
    frustum_culling: bool = True
    #: Shadows (when the environment has them): texels per side of the world's shadow map (the static world
    #: rendered once per sun position, people and vehicles drawn in where they stand); 4096 gives ~0.35 m
    #: texels over the default 1 km world (64 MB of depth on the "GPU", as much again in RAM).
    shadow_map_px: int = 4096
    #: Camera pixels per shadow lookup along each axis (3: one lookup per 3x3 block, interpolated back): on
    #: llvmpipe the lookups, not the map, are what shadows cost.
    shadow_step: int = 3

    def __post_init__(self) -> None:
        if not 256 <= self.shadow_map_px <= 8192:
            msg = "shadow_map_px must be in [256, 8192]"
            raise ValueError(msg)
        if not 1 <= self.shadow_step <= 8:
            msg = "shadow_step must be in 1..8"
            raise ValueError(msg)
        if self.tile_size_m <= 0 or self.lod_distance_m < 0 or self.haze_distance_m <= 0:
            msg = "tile_size_m and haze_distance_m must be > 0 and lod_distance_m >= 0"
            raise ValueError(msg)
        if not 0 < self.sun_elevation_deg <= 90:
            msg = "sun_elevation_deg must be in (0, 90]"
            raise ValueError(msg)

    @property
    def sun_direction(self) -> tuple[float, float, float]:
        """Unit vector towards the sun in ``map`` (azimuth clockwise from north)."""
        az, el = math.radians(self.sun_azimuth_deg), math.radians(self.sun_elevation_deg)
        return (math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el))
