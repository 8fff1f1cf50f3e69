"""Planning: every (arm, seed, repeat) gets its effective scenario, a configuration hash and a key."""

from __future__ import annotations

from pathlib import Path

from builders import LOITER, SAR, campaign_file

from uav_campaigns.cli.campaign import _plan
from uav_campaigns.core.config import load_campaign
from uav_campaigns.core.plan import arm_overrides
from uav_common.config import load_yaml_mapping
from uav_scenarios.core.config import DepthSource


def test_runs_are_arm_by_seed_by_repeat_and_seeds_reach_world_person_and_noise(tmp_path: Path) -> None:
    body = "arms: {a: {}, b: {depth_source: estimated}}\nseeds: [5, 6]\nrepeats: 2\n"
    runs = _plan(load_campaign(campaign_file(tmp_path, body, scenario=SAR)))
    assert [(r.arm, r.seed, r.repeat) for r in runs] == [
        (arm, seed, rep) for arm in ("a", "b") for seed in (5, 6) for rep in (0, 1)
    ]
    for r in runs:
        assert r.scenario.world.seed == r.seed
        assert r.scenario.search is not None
        assert r.scenario.search.person.placement_seed == r.seed
        assert r.scenario.node_params["sim_bridge"]["noise"]["seed"] == r.seed
        assert r.scenario.node_params["sitl"]["estimator"]["seed"] == r.seed
    assert {r.scenario.depth_source for r in runs if r.arm == "b"} == {DepthSource.ESTIMATED}
    # repeats share the configuration, not the key
    a5 = [r for r in runs if r.arm == "a" and r.seed == 5]
    assert a5[0].config_hash == a5[1].config_hash
    assert a5[0].key != a5[1].key


def test_arm_overrides_merge_over_the_scenario_key_by_key(tmp_path: Path) -> None:
    body = """\
    overrides: {autonomy: {cruise_speed_mps: 6.0}}
    arms:
      nested: {autonomy: {weights: {age: -1.0}}}
      dotted: {autonomy.weights.age: -1.0}
    seeds: [1]
    time_limit_s: 33
    """
    runs = _plan(load_campaign(campaign_file(tmp_path, body)))
    base = load_yaml_mapping(LOITER)["autonomy"]["weights"]
    for r in runs:
        assert r.scenario.autonomy.weights == {**base, "age": -1.0}  # the other weights stay the scenario's
        assert r.scenario.autonomy.cruise_speed_mps == 6.0
        assert r.scenario.stop.time_limit_s == 33.0
        assert r.scenario.node_params["sitl"]["failsafe"] == {"geofence_max_altitude_m": 200.0}  # kept from the base
    nested, dotted = runs
    assert nested.config_hash == dotted.config_hash  # the same effective configuration, spelled two ways
    assert arm_overrides({"a.b": 1, "a": {"c": 2}}) == {"a": {"b": 1, "c": 2}}


def test_the_hash_is_the_configuration_not_names_paths_or_the_wall_guard(tmp_path: Path) -> None:
    one = campaign_file(tmp_path, "name: first\narms: {x: {}}\nseeds: [1]\n", name="one.yaml")
    two = campaign_file(tmp_path, "name: second\narms: {y: {}}\nseeds: [1]\nrun_budget_s: 99\n", name="two.yaml")
    (r1,), (r2,) = _plan(load_campaign(one)), _plan(load_campaign(two))
    assert r1.scenario.name != r2.scenario.name
    assert r1.scenario.stop.wall_timeout_s != r2.scenario.stop.wall_timeout_s
    assert r1.config_hash == r2.config_hash
    # the world file is hashed by content: a copy elsewhere is the same configuration, an edit is not
    world = tmp_path / "w.yaml"
    world.write_text((LOITER.parent.parent / "worlds" / "default.yaml").read_text())
    copy = campaign_file(tmp_path, f"arms: {{x: {{world: {{config: {world}}}}}}}\nseeds: [1]\n", name="copy.yaml")
    assert _plan(load_campaign(copy))[0].config_hash == r1.config_hash
    world.write_text(world.read_text() + "\n# edited\n")
    edited = _plan(load_campaign(copy))[0]
    assert edited.config_hash != r1.config_hash


def test_the_campaign_sets_time_recording_and_budget(tmp_path: Path) -> None:
    body = """\
    arms: {a: {}}
    seeds: [1]
    time_limit_s: 50
    time: {mode: lockstep, deterministic: false, step_s: 0.2}
    record: none
    """
    (run,) = _plan(load_campaign(campaign_file(tmp_path, body)))
    assert run.scenario.time.step_s == 0.2
    assert not run.scenario.time.deterministic
    assert not run.scenario.recording.enabled
    assert run.scenario.stop.wall_timeout_s == 240.0 + 20.0 * 50  # the default budget for 50 simulated s
