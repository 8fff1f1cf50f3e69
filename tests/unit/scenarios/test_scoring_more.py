"""Scoring pieces added with the scenario runs: fast voxel accuracy, grid downsampling, coverage
efficiency, the depth evaluator's message, depth statistics by context."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_msgs.msg import DepthMetrics, DepthStats
from uav_scenarios.core.config import ScoringSpec
from uav_scenarios.core.scoring.metrics import (
    coverage_efficiency,
    downsample_grid,
    voxel_accuracy,
    voxel_keys_from_indices,
)
from uav_scenarios.core.scoring.run import RunScorer
from uav_scenarios.core.scoring.types import Detection, DetectionFrame, GridSnapshot, PoseSample, SceneTruth
from uav_scenarios.ros.records import depth_metrics_from_msg


def test_voxel_accuracy_matches_set_arithmetic() -> None:
    rng = np.random.default_rng(4)
    truth = voxel_keys_from_indices(rng.integers(-40, 40, size=(5000, 3)))
    mapped = np.concatenate(
        [truth[rng.random(truth.size) < 0.3], voxel_keys_from_indices(rng.integers(50, 60, (300, 3)))]
    )
    acc = voxel_accuracy(mapped[rng.permutation(mapped.size)], truth)
    e, g = set(mapped.tolist()), set(truth.tolist())
    assert acc.n_common == len(e & g)
    assert acc.iou == pytest.approx(len(e & g) / len(e | g))
    assert acc.precision == pytest.approx(len(e & g) / len(e))
    assert acc.recall == pytest.approx(len(e & g) / len(g))
    cols = {k >> 21 for k in e}
    seen = {k for k in g if (k >> 21) in cols}
    assert acc.recall_observed == pytest.approx(len(e & g) / len(seen))
    assert acc.iou_observed == pytest.approx(len(e & g) / len(e | seen))
    empty = voxel_accuracy(np.zeros(0, np.int64), truth)
    assert empty.recall == 0.0
    assert math.isnan(empty.precision)


def test_downsample_grid_reduces_by_max_and_mean() -> None:
    elev = np.arange(16, dtype=np.float64).reshape(4, 4)
    elev[0, 0] = np.nan
    score = np.ones((4, 4))
    score[2:, 2:] = np.nan
    g = GridSnapshot(1.0, 0.5, -1.0, -1.0, {"elevation_m": elev, "score": score})
    d = downsample_grid(g, 2)
    assert d.shape == (2, 2)
    assert d.resolution_m == 1.0
    assert (d.origin_x_m, d.origin_y_m) == (-1.0, -1.0)
    assert d.layers["elevation_m"][0, 0] == 5.0  # block max, NaN ignored
    assert d.layers["elevation_m"][1, 1] == 15.0
    assert d.layers["score"][0, 0] == 1.0
    assert math.isnan(d.layers["score"][1, 1])  # no finite value in the block
    assert downsample_grid(g, 4) is g
    odd = downsample_grid(GridSnapshot(0.0, 1.0, 0.0, 0.0, {"x": np.ones((5, 3))}), 2)
    assert odd.shape == (2, 1)


def test_coverage_efficiency_of_a_straight_pass() -> None:
    # 100 m swath, 75 m along track, 10 m/s for 60 s: 600 m of new ground after the first footprint
    swath, along, v, t = 100.0, 75.0, 10.0, 60.0
    straight = swath * along + swath * v * t
    cov = coverage_efficiency(straight, t, swath_m=swath, along_m=along, speed_mps=v)
    assert cov.limit_m2_per_s == 1000.0
    assert cov.efficiency == pytest.approx(1.0)
    half = coverage_efficiency(swath * along + 0.5 * swath * v * t, t, swath_m=swath, along_m=along, speed_mps=v)
    assert half.efficiency == pytest.approx(0.5)
    assert math.isnan(coverage_efficiency(1.0, 0.0, swath_m=swath, along_m=along, speed_mps=v).efficiency)
    assert math.isnan(coverage_efficiency(1.0, 5.0, swath_m=swath, along_m=along, speed_mps=math.nan).efficiency)


def stats(label: str, n: int, within: float, abs_rel: float) -> DepthStats:
    return DepthStats(
        label=label, n_evaluated=n, n_covered=n, coverage=1.0, within_abs=within, within_rel=within,
        delta1=within, delta2=1.0, delta3=1.0, abs_rel=abs_rel, rmse_m=1.0, mae_m=0.5, bias_m=0.0,
        median_abs_err_m=0.4, range_min_m=math.nan, range_max_m=math.nan,
    )  # fmt: skip


def depth_msg(t: float, within: float) -> DepthMetrics:
    msg = DepthMetrics(camera="nadir", overall=stats("all", 100, within, 0.02))
    msg.header.stamp.secs, msg.header.stamp.nsecs = int(t), round((t % 1) * 1e9)
    msg.range_bands = [stats("0-20m", 0, math.nan, math.nan), stats("20-40m", 60, within, 0.01)]
    msg.classes = [stats("terrain", 80, within, 0.02), stats("building", 20, 0.5, 0.1)]
    return msg


def test_depth_metrics_message_to_sample() -> None:
    s = depth_metrics_from_msg(depth_msg(12.5, 0.9))
    assert s.t_s == pytest.approx(12.5)
    assert s.camera == "nadir"
    assert s.values["within_abs"] == pytest.approx(0.9)
    assert s.values["n_evaluated"] == 100
    assert set(s.breakdown["range"]) == {"20-40m"}  # empty bands are left out
    assert s.breakdown["class"]["building"]["within_abs"] == pytest.approx(0.5)


def test_depth_summary_by_context() -> None:
    scorer = RunScorer(spec=ScoringSpec(), truth=SceneTruth(bounds_m=(-10, -10, 10, 10)))
    level = (0.0, 0.0, 0.0, 1.0)
    tilted = (0.0, math.sin(math.radians(20) / 2), 0.0, math.cos(math.radians(20) / 2))  # pitched 20 deg
    scorer.add_pose(PoseSample(1.0, (0.0, 0.0, 30.0), 0.0, level))
    scorer.add_detections(DetectionFrame(1.0, "nadir", "ground_truth", (
        Detection(5, "person", 1.0, (0, 0, 3, 3), 30.0, 1.0, (0.0, 0.0, 0.0)),
        Detection(6, "vehicle", 1.0, (9, 9, 19, 19), 31.0, 1.0, (2.0, 0.0, 0.0)),
    )), is_truth=True)  # fmt: skip
    scorer.add_depth_metrics(depth_metrics_from_msg(depth_msg(1.0, 0.9)))
    scorer.add_pose(PoseSample(2.0, (0.0, 0.0, 50.0), 0.0, tilted))
    scorer.add_depth_metrics(depth_metrics_from_msg(depth_msg(2.0, 0.7)))
    d = scorer.summary(2.0)["depth"]
    assert d["frames"] == 2
    assert d["within_abs"] == pytest.approx(0.8)
    ctx = d["by_context"]
    assert ctx["altitude"]["20-40 m"]["within_abs"] == pytest.approx(0.9)
    assert ctx["altitude"]["40-60 m"]["within_abs"] == pytest.approx(0.7)
    assert ctx["view_angle"]["0-30 deg"]["frames"] == 2  # a 20 deg pitch stays in the first band
    assert ctx["clutter"]["1-3 objects"]["within_abs"] == pytest.approx(0.9)  # two objects in that nadir frame
    assert ctx["clutter"]["unknown"]["within_abs"] == pytest.approx(0.7)
    assert ctx["class"]["building"]["within_abs"] == pytest.approx(0.5)
    assert ctx["range"]["20-40m"]["frames"] == 2


def test_camera_off_nadir_angle() -> None:
    level = PoseSample(0.0, (0.0, 0.0, 10.0))
    assert level.camera_off_nadir_deg(90.0) == pytest.approx(0.0, abs=1e-9)
    assert level.camera_off_nadir_deg(25.0) == pytest.approx(65.0)
    half = math.radians(30) / 2
    pitched = PoseSample(0.0, (0.0, 0.0, 10.0), 0.0, (0.0, math.sin(half), 0.0, math.cos(half)))  # nose down 30
    assert pitched.camera_off_nadir_deg(25.0) == pytest.approx(35.0)
