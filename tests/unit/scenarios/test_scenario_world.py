"""A scenario's world: seeded person placement clear of obstacles, derived worlds, ground truth."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers.paths import REPO

from uav_scenarios.core.config import PersonSpec, WorldSpec, load_scenario
from uav_scenarios.core.mission import point_in_polygon
from uav_scenarios.core.world import place_person
from uav_scenarios.errors import ScenarioError
from uav_scenarios.shell.world_store import derived_world_yaml, load_world, scene_truth
from uav_sim_bridge.core.world_config import ObjectClass

SMALL = REPO / "tests" / "e2e" / "scenarios" / "small_loiter.yaml"
REGION = ((-150.0, -150.0), (150.0, -150.0), (150.0, -40.0), (-150.0, -40.0))


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    return load_world(load_scenario(SMALL), tmp_path_factory.mktemp("worlds"))


def test_placement_is_seeded_inside_and_clear(world) -> None:  # type: ignore[no-untyped-def]
    spec = PersonSpec(name="person_0000", placement_seed=3, region_m=REGION, clearance_m=5.0)
    a = place_person(spec, world)
    assert a == place_person(spec, world)
    assert a != place_person(replace(spec, placement_seed=4), world)
    assert point_in_polygon(a.x_m, a.y_m, REGION)
    assert math.hypot(a.x_m, a.y_m) > world.config.home_clear_radius_m + 5.0
    person = next(o for o in world.objects if o.name == "person_0000")
    assert a.instance_id == person.instance_id
    for ring in (0.0, 2.5, 5.0):  # no tree, roof or car over the spot or around it
        for ang in np.linspace(0, 2 * math.pi, 8, endpoint=False):
            x, y = a.x_m + ring * math.cos(ang), a.y_m + ring * math.sin(ang)
            assert world.surface_height_at(x, y)[0] - float(world.height_at(x, y)) <= 0.5
    for obj in world.objects:
        if obj.object_class in (ObjectClass.PERSON, ObjectClass.VEHICLE):
            assert math.hypot(obj.pose.position_m[0] - a.x_m, obj.pose.position_m[1] - a.y_m) > 5.0


def test_fixed_position_and_bad_inputs(world) -> None:  # type: ignore[no-untyped-def]
    fixed = place_person(PersonSpec(name="person_0001", position_m=(12.0, -60.0)), world)
    assert (fixed.x_m, fixed.y_m) == (12.0, -60.0)
    with pytest.raises(ScenarioError, match="not a person of this world"):
        place_person(PersonSpec(name="tree_0001", region_m=REGION), world)
    tiny = ((1.0, 1.0), (2.0, 1.0), (2.0, 2.0))  # inside home's clear pad
    with pytest.raises(ScenarioError, match="no spot"):
        place_person(PersonSpec(name="person_0000", region_m=tiny), world)


def test_scene_truth(world, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    quick = scene_truth(world, resolution_m=None, cache_dir=tmp_path / "worlds")
    assert quick.bounds_m == world.terrain.bounds_m
    assert quick.area_m2 == pytest.approx(400.0 * 400.0)
    assert quick.surface_keys.size == 0
    assert quick.ground is not None
    for x, y in ((0.0, 0.0), (37.0, -81.0), (-120.0, 150.0)):
        assert quick.ground.value_at("elevation_m", x, y) == pytest.approx(float(world.height_at(x, y)), abs=1.5)
    assert len(quick.object_classes) == len(world.objects_of_class(ObjectClass.PERSON)) + len(
        world.objects_of_class(ObjectClass.VEHICLE)
    )
    person = next(o for o in world.objects if o.name == "person_0000")
    moved = scene_truth(world, resolution_m=None, moved={person.instance_id: (10.0, -70.0)})
    row = moved.objects[moved.objects[:, 0] == person.instance_id][0]
    assert tuple(row[1:3]) == (10.0, -70.0)
    full = scene_truth(world, resolution_m=2.0, cache_dir=tmp_path / "worlds")
    assert full.surface_keys.size > 1000
    assert np.all(np.diff(full.surface_keys) > 0)  # sorted, unique
    cached = list((tmp_path / "truth").glob("*-2m.npy"))
    assert len(cached) == 1
    again = scene_truth(world, resolution_m=2.0, cache_dir=tmp_path / "worlds")
    assert np.array_equal(again.surface_keys, full.surface_keys)


def test_derived_world_yaml(tmp_path: Path) -> None:
    s = load_scenario(SMALL)
    assert derived_world_yaml(s, tmp_path) == s.world_config_path  # no seed: the file itself
    seeded = replace(s, world=WorldSpec(config=s.world_config_path, seed=99))
    path = derived_world_yaml(seeded, tmp_path)
    assert path.parent == tmp_path
    assert "seed: 99" in path.read_text()
    assert derived_world_yaml(seeded, tmp_path) == path  # same content, same file
    assert load_world(seeded, tmp_path / "c").config.seed == 99
