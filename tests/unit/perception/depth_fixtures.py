"""Shared helpers of the depth unit tests (a module name no other test folder uses)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from synthetic_scene import nadir_rotation

from uav_perception.core.depth.types import CameraPose, ColorFrame

HEADING_RAD = 0.3
ALTITUDE_M = 50.0


@dataclass(frozen=True)
class Rendered:
    """A synthetic frame with its exact ground truth."""

    frame: ColorFrame
    depth_m: np.ndarray
    instances: np.ndarray


def flight_pose(along_m: float, *, altitude_m: float = ALTITUDE_M) -> CameraPose:
    """Nadir camera on a straight flight (heading 0.3 rad) ``along_m`` from the origin."""
    fwd = np.array([math.cos(HEADING_RAD), math.sin(HEADING_RAD), 0.0])
    return CameraPose(nadir_rotation(HEADING_RAD), np.array([0.0, 0.0, altitude_m]) + along_m * fwd)
