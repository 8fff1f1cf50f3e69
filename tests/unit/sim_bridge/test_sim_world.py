from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from sim_worlds import DEFAULT_WORLD_YAML, flat_config, small_config

from uav_common.config import ConfigError
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import CustomObjectConfig, ObjectClass, TerrainConfig, load_world_config
from uav_sim_bridge.errors import WorldFileError
from uav_sim_bridge.shell.world_io import export_mesh, export_objects_json
from uav_sim_bridge.shell.world_store import config_key, generate_world, load_or_generate, load_world_dir, save_world


def test_same_seed_same_world_other_seed_other_world(small_world: World) -> None:
    again = generate_world(small_config())
    assert again.hash == small_world.hash
    np.testing.assert_array_equal(again.mesh.vertices_m, small_world.mesh.vertices_m)
    assert [o.to_json() for o in again.objects] == [o.to_json() for o in small_world.objects]
    other = generate_world(small_config(seed=4))
    assert other.hash != small_world.hash


def test_a_world_without_forest_or_hills_has_finite_colours(flat_world: World) -> None:
    """forest.coverage 0 and hill_height_m 0 are valid settings; they once gave NaN (black) terrain."""
    colors = flat_world.mesh.colors
    assert np.isfinite(colors).all()
    assert colors.min() >= 0.0
    assert colors.max() <= 1.0
    assert colors[:, 1].mean() > 0.2  # a green meadow, not black


def test_default_world_content(default_world: World) -> None:
    counts = {c: len(default_world.objects_of_class(c)) for c in ObjectClass if c is not ObjectClass.SKY}
    assert counts[ObjectClass.TERRAIN] == 1
    assert counts[ObjectClass.ROAD] >= 4  # several villages linked
    assert counts[ObjectClass.BUILDING] >= 30
    assert counts[ObjectClass.TREE] >= 1000
    assert counts[ObjectClass.PERSON] == 30
    assert counts[ObjectClass.VEHICLE] == 20
    x0, y0, x1, y1 = default_world.terrain.bounds_m
    assert (x1 - x0, y1 - y0) == (1000.0, 1000.0)
    # ids are 1..N in order, and the mesh only uses known ids
    assert [o.instance_id for o in default_world.objects] == list(range(1, len(default_world.objects) + 1))
    assert default_world.mesh.vertex_instance.max() == len(default_world.objects)
    assert set(np.unique(default_world.face_instance)) == {o.instance_id for o in default_world.objects}
    assert len(default_world.objects) < 65535


def test_villages_are_disjoint_and_linked(default_world: World) -> None:
    villages = default_world.roads.villages_m
    assert len(villages) >= 3
    d = np.hypot(*(villages[:, None, :] - villages[None, :, :]).transpose(2, 0, 1))
    assert d[~np.eye(len(villages), dtype=bool)].min() >= 200.0
    # every village is touched by a road
    pts = default_world.roads.samples(2.0)
    for v in villages:
        assert np.min(np.hypot(pts[:, 0] - v[0], pts[:, 1] - v[1])) < 5.0


def test_home_contract(default_world: World) -> None:
    assert float(default_world.height_at(0.0, 0.0)) == 0.0
    # flat pad: within 15 m the terrain is level to a centimetre
    ang = np.linspace(0, 2 * math.pi, 64)
    for r in (5.0, 10.0, 15.0):
        h = default_world.height_at(r * np.cos(ang), r * np.sin(ang))
        assert np.abs(h).max() < 0.01
    for obj in default_world.objects[1:]:
        reach = 0.5 * math.hypot(obj.size_m[0], obj.size_m[1])
        if obj.object_class is ObjectClass.ROAD:
            continue  # checked below with the real road surface
        assert math.hypot(*obj.pose.position_m[:2]) - reach >= 15.0, obj.name
    cls = default_world.instance_class[default_world.face_instance]
    tris = default_world.triangles(cls != ObjectClass.TERRAIN)
    assert np.hypot(tris[..., 0], tris[..., 1]).min() >= 15.0


def test_objects_stand_on_the_ground(default_world: World) -> None:
    for obj in default_world.objects:
        if obj.object_class in (ObjectClass.PERSON, ObjectClass.TREE, ObjectClass.BUILDING):
            x, y, z = obj.pose.position_m
            assert z == pytest.approx(float(default_world.height_at(x, y)), abs=0.01), obj.name
        if obj.object_class is ObjectClass.VEHICLE:
            x, y, z = obj.pose.position_m
            assert 0.0 <= z - float(default_world.height_at(x, y)) <= 0.2, obj.name


def test_height_at_is_exact_on_the_terrain_mesh(default_world: World) -> None:
    t = default_world.terrain
    verts, faces = t.mesh()
    rng = np.random.default_rng(1)
    pick = rng.integers(0, len(faces), 500)
    bary = rng.dirichlet([1, 1, 1], 500)
    tri = verts[faces[pick]]
    p = np.einsum("nk,nkd->nd", bary, tri)
    np.testing.assert_allclose(t.height_at(p[:, 0], p[:, 1]), p[:, 2], atol=1e-9)
    # vectorised over any shape, clamped outside
    assert t.height_at(np.zeros((2, 3)), np.zeros((2, 3))).shape == (2, 3)
    assert float(t.height_at(1e6, 0)) == float(t.height_at(t.bounds_m[2], 0))


def test_surface_height_sees_roofs_and_roads(default_world: World) -> None:
    b = default_world.objects_of_class(ObjectClass.BUILDING)[0]
    x, y, _ = b.pose.position_m
    z, iid = default_world.surface_height_at(x, y)
    assert iid == b.instance_id
    assert z > float(default_world.height_at(x, y)) + 2.5
    road = default_world.roads.polylines[0]
    mid = road[len(road) // 2]
    z, iid = default_world.surface_height_at(float(mid[0]), float(mid[1]))
    assert default_world.object(iid).object_class is ObjectClass.ROAD
    assert 0.05 < z - float(default_world.height_at(*mid)) < 0.3
    assert default_world.surface_height_at(0.0, 0.0) == (0.0, 1)


def test_save_load_round_trip_and_corruption(small_world: World, tmp_path: Path) -> None:
    save_world(small_world, tmp_path / "w")
    loaded = load_world_dir(tmp_path / "w")
    assert loaded.hash == small_world.hash
    assert loaded.config == small_world.config
    assert loaded.objects == small_world.objects
    with np.load(tmp_path / "w" / "world.npz") as z:
        arrays = dict(z)
    arrays["vertices_m"][0, 0] += 1.0
    np.savez(tmp_path / "w" / "world.npz", **arrays)
    with pytest.raises(WorldFileError, match="hash mismatch"):
        load_world_dir(tmp_path / "w")
    (tmp_path / "w" / "objects.json").write_text("[{")
    with pytest.raises(WorldFileError, match="corrupt"):
        load_world_dir(tmp_path / "w")
    with pytest.raises(WorldFileError, match="not a saved world"):
        load_world_dir(tmp_path / "nothing")


def test_load_or_generate_uses_and_repairs_the_cache(tmp_path: Path) -> None:
    cfg = flat_config()
    first = load_or_generate(cfg, tmp_path)
    slot = next(tmp_path.iterdir())
    assert slot.name.startswith("flat-")
    assert load_or_generate(cfg, tmp_path).hash == first.hash
    (slot / "world.npz").write_bytes(b"garbage")
    assert load_or_generate(cfg, tmp_path).hash == first.hash  # regenerated, not trusted
    assert config_key(cfg) != config_key(replace(cfg, seed=2))


def test_exports(small_world: World, tmp_path: Path) -> None:
    export_mesh(small_world, tmp_path / "world.ply")
    mesh = trimesh.load(tmp_path / "world.ply", force="mesh")
    assert len(mesh.faces) == int((small_world.mesh.face_lod != 2).sum())
    export_mesh(small_world, tmp_path / "world.glb")
    assert (tmp_path / "world.glb").stat().st_size > 1000
    export_objects_json(small_world, tmp_path / "objects.json")
    doc = json.loads((tmp_path / "objects.json").read_text())
    assert doc["world"]["hash"] == small_world.hash
    assert len(doc["objects"]) == len(small_world.objects)
    assert {o["class"] for o in doc["objects"]} == {"terrain", "road", "building", "tree", "person", "vehicle"}
    with pytest.raises(WorldFileError, match="unknown mesh format"):
        export_mesh(small_world, tmp_path / "world.xyz")


def test_user_heightmap_and_mesh(tmp_path: Path) -> None:
    ramp = np.tile(np.linspace(0, 65535, 64, dtype=np.uint16), (64, 1))  # west low, east high
    cv2.imwrite(str(tmp_path / "hm.png"), ramp)
    box = trimesh.creation.box(extents=(4.0, 4.0, 6.0))
    box.apply_translation((0, 0, 3.0))
    box.export(tmp_path / "tower.stl")
    (tmp_path / "w.yaml").write_text(
        "name: user\nterrain: {size_m: 200, heightmap_image: hm.png, heightmap_min_m: 0, heightmap_max_m: 40}\n"
        "roads: {villages: 0}\nforest: {coverage: 0}\npeople: {count: 0}\nvehicles: {count: 0}\n"
        "custom_objects:\n  - {mesh: tower.stl, object_class: building, position_m: [60, 40], name: tower}\n"
    )
    cfg = load_world_config(tmp_path / "w.yaml")
    assert cfg.custom_objects[0].mesh == tmp_path / "tower.stl"
    world = generate_world(cfg)
    assert float(world.height_at(0, 0)) == 0.0
    assert float(world.height_at(90, -20)) > float(world.height_at(60, -20)) > float(world.height_at(30, -20))
    tower = world.objects[-1]
    assert tower.name == "tower"
    assert tower.object_class is ObjectClass.BUILDING
    z, iid = world.surface_height_at(60.0, 40.0)
    assert iid == tower.instance_id
    assert z == pytest.approx(float(world.height_at(60.0, 40.0)) + 6.0, abs=1e-3)


def test_missing_inputs_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="not found"):
        load_world_config(tmp_path / "nope.yaml")
    (tmp_path / "bad.yaml").write_text("terrain: {size_m: [1,\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_world_config(tmp_path / "bad.yaml")
    (tmp_path / "typo.yaml").write_text("terain: {}\n")
    with pytest.raises(ConfigError, match="unknown key"):
        load_world_config(tmp_path / "typo.yaml")
    (tmp_path / "cls.yaml").write_text("custom_objects: [{mesh: a.ply, object_class: dragon}]\n")
    with pytest.raises(ConfigError, match="unknown object class"):
        load_world_config(tmp_path / "cls.yaml")
    with pytest.raises(WorldFileError, match="not found"):
        generate_world(flat_config(terrain=TerrainConfig(size_m=200.0, heightmap_image=tmp_path / "no.png")))
    (tmp_path / "junk.png").write_bytes(b"not a png")
    with pytest.raises(WorldFileError, match="could not be decoded"):
        generate_world(flat_config(terrain=TerrainConfig(size_m=200.0, heightmap_image=tmp_path / "junk.png")))
    with pytest.raises(WorldFileError, match="not found"):
        generate_world(flat_config(custom_objects=(CustomObjectConfig(mesh=tmp_path / "none.ply"),)))


def test_default_yaml_loads() -> None:
    cfg = load_world_config(DEFAULT_WORLD_YAML)
    assert cfg.name == "default"
    assert cfg.terrain.size_m == 1000.0
