"""Fixtures of the depth unit tests: a camera and synthetic frames rendered once per session."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from depth_fixtures import Rendered, flight_pose
from synthetic_scene import SyntheticScene, default_scene

from uav_perception.core.depth.types import ColorFrame, PinholeCamera


@pytest.fixture(scope="session")
def scene() -> SyntheticScene:
    return default_scene(seed=0)


@pytest.fixture(scope="session")
def camera() -> PinholeCamera:
    """320x240, 90 deg horizontal field of view (the bridge's 640x480 default, halved)."""
    return PinholeCamera(320, 240, 160.0, 160.0, 159.5, 119.5)


@pytest.fixture(scope="session")
def flight(scene: SyntheticScene, camera: PinholeCamera) -> list[Rendered]:
    """Two nadir frames 8 m apart along the flight direction, 1 s apart, 50 m above the origin."""
    out = []
    for k, along in enumerate((-4.0, 4.0)):
        pose = flight_pose(along)
        rgb, depth, inst = scene.render(camera, pose)
        out.append(Rendered(ColorFrame((100 + k) * 10**9, rgb, pose), depth, inst))
    return out
