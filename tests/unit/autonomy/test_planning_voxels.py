"""3D planning over the voxel map: the fast octree decoder against liboctomap's stream and the reference
decoder, occupancy on the planner lattice, and A* through a gate, over a mesa, in known-free space only,
inside a geofence; path conflicts after the map grows."""

from __future__ import annotations

import itertools
import json
import math
import subprocess

import numpy as np
import pytest
from helpers.paths import DEVEL_LIB
from scipy.spatial import cKDTree

from uav_autonomy.core.octree_reader import OctreeLeaves, decode_binary_octree
from uav_autonomy.core.planning import PlannerConfig, path_conflict_m
from uav_autonomy.core.planning_voxels import (
    decode_octree,
    grid_from_occupancy,
    occupancy_from_leaves,
    plan_on_voxel_map,
)
from uav_autonomy.errors import InvalidInputError, NoPathError

MAP_CORE = DEVEL_LIB / "uav_mapping" / "map_core_tests"
RES = 1.0  # voxel map resolution in these tests (the map server's is 0.5 m; any works)


def _sorted(leaves: OctreeLeaves) -> np.ndarray:
    arr = np.c_[leaves.index_min, leaves.size_voxels, leaves.occupied]
    return arr[np.lexsort(arr.T[::-1])]


@pytest.fixture(scope="module")
def liboctomap_sample(tmp_path_factory: pytest.TempPathFactory) -> tuple[bytes, float]:
    assert MAP_CORE.exists(), f"{MAP_CORE} is missing: run `make build` (make test builds first)"
    out = tmp_path_factory.mktemp("octree")
    proc = subprocess.run(
        [str(MAP_CORE), "--write-sample", str(out)], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout.strip().splitlines()[-1])
    return (out / "sample_binary.bin").read_bytes(), float(info["resolution_m"])


def test_fast_decoder_equals_the_reference_on_a_liboctomap_stream(liboctomap_sample: tuple[bytes, float]) -> None:
    data, res = liboctomap_sample
    fast = decode_octree(data, res)
    ref = decode_binary_octree(data, res)
    assert fast.resolution_m == res
    assert len(fast.occupied) == len(ref.occupied) > 1000
    np.testing.assert_array_equal(_sorted(fast), _sorted(ref))


def test_fast_decoder_hand_built_tree_and_errors() -> None:
    # The map_server reader's hand-built tree: one occupied voxel at index (0, 0, 0), one free at (1, 0, 1).
    data = bytes([0x00, 0xC0]) + bytes([0x03, 0x00]) * 14 + bytes([0x02, 0x04])
    leaves = decode_octree(data, 0.5)
    np.testing.assert_array_equal(_sorted(leaves), _sorted(decode_binary_octree(data, 0.5)))
    assert leaves.occupied.tolist().count(True) == 1
    np.testing.assert_array_equal(leaves.index_min[leaves.occupied], [[0, 0, 0]])
    np.testing.assert_array_equal(leaves.index_min[~leaves.occupied], [[1, 0, 1]])
    assert decode_octree(b"", 0.5).occupied.size == 0
    with pytest.raises(InvalidInputError, match="truncated"):
        decode_octree(data[:-2], 0.5)
    with pytest.raises(InvalidInputError, match="truncated"):
        decode_octree(data[:-1], 0.5)
    with pytest.raises(InvalidInputError, match="after its last node"):
        decode_octree(data + b"\x00\x00", 0.5)
    with pytest.raises(InvalidInputError, match="resolution_m"):
        decode_octree(data, 0.0)
    with pytest.raises(InvalidInputError, match="finest depth"):
        decode_octree(bytes([0x03, 0x00]) * 17 + bytes([0x02, 0x00]), 0.5)


# --------------------------------------------------------------------------------------------- scenes


def _boxes(boxes: list[tuple[tuple[int, int, int], tuple[int, int, int], bool]], size: int = 1) -> OctreeLeaves:
    """Leaves of edge ``size`` voxels (like pruned octree nodes) filling index boxes ``[lo, hi)``."""
    corners, occupied = [], []
    for lo, hi, occ in boxes:
        axes = [np.arange(a, b, size) for a, b in zip(lo, hi, strict=True)]
        pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        corners.append(pts)
        occupied.append(np.full(len(pts), occ))
    index = np.concatenate(corners).astype(np.int64)
    return OctreeLeaves(RES, index, np.full(len(index), size, np.int64), np.concatenate(occupied))


def _ground(x0: int = -60, x1: int = 460, y0: int = -80, y1: int = 80) -> tuple:
    return ((x0, y0, -1), (x1, y1, 0), True)  # top of the ground at z = 0


def _min_clearance(path: np.ndarray, solid: OctreeLeaves, skip: int = 1) -> float:
    """Smallest distance from the path (after its first ``skip`` legs, sampled every 0.25 m) to any
    occupied voxel (nearest voxel centre minus its half diagonal: a lower bound of the box distance)."""
    centres = (solid.index_min[solid.occupied] + 0.5) * RES
    pts = np.concatenate(
        [np.linspace(a, b, max(2, int(np.linalg.norm(b - a) / 0.25))) for a, b in itertools.pairwise(path[skip:])]
    )
    dist, _ = cKDTree(centres).query(pts)
    return float(dist.min()) - 0.5 * math.sqrt(3.0) * RES


CFG = PlannerConfig(
    algorithm="astar", voxel_xy_m=5.0, voxel_z_m=5.0, clearance_m=8.0, min_altitude_m=5.0, max_altitude_m=100.0,
    goal_height_m=20.0, heuristic_weight=1.0, domain_margin_m=20.0,
)  # fmt: skip


def test_gate_in_a_wall_is_used_when_the_wall_rises_above_the_ceiling() -> None:
    # A wall x in [190, 210) up to z = 150 with a known-free opening y in [-20, 20), z in [20, 60).
    wall = [
        ((190, -80, 0), (210, -20, 150), True),
        ((190, 20, 0), (210, 80, 150), True),
        ((190, -20, 0), (210, 20, 20), True),
        ((190, -20, 60), (210, 20, 150), True),
        ((190, -20, 20), (210, 20, 60), False),
    ]
    leaves = _boxes([_ground(), *wall])
    occ = occupancy_from_leaves(leaves, CFG)
    path, grid = plan_on_voxel_map((0.0, 0.0, 0.5), (400.0, 0.0), occ, CFG)
    np.testing.assert_allclose(path[-1], [400.0, 0.0, 20.0])  # goal_height above the ground
    crossing = [p for a, b in itertools.pairwise(path) for p in np.linspace(a, b, 100) if 190.0 <= p[0] < 210.0]
    assert crossing, path
    assert all(-20.0 < p[1] < 20.0 and 20.0 < p[2] < 60.0 for p in crossing), path
    assert _min_clearance(path, leaves) >= 8.0 - 1.0  # shortcuts are checked every half voxel
    assert path_conflict_m(path, grid, skip_m=15.0) is None


def test_unknown_inside_of_a_mesa_is_solid_even_when_unknown_space_is_free() -> None:
    # Only the mesa's top is known (as after a nadir flight): z in [80, 81) over x in [150, 250).
    leaves = _boxes([_ground(), ((150, -80, 80), (250, 80, 81), True)])
    cfg = PlannerConfig(**{**CFG.__dict__, "max_altitude_m": 140.0, "unknown_space": "free"})
    path, _ = plan_on_voxel_map((0.0, 0.0, 0.5), (400.0, 0.0), occupancy_from_leaves(leaves, cfg), cfg)
    over = [p for a, b in itertools.pairwise(path) for p in np.linspace(a, b, 100) if 150.0 <= p[0] < 250.0]
    assert over, path
    assert min(p[2] for p in over) >= 81.0 + 8.0 - 1e-6, path


def test_unknown_space_occupied_keeps_the_path_in_known_free_space() -> None:
    # Known free: a corridor y in [-40, 40), z in [0, 60) along the whole way (pruned into 4 m leaves, which
    # straddle the 5 m planner cells), with a block in it. Unknown elsewhere.
    corridor = _boxes([((-60, -40, 0), (460, 40, 60), False)], size=4)
    solid = _boxes([_ground(), ((192, -12, 0), (208, 12, 32), True)])
    leaves = OctreeLeaves(
        RES,
        np.concatenate([corridor.index_min, solid.index_min]),
        np.concatenate([corridor.size_voxels, solid.size_voxels]),
        np.concatenate([corridor.occupied, solid.occupied]),
    )
    cfg = PlannerConfig(**{**CFG.__dict__, "unknown_space": "occupied", "goal_height_m": 20.0})
    occ = occupancy_from_leaves(leaves, cfg)
    path, _ = plan_on_voxel_map((0.0, 0.0, 10.0), (400.0, 0.0), occ, cfg)
    pts = np.concatenate([np.linspace(a, b, 200) for a, b in itertools.pairwise(path[1:])])
    assert (np.abs(pts[:, 1]) < 40.0).all()
    assert (pts[:, 2] < 60.0).all()
    assert _min_clearance(path, solid) >= 8.0 - 1.0
    # Without the corridor nothing is known: no path.
    with pytest.raises(NoPathError):
        plan_on_voxel_map((0.0, 0.0, 10.0), (400.0, 0.0), occupancy_from_leaves(_boxes([_ground()]), cfg), cfg)


def test_geofence_and_no_fly_zone_on_the_voxel_map() -> None:
    leaves = _boxes([_ground()])
    zone = ((150.0, -30.0), (250.0, -30.0), (250.0, 30.0), (150.0, 30.0))
    fence = ((-50.0, -60.0), (450.0, -60.0), (450.0, 60.0), (-50.0, 60.0))
    cfg = PlannerConfig(**{**CFG.__dict__, "no_fly_zones_xy_m": (zone,), "geofence_xy_m": fence})
    path, _ = plan_on_voxel_map((0.0, 0.0, 0.5), (400.0, 0.0), occupancy_from_leaves(leaves, cfg), cfg)
    pts = np.concatenate([np.linspace(a, b, 200) for a, b in itertools.pairwise(path)])
    in_zone = (pts[:, 0] > 150.0) & (pts[:, 0] < 250.0) & (np.abs(pts[:, 1]) < 30.0)
    assert not in_zone.any()
    assert (np.abs(pts[:, 1]) < 60.0).all()


def test_a_new_obstacle_on_the_path_is_a_conflict_and_the_replan_avoids_it() -> None:
    cfg = CFG
    empty = occupancy_from_leaves(_boxes([_ground()]), cfg)
    path, grid = plan_on_voxel_map((0.0, 0.0, 20.0), (400.0, 0.0), empty, cfg)
    assert path_conflict_m(path, grid) is None
    assert np.abs(path[:, 1]).max() <= 2.5  # straight over flat ground (through voxel centres)
    tower = ((190, -30, 0), (210, 30, 95), True)
    grown_leaves = _boxes([_ground(), tower])
    grown = occupancy_from_leaves(grown_leaves, cfg)
    grid2 = grid_from_occupancy(grown, (0.0, 0.0, 20.0), (400.0, 0.0, 20.0), cfg)
    hit = path_conflict_m(path, grid2)
    assert hit is not None
    assert 190.0 - 8.0 - 10.0 < hit < 200.0  # where the old path first comes within the clearance
    new, grid3 = plan_on_voxel_map((0.0, 0.0, 20.0), (400.0, 0.0), grown, cfg)
    assert path_conflict_m(new, grid3) is None
    assert _min_clearance(new, grown_leaves) >= 8.0 - 2.5
    assert np.abs(new[:, 1]).max() > 30.0  # around the tower (it rises to the ceiling)


def test_occupancy_fractions_and_columns() -> None:
    cfg = PlannerConfig(voxel_xy_m=4.0, voxel_z_m=4.0, min_altitude_m=2.0, max_altitude_m=40.0, clearance_m=0.0)
    # One lattice cell (x, y in [0, 4), z in [0, 4) around centre 2) half known free; an occupied voxel at z 10.
    leaves = _boxes([((0, 0, 0), (4, 4, 2), False), ((1, 1, 10), (2, 2, 11), True)])
    occ = occupancy_from_leaves(leaves, cfg)
    np.testing.assert_array_equal(occ.free_cells, [[0, 0, 0]])
    np.testing.assert_allclose(occ.free_fraction, [0.5])
    np.testing.assert_array_equal(occ.occupied, [[0, 0, 2]])  # z 10..11 is in layer 2 (centre 10)
    assert occ.top_at(1.5, 1.5) == 11.0
    assert math.isnan(occ.top_at(9.0, 1.5))
