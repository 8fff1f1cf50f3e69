from __future__ import annotations

import numpy as np
import pytest
import trimesh
from sim_worlds import flat_config

from uav_common.voxel_keys import pack_keys, unpack_keys
from uav_sim_bridge.core.voxels import object_surface_voxels, union_keys, voxel_centres
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import CustomObjectConfig, ObjectClass
from uav_sim_bridge.shell.world_store import generate_world


def test_flat_terrain_is_one_layer(flat_world: World) -> None:
    keys = flat_world.surface_voxels(1.0)
    assert set(np.unique(keys[:, 2])) == {0}  # z in [0, 1): the ground layer, nothing below
    assert len(keys) == 400 * 400
    np.testing.assert_allclose(voxel_centres(keys[:1], 1.0)[0, 2], 0.5)


def test_box_contributes_its_surface_not_its_volume(tmp_path) -> None:
    box = trimesh.creation.box(extents=(8.0, 8.0, 8.0))
    box.apply_translation((0, 0, 4.0))
    box.export(tmp_path / "cube.ply")
    world = generate_world(
        flat_config(custom_objects=(CustomObjectConfig(mesh=tmp_path / "cube.ply", position_m=(50.0, 50.0)),))
    )
    keys = world.surface_voxels(1.0)
    inside = (keys[:, 0] >= 47) & (keys[:, 0] < 53) & (keys[:, 1] >= 47) & (keys[:, 1] < 53)
    # interior columns: only the roof layer (z = 8 -> key 8); the terrain under the box is covered
    assert set(keys[inside, 2]) == {8}
    walls = (keys[:, 0] == 46) & (keys[:, 1] == 50)
    assert set(keys[walls, 2]) == set(range(9))  # the wall from the ground to the roof
    assert keys[:, 2].min() >= 0  # nothing below ground


def test_pack_unpack_keys() -> None:
    keys = np.array([[0, 0, 0], [-5, 7, -1], [1000, -999, 12], [(1 << 20) - 1, -(1 << 20) + 1, 3]])
    np.testing.assert_array_equal(unpack_keys(pack_keys(keys)), keys)
    assert union_keys(keys, keys[:2]).shape == (4, 3)
    with pytest.raises(ValueError, match="out of range"):
        pack_keys(np.array([[1 << 20, 0, 0]]))


def test_object_sampling_hits_every_voxel_of_a_big_triangle() -> None:
    tri = np.array([[[0.0, 0.0, 0.5], [10.0, 0.0, 0.5], [0.0, 10.0, 0.5]]])
    keys = object_surface_voxels(tri, 1.0)
    expected = {(i, j, 0) for i in range(10) for j in range(10) if i + j <= 9}
    assert expected <= {tuple(k) for k in keys}
    assert len(keys) <= len(expected) + 10


def test_default_world_voxels_cover_objects(small_world: World) -> None:
    keys = small_world.surface_voxels(1.0)
    tree = small_world.objects_of_class(ObjectClass.TREE)[0]
    x, y, z = tree.pose.position_m
    top = np.floor(np.array([x, y, z + tree.size_m[2] - 0.6]))
    assert np.any(np.all(np.abs(keys - top) <= 1, axis=1))
    assert small_world.surface_voxels(1.0) is keys  # cached
    with pytest.raises(ValueError, match="resolution_m"):
        small_world.surface_voxels(0.0)
