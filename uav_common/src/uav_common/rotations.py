"""Rotation math in one convention: Hamilton quaternions stored as ``[w, x, y, z]``.

A quaternion ``q_a_b`` rotates vectors from frame ``b`` into frame ``a``
(``v_a = R(q_a_b) @ v_b``).  Euler angles are intrinsic Z-Y-X (yaw, pitch, roll),
as used by MAVLink ``ATTITUDE`` and JSBSim.  Angles are radians.

This module knows nothing about ENU or NED; :mod:`uav_common.frames` does.
Everything is pure numpy and accepts a single quaternion of shape ``(4,)``.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "euler_from_quat",
    "matrix_from_quat",
    "quat_conjugate",
    "quat_from_euler",
    "quat_from_matrix",
    "quat_multiply",
    "quat_normalize",
    "rotate",
]


def quat_normalize(q: npt.ArrayLike) -> FloatArray:
    """Unit quaternion with non-negative ``w`` (the canonical one of ``q`` and ``-q``)."""
    arr = np.asarray(q, dtype=np.float64)
    norm = float(np.linalg.norm(arr))
    if not math.isfinite(norm) or norm < 1e-12:
        msg = f"quaternion {arr.tolist()} cannot be normalised"
        raise ValueError(msg)
    arr = arr / norm
    return -arr if arr[0] < 0 else arr


def quat_multiply(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``)."""
    aw, ax, ay, az = np.asarray(a, dtype=np.float64)
    bw, bx, by, bz = np.asarray(b, dtype=np.float64)
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def quat_conjugate(q: npt.ArrayLike) -> FloatArray:
    """Inverse rotation of a unit quaternion."""
    w, x, y, z = np.asarray(q, dtype=np.float64)
    return np.array([w, -x, -y, -z])


def matrix_from_quat(q: npt.ArrayLike) -> FloatArray:
    """3x3 rotation matrix of unit quaternion ``q``."""
    w, x, y, z = quat_normalize(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quat_from_matrix(m: npt.ArrayLike) -> FloatArray:
    """Unit quaternion of a 3x3 rotation matrix (Shepperd's method)."""
    r = np.asarray(m, dtype=np.float64)
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    return quat_normalize(q)


def quat_from_euler(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """Quaternion of intrinsic Z-Y-X Euler angles."""
    cr, sr = math.cos(roll_rad / 2), math.sin(roll_rad / 2)
    cp, sp = math.cos(pitch_rad / 2), math.sin(pitch_rad / 2)
    cy, sy = math.cos(yaw_rad / 2), math.sin(yaw_rad / 2)
    return quat_normalize(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def euler_from_quat(q: npt.ArrayLike) -> tuple[float, float, float]:
    """Intrinsic Z-Y-X Euler angles ``(roll, pitch, yaw)`` in radians of ``q``."""
    w, x, y, z = quat_normalize(q)
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    sinp = max(-1.0, min(1.0, 2 * (w * y - z * x)))
    pitch = math.asin(sinp)
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def rotate(q: npt.ArrayLike, v: npt.ArrayLike) -> FloatArray:
    """Rotate vector(s) ``v`` of shape ``(3,)`` or ``(N, 3)`` by ``q``."""
    return np.asarray(v, dtype=np.float64) @ matrix_from_quat(q).T
