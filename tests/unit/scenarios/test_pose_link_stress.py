"""Scenario keys for the pose source, lossy links and stress presets; their router configuration; and the
scorer's pose error (the estimate the autonomy flew on against the ground truth)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from helpers.paths import REPO

from mavlink_router.core.config import parse_config_text
from mavlink_router.core.impairment import ImpairmentConfig, LinkDirection
from sitl.cli import build_parser, load_from_args
from uav_common.config import ConfigError
from uav_scenarios.core.config import (
    PoseSource,
    ScoringSpec,
    effective_yaml,
    estimate_topic,
    load_scenario,
    played_topics,
    recorded_topics,
)
from uav_scenarios.core.launch import ODOMETRY_MESSAGES, RunPorts, router_conf, sitl_argv
from uav_scenarios.core.scoring.metrics import pose_error
from uav_scenarios.core.scoring.run import RunScorer
from uav_scenarios.core.scoring.types import ControllerSample, EstimateStatusSample, PoseSample, SceneTruth

LOITER = REPO / "config/scenarios/loiter.yaml"
STRESS = REPO / "config/stress"
PORTS = RunPorts(
    sitl_tcp=41000, sim=41001, router_tcp=41002, gcs=41003, controller=41004, mavsdk=41005, adhoc=41006, odometry=41007
)


def write(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "s.yaml"
    path.write_text(f"name: x\nmission: loiter\nworld: {{config: {REPO / 'config/worlds/default.yaml'}}}\n{body}")
    return path


# ---- pose source and links ------------------------------------------------------------------------------------


def test_pose_source_defaults_to_ground_truth_and_names_its_topic(tmp_path: Path) -> None:
    s = load_scenario(LOITER)
    assert s.pose_source is PoseSource.GROUND_TRUTH
    assert estimate_topic(s) == "/uav/ground_truth/odom"
    a = load_scenario(write(tmp_path, "pose_source: autopilot\n"))
    assert estimate_topic(a) == "/uav/autopilot/odom"
    assert {"/uav/autopilot/odom", "/autopilot_odometry/status"} <= set(recorded_topics(a))
    assert "/uav/autopilot/odom" not in recorded_topics(s)
    assert "/uav/autopilot/odom" in played_topics(a)
    with pytest.raises(ConfigError, match=r"pose_source.*'gps'"):
        load_scenario(write(tmp_path, "pose_source: gps\n"))


@pytest.mark.parametrize(
    ("body", "text"),
    [
        (
            "link: {endpoints: {controller: {loss_pct: 120}}}",
            r"link\.endpoints\.controller.*loss_pct must be in \[0, 100\], got 120",
        ),
        ("link: {endpoints: {controller: {loss_pct: -1}}}", r"link\.endpoints\.controller.*loss_pct"),
        ("link: {endpoints: {controller: {delay_ms: .nan}}}", r"link\.endpoints\.controller\.delay_ms.*not NaN"),
        ("link: {endpoints: {controller: {delay_ms: 90000}}}", r"delay_ms must be in \[0, 60000\]"),
        (
            "link: {endpoints: {controller: {loss_percent: 20}}}",
            r"link\.endpoints\.controller.*unknown key.*'loss_percent'",
        ),
        ("link: {endpoints: {radio: {loss_pct: 20}}}", r"link.*unknown endpoint\(s\) \['radio'\]"),
        (
            "link: {endpoints: {gcs: {loss_pct: 90, loss_burst: 2}}}",
            r"loss_burst 2 is too short for loss_pct 90: a mean burst of at least 9 frames",
        ),
        ("link: {endpoints: {gcs: {direction: sideways}}}", r"link\.endpoints\.gcs\.direction"),
        ("link: {seed: -3}", r"seed must be >= 0"),
    ],
)
def test_bad_link_values_name_the_key(tmp_path: Path, body: str, text: str) -> None:
    with pytest.raises(ConfigError, match=text):
        load_scenario(write(tmp_path, body + "\n"))


def test_router_configuration_of_a_lossy_autopilot_pose_run(tmp_path: Path) -> None:
    s = load_scenario(
        write(
            tmp_path,
            "pose_source: autopilot\nlink:\n  seed: 7\n  endpoints:\n"
            "    controller: {loss_pct: 20, delay_ms: 30, jitter_ms: 20, reorder_pct: 1}\n"
            "    gcs: {loss_pct: 50, loss_burst: 4, direction: in}\n",
        )
    )
    cfg = parse_config_text(router_conf(PORTS, tmp_path / "logs", s), source="run")
    udp = {u.name: u for u in cfg.udp}
    assert udp["odometry"].port == 41007
    assert udp["odometry"].options.out_filter.allow_msg_ids == frozenset(ODOMETRY_MESSAGES)
    assert udp["odometry"].options.link is None
    assert udp["controller"].options.link == ImpairmentConfig(
        loss_pct=20.0, delay_ms=30.0, jitter_ms=20.0, reorder_pct=1.0, seed=7
    )
    assert udp["gcs"].options.link == ImpairmentConfig(
        loss_pct=50.0, loss_burst=4.0, direction=LinkDirection.IN, seed=7
    )
    assert udp["mavsdk"].options.link is None
    # a ground-truth run has no odometry endpoint (an odometry link entry then changes nothing)
    plain = parse_config_text(router_conf(PORTS, None, load_scenario(LOITER)), source="run")
    assert "odometry" not in {u.name for u in plain.udp}
    assert all(u.options.link is None for u in plain.udp)


# ---- stress presets -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("preset", ["calm", "lossy_link", "poor_gps"])
def test_runnable_stress_presets_lay_over_a_scenario(preset: str, tmp_path: Path) -> None:
    s = load_scenario(LOITER, stress=(preset,), stress_dir=STRESS)
    assert s.stress_applied == (preset,)
    assert s.name == "loiter"  # a preset stresses a scenario, it does not rename it
    assert s.node_params["sitl"]["failsafe"] == {"geofence_max_altitude_m": 200.0}  # merged key by key
    # the effective scenario records the preset and loads anywhere without applying it twice
    eff = tmp_path / "run" / "scenario.yaml"
    eff.parent.mkdir()
    eff.write_text(effective_yaml(s))
    again = load_scenario(eff)
    assert again.stress_applied == (preset,)
    assert again.link == s.link
    assert again.node_params == s.node_params
    # the SITL takes the preset's settings (node_params.sitl passes through to uav-sitl --set)
    argv = sitl_argv(s, PORTS, params_file=tmp_path / "p.json")
    cfg = load_from_args(build_parser().parse_args(argv[1:]))
    if preset == "poor_gps":  # the SITL's own preset, its numbers filled in by the SITL
        assert cfg.estimator.mode.value == "noisy"
        assert cfg.estimator.preset is not None
        assert cfg.estimator.preset.value == "poor_gps"
        assert cfg.estimator.horizontal_noise_m == 2.5
        assert cfg.estimator.heading_bias_deg == 6.0
        assert cfg.estimator.gps_dropouts_per_hour == 12.0
        assert cfg.estimator.seed == 1
    if preset == "lossy_link":
        assert s.link.endpoints["controller"].loss_pct == 20.0
        assert s.link.endpoints["gcs"].loss_burst == 3.0
        assert "odometry" not in s.link.endpoints  # a mapping companion is wired to the autopilot


@pytest.mark.parametrize(
    ("preset", "speed_mps", "turbulence"), [("gusty", 5.0, "moderate"), ("strong_wind", 12.0, "light")]
)
def test_wind_presets_reach_the_sitl(preset: str, speed_mps: float, turbulence: str, tmp_path: Path) -> None:
    s = load_scenario(LOITER, stress=(preset,), stress_dir=STRESS)
    assert s.wind is not None
    assert s.wind.speed_mps == speed_mps
    argv = sitl_argv(s, PORTS, params_file=tmp_path / "p.json")
    cfg = load_from_args(build_parser().parse_args(argv[1:]))
    assert cfg.wind.speed_mps == speed_mps
    assert cfg.wind.turbulence.value == turbulence
    assert cfg.wind.shear_exponent == 0.14
    assert cfg.wind.seed == 1
    assert cfg.wind.enabled
    # node_params.sitl still wins over the scenario's wind, key by key
    over = load_scenario(
        write(tmp_path, f"stress: [{preset}]\nnode_params: {{sitl: {{wind: {{seed: 9}}}}}}\n"), stress_dir=STRESS
    )
    cfg = load_from_args(build_parser().parse_args(sitl_argv(over, PORTS, params_file=tmp_path / "q.json")[1:]))
    assert (cfg.wind.seed, cfg.wind.speed_mps) == (9, speed_mps)


def test_a_calm_scenario_leaves_the_sitl_calm(tmp_path: Path) -> None:
    argv = sitl_argv(load_scenario(LOITER), PORTS, params_file=tmp_path / "p.json")
    assert not any(a.startswith("wind.") for a in argv)
    assert not load_from_args(build_parser().parse_args(argv[1:])).wind.enabled


@pytest.mark.parametrize(("order", "mode"), [(("poor_gps", "calm"), "truth"), (("calm", "poor_gps"), "noisy")])
def test_the_last_estimator_preset_laid_on_wins(order: tuple[str, str], mode: str, tmp_path: Path) -> None:
    """calm after poor_gps is the truth again (it clears the SITL preset), poor_gps after calm is noisy."""
    s = load_scenario(LOITER, stress=order, stress_dir=STRESS)
    cfg = load_from_args(build_parser().parse_args(sitl_argv(s, PORTS, params_file=tmp_path / "p.json")[1:]))
    assert cfg.estimator.mode.value == mode
    assert (cfg.estimator.preset is None) == (mode == "truth")


def test_the_motor_degradation_preset_scripts_its_fault() -> None:
    s = load_scenario(LOITER, stress=("motor_degradation",), stress_dir=STRESS)
    (fault,) = s.faults
    assert (fault.at_s, fault.unit, fault.type, fault.instance, fault.duration_s) == (60.0, "motor", "wrong", 1, None)
    assert s.stress_applied == ("motor_degradation",)


def test_stress_in_the_scenario_file_and_its_errors(tmp_path: Path) -> None:
    (tmp_path / "stress").mkdir()
    (tmp_path / "stress" / "slow.yaml").write_text("autonomy: {cruise_speed_mps: 3.0}\n")
    (tmp_path / "stress" / "rename.yaml").write_text("name: other\n")
    (tmp_path / "scn").mkdir()
    path = tmp_path / "scn" / "s.yaml"
    world = REPO / "config/worlds/default.yaml"
    path.write_text(f"name: x\nmission: loiter\nworld: {{config: {world}}}\nstress: slow\n")
    s = load_scenario(path)  # names are looked up in the stress folder next to the scenario's folder
    assert s.autonomy.cruise_speed_mps == 3.0
    assert s.stress_applied == ("slow",)
    path.write_text(f"name: x\nmission: loiter\nworld: {{config: {world}}}\nstress: [nope]\n")
    with pytest.raises(ConfigError, match=r"stress: no preset 'nope'.*presets there: \['rename', 'slow'\]"):
        load_scenario(path)
    path.write_text(f"name: x\nmission: loiter\nworld: {{config: {world}}}\nstress: [rename]\n")
    with pytest.raises(ConfigError, match=r"rename.yaml: a stress preset may not set \['name'\]"):
        load_scenario(path)


def test_wind_and_fault_values_are_checked(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"wind.*speed_mps must be in \[0, 40\], got 80"):
        load_scenario(write(tmp_path, "wind: {speed_mps: 80}\n"))
    with pytest.raises(ConfigError, match=r"faults.*unit: unknown fault unit 'wing'"):
        load_scenario(write(tmp_path, "faults: [{at_s: 10, unit: wing, type: off}]\n"))
    with pytest.raises(ConfigError, match=r"faults.*type: unknown fault type 'melted'"):
        load_scenario(write(tmp_path, "faults: [{at_s: 10, unit: gps, type: melted}]\n"))
    # "at t = 120 s, GPS off": YAML reads a bare off as false, which means the same here
    (gps,) = load_scenario(write(tmp_path, "faults: [{at_s: 120, unit: gps, type: off, duration_s: 30}]\n")).faults
    assert (gps.type, gps.duration_s) == ("off", 30.0)
    # what the SITL does not simulate is refused at load, naming the key, not answered UNSUPPORTED mid-run
    with pytest.raises(ConfigError, match=r"faults.*type: gyro off is not simulated by the SITL"):
        load_scenario(write(tmp_path, "faults: [{at_s: 10, unit: gyro, type: off}]\n"))
    with pytest.raises(ConfigError, match=r"faults.*camera_nadir wrong is not simulated; a camera takes garbage/"):
        load_scenario(write(tmp_path, "faults: [{at_s: 10, unit: camera_nadir, type: wrong}]\n"))
    with pytest.raises(ConfigError, match=r"faults: failure injection is PX4's.*ardupilot"):
        load_scenario(write(tmp_path, "autopilot: ardupilot\nfaults: [{at_s: 10, unit: gps, type: off}]\n"))


# ---- pose error -----------------------------------------------------------------------------------------------


def circle(t: np.ndarray, radius_m: float = 50.0, speed_mps: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    w = speed_mps / radius_m
    xyz = np.stack([radius_m * np.cos(w * t), radius_m * np.sin(w * t), np.full_like(t, 40.0)], axis=1)
    return xyz, w * t + math.pi / 2  # heading along the circle


def test_pose_error_of_a_biased_estimate() -> None:
    t = np.arange(0.0, 60.0, 0.02)
    xyz, yaw = circle(t)
    te = np.arange(1.0, 59.0, 0.1)
    exyz, eyaw = circle(te)
    exyz = exyz + np.array([3.0, -4.0, 0.0])  # 5 m horizontal bias
    err = pose_error(t, xyz, yaw, est_t_s=te, est_xyz_m=exyz, est_yaw_rad=eyaw + math.radians(2.0))
    assert err.samples == len(te)
    assert err.position_mean_m == pytest.approx(5.0, abs=0.01)
    assert err.horizontal_rms_m == pytest.approx(5.0, abs=0.01)
    assert err.vertical_rms_m == pytest.approx(0.0, abs=1e-9)
    np.testing.assert_allclose(err.bias_enu_m, (3.0, -4.0, 0.0), atol=0.01)
    assert err.yaw_rms_deg == pytest.approx(2.0, abs=0.01)


def test_a_late_stamp_is_a_pose_error() -> None:
    """An estimate stamped 0.25 s late at 8 m/s is 2 m off where the map and the planner put it."""
    t = np.arange(0.0, 60.0, 0.02)
    xyz, yaw = circle(t)
    te = np.arange(1.0, 59.0, 0.1)
    exyz, eyaw = circle(te - 0.25)
    err = pose_error(t, xyz, yaw, est_t_s=te, est_xyz_m=exyz, est_yaw_rad=eyaw)
    assert err.position_mean_m == pytest.approx(2.0, abs=0.02)


def test_pose_error_needs_truth_around_each_estimate() -> None:
    t = np.arange(0.0, 10.0, 0.02)
    xyz, yaw = circle(t)
    err = pose_error(t, xyz, yaw, est_t_s=[20.0, 30.0], est_xyz_m=[[0, 0, 0]] * 2, est_yaw_rad=[0.0, 0.0])
    assert err.samples == 0
    assert math.isnan(err.position_rms_m)
    gap = pose_error(
        [0.0, 5.0], [[0, 0, 0], [1, 0, 0]], [0.0, 0.0], est_t_s=[2.0], est_xyz_m=[[0, 0, 0]], est_yaw_rad=[0.0]
    )
    assert gap.samples == 0  # two truth samples 5 s apart do not say where the vehicle was in between


def test_the_scorer_reports_the_pose_error_and_what_happened_to_the_estimate() -> None:
    run = RunScorer(spec=ScoringSpec(), truth=SceneTruth(bounds_m=(-100.0, -100.0, 100.0, 100.0)))
    run.start_t_s = 0.0
    t = np.arange(0.0, 20.0, 0.02)
    xyz, yaw = circle(t)
    status = EstimateStatusSample(1.0, "OK", source="ODOMETRY", time_sync="timesync", time_offset_s=0.001)
    run.add_estimate_status(status)
    for k, tk in enumerate(t):
        run.add_pose(PoseSample(float(tk), tuple(xyz[k]), float(yaw[k])))
        if k % 2 == 0 and tk > 0.5:
            run.add_estimate(PoseSample(float(tk), (xyz[k, 0] + 1.0, xyz[k, 1], xyz[k, 2]), float(yaw[k])))
    run.add_estimate_status(EstimateStatusSample(15.0, "STALE", reason="no fresh estimate for 1.2 s (timeout 1 s)"))
    run.add_controller(ControllerSample(10.0, "AUTONOMOUS"))
    run.add_controller(
        ControllerSample(15.1, "IDLE", last_event="pose estimate on /uav/autopilot/odom cannot be flown on")
    )
    summary = run.summary(20.0)
    pe = summary["pose_estimate"]
    assert 150 <= pe["estimates"] <= 200  # scored at most at 10 Hz, not at the estimate's 25 Hz
    assert pe["error"]["position_rms_m"] == pytest.approx(1.0, abs=0.01)
    assert pe["error"]["bias_enu_m"][0] == pytest.approx(1.0, abs=0.01)
    assert pe["stale_or_invalid_events"] == 1
    events = [e["what"] for e in summary["events"]]
    assert "pose estimate OK" in events
    assert "pose estimate STALE: no fresh estimate for 1.2 s (timeout 1 s)" in events
    assert "controller IDLE because: pose estimate on /uav/autopilot/odom cannot be flown on" in events
    assert run.sample(19.0)["pose_error_m"] == pytest.approx(1.0, abs=0.01)
    # a ground-truth run: no estimate, nothing invented
    plain = RunScorer(spec=ScoringSpec(), truth=SceneTruth(bounds_m=(-1.0, -1.0, 1.0, 1.0)))
    assert plain.summary(1.0)["pose_estimate"]["estimates"] == 0
    assert math.isnan(plain.sample(1.0)["pose_error_m"])


def test_uav_run_lays_stress_presets_over_the_scenario_and_refuses_bad_ones(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from uav_scenarios.cli.run import main  # noqa: PLC0415

    assert main([str(LOITER), "--stress", "no_such_preset", "--runs-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "stress: no preset 'no_such_preset'" in err
    assert "lossy_link" in err  # it lists what there is
    assert not list(tmp_path.iterdir())  # nothing was started, no run folder made
