"""Position tracker and MOT evaluation."""

from __future__ import annotations

import numpy as np
import pytest

from uav_scenarios.core.scoring.types import Detection
from uav_scenarios.core.tracking import MotScorer, PositionTracker, TrackerConfig
from uav_scenarios.errors import ScoringError


def det(x: float, y: float, cls: str = "person") -> Detection:
    return Detection(0, cls, 1.0, (0, 0, 1, 1), 50.0, 1.0, (x, y, 0.0))


def walk(
    n: int, rng: np.random.Generator, noise_m: float
) -> list[tuple[float, list[Detection], list[tuple[int, float, float]]]]:
    """Two people walking apart at 1.5 m/s plus a parked vehicle, seen at 5 Hz."""
    frames = []
    for k in range(n):
        t = 0.2 * k
        truth = [(11, 1.5 * t, 0.0), (12, -1.5 * t, 40.0), (13, 20.0, 20.0)]
        dets = [
            det(x + rng.normal(0, noise_m), y + rng.normal(0, noise_m), "vehicle" if iid == 13 else "person")
            for iid, x, y in truth
        ]
        frames.append((t, dets, truth))
    return frames


def test_tracker_keeps_identities_and_scores_perfectly_without_noise() -> None:
    tracker = PositionTracker(TrackerConfig(gate_m=3.0, min_hits=1))
    mot = MotScorer(gate_m=2.0)
    ids_seen: set[int] = set()
    for t, dets, truth in walk(50, np.random.default_rng(0), 0.0):
        tracks = tracker.update(t, dets)
        ids_seen |= {tr.track_id for tr in tracks}
        mot.update(
            [i for i, _, _ in truth],
            [(x, y) for _, x, y in truth],
            [tr.track_id for tr in tracks],
            [tr.position_m[:2] for tr in tracks],
        )
    result = mot.result()
    assert ids_seen == {1, 2, 3}
    assert result.mota == pytest.approx(1.0)
    assert result.idf1 == pytest.approx(1.0)
    assert result.id_switches == 0
    assert result.num_frames == 50


def test_tracker_estimates_velocity_under_noise() -> None:
    tracker = PositionTracker(TrackerConfig(gate_m=4.0, min_hits=2))
    velocities: dict[int, list[float]] = {}
    classes: dict[int, str] = {}
    for k, (t, dets, _) in enumerate(walk(80, np.random.default_rng(1), 0.3)):
        for tr in tracker.update(t, dets):
            classes[tr.track_id] = tr.class_name
            if k >= 30:  # after the filter settles; alpha-beta velocity noise is ~0.4 m/s per frame here
                velocities.setdefault(tr.track_id, []).append(tr.velocity_mps[0])
    mean_vx = sorted(float(np.mean(v)) for v in velocities.values())
    assert len(mean_vx) == 3  # no track was lost and re-born
    assert mean_vx[0] == pytest.approx(-1.5, abs=0.25)
    assert mean_vx[1] == pytest.approx(0.0, abs=0.25)
    assert mean_vx[2] == pytest.approx(1.5, abs=0.25)
    assert sorted(classes.values()) == ["person", "person", "vehicle"]


def test_min_hits_and_coasting() -> None:
    tracker = PositionTracker(TrackerConfig(min_hits=2, max_coast_s=1.0))
    assert tracker.update(0.0, [det(0, 0)]) == ()  # tentative
    assert len(tracker.update(0.1, [det(0.1, 0)])) == 1
    assert tracker.update(0.5, []) == ()  # coasting tracks are not reported
    tracker.update(2.0, [])  # dropped after 1 s without update
    (new,) = tracker.update(2.1, [det(0.2, 0)]) or (None,)
    assert new is None  # a fresh, tentative track (id 2)
    assert tracker.update(2.2, [det(0.2, 0)])[0].track_id == 2


def test_detections_without_position_or_below_threshold_are_counted_not_tracked() -> None:
    tracker = PositionTracker(TrackerConfig(min_hits=1, min_score=0.5))
    unplaced = Detection(0, "person", 0.9, (0, 0, 1, 1), 5.0, 1.0)  # the geolocator could not place it (NaN)
    weak = Detection(0, "person", 0.3, (0, 0, 1, 1), 5.0, 1.0, (1.0, 1.0, 0.0))
    tracks = tracker.update(0.0, [unplaced, weak, det(10.0, 0.0)])
    assert [t.position_m[:2] for t in tracks] == [(10.0, 0.0)]
    assert (tracker.received, tracker.unplaced, tracker.below_threshold) == (3, 1, 1)


def test_out_of_order_frames_rejected() -> None:
    tracker = PositionTracker()
    tracker.update(1.0, [])
    with pytest.raises(ScoringError, match="out of order"):
        tracker.update(0.5, [])


def test_mot_counts_switch_miss_and_false_positive() -> None:
    mot = MotScorer(gate_m=1.0)
    mot.update([1], [(0.0, 0.0)], [7], [(0.1, 0.0)])
    mot.update([1], [(1.0, 0.0)], [8], [(1.1, 0.0)])  # identity switch 7 -> 8
    mot.update([1], [(2.0, 0.0)], [], [])  # miss
    mot.update([], [], [9], [(5.0, 5.0)])  # false positive
    r = mot.result()
    assert (r.id_switches, r.num_misses, r.num_false_positives, r.num_matches) == (1, 1, 1, 1)
    assert r.mota == pytest.approx(1 - (1 + 1 + 1) / 3)
    assert r.motp_rms_m == pytest.approx(0.1)


def test_empty_mot_is_nan() -> None:
    r = MotScorer(gate_m=1.0).result()
    assert r.num_frames == 0
    assert np.isnan(r.mota)
