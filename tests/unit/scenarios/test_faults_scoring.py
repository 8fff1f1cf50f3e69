"""Scripted faults: the schedule the mission manager sends, and what the scorer makes of a fault and what
followed it; the setpoint tracking error (pure parts)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_scenarios.core.config import FaultSpec, ScoringSpec
from uav_scenarios.core.faults import FaultSchedule, fault_actions
from uav_scenarios.core.scoring.faults import distance_to_polyline_m, fault_summary, tracking_stats
from uav_scenarios.core.scoring.run import RunScorer
from uav_scenarios.core.scoring.types import (
    ControllerSample,
    EstimateStatusSample,
    FaultSample,
    PathSample,
    PoseSample,
    SceneTruth,
    TargetSample,
)


def test_faults_become_mavlink_commands_in_time_order_each_sent_once() -> None:
    faults = (
        FaultSpec(at_s=60.0, unit="motor", type="wrong", instance=1),
        FaultSpec(at_s=20.0, unit="gps", type=False, duration_s=15.0),  # YAML's bare `off`
    )
    actions = fault_actions(faults)
    assert [(a.at_s, a.label, a.unit_code, a.type_code, a.instance) for a in actions] == [
        (20.0, "gps off", 4, 1, 0),
        (35.0, "gps ok (end of fault 1)", 4, 0, 0),
        (60.0, "motor 1 wrong", 101, 4, 1),
    ]
    schedule = FaultSchedule(actions)
    assert schedule.due(19.9) == []
    assert [a.label for a in schedule.due(36.0)] == ["gps off", "gps ok (end of fault 1)"]
    assert schedule.due(36.0) == []  # never twice
    assert schedule.next_at_s == 60.0
    assert [a.label for a in schedule.due(math.inf)] == ["motor 1 wrong"]
    assert schedule.next_at_s is None


def test_a_fault_and_what_followed_it() -> None:
    faults = [
        FaultSample(t_s=130.0, index=0, at_s=30.0, unit="gps", failure_type="off", result="ACCEPTED"),
        FaultSample(t_s=160.0, index=0, at_s=60.0, unit="gps", failure_type="ok", clear=True, result="ACCEPTED"),
    ]
    changes = [
        (120.0, "autopilot OFFBOARD"),  # before: not what followed
        (135.2, "autopilot AUTO.LAND"),
        (135.4, "controller LAND: autopilot left OFFBOARD"),
        (170.0, "controller IDLE: LAND complete: landed and disarmed"),
    ]
    out = fault_summary(faults, changes, start_s=100.0, end_s=170.0)
    assert [f["run_t_s"] for f in out] == [30.0, 60.0]
    assert [c["what"] for c in out[0]["followed"]] == [
        "autopilot AUTO.LAND",
        "controller LAND: autopilot left OFFBOARD",
    ]
    assert out[0]["followed"][0]["after_s"] == pytest.approx(5.2)
    assert [c["what"] for c in out[1]["followed"]] == ["controller IDLE: LAND complete: landed and disarmed"]
    assert out[1]["clear"]
    assert out[1]["type"] == "ok"


def test_the_run_scorer_records_faults_as_events_with_what_followed() -> None:
    s = RunScorer(spec=ScoringSpec(), truth=SceneTruth(bounds_m=(-100.0, -100.0, 100.0, 100.0)))
    s.start_t_s = 0.0
    s.add_controller(ControllerSample(1.0, "AUTONOMOUS", "OFFBOARD", armed=True, in_air=True))
    s.add_fault(FaultSample(10.0, 0, 10.0, "gps", "off", result="ACCEPTED", detail="Failure injected: gps off"))
    s.add_controller(ControllerSample(15.5, "AUTONOMOUS", "AUTO.LAND", armed=True, in_air=True))
    s.add_controller(
        ControllerSample(15.6, "LAND", "AUTO.LAND", True, True, "autopilot left OFFBOARD: now in AUTO.LAND")
    )
    s.add_estimate_status(EstimateStatusSample(17.0, "STALE", reason="no fresh estimate for 1.2 s"))
    m = s.summary(20.0)
    assert "fault gps off: ACCEPTED (Failure injected: gps off)" in [e["what"] for e in m["events"]]
    (fault,) = m["faults"]
    assert (fault["unit"], fault["type"], fault["result"], fault["run_t_s"]) == ("gps", "off", "ACCEPTED", 10.0)
    assert [c["what"] for c in fault["followed"]] == [
        "autopilot AUTO.LAND",
        "controller LAND: autopilot left OFFBOARD: now in AUTO.LAND",
        "pose estimate STALE: no fresh estimate for 1.2 s",
    ]


def test_distance_to_a_path() -> None:
    path = [(0.0, 0.0, 10.0), (100.0, 0.0, 10.0), (100.0, 50.0, 10.0)]
    assert distance_to_polyline_m((50.0, 3.0, 10.0), path) == pytest.approx(3.0)
    assert distance_to_polyline_m((103.0, 25.0, 14.0), path) == pytest.approx(5.0)
    assert distance_to_polyline_m((-3.0, 0.0, 14.0), path) == pytest.approx(5.0)  # beyond the start: its end
    assert distance_to_polyline_m((1.0, 1.0, 1.0), [(1.0, 1.0, 2.0)]) == pytest.approx(1.0)
    assert math.isnan(distance_to_polyline_m((0.0, 0.0, 0.0), np.zeros((0, 3))))


def test_setpoint_tracking_error_grows_with_the_push_off_the_path() -> None:
    def run(offset_m: float) -> dict[str, float]:
        s = RunScorer(spec=ScoringSpec(), truth=SceneTruth(bounds_m=(-500.0, -500.0, 500.0, 500.0)))
        s.add_controller(ControllerSample(0.0, "AUTONOMOUS", "OFFBOARD", armed=True, in_air=True))
        s.add_path(PathSample(0.0, ((0.0, 0.0, 30.0), (200.0, 0.0, 30.0))))
        for k in range(200):  # 20 s at 10 Hz along the path, pushed sideways by a growing gust
            t = 0.1 * k
            s.add_pose(PoseSample(t, (8.0 * t, offset_m * math.sin(0.3 * t), 30.0)))
        s.add_controller(ControllerSample(20.0, "HOLD", "OFFBOARD", armed=True, in_air=True))
        s.add_pose(PoseSample(20.1, (160.0, 50.0, 30.0)))  # not AUTONOMOUS: not scored
        return s.summary(20.1)["setpoint_tracking"]

    calm, windy = run(0.0), run(4.0)
    assert calm["samples"] == windy["samples"] == 200
    assert calm["rms_m"] == pytest.approx(0.0, abs=1e-9)
    assert windy["rms_m"] == pytest.approx(4.0 / math.sqrt(2), rel=0.05)
    assert 3.8 < windy["p95_m"] <= windy["max_m"] <= 4.0
    assert tracking_stats([])["samples"] == 0


def test_autopilot_tracking_measures_the_truth_against_the_autopilots_own_target() -> None:
    s = RunScorer(spec=ScoringSpec(), truth=SceneTruth(bounds_m=(-500.0, -500.0, 500.0, 500.0)))
    s.add_target(TargetSample(0.0, (10.0, 20.0, 30.0)))  # a hold point: any mode, no controller needed
    for k in range(100):  # 10 s at 50 Hz: scored at most 10 times a second
        t = 0.02 * k
        s.add_pose(PoseSample(t, (10.0 + 0.3, 20.0 - 0.4, 31.0)))
        if k % 5 == 0:
            s.add_target(TargetSample(t, (10.0, 20.0, 30.0)))
    s.add_target(TargetSample(2.0, (math.nan, 0.0, 0.0)))  # non-finite: ignored
    s.add_pose(PoseSample(3.5, (0.0, 0.0, 0.0)))  # the target is 1.5 s old: not scored
    at = s.summary(4.0)["autopilot_tracking"]
    assert at["samples"] == 20
    assert at["horizontal_rms_m"] == pytest.approx(0.5)
    assert at["horizontal_max_m"] == pytest.approx(0.5)
    assert at["rms_m"] == pytest.approx(math.hypot(0.5, 1.0))
    empty = RunScorer(spec=ScoringSpec(), truth=SceneTruth(bounds_m=(-1.0, -1.0, 1.0, 1.0))).summary(1.0)
    assert empty["autopilot_tracking"]["samples"] == 0
    assert math.isnan(empty["autopilot_tracking"]["horizontal_rms_m"])
