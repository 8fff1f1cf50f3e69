"""Seeded degraded-sensor models: depth noise growing with range, dropouts, pose noise.

All randomness comes from a ``numpy.random.Generator`` passed in, so a run with the
same seed and the same sequence of calls degrades the sensors identically.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.transforms import RigidTransform, rotation_from_rpy

__all__ = ["DepthNoiseConfig", "NoiseConfig", "PoseNoise", "PoseNoiseConfig", "degrade_depth"]


@dataclass(frozen=True)
class DepthNoiseConfig:
    """Depth noise ``sigma(z) = sigma_m + sigma_per_m2 * z**2`` (stereo-like), dropouts and a range limit.

    A pixel drops out (NaN) with probability ``dropout + dropout_per_100m * z / 100``,
    and every return beyond ``max_range_m`` is dropped.
    """

    sigma_m: float = 0.01
    sigma_per_m2: float = 0.0005
    dropout: float = 0.01
    dropout_per_100m: float = 0.05
    max_range_m: float = 300.0

    def __post_init__(self) -> None:
        if min(self.sigma_m, self.sigma_per_m2, self.dropout, self.dropout_per_100m) < 0:
            msg = "depth noise parameters must be >= 0"
            raise ValueError(msg)
        if self.dropout > 1 or self.max_range_m <= 0:
            msg = "dropout must be <= 1 and max_range_m > 0"
            raise ValueError(msg)


@dataclass(frozen=True)
class PoseNoiseConfig:
    """Pose noise of the published ``map -> base_link`` tf: white jitter plus a random-walk drift."""

    position_sigma_m: float = 0.05
    position_drift_m_per_sqrt_s: float = 0.02
    yaw_sigma_deg: float = 0.3
    attitude_sigma_deg: float = 0.1

    def __post_init__(self) -> None:
        if (
            min(self.position_sigma_m, self.position_drift_m_per_sqrt_s, self.yaw_sigma_deg, self.attitude_sigma_deg)
            < 0
        ):
            msg = "pose noise parameters must be >= 0"
            raise ValueError(msg)


@dataclass(frozen=True)
class NoiseConfig:
    """``noise`` section: ``enabled: false`` publishes exact ground truth."""

    enabled: bool = False
    seed: int = 0
    depth: DepthNoiseConfig = field(default_factory=DepthNoiseConfig)
    pose: PoseNoiseConfig = field(default_factory=PoseNoiseConfig)


def degrade_depth(
    depth_m: npt.NDArray[np.float32], cfg: DepthNoiseConfig, rng: np.random.Generator
) -> npt.NDArray[np.float32]:
    """A noisy copy of a z-depth image (NaN stays NaN; dropped pixels become NaN)."""
    d = np.asarray(depth_m, dtype=np.float32)
    z = np.where(np.isfinite(d), d, np.float32(0.0))
    sigma = cfg.sigma_m + cfg.sigma_per_m2 * z * z
    noisy = z + sigma * rng.standard_normal(d.shape).astype(np.float32)
    p_drop = cfg.dropout + cfg.dropout_per_100m * z / 100.0
    drop = (rng.random(d.shape) < p_drop) | ~np.isfinite(d) | (z > cfg.max_range_m) | (noisy <= 0)
    return np.where(drop, np.float32(np.nan), noisy).astype(np.float32)


class PoseNoise:
    """Stateful pose degradation: ``apply(t_map_base, sim_time_s, rng)`` -> noisy pose."""

    def __init__(self, cfg: PoseNoiseConfig) -> None:
        self.cfg = cfg
        self._drift_m = np.zeros(3)
        self._last_time_s: float | None = None

    def apply(self, t_map_base: RigidTransform, sim_time_s: float, rng: np.random.Generator) -> RigidTransform:
        c = self.cfg
        if self._last_time_s is not None and sim_time_s > self._last_time_s:
            dt = sim_time_s - self._last_time_s
            self._drift_m = self._drift_m + c.position_drift_m_per_sqrt_s * math.sqrt(dt) * rng.standard_normal(3)
        self._last_time_s = sim_time_s
        jitter = c.position_sigma_m * rng.standard_normal(3)
        att = np.radians([c.attitude_sigma_deg, c.attitude_sigma_deg, c.yaw_sigma_deg]) * rng.standard_normal(3)
        rot = rotation_from_rpy(float(att[0]), float(att[1]), float(att[2])) @ t_map_base.rotation
        return RigidTransform(rot, t_map_base.translation_m + self._drift_m + jitter)
