"""MCDM: weighted sum, argmax with deterministic ties, weights, hysteresis."""

from __future__ import annotations

import math

import numpy as np
import pytest

from uav_autonomy.core.features import FeatureMaps
from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.core.mcdm import (
    GoalReasonKind,
    GoalSelector,
    GoalSelectorConfig,
    argmax_cell,
    validate_weights,
    weighted_score,
)
from uav_autonomy.errors import InvalidInputError
from uav_common.config import ConfigError, from_mapping

SPEC = GridSpec(10.0, 0.0, 0.0, width=10, height=1)  # cells centred at x = 5, 15, ..., 95


def _maps(frontier: list[float], drone: list[float] | None = None) -> FeatureMaps:
    f = np.asarray([frontier], dtype=np.float32)
    d = np.zeros_like(f) if drone is None else np.asarray([drone], dtype=np.float32)
    zeros = np.zeros_like(f)
    return FeatureMaps(
        SPEC,
        {
            "elevation_m": np.arange(10, dtype=np.float32)[None, :],
            "age": zeros,
            "frontier": f,
            "target": zeros,
            "drone": d,
            "origin": zeros,
        },
    )


def test_weighted_score_hand_computed() -> None:
    a = np.array([[1.0, 0.0], [0.5, 0.25]], dtype=np.float32)
    b = np.array([[0.0, 1.0], [0.5, 1.0]], dtype=np.float32)
    s = weighted_score({"age": a, "frontier": b}, {"age": 2.0, "frontier": 1.0, "target": 0.0})
    np.testing.assert_allclose(s, [[2.0, 1.0], [1.5, 1.5]])
    with pytest.raises(InvalidInputError, match="'target' has weight"):
        weighted_score({"age": a}, {"target": 1.0})


def test_argmax_ties_are_row_major_and_nan_never_wins() -> None:
    s = np.array([[0.0, 2.0, 2.0], [2.0, 1.0, 0.0]], dtype=np.float32)
    assert argmax_cell(s) == (0, 1)
    s[0, 0] = math.nan
    assert argmax_cell(s) == (0, 1)
    with pytest.raises(InvalidInputError, match="NaN"):
        argmax_cell(np.full((2, 2), math.nan, dtype=np.float32))


def test_weights_validation() -> None:
    assert validate_weights({"target": 2.0})["frontier"] == 0.0
    with pytest.raises(InvalidInputError, match="unknown feature"):
        validate_weights({"novelty": 1.0})
    with pytest.raises(InvalidInputError, match="finite"):
        validate_weights({"age": math.inf})
    with pytest.raises(ConfigError, match="unknown feature"):
        from_mapping(GoalSelectorConfig, {"weights": {"novelty": 1.0}}, source="test")


def test_weights_change_the_argmax() -> None:
    sel = GoalSelector(GoalSelectorConfig(weights={"frontier": 1.0, "drone": 0.0}))
    maps = _maps([0, 0, 0, 0, 0, 0, 0, 0, 0, 1.0], drone=[1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    assert sel.select(maps, drone_xy_m=None).cell == (0, 9)
    sel.set_weights({"frontier": 1.0, "drone": 2.0})
    d = sel.select(maps, drone_xy_m=None)
    assert d.cell == (0, 0)
    assert d.reason is GoalReasonKind.WEIGHTS_CHANGED
    with pytest.raises(InvalidInputError):
        sel.set_weights({"frontier": math.nan})
    assert sel.weights["drone"] == 2.0  # a rejected update changes nothing


def test_decision_reports_contributions() -> None:
    sel = GoalSelector(GoalSelectorConfig(weights={"frontier": 2.0, "drone": 0.5}))
    d = sel.select(_maps([0.1] * 9 + [0.8], drone=[0.0] * 9 + [0.4]), drone_xy_m=None)
    assert d.reason is GoalReasonKind.INITIAL
    assert d.changed
    assert d.goal_xy_m == (95.0, 5.0)
    assert d.elevation_m == 9.0
    assert d.contributions["frontier"] == pytest.approx(1.6)
    assert d.contributions["drone"] == pytest.approx(0.2)
    assert d.score == pytest.approx(sum(d.contributions.values()), abs=1e-6)


def test_hysteresis_keeps_goal_until_clearly_better() -> None:
    cfg = GoalSelectorConfig(
        weights={"frontier": 1.0}, switch_margin=0.1, min_goal_separation_m=25.0, clear_improvement_margin=0.3
    )
    sel = GoalSelector(cfg)
    base = [0.0] * 10
    first = sel.select(_maps([*base[:9], 0.5]), drone_xy_m=(0.0, 0.0))
    assert first.cell == (0, 9)
    # A far cell slightly better: kept.
    slightly = sel.select(_maps([0.55, *base[1:9], 0.5]), drone_xy_m=(0.0, 0.0))
    assert slightly.cell == (0, 9)
    assert slightly.reason is GoalReasonKind.HYSTERESIS_KEPT
    assert not slightly.changed
    # A far cell better by more than switch_margin: switch.
    far = sel.select(_maps([0.65, *base[1:9], 0.5]), drone_xy_m=(50.0, 0.0))
    assert far.cell == (0, 0)
    assert far.reason is GoalReasonKind.NEW_BEST
    assert far.changed
    # A nearby cell (10 m away) better by 0.2 (< clear margin 0.3): kept.
    near = sel.select(_maps([0.65, 0.85, *base[2:]]), drone_xy_m=(50.0, 0.0))
    assert near.cell == (0, 0)
    assert near.reason is GoalReasonKind.HYSTERESIS_KEPT
    # Nearby and clearly better: switch.
    clear = sel.select(_maps([0.65, 1.0, *base[2:]]), drone_xy_m=(50.0, 0.0))
    assert clear.cell == (0, 1)
    assert clear.reason is GoalReasonKind.CLEARLY_BETTER_NEARBY


def test_reaching_the_goal_moves_on_beyond_the_separation() -> None:
    cfg = GoalSelectorConfig(weights={"frontier": 1.0}, min_goal_separation_m=25.0, goal_reached_radius_m=5.0)
    sel = GoalSelector(cfg)
    values = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    assert sel.select(_maps(values), drone_xy_m=(0.0, 0.0)).cell == (0, 9)
    d = sel.select(_maps(values), drone_xy_m=(94.0, 5.0))
    # Cells within 25 m of x = 95 (x = 75, 85, 95) are excluded: the best left is x = 65.
    assert d.reason is GoalReasonKind.GOAL_REACHED
    assert d.cell == (0, 6)


def test_target_moved_bypasses_hysteresis() -> None:
    sel = GoalSelector(GoalSelectorConfig(weights={"frontier": 1.0}, switch_margin=0.5))
    sel.select(_maps([0.0] * 9 + [0.5]), drone_xy_m=None)
    sel.target_moved()
    d = sel.select(_maps([0.6] + [0.0] * 8 + [0.5]), drone_xy_m=None)
    assert d.cell == (0, 0)
    assert d.reason is GoalReasonKind.TARGET_MOVED


def test_an_unreachable_goal_is_dropped_and_its_surroundings_avoided_until_the_retry() -> None:
    # The best cells (x = 85, 95) lie on a hill the planner cannot reach: without the report the selector
    # would hold x = 95 forever (hysteresis) while the drone hovers short of it.
    cfg = GoalSelectorConfig(
        weights={"frontier": 1.0}, switch_margin=0.05, unreachable_radius_m=15.0, unreachable_retry_s=60.0
    )
    sel = GoalSelector(cfg)
    values = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]
    assert sel.select(_maps(values), drone_xy_m=(0.0, 0.0), now_s=10.0).cell == (0, 9)
    assert sel.select(_maps(values), drone_xy_m=(0.0, 0.0), now_s=11.0).reason is GoalReasonKind.HYSTERESIS_KEPT
    sel.mark_unreachable((95.0, 5.0), now_s=12.0)
    d = sel.select(_maps(values), drone_xy_m=(0.0, 0.0), now_s=12.0)
    # x = 85 and 95 are within 15 m of the unreachable goal: the best reachable cell is x = 75.
    assert (d.cell, d.reason, d.changed) == ((0, 7), GoalReasonKind.GOAL_UNREACHABLE, True)
    assert d.score == pytest.approx(0.8)
    assert sel.unreachable_xy_m == [(95.0, 5.0)]
    # Still excluded while the drone flies to x = 75 ...
    assert sel.select(_maps(values), drone_xy_m=(30.0, 0.0), now_s=60.0).cell == (0, 7)
    # ... and forgotten after the retry time: the hill is worth a new attempt.
    again = sel.select(_maps(values), drone_xy_m=(30.0, 0.0), now_s=72.5)
    assert again.cell == (0, 9)
    assert sel.unreachable_xy_m == []


def test_unreachable_everywhere_falls_back_to_the_plain_argmax() -> None:
    sel = GoalSelector(GoalSelectorConfig(weights={"frontier": 1.0}, unreachable_radius_m=500.0))
    values = [0.1] * 9 + [1.0]
    sel.select(_maps(values), drone_xy_m=None, now_s=0.0)
    sel.mark_unreachable((95.0, 5.0), now_s=0.0)
    d = sel.select(_maps(values), drone_xy_m=None, now_s=1.0)
    assert d.cell == (0, 9)  # nothing else is left: keep trying rather than fail
    with pytest.raises(InvalidInputError, match="finite"):
        sel.mark_unreachable((math.nan, 0.0), now_s=1.0)


def test_config_validation() -> None:
    with pytest.raises(ConfigError, match="switch_margin"):
        from_mapping(GoalSelectorConfig, {"switch_margin": -1.0}, source="test")
    with pytest.raises(ConfigError, match="unreachable_retry_s"):
        from_mapping(GoalSelectorConfig, {"unreachable_retry_s": math.inf}, source="test")
    with pytest.raises(ConfigError, match="2 points"):
        from_mapping(GoalSelectorConfig, {"target_xy_m": [[0, 0], [1, 1]]}, source="test")
