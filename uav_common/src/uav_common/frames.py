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
    "enu_to_ned",
    "flu_to_frd",
    "frd_to_flu",
    "ned_to_enu",
    "quat_enu_flu_to_ned_frd",
    "quat_ned_frd_to_enu_flu",
    "ros_xyzw_to_wxyz",
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
