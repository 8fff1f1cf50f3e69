"""The robot description (config/robot.yaml) and MAVLink covariances through uav_common.frames."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from helpers.paths import CONFIG

from uav_common.config import ConfigError
from uav_common.frames import covariance_urt21, pose_covariance_ned_to_enu, twist_covariance_frd_to_flu
from uav_common.robot import OPTICAL_FROM_FLU, load_robot_description
from uav_common.rotations import matrix_from_quat


def test_the_shipped_robot_description_places_the_cameras() -> None:
    robot = load_robot_description(CONFIG / "robot.yaml")
    assert set(robot.cameras) == {"nadir", "forward"}
    tf = {(t.parent, t.child): t for t in robot.static_transforms()}
    assert set(tf) == {
        ("base_link", "camera_forward"), ("camera_forward", "camera_forward_optical"),
        ("base_link", "camera_nadir"), ("camera_nadir", "camera_nadir_optical"),
    }  # fmt: skip
    nadir = tf[("base_link", "camera_nadir")]
    assert nadir.translation_m == (0.0, 0.0, -0.08)
    # the nadir camera's optical axis (optical z) points down (base_link -z)
    r = matrix_from_quat(nadir.q_wxyz) @ matrix_from_quat(tf[("camera_nadir", "camera_nadir_optical")].q_wxyz)
    np.testing.assert_allclose(r @ [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(matrix_from_quat(tf[("camera_nadir", "camera_nadir_optical")].q_wxyz), OPTICAL_FROM_FLU)
    # the forward camera looks 25 degrees down
    fwd = matrix_from_quat(tf[("base_link", "camera_forward")].q_wxyz) @ [1.0, 0.0, 0.0]
    assert math.degrees(math.atan2(-fwd[2], fwd[0])) == pytest.approx(25.0)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("cameras: {nadir: {xyz_m: [0, 0], rpy_deg: [0, 90, 0]}}", r"cameras\.nadir.*xyz_m"),
        ("cameras: {nadir: {xyz_m: [0, 0, 30], rpy_deg: [0, 90, 0]}}", "within 10 m"),
        ("cameras: {nadir: {rpy: [0, 90, 0]}}", r"unknown key.*'rpy'"),
        ("cameras: {'front cam': {}}", "camera names are frame-name parts"),
        ("base_frame: ''", "base_frame must be a plain frame name"),
    ],
)
def test_bad_robot_descriptions_name_the_key(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "robot.yaml"
    path.write_text(text + "\n")
    with pytest.raises(ConfigError, match=match):
        load_robot_description(path)


def test_a_missing_camera_names_the_known_ones() -> None:
    robot = load_robot_description(CONFIG / "robot.yaml")
    with pytest.raises(KeyError, match="no camera 'rear'; cameras: forward, nadir"):
        robot.mount("rear")


def test_mavlink_covariances() -> None:
    m = np.arange(36, dtype=float).reshape(6, 6)
    m = m + m.T
    urt = m[np.triu_indices(6)]
    np.testing.assert_array_equal(covariance_urt21(urt), m)
    assert covariance_urt21([math.nan] + [0.0] * 20) is None  # MAVLink's "unknown"
    with pytest.raises(ValueError, match="21 values"):
        covariance_urt21([0.0] * 20)
    with pytest.raises(ValueError, match="non-finite"):
        covariance_urt21([1.0, math.nan] + [0.0] * 19)
    c = np.diag([4.0, 1.0, 9.0, 0.1, 0.2, 0.3])
    enu = pose_covariance_ned_to_enu(c)
    np.testing.assert_allclose(np.diag(enu), [1.0, 4.0, 9.0, 0.2, 0.1, 0.3])
    np.testing.assert_allclose(pose_covariance_ned_to_enu(enu), c)  # the map is its own inverse
    t = np.eye(6)
    t[0, 1] = t[1, 0] = 0.5
    np.testing.assert_allclose(twist_covariance_frd_to_flu(t)[0, 1], -0.5)
