"""Pure metric functions on hand-computed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from uav_scenarios.core.scoring.metrics import (
    altitude_stats,
    band_label,
    band_of,
    battery_use,
    bbox_iou,
    mapped_area_m2,
    match_detections,
    mean_cell_age_s,
    path_length_m,
    view_angle_deg,
    voxel_accuracy,
    voxel_keys,
    voxel_keys_from_indices,
)
from uav_scenarios.core.scoring.types import BatterySample, Detection, GridSnapshot
from uav_scenarios.errors import ScoringError


def test_voxel_keys_align_with_floor_indexing() -> None:
    # -0.1 is in voxel -1 and 0.49 in voxel 0 at 0.5 m, like OctoMap/OpenVDB index space.
    keys = voxel_keys([[-0.1, 0.0, 0.0], [0.49, 0.0, 0.0], [0.51, 0.0, 0.0], [0.2, 0.1, 0.3]], 0.5)
    expected = voxel_keys_from_indices([[-1, 0, 0], [0, 0, 0], [1, 0, 0]])
    np.testing.assert_array_equal(keys, expected)


def test_voxel_keys_drop_non_finite_and_reject_bad_input() -> None:
    assert voxel_keys([[math.nan, 0, 0], [math.inf, 1, 1]], 1.0).size == 0
    with pytest.raises(ScoringError, match="resolution"):
        voxel_keys([[0, 0, 0]], 0.0)
    with pytest.raises(ScoringError, match="shape"):
        voxel_keys_from_indices([[1, 2]])
    with pytest.raises(ScoringError, match="out of range"):
        voxel_keys_from_indices([[2**21, 0, 0]])


@given(st.lists(st.tuples(*(st.integers(-(2**20), 2**20 - 1),) * 3), min_size=1, max_size=50))
def test_voxel_keys_are_injective(ijk: list[tuple[int, int, int]]) -> None:
    keys = voxel_keys_from_indices(ijk)
    assert keys.size == len(set(ijk))


def test_voxel_accuracy_hand_computed() -> None:
    truth = voxel_keys_from_indices([[0, 0, 0], [1, 0, 0], [2, 0, 0], [9, 9, 0]])
    mapped = voxel_keys_from_indices([[0, 0, 0], [1, 0, 0], [1, 0, 5]])
    acc = voxel_accuracy(mapped, truth)
    assert (acc.n_common, acc.n_map, acc.n_truth) == (2, 3, 4)
    assert acc.iou == pytest.approx(2 / 5)
    assert acc.precision == pytest.approx(2 / 3)
    assert acc.recall == pytest.approx(2 / 4)
    # Columns the map has seen: (0,0) and (1,0); truth there: 2 voxels, both found.
    assert acc.recall_observed == pytest.approx(1.0)


def test_voxel_accuracy_empty_sets_are_nan_not_errors() -> None:
    acc = voxel_accuracy(np.zeros(0, np.int64), np.zeros(0, np.int64))
    assert math.isnan(acc.iou)
    assert math.isnan(acc.precision)


def grid(observed: np.ndarray, last_seen: np.ndarray | None = None, res: float = 2.0) -> GridSnapshot:
    layers = {"observed": observed.astype(np.float64)}
    if last_seen is not None:
        layers["last_seen_s"] = last_seen
    return GridSnapshot(t_s=0.0, resolution_m=res, origin_x_m=-4.0, origin_y_m=-4.0, layers=layers)


def test_mapped_area_counts_only_cells_inside_the_scene() -> None:
    obs = np.ones((4, 4))  # 8 m x 8 m grid from (-4, -4)
    assert mapped_area_m2(grid(obs), (-4.0, -4.0, 4.0, 4.0)) == pytest.approx(64.0)
    assert mapped_area_m2(grid(obs), (0.0, 0.0, 100.0, 100.0)) == pytest.approx(16.0)
    obs[0, 0] = 0
    assert mapped_area_m2(grid(obs), (-4.0, -4.0, 4.0, 4.0)) == pytest.approx(60.0)


def test_mean_cell_age() -> None:
    obs = np.array([[1, 1], [0, 1]])
    last = np.array([[10.0, 20.0], [math.nan, 30.0]])
    assert mean_cell_age_s(grid(obs, last), 40.0) == pytest.approx((30 + 20 + 10) / 3)
    assert math.isnan(mean_cell_age_s(grid(np.zeros((2, 2)), last), 40.0))


def test_grid_value_at_rows_are_south_first() -> None:
    g = GridSnapshot(0.0, 1.0, 0.0, 0.0, {"elevation_m": np.array([[1.0, 2.0], [3.0, 4.0]])})
    assert g.value_at("elevation_m", 0.5, 0.5) == 1.0
    assert g.value_at("elevation_m", 1.5, 1.5) == 4.0
    assert g.value_at("elevation_m", 0.5, 1.5) == 3.0
    assert math.isnan(g.value_at("elevation_m", -0.5, 0.5))


def test_path_length() -> None:
    assert path_length_m([0, 1, 2], [[0, 0, 0], [3, 4, 0], [3, 4, 2]]) == pytest.approx(7.0)
    assert path_length_m([0], [[1, 2, 3]]) == 0.0
    with pytest.raises(ScoringError, match="back in time"):
        path_length_m([1, 0], [[0, 0, 0], [1, 0, 0]])


def test_altitude_stats_ignore_takeoff_and_weight_by_time() -> None:
    t = [0, 1, 2, 3, 4, 6]
    h = [0, 5, 20, 20, 8, 20]  # takeoff below floor ignored; 2 s spent at 8 m
    stats = altitude_stats(t, h, floor_m=10.0)
    assert stats.min_m == 8.0
    assert stats.time_below_floor_s == pytest.approx(2.0)
    assert stats.airborne_s == pytest.approx(4.0)
    assert stats.mean_m == pytest.approx((20 * 1 + 20 * 1 + 8 * 2) / 4)
    never = altitude_stats([0, 1], [1, 2], floor_m=10.0)
    assert math.isnan(never.min_m)
    assert never.time_below_floor_s == 0.0


def test_battery_use_prefers_consumed_counter_then_integrates_current() -> None:
    counted = [BatterySample(0, 16.8, 100, 0.0), BatterySample(60, 16.0, 90, 250.0)]
    use = battery_use(counted)
    assert (use.used_mah, use.used_pct, use.min_voltage_v) == (250.0, 10.0, 16.0)
    integrated = [BatterySample(0, 16.8, 100, current_a=18.0), BatterySample(3600, 15.0, 20, current_a=18.0)]
    assert battery_use(integrated).used_mah == pytest.approx(18000.0)
    assert math.isnan(battery_use([]).used_mah)


def det(box: tuple[int, int, int, int], cls: str = "person", iid: int = 0) -> Detection:
    return Detection(iid, cls, 1.0, box, 10.0, 1.0, (0.0, 0.0, 0.0))


def test_bbox_iou() -> None:
    assert bbox_iou((0, 0, 9, 9), (0, 0, 9, 9)) == 1.0
    assert bbox_iou((0, 0, 9, 9), (10, 10, 19, 19)) == 0.0
    assert bbox_iou((0, 0, 9, 9), (5, 0, 14, 9)) == pytest.approx(50 / 150)


def test_match_detections_is_optimal_and_class_aware() -> None:
    truth = [det((0, 0, 9, 9)), det((20, 0, 29, 9)), det((40, 0, 49, 9), "vehicle")]
    hyp = [det((21, 0, 30, 9)), det((1, 0, 10, 9)), det((40, 0, 49, 9), "person"), det((90, 90, 99, 99))]
    matches, fn, fp = match_detections(truth, hyp)
    assert sorted(matches) == [(0, 1), (1, 0)]
    assert fn == [2]  # the vehicle was reported as a person: wrong class is a miss
    assert sorted(fp) == [2, 3]
    assert match_detections([], hyp)[2] == [0, 1, 2, 3]


def test_view_angle_and_bands() -> None:
    assert view_angle_deg((0, 0, 50), (0, 0, 0)) == pytest.approx(0.0)
    assert view_angle_deg((0, 0, 50), (50, 0, 0)) == pytest.approx(45.0)
    assert math.isnan(view_angle_deg((0, 0, 50), (math.nan, 0, 0)))
    edges = (0.0, 20.0, 40.0)
    assert [band_of(v, edges) for v in (0.0, 19.9, 20.0, 40.0, 41.0, -1.0, math.nan)] == [0, 0, 1, 1, -1, -1, -1]
    assert band_label(1, edges, "m") == "20-40 m"
    assert band_label(-1, edges) == "unknown"
