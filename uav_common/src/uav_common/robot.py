"""The robot description: where each sensor sits on the airframe (``config/robot.yaml``).

One file says where every camera is mounted on ``base_link``; it is the file a real airframe edits
after measuring its mounts. Everything that needs a camera's extrinsics reads it from here: the
``robot_description`` node publishes the static transforms ``base_link -> camera_<name> ->
camera_<name>_optical`` from it (on a real vehicle and in a scenario run alike), and the simulator
renders each camera from the same mount.

Conventions (REP 103): ``camera_<name>`` is the FLU mount frame (x along the optical axis, y left,
z up), placed by ``xyz_m`` and intrinsic Z-Y-X ``rpy_deg`` (positive pitch tilts x *down*: a nadir
camera is ``[0, 90, 0]``); ``camera_<name>_optical`` is x right, y down, z forward.

Pure: no ROS, no I/O beyond :func:`load_robot_description` reading the YAML file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from uav_common.config import load_config
from uav_common.rotations import quat_from_euler, quat_from_matrix
from uav_common.validate import require_finite_vector

__all__ = [
    "OPTICAL_FROM_FLU",
    "CameraMount",
    "RobotDescription",
    "StaticTransform",
    "load_robot_description",
]

#: Axes of an optical frame (x right, y down, z forward) expressed in the FLU camera frame: ``R_flu_optical``.
OPTICAL_FROM_FLU = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class CameraMount:
    """Pose of the FLU camera frame ``camera_<name>`` on ``base_link``."""

    xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        require_finite_vector("xyz_m", self.xyz_m, 3)
        require_finite_vector("rpy_deg", self.rpy_deg, 3)
        if any(abs(v) > 10.0 for v in self.xyz_m):
            msg = f"xyz_m must be within 10 m of base_link, got {list(self.xyz_m)}"
            raise ValueError(msg)

    @property
    def q_wxyz(self) -> tuple[float, float, float, float]:
        """``q_base_link_camera`` as ``[w, x, y, z]``."""
        roll, pitch, yaw = (math.radians(a) for a in self.rpy_deg)
        q = quat_from_euler(roll, pitch, yaw)
        return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


@dataclass(frozen=True)
class StaticTransform:
    """``parent -> child``: ``p_parent = R(q) p_child + t``."""

    parent: str
    child: str
    translation_m: tuple[float, float, float]
    q_wxyz: tuple[float, float, float, float]


@dataclass(frozen=True)
class RobotDescription:
    """The airframe's frames and sensor mounts (``config/robot.yaml``)."""

    base_frame: str = "base_link"
    cameras: dict[str, CameraMount] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.base_frame or "/" in self.base_frame.strip("/"):
            msg = f"base_frame must be a plain frame name, got {self.base_frame!r}"
            raise ValueError(msg)
        for name in self.cameras:
            if not name or not all(c.isalnum() or c == "_" for c in name):
                msg = f"camera names are frame-name parts (letters, digits, _), got {name!r}"
                raise ValueError(msg)

    @staticmethod
    def camera_frame(name: str) -> str:
        return f"camera_{name}"

    @staticmethod
    def optical_frame(name: str) -> str:
        return f"camera_{name}_optical"

    def mount(self, name: str) -> CameraMount:
        """The mount of camera ``name``.

        Raises:
            KeyError: the description has no such camera (the message names the known ones).
        """
        if name not in self.cameras:
            msg = f"the robot description has no camera {name!r}; cameras: {', '.join(sorted(self.cameras)) or 'none'}"
            raise KeyError(msg)
        return self.cameras[name]

    def static_transforms(self) -> list[StaticTransform]:
        """``base_link -> camera_<name>`` (the mount) and ``camera_<name> -> camera_<name>_optical``, per camera."""
        q_optical = quat_from_matrix(OPTICAL_FROM_FLU)
        optical = (float(q_optical[0]), float(q_optical[1]), float(q_optical[2]), float(q_optical[3]))
        out: list[StaticTransform] = []
        for name in sorted(self.cameras):
            mount = self.cameras[name]
            frame = self.camera_frame(name)
            out.append(StaticTransform(self.base_frame, frame, mount.xyz_m, mount.q_wxyz))
            out.append(StaticTransform(frame, self.optical_frame(name), (0.0, 0.0, 0.0), optical))
        return out


def load_robot_description(path: Path) -> RobotDescription:
    """Parse ``config/robot.yaml`` (strict: unknown keys and bad values name the file and key).

    Raises:
        uav_common.errors.ConfigError: missing file, bad YAML, unknown key, bad value.
    """
    return load_config(RobotDescription, path)
