"""Pure parts of the bridge: schedules, state conversion, home, noise, config."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from helpers.paths import CONFIG
from hypothesis import given, settings
from hypothesis import strategies as st

from uav_common.config import ConfigError, from_mapping, load_config, load_yaml_mapping
from uav_common.geo import GeoPoint, LocalProjection
from uav_common.robot import CameraMount, RobotDescription, load_robot_description
from uav_sim_bridge.config import SimBridgeConfig, mounted_cameras, resolve_world_path
from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.schedule import LockstepConfig, RateSchedule
from uav_sim_bridge.core.sensor_noise import DepthNoiseConfig, PoseNoise, PoseNoiseConfig, degrade_depth
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.vehicle_state import home_from_fix, state_from_odometry
from uav_sim_bridge.errors import SimBridgeConfigError


def test_rate_schedule_fires_on_the_sim_time_grid() -> None:
    s = RateSchedule(10.0)
    fired = [t for t in np.round(np.arange(0.0, 1.0001, 0.02), 6) if s.due(float(t))]
    assert fired == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0])
    s = RateSchedule(10.0)
    assert s.due(0.013)
    assert not s.due(0.05)
    assert s.due(0.47)  # a jump fires once, not five times
    assert not s.due(0.48)
    assert s.due(0.1)  # time went backwards: restarted simulator
    with pytest.raises(ValueError, match="rate_hz"):
        RateSchedule(0.0)


def test_a_camera_on_the_state_grid_misses_no_frame_over_a_long_run() -> None:
    # The SITL steps JSBSim at 250 Hz and stamps a state every 5 steps with sim_time_us(steps * dt). steps * dt
    # in floating point can land a hair below the instant (8.2 s became 8199999 us when truncated), and a 10 Hz
    # camera then skipped that frame: about one frame in a hundred, seen as gaps in recorded bags.
    from sitl.shell.encode import sim_time_us  # noqa: PLC0415  (the other end of the sim link)

    cam = RateSchedule(10.0)
    stamps_us = [sim_time_us(steps * 0.004) for steps in range(0, 250 * 600 + 1, 5)]  # 10 min, 50 Hz
    assert stamps_us == [steps * 4000 for steps in range(0, 250 * 600 + 1, 5)]
    states = [state_from_odometry(us, (0.0, 0.0, 0.0), [1.0, 0.0, 0.0, 0.0], (0, 0, 0), (0, 0, 0)) for us in stamps_us]
    frames = [s.sim_time_s for s in states if cam.due(s.sim_time_s)]
    assert len(frames) == 10 * 600 + 1
    assert np.diff(frames) == pytest.approx(0.1)


def test_state_from_odometry_converts_ned_frd_to_enu_flu() -> None:
    yaw_ned = math.radians(30.0)  # 30 deg east of north
    q = [math.cos(yaw_ned / 2), 0.0, 0.0, math.sin(yaw_ned / 2)]
    s = state_from_odometry(12_345_000, (10.0, 20.0, -30.0), q, (1.0, 0.5, -0.2), (0.1, 0.2, 0.3))
    assert s.sim_time_s == pytest.approx(12.345)
    np.testing.assert_allclose(s.position_m, [20.0, 10.0, 30.0])
    assert s.t_map_base.yaw_rad == pytest.approx(math.radians(60.0))  # ENU yaw from east
    np.testing.assert_allclose(s.velocity_body_mps, [1.0, -0.5, 0.2])  # FRD -> FLU
    np.testing.assert_allclose(s.angular_velocity_body_radps, [0.1, -0.2, -0.3])
    fwd = s.velocity_map_mps  # 1 m/s forward at heading 30 deg east of north (+ sideways/vertical parts)
    assert fwd[2] == pytest.approx(0.2)
    with pytest.raises(ValueError, match="invalid"):
        state_from_odometry(0, (math.nan, 0.0, 0.0), q, (0, 0, 0), (0, 0, 0))
    with pytest.raises(ValueError, match="normalised"):
        state_from_odometry(0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), (0, 0, 0), (0, 0, 0))


@settings(max_examples=40, deadline=None)
@given(st.floats(-1500, 1500), st.floats(-1500, 1500), st.floats(-200, 50), st.floats(-60, 60), st.floats(-170, 170))
def test_home_from_fix_inverts_the_projection(n: float, e: float, d: float, lat: float, lon: float) -> None:
    home = GeoPoint(lat, lon, 488.0)
    fix = LocalProjection(home).to_geo(n, e, d)
    got = home_from_fix(fix, (n, e, d))
    back = LocalProjection(got).to_ned(fix)
    np.testing.assert_allclose(back, (n, e, d), atol=1e-3)
    assert got.alt_amsl_m == pytest.approx(488.0, abs=1e-6)


def test_depth_noise_grows_with_range_and_is_seeded() -> None:
    cfg = DepthNoiseConfig(sigma_m=0.01, sigma_per_m2=0.001, dropout=0.0, dropout_per_100m=0.0, max_range_m=500.0)
    near = np.full((200, 200), 10.0, np.float32)
    far = np.full((200, 200), 100.0, np.float32)
    n1 = degrade_depth(near, cfg, np.random.default_rng(1))
    f1 = degrade_depth(far, cfg, np.random.default_rng(1))
    assert np.nanstd(n1 - near) == pytest.approx(0.01 + 0.001 * 100, rel=0.1)
    assert np.nanstd(f1 - far) == pytest.approx(0.01 + 0.001 * 10000, rel=0.1)
    np.testing.assert_array_equal(n1, degrade_depth(near, cfg, np.random.default_rng(1)))
    assert not np.array_equal(n1, degrade_depth(near, cfg, np.random.default_rng(2)))


def test_dropouts_and_range_limit() -> None:
    cfg = DepthNoiseConfig(sigma_m=0.0, sigma_per_m2=0.0, dropout=0.1, dropout_per_100m=0.2, max_range_m=150.0)
    d = np.array([[50.0] * 1000 + [100.0] * 1000 + [200.0] * 10 + [np.nan] * 5], np.float32)
    out = degrade_depth(d, cfg, np.random.default_rng(0))
    assert np.isnan(out[0, :1000]).mean() == pytest.approx(0.2, abs=0.04)
    assert np.isnan(out[0, 1000:2000]).mean() == pytest.approx(0.3, abs=0.04)
    assert np.isnan(out[0, 2000:]).all()  # beyond max range, and NaN stays NaN
    kept = ~np.isnan(out[0, :2000])
    np.testing.assert_array_equal(out[0, :2000][kept], d[0, :2000][kept])


def test_pose_noise_is_bounded_and_reproducible() -> None:
    cfg = PoseNoiseConfig(position_sigma_m=0.05, position_drift_m_per_sqrt_s=0.02, yaw_sigma_deg=0.3)
    truth = RigidTransform.from_rpy([10.0, 20.0, 30.0], yaw_rad=1.0)

    def run(seed: int) -> list[RigidTransform]:
        noise, rng = PoseNoise(cfg), np.random.default_rng(seed)
        return [noise.apply(truth, 0.02 * k, rng) for k in range(500)]

    a, b = run(3), run(3)
    assert all(np.array_equal(x.matrix(), y.matrix()) for x, y in zip(a, b, strict=True))
    err = np.array([x.translation_m - truth.translation_m for x in a])
    assert 0.01 < np.abs(err).mean() < 0.5
    yaw_err = np.array([x.yaw_rad - truth.yaw_rad for x in a])
    assert np.std(yaw_err) == pytest.approx(math.radians(0.3), rel=0.25)


def test_shipped_config_loads() -> None:
    cfg = load_config(SimBridgeConfig, CONFIG / "sim_bridge.yaml")
    assert set(cfg.cameras) == {"nadir", "forward"}
    assert cfg.lockstep.role == "master"
    assert cfg.detections.max_range_m == 100.0
    assert cfg.world_yaml() == CONFIG / "worlds" / "default.yaml"


@pytest.mark.parametrize(
    ("data", "match"),
    [
        ({"cameras": {"nadir": {"hfov_deg": 90, "zoom": 2}}}, "unknown key"),
        ({"lockstep": {"role": "boss"}}, "role"),
        ({"detections": {"cameras": ["rear"]}}, "unknown camera"),
        ({"sim_link": {"port": 70000}}, "port"),
        ({"sim_link": {"terrain_report_rate_hz": 2}}, "terrain_report_rate_hz"),
        ({"noise": {"depth": {"dropout": 2}}}, "dropout"),
        ({"collision": {"vehicle_radius_m": 0}}, "vehicle_radius_m"),
        ({"cameras": {"front cam": {"hfov_deg": 90}}}, "identifier"),
    ],
)
def test_bad_node_config_is_a_clear_error(data: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        from_mapping(SimBridgeConfig, data, source="test")


def test_world_paths(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert resolve_world_path("default") == CONFIG / "worlds/default.yaml"
    assert resolve_world_path("hills", tmp_path) == tmp_path / "hills.yaml"
    monkeypatch.chdir(tmp_path)  # as ROS nodes, which run in ~/.ros: relative paths are the config folder's
    assert resolve_world_path("config/worlds/default.yaml").resolve() == CONFIG / "worlds/default.yaml"
    assert resolve_world_path("worlds/default.yaml").resolve() == CONFIG / "worlds/default.yaml"
    assert resolve_world_path(str(tmp_path / "w.yaml")) == tmp_path / "w.yaml"
    assert LockstepConfig().steps_per_grant == 5


def test_camera_mounts_come_from_the_robot_description() -> None:
    """The bridge renders each camera from config/robot.yaml's mount: the file the robot_description node
    publishes the static transforms from (one source for the simulator and a real airframe)."""
    robot = load_robot_description(CONFIG / "robot.yaml")
    data = load_yaml_mapping(CONFIG / "sim_bridge.yaml")
    data["cameras"] = mounted_cameras(data["cameras"], robot, source="sim_bridge.yaml")
    cfg = from_mapping(SimBridgeConfig, data, source="test")
    assert cfg.cameras["nadir"].mount.rpy_deg == (0.0, 90.0, 0.0)
    assert cfg.cameras["forward"].mount.xyz_m == (0.12, 0.0, -0.04)
    # the transforms the robot_description node publishes are the ones the bridge renders from
    by_child = {t.child: t for t in robot.static_transforms()}
    for name, cam in cfg.cameras.items():
        model = CameraModel.from_config(name, cam)
        t = by_child[f"camera_{name}"]
        assert t.parent == "base_link"
        np.testing.assert_allclose(t.translation_m, model.t_base_camera.translation_m, atol=1e-12)
        q_base_optical = RigidTransform.from_quat(t.q_wxyz, t.translation_m) @ RigidTransform.from_quat(
            by_child[f"camera_{name}_optical"].q_wxyz, (0.0, 0.0, 0.0)
        )
        np.testing.assert_allclose(q_base_optical.rotation, model.t_base_optical.rotation, atol=1e-12)
    # no config names: the default cameras, mounted from the description
    defaults = mounted_cameras(None, robot, source="x")
    assert defaults["nadir"]["mount"]["rpy_deg"] == [0.0, 90.0, 0.0]


def test_a_mount_in_the_bridge_config_or_a_camera_without_one_is_an_error() -> None:
    robot = RobotDescription(cameras={"nadir": CameraMount((0.0, 0.0, -0.1), (0.0, 90.0, 0.0))})
    with pytest.raises(SimBridgeConfigError, match=r"cameras.nadir.mount: camera extrinsics live in the robot"):
        mounted_cameras({"nadir": {"hfov_deg": 90, "mount": {"rpy_deg": [0, 45, 0]}}}, robot, source="b.yaml")
    with pytest.raises(SimBridgeConfigError, match=r"camera 'rear' has no mount.*cameras: nadir"):
        mounted_cameras({"rear": {"hfov_deg": 90}}, robot, source="b.yaml")
