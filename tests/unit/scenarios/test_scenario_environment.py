"""A scenario's environment (presets + free values) and actors: resolved, validated, passed to the bridge; the
voxels moving objects leave behind; the per-environment summary of uav-run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.paths import REPO

from uav_common.voxel_keys import pack_keys
from uav_scenarios.cli.run import environment_table
from uav_scenarios.core.config import load_scenario
from uav_scenarios.core.params import RunContext, node_params
from uav_scenarios.core.scoring.trails import ObjectStateRecord, TrailTracker, box_voxel_keys
from uav_scenarios.errors import ScenarioConfigError
from uav_scenarios.shell.environment import check_actors, scenario_environment, with_environment
from uav_scenarios.shell.world_store import load_world
from uav_sim_bridge.config import resolve_environment

LOITER = REPO / "config" / "scenarios" / "loiter.yaml"
SAR = REPO / "config" / "scenarios" / "search_and_rescue.yaml"
SMALL = REPO / "tests" / "e2e" / "scenarios" / "small_loiter.yaml"


def _scenario(tmp_path: Path, base: Path, **extra: object) -> Path:
    data = yaml.safe_load(base.read_text())
    data["world"]["config"] = str((base.parent / data["world"]["config"]).resolve())
    data.update(extra)
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_environment_preset_and_free_values(tmp_path: Path) -> None:
    path = _scenario(
        tmp_path, LOITER, environment={"preset": "haze", "overcast": 0.2, "cameras": {"forward": {"jpeg_quality": 60}}}
    )
    scenario = load_scenario(path)
    merged, env = scenario_environment(scenario, 47.4)
    assert env.preset == "haze"
    assert env.overcast == 0.2  # the free value wins over the preset's 0.45
    assert env.visibility_m == 1500.0  # the rest comes from the preset
    assert env.effects_for("forward").jpeg_quality == 60
    assert env.effects_for("nadir").jpeg_quality == 80
    assert env.depth_noise is not None
    # the bridge gets the scenario's environment; resolved, it is self-contained (what uav-run records)
    # (as YAML text: ROS parameters cannot hold the nulls an environment may have)
    passed = node_params(scenario, "sim_bridge", RunContext())["environment"]
    assert yaml.safe_load(passed) == scenario.environment
    assert resolve_environment(passed) == resolve_environment(scenario.environment)
    assert yaml.safe_load(yaml.safe_dump(merged))["visibility_m"] == 1500.0
    other = with_environment(scenario, "dusk_noise")
    assert scenario_environment(other, 47.4)[1].preset == "dusk_noise"
    assert scenario_environment(other, 47.4)[1].overcast == 0.2  # the scenario's own values still apply
    clean = load_scenario(LOITER)
    assert scenario_environment(clean, 47.4)[1].preset == "clean"
    assert "environment" not in node_params(clean, "sim_bridge", RunContext())


@pytest.mark.parametrize(
    ("environment", "match"),
    [
        ({"preset": "sunny"}, r"scenario\.yaml: 'environment\.preset': unknown environment preset 'sunny'"),
        ({"fog_density": 0.2}, r"scenario\.yaml: 'environment' has unknown key\(s\) 'fog_density'"),
        ({"time_of_day_h": 25.0}, r"scenario\.yaml: 'environment': time_of_day_h must be in \[0, 24\)"),
        ({"time_of_day_h": 1.0}, r"scenario\.yaml: 'environment\.time_of_day_h': the sun is .* below the horizon"),
        ({"overcast": "lots"}, r"scenario\.yaml: key 'environment\.overcast' expected a number"),
        ({"cameras": {"default": {"jpeg_quality": 101}}}, r"'environment\.cameras\.default': jpeg_quality must be"),
        ({"cameras": {"default": {"motion_blur": True}}}, r"motion_blur needs an exposure section"),
    ],
)
def test_bad_environment_names_the_file_and_key(tmp_path: Path, environment: dict[str, object], match: str) -> None:
    scenario = load_scenario(_scenario(tmp_path, LOITER, environment=environment))
    with pytest.raises(ScenarioConfigError, match=match):
        scenario_environment(scenario, 47.4)


def test_actors_are_checked_against_the_world(tmp_path: Path) -> None:
    world = load_world(load_scenario(SMALL), tmp_path / "worlds")
    person = world.objects[[o.object_class.label for o in world.objects].index("person")].name
    good = load_scenario(
        _scenario(
            tmp_path,
            SMALL,
            actors={
                "people": {"moving": 2, "speed_mps": [1.2, 1.4]},
                "vehicles": {"moving": 1},
                "objects": {person: {"motion": "path", "path_m": [[20, 20], [40, 30]], "speed_mps": 1.0}},
            },
        )
    )
    plan = check_actors(good, world)
    assert person in {m.obj.name for m in plan.movers}
    actors = node_params(good, "sim_bridge", RunContext())["actors"]
    assert actors["people"] == {"moving": 2, "speed_mps": [1.2, 1.4]}  # no nulls: ROS parameters cannot hold them
    assert "seed" not in actors
    bad = load_scenario(_scenario(tmp_path, SMALL, actors={"objects": {"person_9999": {"motion": "random"}}}))
    with pytest.raises(ScenarioConfigError, match=r"scenario\.yaml: actors\.objects\.person_9999: no person"):
        check_actors(bad, world)
    with pytest.raises(ScenarioConfigError, match=r"actors\.objects\.p\.path_m|motion: path needs path_m"):
        load_scenario(_scenario(tmp_path, SMALL, actors={"objects": {"p": {"motion": "path"}}}))
    with pytest.raises(ScenarioConfigError, match=r"actors\.people\.speed_mps"):
        load_scenario(_scenario(tmp_path, SMALL, actors={"people": {"speed_mps": [1.0]}}))


def test_person_of_interest_pose_goes_to_the_bridge(tmp_path: Path) -> None:
    data = yaml.safe_load(SAR.read_text())
    data["search"]["person"]["pose"] = "lying"
    scenario = load_scenario(_scenario(tmp_path, SAR, search=data["search"]))
    ctx = RunContext(person={"name": "person_0000", "instance_id": 9, "x_m": 1.0, "y_m": -300.0})
    params = node_params(scenario, "sim_bridge", ctx)
    assert params["actors"]["objects"]["person_0000"]["pose"] == "lying"
    assert params["object_poses"]["person_0000"][:2] == [1.0, -300.0]
    with pytest.raises(ScenarioConfigError, match="the person of interest is put in place and stays"):
        load_scenario(_scenario(tmp_path, SAR, actors={"objects": {"person_0000": {"motion": "random"}}}))


def test_trails_count_what_the_map_cleared_and_what_it_kept() -> None:
    res = 0.5
    ground = pack_keys(np.array([[i, j, -1] for i in range(-20, 40) for j in range(-10, 10)]))  # the road surface
    trails = TrailTracker(res, static_keys=np.unique(ground))
    size = (4.0, 2.0, 1.5)

    def at(t: float, x: float) -> ObjectStateRecord:
        return ObjectStateRecord(t, np.array([[7.0, x, 0.0, 0.0, 0.0, *size]]), np.array([True]))

    def seen_at(t: float | None, x_from: float = -100.0):
        """The map's last_seen_s: ``t`` for columns east of ``x_from``, never elsewhere."""
        return lambda x, y: np.where(x >= x_from, np.nan if t is None else t, np.nan)

    box0 = box_voxel_keys((0.0, 0.0, 0.0), 0.0, size, res)
    assert box0.size == 8 * 4 * 3  # 4 x 2 x 1.5 m at 0.5 m: voxel centres inside
    trails.add(at(0.0, 0.0))
    s = trails.evaluate(0.0, box0, seen_at(0.0))  # the map sees the car where it is
    assert (s.mapped, s.left, s.ghosts, s.cleared) == (box0.size, 0, 0, 0)
    trails.add(at(1.0, 10.0))  # it drove 10 m away
    box1 = box_voxel_keys((10.0, 0.0, 0.0), 0.0, size, res)
    s = trails.evaluate(1.0, np.concatenate([box0, box1]), seen_at(None))  # not looked at again: nothing to judge
    assert (s.left, s.seen_again, s.ghosts, s.cleared) == (box0.size, 0, 0, 0)
    assert s.as_dict()["unseen_voxels"] == box0.size
    half = np.sort(box0)[: box0.size // 2]
    s = trails.evaluate(2.0, np.concatenate([half, box1, ground[:5]]), seen_at(2.0))  # seen again: half cleared
    assert s.seen_again == box0.size
    assert s.ghosts == half.size
    assert s.cleared == box0.size - half.size
    assert s.cleared_fraction == pytest.approx(0.5)
    assert s.distance_m == pytest.approx(10.0)
    s = trails.evaluate(3.0, box1, seen_at(3.0))  # the map cleared the rest
    assert (s.ghosts, s.cleared, s.cleared_fraction) == (0, box0.size, 1.0)


def test_environment_summary_table() -> None:
    rows = [
        {"environment": "clean", "exit_code": 0, "stop_reason": "time_limit", "mapped_pct": 8.4,
         "detections": {"tp": 10, "fp": 0, "fn": 2}, "tracking": {"mota": 0.81}, "real_time_factor": 2.9},
        {"environment": "haze", "exit_code": 1, "stop_reason": None, "mapped_pct": None, "detections": None,
         "tracking": None, "real_time_factor": None},
    ]  # fmt: skip
    lines = environment_table(rows)
    assert lines[0].split()[:2] == ["environment", "exit"]
    assert "10/0/2" in lines[1]
    assert "0.810" in lines[1]
    assert lines[2].split()[:3] == ["haze", "1", "-"]


def test_uav_run_checks_environments_and_actors_before_launching(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from uav_scenarios.cli.run import main  # noqa: PLC0415 - the CLI module pulls in the report's plotting

    args = [str(LOITER), "--runs-dir", str(tmp_path / "runs"), "--world-cache-dir", str(tmp_path / "worlds")]
    assert main([*args, "--environment", "sunny"]) == 2
    assert "'environment.preset': unknown environment preset 'sunny'" in capsys.readouterr().err
    assert main([*args, "--each-environment", "clean,sunny"]) == 2
    assert "unknown environment preset 'sunny'" in capsys.readouterr().err
    assert main([*args, "--each-environment", "--run-dir", str(tmp_path / "one")]) == 2
    assert "--each-environment makes one per preset" in capsys.readouterr().err
    bad = _scenario(tmp_path, LOITER, actors={"objects": {"person_9999": {"motion": "random"}}})
    assert main([str(bad), "--world-cache-dir", str(tmp_path / "worlds")]) == 2
    assert "actors.objects.person_9999: no person or vehicle" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()  # nothing was started
