from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from uav_common import frames
from uav_common.rotations import euler_from_quat, matrix_from_quat, quat_from_euler, quat_from_matrix, rotate

angles = st.floats(min_value=-3.1, max_value=3.1)
pitches = st.floats(min_value=-1.5, max_value=1.5)
coords = st.floats(min_value=-1e4, max_value=1e4)


def test_position_swap() -> None:
    assert frames.enu_to_ned([1.0, 2.0, 3.0]).tolist() == [2.0, 1.0, -3.0]
    pts = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    assert np.array_equal(frames.ned_to_enu(frames.enu_to_ned(pts)), pts)


def test_yaw_conventions() -> None:
    # Facing North: ENU yaw 90 deg, NED yaw 0. Facing East: ENU 0, NED 90 deg.
    assert math.isclose(frames.yaw_enu_to_ned(math.pi / 2), 0.0, abs_tol=1e-12)
    assert math.isclose(frames.yaw_enu_to_ned(0.0), math.pi / 2)
    assert math.isclose(frames.yaw_ned_to_enu(math.pi / 2), 0.0, abs_tol=1e-12)


def test_level_attitude_facing_north() -> None:
    q_enu_flu = quat_from_euler(0.0, 0.0, math.pi / 2)  # nose North, level
    q_ned_frd = frames.quat_enu_flu_to_ned_frd(q_enu_flu)
    np.testing.assert_allclose(q_ned_frd, [1.0, 0.0, 0.0, 0.0], atol=1e-12)


@given(angles, pitches, angles)
def test_attitude_conversion_matches_vector_conversion(roll: float, pitch: float, yaw: float) -> None:
    q_enu_flu = quat_from_euler(roll, pitch, yaw)
    q_ned_frd = frames.quat_enu_flu_to_ned_frd(q_enu_flu)
    v_flu = np.array([1.0, 2.0, 3.0])
    # Rotating a body vector then converting the world frame == converting body frame then rotating.
    lhs = frames.enu_to_ned(rotate(q_enu_flu, v_flu))
    rhs = rotate(q_ned_frd, frames.flu_to_frd(v_flu))
    np.testing.assert_allclose(lhs, rhs, atol=1e-9)
    np.testing.assert_allclose(frames.quat_ned_frd_to_enu_flu(q_ned_frd), q_enu_flu, atol=1e-9)
    # Heading agrees with the yaw conversion.
    _, _, yaw_ned = euler_from_quat(q_ned_frd)
    assert math.isclose(math.cos(yaw_ned - frames.yaw_enu_to_ned(yaw)), 1.0, abs_tol=1e-9)


@given(angles, pitches, angles)
def test_euler_and_matrix_round_trip(roll: float, pitch: float, yaw: float) -> None:
    q = quat_from_euler(roll, pitch, yaw)
    r, p, y = euler_from_quat(q)
    np.testing.assert_allclose(quat_from_euler(r, p, y), q, atol=1e-9)
    np.testing.assert_allclose(quat_from_matrix(matrix_from_quat(q)), q, atol=1e-9)


def test_ros_quaternion_order() -> None:
    q = np.array([0.1, 0.2, 0.3, 0.9])
    assert frames.wxyz_to_ros_xyzw(frames.ros_xyzw_to_wxyz(q)).tolist() == q.tolist()
    assert frames.ros_xyzw_to_wxyz(q).tolist() == [0.9, 0.1, 0.2, 0.3]
