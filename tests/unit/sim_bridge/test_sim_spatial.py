from __future__ import annotations

import numpy as np

from uav_sim_bridge.core.spatial import TriangleGrid, closest_points_on_triangles


def _brute_closest(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    # dense barycentric sampling as a reference
    n = 200
    i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
    m = i + j <= n
    b, c = i[m] / n, j[m] / n
    pts = (1 - b - c)[:, None] * tri[0] + b[:, None] * tri[1] + c[:, None] * tri[2]
    return pts[np.argmin(np.linalg.norm(pts - p, axis=1))]


def test_closest_point_matches_brute_force() -> None:
    rng = np.random.default_rng(0)
    for _ in range(40):
        tri = rng.uniform(-5, 5, (3, 3))
        p = rng.uniform(-8, 8, 3)
        q = closest_points_on_triangles(p, tri[None, 0], tri[None, 1], tri[None, 2])[0]
        ref = _brute_closest(p, tri)
        assert np.linalg.norm(q - p) <= np.linalg.norm(ref - p) + 1e-9
        assert np.linalg.norm(q - ref) < 0.1


def test_grid_queries() -> None:
    # a horizontal square roof at z=10 (id 7) and a vertical wall at x=20 (id 8)
    roof = np.array([[[0, 0, 10], [10, 0, 10], [10, 10, 10]], [[0, 0, 10], [10, 10, 10], [0, 10, 10]]], float)
    wall = np.array([[[20, 0, 0], [20, 10, 0], [20, 10, 5]], [[20, 0, 0], [20, 10, 5], [20, 0, 5]]], float)
    grid = TriangleGrid(np.concatenate([roof, wall]), [7, 7, 8, 8], cell_m=4.0)
    assert grid.highest_surface(5.0, 5.0) == (10.0, 7)
    assert grid.highest_surface(50.0, 5.0)[1] == 0
    hits = grid.sphere_contacts([19.7, 5.0, 2.0], 0.5)
    assert [h.instance_id for h in hits] == [8]
    assert abs(hits[0].distance_m - 0.3) < 1e-9
    assert abs(abs(hits[0].normal[0]) - 1.0) < 1e-9
    assert grid.sphere_contacts([5.0, 5.0, 11.0], 0.5) == []
    assert [h.instance_id for h in grid.sphere_contacts([5.0, 5.0, 10.3], 0.5)] == [7]
    empty = TriangleGrid(np.zeros((0, 3, 3)), [])
    assert empty.highest_surface(0, 0)[1] == 0
    assert empty.sphere_contacts([0, 0, 0], 1.0) == []
