"""Rigid transforms between the project's frames (pure numpy).

A :class:`RigidTransform` ``T_a_b`` maps coordinates expressed in frame ``b`` into
frame ``a``: ``p_a = T_a_b.apply(p_b) = R_a_b @ p_b + t_a_b``.  ``rotation`` holds
the axes of ``b`` as columns expressed in ``a``; ``translation_m`` is the origin of
``b`` in ``a``.  Compose with ``T_a_c = T_a_b @ T_b_c``.

Quaternions are ``[w, x, y, z]`` (:mod:`uav_common.rotations`); ROS ``[x, y, z, w]``
order only appears in :mod:`uav_sim_bridge.ros`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from uav_common.robot import OPTICAL_FROM_FLU as ROBOT_OPTICAL_FROM_FLU
from uav_common.rotations import matrix_from_quat, quat_from_euler, quat_from_matrix

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "OPTICAL_FROM_FLU",
    "FloatArray",
    "RigidTransform",
    "rotation_from_rpy",
]

# Axes of an optical frame (x right, y down, z forward) expressed in the FLU camera
# frame it is attached to (x forward, y left, z up): R_flu_optical (the robot description's).
OPTICAL_FROM_FLU: FloatArray = ROBOT_OPTICAL_FROM_FLU


def rotation_from_rpy(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """3x3 rotation of intrinsic Z-Y-X Euler angles (REP 103: positive pitch tilts FLU x down)."""
    return matrix_from_quat(quat_from_euler(roll_rad, pitch_rad, yaw_rad))


_EYE3 = np.eye(3)
_ORTHO_TOL = 1e-6 + 1e-5 * _EYE3  # np.allclose's atol=1e-6 and rtol=1e-5 against the identity


@dataclass(frozen=True)
class RigidTransform:
    """A proper rigid transform ``T_a_b`` (see module docstring)."""

    rotation: FloatArray
    translation_m: FloatArray

    def __post_init__(self) -> None:
        rot = np.asarray(self.rotation, dtype=np.float64)
        trans = np.asarray(self.translation_m, dtype=np.float64)
        if rot.shape != (3, 3) or trans.shape != (3,):
            msg = f"RigidTransform needs a (3, 3) rotation and a (3,) translation, got {rot.shape} and {trans.shape}"
            raise ValueError(msg)
        if not (np.isfinite(rot).all() and np.isfinite(trans).all()):
            msg = "RigidTransform must be finite"
            raise ValueError(msg)
        # np.allclose(rot @ rot.T, I, atol=1e-6) and det >= 0, without their overhead (a camera frame builds a few
        # transforms; the numpy calls cost ~30 us each, more than the arithmetic)
        (a, b, c), (d, e, f), (g, h, i) = rot.tolist()
        det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
        if not (np.abs(rot @ rot.T - _EYE3) <= _ORTHO_TOL).all() or det < 0:
            msg = f"RigidTransform rotation is not a proper rotation matrix: {rot.tolist()}"
            raise ValueError(msg)
        object.__setattr__(self, "rotation", rot)
        object.__setattr__(self, "translation_m", trans)

    @staticmethod
    def identity() -> RigidTransform:
        return RigidTransform(np.eye(3), np.zeros(3))

    @staticmethod
    def from_quat(q_wxyz: npt.ArrayLike, translation_m: npt.ArrayLike) -> RigidTransform:
        """From a ``[w, x, y, z]`` quaternion (normalised here) and a translation."""
        return RigidTransform(matrix_from_quat(q_wxyz), np.asarray(translation_m, dtype=np.float64))

    @staticmethod
    def from_rpy(
        translation_m: npt.ArrayLike, roll_rad: float = 0.0, pitch_rad: float = 0.0, yaw_rad: float = 0.0
    ) -> RigidTransform:
        return RigidTransform(rotation_from_rpy(roll_rad, pitch_rad, yaw_rad), np.asarray(translation_m, np.float64))

    @property
    def quat_wxyz(self) -> FloatArray:
        """Rotation as a unit ``[w, x, y, z]`` quaternion with ``w >= 0``."""
        return quat_from_matrix(self.rotation)

    @property
    def yaw_rad(self) -> float:
        """Heading of the ``b`` frame's x axis in ``a`` (atan2 of its xy components)."""
        return math.atan2(float(self.rotation[1, 0]), float(self.rotation[0, 0]))

    def inverse(self) -> RigidTransform:
        rot_t = self.rotation.T
        return RigidTransform(rot_t, -rot_t @ self.translation_m)

    def __matmul__(self, other: RigidTransform) -> RigidTransform:
        return RigidTransform(
            self.rotation @ other.rotation,
            self.rotation @ other.translation_m + self.translation_m,
        )

    def apply(self, points: npt.ArrayLike) -> FloatArray:
        """Map point(s) ``(3,)`` or ``(N, 3)`` from frame ``b`` into frame ``a``."""
        pts = np.asarray(points, dtype=np.float64)
        return pts @ self.rotation.T + self.translation_m

    def matrix(self) -> FloatArray:
        """4x4 homogeneous matrix."""
        out = np.eye(4)
        out[:3, :3] = self.rotation
        out[:3, 3] = self.translation_m
        return out
