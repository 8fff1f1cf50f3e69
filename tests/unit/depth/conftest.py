"""Fixtures of the depth unit tests: a camera and synthetic frames rendered once per session."""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from synthetic_scene import SyntheticScene, default_scene, nadir_rotation

from uav_autonomy.core.depth_types import CameraPose, ColorFrame, PinholeCamera

HEADING_RAD = 0.3
ALTITUDE_M = 50.0


@dataclass(frozen=True)
class Rendered:
    """A synthetic frame with its exact ground truth."""

    frame: ColorFrame
    depth_m: np.ndarray
    instances: np.ndarray


@pytest.fixture(scope="session")
def scene() -> SyntheticScene:
    return default_scene(seed=0)


@pytest.fixture(scope="session")
def camera() -> PinholeCamera:
    """320x240, 90 deg horizontal field of view (the bridge's 640x480 default, halved)."""
    return PinholeCamera(320, 240, 160.0, 160.0, 159.5, 119.5)


def flight_pose(along_m: float, *, altitude_m: float = ALTITUDE_M) -> CameraPose:
    fwd = np.array([math.cos(HEADING_RAD), math.sin(HEADING_RAD), 0.0])
    return CameraPose(nadir_rotation(HEADING_RAD), np.array([0.0, 0.0, altitude_m]) + along_m * fwd)


@pytest.fixture(scope="session")
def flight(scene: SyntheticScene, camera: PinholeCamera) -> list[Rendered]:
    """Two nadir frames 8 m apart along the flight direction, 1 s apart, 50 m above the origin."""
    out = []
    for k, along in enumerate((-4.0, 4.0)):
        pose = flight_pose(along)
        rgb, depth, inst = scene.render(camera, pose)
        out.append(Rendered(ColorFrame((100 + k) * 10**9, rgb, pose), depth, inst))
    return out
