"""The one module where ROS frames meet MAVLink frames.

Conventions (REP 103 / REP 105 on the ROS side, MAVLink common on the other):

==========================  ==============================  ==============================
quantity                    ROS side                        MAVLink side
==========================  ==============================  ==============================
world frame                 ``map``: x East, y North, z Up  ``LOCAL_NED``: x North, y East, z Down
body frame                  ``base_link``: FLU              body FRD
quaternion storage          ``[x, y, z, w]`` (geometry_msgs) ``[w, x, y, z]`` (ATTITUDE_QUATERNION)
yaw zero / sense            East, counter-clockwise         North, clockwise
==========================  ==============================  ==============================

Both local frames share the same origin: the vehicle's home position.
No other module in the project converts between ENU and NED; they call these.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from uav_common.rotations import FloatArray, quat_multiply, quat_normalize

__all__ = [
    "covariance_urt21",
    "enu_to_ned",
    "flu_to_frd",
    "frd_to_flu",
    "ned_to_enu",
    "pose_covariance_ned_to_enu",
    "quat_enu_flu_to_ned_frd",
    "quat_ned_frd_to_enu_flu",
    "ros_xyzw_to_wxyz",
    "twist_covariance_frd_to_flu",
    "wrap_pi",
    "wxyz_to_ros_xyzw",
    "yaw_enu_to_ned",
    "yaw_ned_to_enu",
]

_SQRT_HALF = math.sqrt(0.5)
# q_ned_enu: rotates ENU-expressed vectors into NED (180 deg about (1, 1, 0)/sqrt 2).
_Q_NED_ENU = np.array([0.0, _SQRT_HALF, _SQRT_HALF, 0.0])
# q_flu_frd: rotates FRD-expressed vectors into FLU (180 deg about x).
_Q_FLU_FRD = np.array([0.0, 1.0, 0.0, 0.0])


def enu_to_ned(v_enu: npt.ArrayLike) -> FloatArray:
    """Vector(s) ``(..., 3)`` from ENU to NED: ``(x_n, y_e, z_d) = (y, x, -z)``."""
    v = np.asarray(v_enu, dtype=np.float64)
    return np.stack([v[..., 1], v[..., 0], -v[..., 2]], axis=-1)


def ned_to_enu(v_ned: npt.ArrayLike) -> FloatArray:
    """Vector(s) ``(..., 3)`` from NED to ENU (the same swap, its own inverse)."""
    return enu_to_ned(v_ned)


def flu_to_frd(v_flu: npt.ArrayLike) -> FloatArray:
    """Body vector(s) ``(..., 3)`` from FLU to FRD: ``(x, -y, -z)``."""
    v = np.asarray(v_flu, dtype=np.float64)
    return np.stack([v[..., 0], -v[..., 1], -v[..., 2]], axis=-1)


def frd_to_flu(v_frd: npt.ArrayLike) -> FloatArray:
    """Body vector(s) ``(..., 3)`` from FRD to FLU."""
    return flu_to_frd(v_frd)


def wrap_pi(angle_rad: float) -> float:
    """Wrap an angle to ``[-pi, pi)``."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def yaw_enu_to_ned(yaw_enu_rad: float) -> float:
    """ROS yaw (from East, CCW) to MAVLink yaw (from North, CW)."""
    return wrap_pi(math.pi / 2.0 - yaw_enu_rad)


def yaw_ned_to_enu(yaw_ned_rad: float) -> float:
    """MAVLink yaw (from North, CW) to ROS yaw (from East, CCW)."""
    return wrap_pi(math.pi / 2.0 - yaw_ned_rad)


def ros_xyzw_to_wxyz(q_xyzw: npt.ArrayLike) -> FloatArray:
    """Reorder a ROS ``[x, y, z, w]`` quaternion to ``[w, x, y, z]``."""
    x, y, z, w = np.asarray(q_xyzw, dtype=np.float64)
    return np.array([w, x, y, z])


def wxyz_to_ros_xyzw(q_wxyz: npt.ArrayLike) -> FloatArray:
    """Reorder a ``[w, x, y, z]`` quaternion to ROS ``[x, y, z, w]``."""
    w, x, y, z = np.asarray(q_wxyz, dtype=np.float64)
    return np.array([x, y, z, w])


def quat_enu_flu_to_ned_frd(q_enu_flu: npt.ArrayLike) -> FloatArray:
    """Attitude of an FLU body in ENU -> attitude of the FRD body in NED (both ``[w, x, y, z]``)."""
    return quat_normalize(quat_multiply(quat_multiply(_Q_NED_ENU, q_enu_flu), _Q_FLU_FRD))


def quat_ned_frd_to_enu_flu(q_ned_frd: npt.ArrayLike) -> FloatArray:
    """Attitude of an FRD body in NED -> attitude of the FLU body in ENU (both ``[w, x, y, z]``)."""
    # Both fixed rotations are 180-degree turns, hence their own inverses.
    return quat_normalize(quat_multiply(quat_multiply(_Q_NED_ENU, q_ned_frd), _Q_FLU_FRD))


# Axis maps as matrices: v_enu = M_ENU_NED v_ned (a proper rotation, its own inverse); v_flu = M_FLU_FRD v_frd.
_M_ENU_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_M_FLU_FRD = np.diag([1.0, -1.0, -1.0])


def covariance_urt21(urt: npt.ArrayLike) -> FloatArray | None:
    """MAVLink's 6x6 covariance as 21 upper-right-triangle values, row by row -> the symmetric 6x6 matrix.

    Returns None when the autopilot says "unknown" (NaN in the first element, the MAVLink convention).

    Raises:
        ValueError: not 21 values, or non-finite values after a finite first one.
    """
    values = np.asarray(urt, dtype=np.float64).reshape(-1)
    if values.size != 21:
        msg = f"a MAVLink covariance has 21 values (upper right triangle of 6x6), got {values.size}"
        raise ValueError(msg)
    if math.isnan(values[0]):
        return None
    if not np.isfinite(values).all():
        msg = f"covariance has non-finite values: {values.tolist()}"
        raise ValueError(msg)
    out = np.zeros((6, 6))
    out[np.triu_indices(6)] = values
    return out + np.triu(out, 1).T


def _block_rotate(cov: npt.ArrayLike, axes: FloatArray) -> FloatArray:
    c = np.asarray(cov, dtype=np.float64).reshape(6, 6)
    b = np.zeros((6, 6))
    b[:3, :3] = axes
    b[3:, 3:] = axes
    return b @ c @ b.T


def pose_covariance_ned_to_enu(cov_ned: npt.ArrayLike) -> FloatArray:
    """Pose covariance ``(x, y, z, roll, pitch, yaw)`` in LOCAL_NED -> ``nav_msgs/Odometry``'s pose covariance in
    ``map`` ENU (position, then rotation about the x, y, z axes).

    The attitude block is taken as small rotations about the world axes (the usual reading of an EKF's
    roll/pitch/yaw variances near level flight), so it maps with the same axis swap as the position.
    """
    return _block_rotate(cov_ned, _M_ENU_NED)


def twist_covariance_frd_to_flu(cov_frd: npt.ArrayLike) -> FloatArray:
    """Twist covariance ``(vx, vy, vz, wx, wy, wz)`` in body FRD -> the same in body FLU (``base_link``)."""
    return _block_rotate(cov_frd, _M_FLU_FRD)
