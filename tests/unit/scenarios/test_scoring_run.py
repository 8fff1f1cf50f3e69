"""The run scorer on a synthetic run with a known answer."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from uav_scenarios.core.config import ScoringSpec
from uav_scenarios.core.scoring.metrics import voxel_keys_from_indices
from uav_scenarios.core.scoring.run import RunScorer, swath_width_m
from uav_scenarios.core.scoring.types import (
    BatterySample,
    CollisionEvent,
    ControllerSample,
    DepthMetricsSample,
    Detection,
    DetectionFrame,
    GoalSample,
    GridSnapshot,
    PoseSample,
    SceneTruth,
    Track,
    TrackFrame,
)

PERSON = 42


def person(x: float, box: tuple[int, int, int, int] = (100, 100, 120, 150), iid: int = PERSON) -> Detection:
    return Detection(iid, "person", 1.0, box, 60.0, 0.9, (x, -300.0, 0.0))


def make_scorer(source: str = "ground_truth") -> RunScorer:
    truth = SceneTruth(
        bounds_m=(-50.0, -50.0, 50.0, 50.0),
        surface_keys=voxel_keys_from_indices([[i, j, 0] for i in range(4) for j in range(4)]),
        surface_resolution_m=1.0,
    )
    return RunScorer(
        spec=ScoringSpec(),
        truth=truth,
        detection_source=source,
        person_id=PERSON,
        cruise_speed_mps=5.0,
        swath_m_per_m=2.0,
    )


def fly(scorer: RunScorer) -> None:
    """Climb to 30 m in 10 s, then fly east at 5 m/s for 20 s."""
    for k in range(31):
        t = float(k)
        z = min(30.0, 3.0 * t)
        x = max(0.0, 5.0 * (t - 10.0))
        scorer.add_pose(PoseSample(t, (x, 0.0, z)))
        scorer.add_battery(BatterySample(t, 16.0 - 0.01 * t, 100.0 - 0.5 * t, 10.0 * t))
        if k % 10 == 0:
            scorer.add_controller(ControllerSample(t, "TAKEOFF" if k < 10 else "AUTONOMOUS"))
            scorer.add_goal(GoalSample(t, (float(k), 0.0, 0.0), "new_best"))


def test_flight_battery_and_coverage() -> None:
    scorer = make_scorer()
    fly(scorer)
    observed = np.zeros((10, 10))
    observed[:5, :] = 1.0  # south half of a 100 m x 100 m grid at 10 m
    last = np.where(observed > 0, 20.0, np.nan)
    scorer.add_layers(GridSnapshot(30.0, 10.0, -50.0, -50.0, {"observed": observed, "last_seen_s": last}))
    scorer.add_map_keys(30.0, voxel_keys_from_indices([[0, 0, 0], [1, 1, 0], [7, 7, 7]]))
    s = scorer.summary(30.0)
    assert s["flight"]["distance_m"] == pytest.approx(30.0 + 100.0)
    assert s["flight"]["agl_min_m"] == pytest.approx(12.0)  # from the first sample above the 10 m floor
    assert s["flight"]["time_below_floor_s"] == 0.0
    assert s["battery"]["used_mah"] == pytest.approx(300.0)
    assert s["battery"]["used_pct"] == pytest.approx(15.0)
    assert s["coverage"]["mapped_pct"] == pytest.approx(50.0)
    # airborne from the first sample above 1 m (t = 1 s) to 30 s
    assert s["time"]["airborne_s"] == pytest.approx(29.0)
    assert s["coverage"]["rate_m2_per_s"] == pytest.approx(5000.0 / 29.0)
    # time-weighted mean AGL from t = 4 s (12 m) on: (12+15+18+21+24+27 + 21*30) / 26
    assert s["flight"]["agl_mean_m"] == pytest.approx((117.0 + 20 * 30.0) / 26.0)
    assert s["coverage"]["swath_limit_m2_per_s"] == pytest.approx(2.0 * s["flight"]["agl_mean_m"] * 5.0)
    assert s["map_accuracy"]["iou"] == pytest.approx(2 / 17)
    assert s["map_accuracy"]["precision"] == pytest.approx(2 / 3)
    assert s["flight"]["goals"] == 4
    row = scorer.sample(30.0)
    assert row["mean_cell_age_s"] == pytest.approx(10.0)
    assert row["controller_state"] == "AUTONOMOUS"
    json.dumps(s)  # plain data


def test_detector_under_test_counts_and_context() -> None:
    scorer = make_scorer(source="yolo")
    fly(scorer)
    for k in range(5):
        t = 31.0 + 0.2 * k
        truth = DetectionFrame(t, "forward", "ground_truth", (person(10.0), person(60.0, (300, 100, 320, 150), 43)))
        scorer.add_detections(truth, is_truth=True)
        # the detector's range is its geolocator's estimate (75 m): the first detection reports the true one
        hyp_dets = (dataclasses.replace(person(10.0, iid=0), range_m=75.0),) if k != 2 else ()
        if k == 4:
            hyp_dets += (person(99.0, (500, 400, 510, 420), 0),)
        scorer.add_detections(DetectionFrame(t, "forward", "yolo", hyp_dets), is_truth=False)
    d = scorer.summary(32.0)["detection"]
    assert (d["frames"], d["tp"], d["fn"], d["fp"]) == (5, 4, 6, 1)
    assert d["precision"] == pytest.approx(4 / 5)
    assert d["recall"] == pytest.approx(4 / 10)
    assert d["person_first_in_view"]["t_s"] == pytest.approx(31.0)
    assert d["person_first_detected"]["t_s"] == pytest.approx(31.0)
    assert d["person_first_detected"]["range_m"] == pytest.approx(60.0)
    by_alt = d["by_context"]["altitude"]
    assert by_alt["20-40 m"]["tp"] == 4
    assert d["by_context"]["clutter"]["1-3 objects"]["fn"] == 6
    assert d["by_context"]["range"]["50-75 m"]["tp"] == 4
    # The drone is at (100, 0, 30); the person 300 m away: a shallow look, 60-90 deg off nadir.
    assert d["by_context"]["view_angle"]["60-90 deg"]["tp"] == 4


def test_ground_truth_as_detector_is_perfect_and_tracking_scored() -> None:
    scorer = make_scorer()
    fly(scorer)
    for k in range(10):
        t = 31.0 + 0.2 * k
        frame = DetectionFrame(t, "forward", "ground_truth", (person(10.0 + k),))
        scorer.add_detections(frame, is_truth=True)
        tracks = (Track(5 if k < 6 else 6, "person", (10.0 + k, -300.0, 0.0)),) if k > 0 else ()
        scorer.add_tracks(TrackFrame(t, "forward", tracks))
    s = scorer.summary(33.0)
    assert (s["detection"]["tp"], s["detection"]["fp"], s["detection"]["fn"]) == (10, 0, 0)
    tr = s["tracking"]
    assert tr["num_frames"] == 10
    assert tr["id_switches"] == 1
    assert tr["num_misses"] == 1
    assert tr["mota"] == pytest.approx(1 - 2 / 10)
    assert "20-40 m" in tr["by_context"]["altitude"]


def test_collisions_depth_events_and_completion() -> None:
    scorer = make_scorer()
    fly(scorer)
    scorer.add_collision(CollisionEvent(20.0, 9, "tree", (50.0, 0.0, 30.0), 5.0))
    scorer.add_depth_metrics(DepthMetricsSample(20.0, {"abs_rel": 0.1, "within_1m": 0.8}))
    scorer.add_depth_metrics(DepthMetricsSample(21.0, {"abs_rel": 0.3, "within_1m": math.nan}))
    scorer.mark_complete(25.0, "person confirmed")
    scorer.mark_complete(26.0, "again")
    s = scorer.summary(30.0)
    assert s["collisions"]["count"] == 1
    assert s["depth"]["abs_rel"] == pytest.approx(0.2)
    assert s["depth"]["within_1m"] == pytest.approx(0.8)
    assert s["depth"]["by_context"]["altitude"]["20-40 m"]["frames"] == 2
    assert s["time"]["complete_s"] == pytest.approx(25.0)
    whats = [e["what"] for e in s["events"]]
    assert "controller AUTONOMOUS" in whats
    assert "complete: person confirmed" in whats
    assert "complete: again" not in whats


def test_swath_width() -> None:
    assert swath_width_m(50.0, 90.0) == pytest.approx(100.0)
