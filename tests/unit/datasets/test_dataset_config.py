"""Dataset configs: the shipped ones load, and every kind of bad input names the file and the key."""

from __future__ import annotations

from pathlib import Path

import pytest
from ds_data import small_dataset
from helpers.paths import CONFIG

from uav_common.errors import ConfigError
from uav_datasets.core.config import DatasetConfig, load_dataset_config
from uav_datasets.core.plan import allocate, plan_viewpoints, shard
from uav_datasets.errors import DatasetConfigError


@pytest.mark.parametrize("path", sorted((CONFIG / "datasets").glob("*.yaml")), ids=lambda p: p.stem)
def test_the_shipped_configs_load(path: Path) -> None:
    cfg = load_dataset_config(path)
    assert cfg.name == path.stem
    if cfg.flight is not None and cfg.flight.scenario is not None:
        assert cfg.flight.scenario.is_file()  # resolved against the config's folder


def test_defaults_and_overrides(tmp_path: Path) -> None:
    cfg = load_dataset_config(small_dataset(tmp_path))
    assert cfg.frame_limit == 24
    assert cfg.with_overrides(frames=7, seed=9).frame_limit == 7
    assert cfg.with_overrides(frames=7, seed=9).seed == 9
    assert cfg.world == str(tmp_path / "ds_world.yaml")  # relative to the config file
    assert not cfg.writes_mot
    assert DatasetConfig(name="x").frame_limit == 100
    with pytest.raises(DatasetConfigError, match="--frames must be >= 1"):
        cfg.with_overrides(frames=0)


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ({"labels.classes": ["person", "persn"]}, ["'labels'", "unknown class 'persn'", "person, vehicle"]),
        ({"labels.classes": ["sky"]}, ["'labels'", "cannot be labelled"]),
        ({"viewpoints.positions": [{"kind": "near_objects", "classes": ["dragon"]}]}, ["positions", "dragon"]),
        (
            {"viewpoints.altitude_agl_m": [100.0, 20.0]},
            ["'viewpoints'", "altitude_agl_m [100.0, 20.0] is impossible", "above the maximum"],
        ),
        ({"viewpoints.altitude_agl_m": [0.0, 20.0]}, ["altitude_agl_m", "above the terrain"]),
        ({"viewpoints.altitude_agl_m": [-5.0, 20.0]}, ["altitude_agl_m", "above the terrain"]),
        ({"viewpoints.altitude_agl_m": [10.0, 90000.0]}, ["altitude_agl_m", "within [0, 5000] m"]),
        ({"viewpoints.pitch_deg": [10.0, 120.0]}, ["pitch_deg", "within [0, 90]"]),
        ({"viewpoints.area_m": [10.0, 0.0, 5.0, 20.0]}, ["area_m", "x_min < x_max"]),
        ({"splits": {"a": {"world_seeds": [1, 2]}, "b": {"world_seeds": [2]}}}, ["world seed 2", "'a'", "'b'"]),
        ({"outputs.mot": True}, ["outputs.mot needs sequences"]),
        ({"outputs.depth": "exr"}, ["outputs.depth", "uint16_mm"]),
        ({"labels.min_visible_pixels": 0}, ["min_visible_pixels must be >= 1"]),
        ({"labels.min_visible_fraction": 1.5}, ["min_visible_fraction"]),
        ({"viewpoints.altitude_agl_m": [10.0]}, ["altitude_agl_m", "exactly 2"]),
        ({"camera.hfov_deg": 300.0}, ["hfov_deg"]),
        ({"colour": "red"}, ["unknown key(s) 'colour'"]),
        ({"viewpoints.altitud_agl_m": [10.0, 20.0]}, ["'viewpoints'", "unknown key(s) 'altitud_agl_m'"]),
        ({"source": "flight"}, ["needs a 'flight' section"]),
        ({"name": "has space"}, ["slug"]),
    ],
)
def test_bad_configs_say_what_and_where(tmp_path: Path, override: dict[str, object], words: list[str]) -> None:
    path = small_dataset(tmp_path, **override)
    with pytest.raises(DatasetConfigError) as info:
        load_dataset_config(path)
    text = str(info.value)
    assert str(path) in text
    for word in words:
        assert word in text
    assert isinstance(info.value, ConfigError)  # exit code 2


def test_flight_needs_one_source(tmp_path: Path) -> None:
    base = {"source": "flight", "splits": {"test": {"world_seeds": [1]}}}
    for flight, word in [
        ({}, "exactly one"),
        ({"run": "a", "scenario": "b"}, "exactly one"),
        ({"run": "r", "end_s": -1.0}, "start_s < end_s"),
    ]:
        with pytest.raises(DatasetConfigError, match=word):
            load_dataset_config(small_dataset(tmp_path, **base, flight=flight))
    cfg = load_dataset_config(small_dataset(tmp_path, **base, flight={"run": "runs/x", "camera": "nadir"}))
    assert cfg.flight is not None
    assert cfg.flight.run == tmp_path / "runs/x"
    assert cfg.writes_mot
    assert cfg.frame_limit == 24
    missing = tmp_path / "nope.yaml"
    with pytest.raises(DatasetConfigError, match="not found"):
        load_dataset_config(missing)


def test_plan_shares_frames_by_split_and_world(tmp_path: Path) -> None:
    assert allocate(10, [0.7, 0.15, 0.15]) == [7, 2, 1]
    assert sum(allocate(1001, [1, 1, 1])) == 1001
    cfg = load_dataset_config(small_dataset(tmp_path))
    plan = plan_viewpoints(cfg, 24)
    assert [p.index for p in plan] == list(range(24))
    assert [p.split for p in plan].count("train") == 18
    assert {p.world_seed for p in plan if p.split == "train"} == {21, 22}
    assert {p.world_seed for p in plan if p.split == "test"} == {23}
    shards = shard(plan, 3)
    assert sorted(p.index for s in shards for p in s) == list(range(24))
    assert all(len({p.world_seed for p in s}) <= 2 for s in shards)
    assert shard(plan[:2], 5) == [[plan[0]], [plan[1]]]
