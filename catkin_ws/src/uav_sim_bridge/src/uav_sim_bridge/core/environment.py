"""The environment of a run: sun, sky, weather, camera effects and depth noise (``environment:`` keys).

An environment is a preset (``config/environments/<name>.yaml``) with free values merged over
it (:func:`merge_environment`): a scenario writes ``environment: {preset: dusk_noise, overcast: 0.3}``,
the bridge's configuration file an ``environment:`` section of the same form. Everything is
validated here; an unknown key or a bad value names the file and the key.

The ``clean`` preset is the default: the renderer's original light (sun at azimuth 135,
elevation 55 degrees, light haze), no shadows, no camera effects and exact depth, so
ground-truth experiments and metrics stay what they were.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from uav_common.config import deep_merge
from uav_sim_bridge.core.camera_effects import CameraEffectsConfig
from uav_sim_bridge.core.sensor_noise import DepthNoiseConfig

__all__ = ["DEFAULT_PRESET", "EnvironmentConfig", "merge_environment"]

DEFAULT_PRESET = "clean"


@dataclass(frozen=True)
class EnvironmentConfig:
    """Light, weather and sensor degradation of a run.

    Attributes:
        preset: the preset these values started from (for reports; the values below are what counts).
        time_of_day_h: local solar time in hours, [0, 24) (12 = the sun at its highest); ``None``:
            the sun is placed by ``sun_azimuth_deg`` and ``sun_elevation_deg`` instead.
        day_of_year: 1..366 (172 = 21 June).
        latitude_deg: where on Earth; ``None`` = the world's (``latitude_deg`` of the world file).
        sun_azimuth_deg: clockwise from north, with no time of day.
        sun_elevation_deg: above the horizon, with no time of day.
        shadows: cast shadows of the sun (terrain, buildings, trees, people, vehicles).
        overcast: 0 (clear) .. 1 (fully overcast: no direct sun, grey sky, soft light).
        visibility_m: meteorological visibility of haze or fog (``None``: the light haze of the clean look).
        seed: seeds the camera effects and depth noise (each camera its own stream).
        cameras: camera effects per camera name; ``default`` applies to every camera not named
            (a named camera's keys are merged over ``default``'s).
        depth_noise: depth-image noise of every camera (``None``: exact depth).
    """

    preset: str = DEFAULT_PRESET
    time_of_day_h: float | None = None
    day_of_year: int = 172
    latitude_deg: float | None = None
    sun_azimuth_deg: float = 135.0
    sun_elevation_deg: float = 55.0
    shadows: bool = False
    overcast: float = 0.0
    visibility_m: float | None = None
    seed: int = 0
    cameras: dict[str, CameraEffectsConfig] = field(default_factory=dict)
    depth_noise: DepthNoiseConfig | None = None

    def __post_init__(self) -> None:
        if self.time_of_day_h is not None and not (
            math.isfinite(self.time_of_day_h) and 0.0 <= self.time_of_day_h < 24.0
        ):
            msg = f"time_of_day_h must be in [0, 24) (local solar time, hours) or null, got {self.time_of_day_h}"
            raise ValueError(msg)
        if not 1 <= self.day_of_year <= 366:
            msg = f"day_of_year must be in 1..366, got {self.day_of_year}"
            raise ValueError(msg)
        if self.latitude_deg is not None and not -90.0 <= self.latitude_deg <= 90.0:
            msg = f"latitude_deg must be in [-90, 90], got {self.latitude_deg}"
            raise ValueError(msg)
        if not 0.0 <= self.sun_azimuth_deg <= 360.0:
            msg = f"sun_azimuth_deg must be in [0, 360], got {self.sun_azimuth_deg}"
            raise ValueError(msg)
        if not -6.0 <= self.sun_elevation_deg <= 90.0:
            msg = f"sun_elevation_deg must be in [-6, 90] (civil twilight to zenith), got {self.sun_elevation_deg}"
            raise ValueError(msg)
        if not 0.0 <= self.overcast <= 1.0:
            msg = f"overcast must be in [0, 1], got {self.overcast}"
            raise ValueError(msg)
        if self.visibility_m is not None and not 20.0 <= self.visibility_m <= 1e6:
            msg = f"visibility_m must be in [20, 1e6] m or null, got {self.visibility_m}"
            raise ValueError(msg)
        if self.seed < 0:
            msg = f"seed must be >= 0, got {self.seed}"
            raise ValueError(msg)

    def effects_for(self, camera: str) -> CameraEffectsConfig:
        """The effects of camera ``camera`` (its own entry, else ``default``, else none)."""
        return self.cameras.get(camera) or self.cameras.get("default") or CameraEffectsConfig()

    @property
    def has_camera_effects(self) -> bool:
        return any(c.active for c in self.cameras.values())


def merge_environment(raw: Mapping[str, Any], load_preset: Callable[[str], Mapping[str, Any]]) -> dict[str, Any]:
    """The environment mapping of ``raw`` with its preset resolved: ``load_preset(raw["preset"])`` (default
    ``clean``) with the other keys of ``raw`` merged over it, and each named camera's effects merged over
    ``cameras.default``. The result still needs parsing (``from_mapping(EnvironmentConfig, ...)``).

    Raises:
        ConfigError: from ``load_preset`` (unknown preset: it names the file it looked for).
    """
    preset = str(raw.get("preset", DEFAULT_PRESET))
    base = dict(load_preset(preset))
    base.pop("preset", None)
    over = {k: v for k, v in raw.items() if k != "preset"}
    merged = deep_merge(base, over)
    merged["preset"] = preset
    cams = merged.get("cameras")
    if isinstance(cams, Mapping) and isinstance(cams.get("default"), Mapping):
        default = cams["default"]
        merged["cameras"] = {
            name: (deep_merge(default, value) if name != "default" and isinstance(value, Mapping) else value)
            for name, value in cams.items()
        }
    return merged
