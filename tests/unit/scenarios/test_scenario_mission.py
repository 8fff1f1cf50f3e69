"""Mission logic: stop criteria, confirmation gate, resuming after a controller yield."""

from __future__ import annotations

import math

import pytest
from helpers.paths import REPO

from uav_scenarios.core.config import StopCriteria, load_scenario
from uav_scenarios.core.mission import (
    ConfirmationGate,
    Phase,
    StopReason,
    check_stop,
    controller_state_for,
    flying_phase,
    point_in_polygon,
    resume_needed,
)
from uav_scenarios.core.scoring.types import Detection


def stop_of(stop: StopCriteria, **kw: float | int | bool | None) -> StopReason | None:
    args: dict = {
        "elapsed_s": 0.0,
        "mapped_pct": math.nan,
        "battery_pct": math.nan,
        "collisions": 0,
        "crashed": False,
        "found_for_s": None,
        "wall_elapsed_s": 0.0,
    }
    args.update(kw)
    return check_stop(stop, **args)


def test_stop_criteria_in_order() -> None:
    stop = StopCriteria(time_limit_s=100, mapped_pct=50, target_found=True, battery_reserve_pct=20, wall_timeout_s=60)
    assert stop_of(stop) is None
    assert stop_of(stop, elapsed_s=100) is StopReason.TIME_LIMIT
    assert stop_of(stop, mapped_pct=50.0) is StopReason.MAPPED
    assert stop_of(stop, found_for_s=1.0) is None  # hold over the person first
    assert stop_of(stop, found_for_s=5.0) is StopReason.TARGET_FOUND
    assert stop_of(stop, battery_pct=19.0, found_for_s=9.0) is StopReason.BATTERY_RESERVE
    assert stop_of(stop, collisions=1, battery_pct=10.0) is StopReason.COLLISION
    assert stop_of(stop, crashed=True, collisions=1) is StopReason.CRASHED
    assert stop_of(stop, wall_elapsed_s=61) is StopReason.WALL_TIMEOUT
    lenient = StopCriteria(on_collision=False, battery_reserve_pct=None)
    assert stop_of(lenient, collisions=3, battery_pct=1.0) is None


def person(x: float, y: float, iid: int = 7) -> Detection:
    return Detection(iid, "person", 1.0, (0, 0, 1, 1), 50.0, 1.0, (x, y, 0.0))


def test_confirmation_needs_n_detections_in_window_at_one_place() -> None:
    gate = ConfirmationGate(needed=3, window_s=2.0, gate_m=5.0)
    assert gate.update(0.0, (person(10, 10),)) is None
    assert gate.update(3.0, (person(10.5, 10),)) is None  # the first fell out of the window
    assert gate.update(3.5, (person(100, 100, 8),)) is None  # elsewhere: another cluster
    assert gate.update(3.6, (Detection(9, "vehicle", 1, (0, 0, 1, 1), 5, 1, (10, 10, 0)),)) is None
    assert gate.update(3.8, (person(math.nan, 10),)) is None  # no position: cannot confirm
    assert gate.update(3.9, (person(10.2, 10),)) is None  # two in the window
    found = gate.update(4.0, (person(9.3, 10),))
    assert found is not None
    assert found.t_s == 4.0
    assert found.instance_id == 7
    assert found.position_m[0] == pytest.approx(10.0)
    assert gate.update(9.0, ()) is found


def test_point_in_polygon() -> None:
    square = ((0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0))
    assert point_in_polygon(5, 5, square)
    assert not point_in_polygon(15, 5, square)


def test_gate_confirms_only_the_person_of_interest() -> None:
    gate = ConfirmationGate(needed=2, window_s=5.0, instance_id=42)
    other = Detection(7, "person", 1.0, (0, 0, 5, 5), 50.0, 1.0, (10.0, 0.0, 0.0))
    assert gate.update(1.0, (other,)) is None
    assert gate.update(2.0, (other,)) is None  # someone else, however often
    unknown = Detection(0, "person", 0.8, (0, 0, 5, 5), 50.0, 1.0, (30.0, 0.0, 0.0))
    assert gate.update(3.0, (unknown,)) is None
    found = gate.update(4.0, (unknown,))  # a detector that cannot tell people apart counts
    assert found is not None
    assert found.position_m[0] == pytest.approx(30.0)


def test_resume_after_a_yield_in_the_air_only() -> None:
    args = {"in_air": True, "link_ok": True, "autopilot_mode": "AUTO.LOITER"}
    assert resume_needed(Phase.LOITERING, "IDLE", **args)
    assert resume_needed(Phase.HOLDING, "IDLE", **args)
    assert not resume_needed(Phase.LOITERING, "AUTONOMOUS", **args)
    assert not resume_needed(Phase.TAKEOFF, "IDLE", **args)
    assert not resume_needed(Phase.DONE, "IDLE", **args)
    assert not resume_needed(Phase.SEARCHING, "IDLE", **{**args, "in_air": False})
    assert not resume_needed(Phase.SEARCHING, "IDLE", **{**args, "link_ok": False})
    assert not resume_needed(Phase.SEARCHING, "IDLE", **{**args, "autopilot_mode": "AUTO.RTL"})


def test_phases_and_controller_states() -> None:
    loiter = load_scenario(REPO / "config/scenarios/loiter.yaml")
    sar = load_scenario(REPO / "config/scenarios/search_and_rescue.yaml")
    mower = load_scenario(REPO / "config/scenarios/sar_lawnmower.yaml")
    assert flying_phase(loiter) is Phase.LOITERING
    assert flying_phase(sar) is Phase.SEARCHING
    assert controller_state_for(sar) == "AUTONOMOUS"
    assert controller_state_for(mower) == "SCRIPTED"


def placed(x: float, y: float, score: float = 0.9, sigma_m: float = 1.0) -> Detection:
    """A box-only detector's person, placed by the geolocator (instance id 0, a covariance)."""
    cov = (sigma_m**2, 0.0, 0.0, 0.0, sigma_m**2, 0.0, 0.0, 0.0, 1.0)
    return Detection(0, "person", score, (0, 0, 5, 5), 50.0, math.nan, (x, y, 0.0), cov, "elevation")


def test_the_gate_counts_what_it_cannot_use_and_never_drops_it_unseen() -> None:
    area = ((-50.0, -50.0), (50.0, -50.0), (50.0, 50.0), (-50.0, 50.0))
    gate = ConfirmationGate(needed=2, window_s=5.0, min_score=0.5, area=area)
    unplaced = Detection(0, "person", 0.9, (0, 0, 5, 5), 50.0, math.nan, (math.nan,) * 3, (), "unplaced:no_surface")
    frames = [
        (unplaced, placed(0, 0, score=0.2)),  # no position; below the operating threshold
        (placed(0, 0, sigma_m=25.0), placed(80, 0)),  # placed too vaguely to be a place; outside the search area
        (placed(80, 0), unplaced),
    ]
    for k, frame in enumerate(frames):
        assert gate.update(float(k), frame) is None
    assert (gate.unplaced, gate.below_threshold, gate.too_uncertain, gate.outside_area, gate.used) == (2, 1, 1, 2, 0)
    assert gate.update(3.0, (placed(10, 10),)) is None
    found = gate.update(3.5, (placed(10.5, 10),))
    assert found is not None
    assert found.position_m[:2] == pytest.approx((10.25, 10.0))


def test_the_operator_check_turns_down_a_bystander_and_the_search_goes_on() -> None:
    gate = ConfirmationGate(needed=2, window_s=5.0, verify_xy=(40.0, 0.0))
    assert gate.update(0.0, (placed(0, 0),)) is None
    assert gate.update(0.5, (placed(0.5, 0),)) is None  # a candidate, but 40 m from the person searched for
    assert len(gate.rejections) == 1
    assert gate.rejections[0].position_m[0] == pytest.approx(0.25)
    assert gate.update(1.0, (placed(0.2, 0), placed(0.1, 0))) is None  # the same bystander again: absorbed
    assert gate.update(2.0, (placed(39.0, 1.0),)) is None
    found = gate.update(2.5, (placed(39.5, 0.5),))
    assert found is not None
    assert found.position_m[0] == pytest.approx(39.25)
    assert len(gate.rejections) == 1
    # without the check the first candidate ends the search, right or wrong
    blind = ConfirmationGate(needed=2, window_s=5.0)
    blind.update(0.0, (placed(0, 0),))
    wrong = blind.update(0.5, (placed(0.5, 0),))
    assert wrong is not None
    assert wrong.position_m[0] == pytest.approx(0.25)
