"""Scenario files: the shipped ones load, broken ones fail with the file and key."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from helpers.paths import REPO

from uav_common.config import ConfigError
from uav_scenarios.core.config import (
    GEOLOCATED_TOPIC,
    DepthSource,
    DetectorKind,
    MissionKind,
    RecordingSpec,
    StopCriteria,
    Strategy,
    TimeMode,
    effective_yaml,
    load_scenario,
    played_topics,
    recorded_topics,
)

SCENARIOS = sorted((REPO / "config" / "scenarios").glob("*.yaml"))


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.name for p in SCENARIOS])
def test_every_shipped_scenario_loads(path: Path) -> None:
    scenario = load_scenario(path)
    assert scenario.source == path.resolve()
    assert scenario.world_config_path.is_absolute()
    assert scenario.world_config_path.parent == (REPO / "config" / "worlds").resolve()


def test_loiter_weights_equal_and_target_home() -> None:
    s = load_scenario(REPO / "config/scenarios/loiter.yaml")
    assert s.mission is MissionKind.LOITER
    assert set(s.autonomy.weights.values()) == {1.0}
    assert set(s.autonomy.weights) == {"age", "frontier", "target", "drone"}
    assert s.autonomy.target.point_m == (0.0, 0.0)


def test_sar_weights_and_prior_to_the_south() -> None:
    s = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    assert s.mission is MissionKind.SEARCH_AND_RESCUE
    w = s.autonomy.weights
    assert (w["target"], w["frontier"], w["drone"], w["age"], w["origin"]) == (2.0, 1.0, 1.0, 0.0, 0.0)
    assert s.autonomy.target.point_m is not None
    assert s.autonomy.target.point_m[1] < -100.0
    assert s.search is not None
    assert s.search.detection_range_m == 100.0
    assert s.stop.target_found


def test_baselines_share_the_sar_setup() -> None:
    base = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    for name, strategy in (("sar_lawnmower", Strategy.LAWNMOWER), ("sar_expanding_square", Strategy.EXPANDING_SQUARE)):
        s = load_scenario(REPO / f"config/scenarios/{name}.yaml")
        assert s.strategy is strategy
        assert s.search == base.search
        assert s.world == base.world
        assert s.stop == base.stop


def write(tmp_path: Path, text: str) -> Path:
    """A scenario file in tmp_path; it flies in the repository's default world unless it says otherwise."""
    if "world:" not in text:
        text += f"world: {{config: {REPO / 'config/worlds/default.yaml'}}}\n"
    path = tmp_path / "s.yaml"
    path.write_text(text)
    return path


def test_missing_world_file_names_it(tmp_path: Path) -> None:
    path = write(tmp_path, "name: x\nmission: loiter\nworld: {config: nope.yaml}\n")
    with pytest.raises(ConfigError, match=r"world.config nope.yaml does not exist"):
        load_scenario(path)


def test_unknown_key_names_file_and_key(tmp_path: Path) -> None:
    path = write(tmp_path, "name: x\nmission: loiter\nstop:\n  time_limt_s: 3\n")
    with pytest.raises(ConfigError, match=r"s\.yaml.*'stop'.*time_limt_s"):
        load_scenario(path)


def test_wrong_type_names_key(tmp_path: Path) -> None:
    path = write(tmp_path, "name: x\nmission: loiter\ntime:\n  speed_factor: fast\n")
    with pytest.raises(ConfigError, match=r"time\.speed_factor.*number"):
        load_scenario(path)


def test_sar_without_search_section_is_rejected(tmp_path: Path) -> None:
    path = write(tmp_path, "name: x\nmission: search_and_rescue\n")
    with pytest.raises(ConfigError, match="needs a 'search' section"):
        load_scenario(path)


def test_unknown_feature_weight_is_rejected(tmp_path: Path) -> None:
    path = write(tmp_path, "name: x\nmission: loiter\nautonomy:\n  weights: {age: 1, fronteir: 1}\n")
    with pytest.raises(ConfigError, match="fronteir"):
        load_scenario(path)


def test_all_zero_weights_rejected(tmp_path: Path) -> None:
    path = write(tmp_path, "name: x\nmission: loiter\nautonomy:\n  weights: {age: 0}\n")
    with pytest.raises(ConfigError, match="at least one feature weight"):
        load_scenario(path)


def test_negative_weight_allowed_but_not_nan(tmp_path: Path) -> None:
    ok = write(tmp_path, "name: x\nmission: loiter\nautonomy:\n  weights: {age: -1, frontier: 1}\n")
    assert load_scenario(ok).autonomy.weights["age"] == -1.0
    bad = write(tmp_path, "name: x\nmission: loiter\nautonomy:\n  weights: {age: .nan}\n")
    with pytest.raises(ConfigError, match="NaN"):
        load_scenario(bad)


def test_deterministic_needs_lockstep(tmp_path: Path) -> None:
    path = write(tmp_path, "name: x\nmission: loiter\ntime: {mode: free, deterministic: true}\n")
    with pytest.raises(ConfigError, match="lockstep"):
        load_scenario(path)


def test_effective_yaml_loads_anywhere(tmp_path: Path) -> None:
    s = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    out = tmp_path / "elsewhere" / "scenario.yaml"
    out.parent.mkdir()
    out.write_text(effective_yaml(s))
    again = load_scenario(out)
    assert again.world_config_path == s.world_config_path
    same_world = replace(s.world, config=s.world_config_path)
    assert replace(again, source=None) == replace(s, source=None, world=same_world)


def test_missing_file_says_so(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_scenario(tmp_path / "nope.yaml")


def test_bad_name_rejected(tmp_path: Path) -> None:
    path = write(tmp_path, "name: 'a b/c'\nmission: loiter\n")
    with pytest.raises(ConfigError, match="slug"):
        load_scenario(path)


def test_overrides_apply_and_validate(tmp_path: Path) -> None:
    path = write(tmp_path, "name: x\nmission: loiter\n")
    s = load_scenario(path, overrides={"stop": StopCriteria(time_limit_s=12.0)})
    assert s.stop.time_limit_s == 12.0
    assert s.time.mode is TimeMode.FREE
    with pytest.raises(ConfigError, match="invalid override"):
        load_scenario(path, overrides={"no_such_field": 1})


def test_recorded_topics_presets() -> None:
    s = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    report = recorded_topics(s)
    replay = recorded_topics(replace(s, recording=RecordingSpec(preset="replay", extra_topics=("/extra", "/tf"))))
    assert "/scenario/metrics" in report
    assert "/tf" not in report
    assert "/clock" not in report  # rosbag play --clock makes it
    assert set(report) < set(replay)
    assert replay.count("/tf") == 1
    assert "/extra" in replay
    # ground-truth depth: the map camera's depth and color images (the map server back-projects them)
    assert {
        "/cameras/nadir/depth/image_raw",
        "/cameras/nadir/color/image_raw",
        "/cameras/nadir/depth/camera_info",
    } <= set(replay)
    assert "/cameras/nadir/points" not in replay
    assert "/cameras/nadir/color/camera_info" not in replay  # no reader in a replay: rosbag play would wait
    estimated = replace(s, depth_source=DepthSource.ESTIMATED, recording=RecordingSpec(preset="replay"))
    assert "/cameras/nadir/depth/image_raw" in recorded_topics(estimated)
    assert "/cameras/nadir/points" not in recorded_topics(estimated)
    # a replay plays what the regenerating nodes read, never what they write
    played = played_topics(s)
    assert "/cameras/nadir/depth/image_raw" in played
    assert not {"/map_server/layers", "/autonomy/features", "/scenario/metrics", "/scenario/tracks"} & set(played)
    with pytest.raises(ValueError, match="preset"):
        replace(RecordingSpec(), preset="everything")


def test_the_detector_under_test_and_its_topics(tmp_path: Path) -> None:
    sar = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    perception = sar.perception
    assert perception.detector is DetectorKind.GROUND_TRUTH
    assert perception.camera == "forward"
    assert perception.boxes_topic == "/detections/forward/ground_truth"
    assert perception.source == "ground_truth_boxes"
    topics = recorded_topics(sar)
    # the truth, the detector's own boxes as they came and their placements are all in the bag
    assert {"/detections/ground_truth", "/detections/forward/ground_truth", GEOLOCATED_TOPIC} <= set(topics)
    assert GEOLOCATED_TOPIC in played_topics(sar)  # a replay re-tracks and re-scores the recorded placements
    text = (REPO / "config/scenarios/search_and_rescue.yaml").read_text()
    text = text.replace("../worlds/default.yaml", str(REPO / "config/worlds/default.yaml"))
    path = tmp_path / "stand_in.yaml"
    path.write_text(text.replace("detector: ground_truth", "detector: degraded_truth\n  degraded: {seed: 4}"))
    stand_in = load_scenario(path).perception
    assert stand_in.boxes_topic == "/degraded_detector/detections"
    assert stand_in.degraded == {"seed": 4}
    learned = load_scenario(REPO / "config/scenarios/sar_learned_detector.yaml")
    assert learned.perception.detector is DetectorKind.LEARNED
    assert (learned.perception.boxes_topic, learned.perception.source) == ("/detector/detections", "learned")
    assert learned.world.seed == 7  # held out: the detector's training worlds are 11-16
    assert "/detector/detections" in recorded_topics(learned)


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        ("  confirm_detections: 3\n", "search.detection_topic and search.camera have moved"),
        ("detector: ground_truth", "external needs detector_topic"),
        ("score_threshold: 0.5", "score_threshold must be within"),
        ("camera: forward\n  score", "detector_topic is for detector: external"),
        ("camera: forward\n  score_", "model is for detector: learned, not ground_truth"),
    ],
)
def test_bad_perception_sections_say_what_to_do(tmp_path: Path, edit: str, match: str) -> None:
    text = (REPO / "config/scenarios/search_and_rescue.yaml").read_text()
    replacement = {
        "  confirm_detections: 3\n": "  confirm_detections: 3\n  detection_topic: /detections/ground_truth\n",
        "detector: ground_truth": "detector: external",
        "score_threshold: 0.5": "score_threshold: 1.5",
        "camera: forward\n  score": "camera: forward\n  detector_topic: /mine\n  score",
        "camera: forward\n  score_": "camera: forward\n  model: m.onnx\n  score_",
    }[edit]
    assert edit in text
    path = tmp_path / "bad.yaml"
    path.write_text(text.replace(edit, replacement, 1))
    with pytest.raises(ConfigError, match=match):
        load_scenario(path)
