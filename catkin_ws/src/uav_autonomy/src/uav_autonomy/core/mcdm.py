"""Multi-criteria goal selection: ``S = sum_k w_k * p_k`` and a hysteretic argmax.

Ties break deterministically: among equal best scores the first cell in row-major
order wins (lowest row, i.e. southern-most, then lowest column, western-most).
NaN scores never win.

Hysteresis (:class:`GoalSelector`): once a goal is held, a new best cell replaces it
only if its score beats the current goal's *current* score by ``switch_margin``;
a new best closer than ``min_goal_separation_m`` to the current goal must beat it
by ``clear_improvement_margin``. The goal is replaced unconditionally when the
drone has reached it (then cells within ``min_goal_separation_m`` of it are
excluded), when the weights or the target change, when it left the grid, or when
the planner reported it unreachable.

Unreachable goals (:meth:`GoalSelector.mark_unreachable`): the path planner could
not reach a goal (e.g. a hill above its ceiling, a geofence). Every cell within
``unreachable_radius_m`` of it is excluded for ``unreachable_retry_s`` seconds (the
caller's clock), so the selector moves on instead of holding a goal the drone
never reaches. If every cell is excluded, the exclusions are ignored.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from uav_autonomy.core.features import SCORED_FEATURES, FeatureMaps
from uav_autonomy.core.grid_geometry import FloatGrid, GridSpec
from uav_autonomy.errors import InvalidInputError

__all__ = [
    "GoalDecision",
    "GoalReasonKind",
    "GoalSelector",
    "GoalSelectorConfig",
    "argmax_cell",
    "validate_weights",
    "weighted_score",
]


def _default_weights() -> dict[str, float]:
    return {"age": 1.0, "frontier": 1.0, "target": 1.0, "drone": 1.0, "origin": 0.0}


def validate_weights(weights: Mapping[str, float]) -> dict[str, float]:
    """Check names against :data:`SCORED_FEATURES` and values for finiteness.

    Missing features get weight 0. Negative weights are allowed (they make a
    feature repel instead of attract).

    Raises:
        InvalidInputError: an unknown feature name or a non-finite weight.
    """
    unknown = sorted(set(weights) - set(SCORED_FEATURES))
    if unknown:
        msg = f"unknown feature(s) {unknown} in weights; known: {list(SCORED_FEATURES)}"
        raise InvalidInputError(msg)
    out = dict.fromkeys(SCORED_FEATURES, 0.0)
    for name, value in weights.items():
        w = float(value)
        if not math.isfinite(w):
            msg = f"weight of '{name}' must be finite, got {value}"
            raise InvalidInputError(msg)
        out[name] = w
    return out


@dataclass(frozen=True)
class GoalSelectorConfig:
    """Settings of the goal selector (section ``goal_selector`` of ``config/autonomy.yaml``)."""

    weights: dict[str, float] = field(default_factory=_default_weights)
    target_xy_m: tuple[tuple[float, float], ...] = ()
    switch_margin: float = 0.05
    min_goal_separation_m: float = 20.0
    clear_improvement_margin: float = 0.25
    goal_reached_radius_m: float = 8.0
    reevaluate_rate_hz: float = 1.0
    unreachable_radius_m: float = 20.0
    unreachable_retry_s: float = 120.0

    def __post_init__(self) -> None:
        try:
            validate_weights(self.weights)
        except InvalidInputError as err:
            raise ValueError(str(err)) from err
        for name in (
            "switch_margin",
            "min_goal_separation_m",
            "clear_improvement_margin",
            "goal_reached_radius_m",
            "unreachable_radius_m",
            "unreachable_retry_s",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                msg = f"{name} must be a finite number >= 0, got {value}"
                raise ValueError(msg)
        if not (math.isfinite(self.reevaluate_rate_hz) and self.reevaluate_rate_hz > 0.0):
            msg = f"reevaluate_rate_hz must be > 0, got {self.reevaluate_rate_hz}"
            raise ValueError(msg)
        if len(self.target_xy_m) == 2:
            msg = "target_xy_m is [] (none), one [x, y] point or a polygon of >= 3 points; got 2 points"
            raise ValueError(msg)


def weighted_score(features: Mapping[str, FloatGrid], weights: Mapping[str, float]) -> FloatGrid:
    """``S = sum_k w_k * p_k`` over the features with non-zero weight.

    Args:
        features: name -> ``(H, W)`` float32 layer in ``[0, 1]``.
        weights: name -> weight; every name with a non-zero weight must be present.

    Returns:
        ``(H, W)`` float32 score.

    Raises:
        InvalidInputError: a weighted feature is missing, or layers differ in shape.
    """
    used = [(name, float(w)) for name, w in weights.items() if w != 0.0]
    shapes = {np.shape(v) for v in features.values()}
    if len(shapes) != 1:
        msg = f"feature layers differ in shape: {sorted(shapes)}"
        raise InvalidInputError(msg)
    (shape,) = shapes
    for name, w in used:
        if name not in features:
            msg = f"feature '{name}' has weight {w} but was not computed; have {sorted(features)}"
            raise InvalidInputError(msg)
    score = np.zeros(shape, dtype=np.float32)
    tmp = np.empty(shape, dtype=np.float32) if len(used) > 1 else score
    for i, (name, w) in enumerate(used):
        if i == 0:
            np.multiply(features[name], np.float32(w), out=score)
        elif w == 1.0:
            score += features[name]
        else:
            np.multiply(features[name], np.float32(w), out=tmp)
            score += tmp
    return score


def argmax_cell(score: FloatGrid) -> tuple[int, int]:
    """``(row, col)`` of the best score; first in row-major order on ties; NaN never wins.

    Raises:
        InvalidInputError: the grid is empty or every score is NaN.
    """
    if score.size == 0:
        msg = "cannot pick a goal on an empty score grid"
        raise InvalidInputError(msg)
    flat = score.ravel()
    idx = int(np.argmax(flat))
    if math.isnan(float(flat[idx])):  # np.argmax returns the first NaN if there is one
        nan = np.isnan(flat)
        if nan.all():
            msg = "every cell's score is NaN; no goal can be chosen"
            raise InvalidInputError(msg)
        idx = int(np.argmax(np.where(nan, -np.inf, flat)))
    row, col = divmod(idx, score.shape[1])
    return int(row), int(col)


class GoalReasonKind(enum.Enum):
    """Why the goal is what it is (``uav_msgs/GoalReason.reason``)."""

    INITIAL = "initial"
    NEW_BEST = "new_best"
    CLEARLY_BETTER_NEARBY = "clearly_better_nearby"
    HYSTERESIS_KEPT = "hysteresis_kept"
    GOAL_REACHED = "goal_reached"
    TARGET_MOVED = "target_moved"
    WEIGHTS_CHANGED = "weights_changed"
    GOAL_OFF_GRID = "goal_off_grid"
    GOAL_UNREACHABLE = "goal_unreachable"


@dataclass(frozen=True)
class GoalDecision:
    """A goal and why.

    Attributes:
        goal_xy_m: goal cell centre, metres ENU.
        cell: ``(row, col)`` on ``spec``.
        elevation_m: known elevation at the goal (NaN unknown).
        score: ``S`` at the goal.
        values: feature value ``p_k`` at the goal for every scored feature.
        weights: the weights used.
        reason: why this goal was chosen or kept.
        changed: the goal differs from the previous decision's.
    """

    goal_xy_m: tuple[float, float]
    cell: tuple[int, int]
    spec: GridSpec
    elevation_m: float
    score: float
    values: dict[str, float]
    weights: dict[str, float]
    reason: GoalReasonKind
    changed: bool

    @property
    def contributions(self) -> dict[str, float]:
        """``w_k * p_k`` per feature."""
        return {k: self.weights[k] * v for k, v in self.values.items()}


class GoalSelector:
    """Stateful hysteretic goal selection over successive :class:`FeatureMaps`."""

    def __init__(self, config: GoalSelectorConfig) -> None:
        self.config = config
        self._weights = validate_weights(config.weights)
        self._goal_xy_m: tuple[float, float] | None = None
        self._force: GoalReasonKind | None = None
        self._unreachable: list[tuple[tuple[float, float], float]] = []  # (goal, excluded until, caller's clock)

    @property
    def weights(self) -> dict[str, float]:
        return dict(self._weights)

    @property
    def goal_xy_m(self) -> tuple[float, float] | None:
        return self._goal_xy_m

    def set_weights(self, weights: Mapping[str, float]) -> None:
        """Replace the weights (validated first; on error nothing changes)."""
        self._weights = validate_weights(weights)
        self._force = GoalReasonKind.WEIGHTS_CHANGED

    def target_moved(self) -> None:
        """The target changed: the next decision ignores hysteresis."""
        self._force = GoalReasonKind.TARGET_MOVED

    @property
    def unreachable_xy_m(self) -> list[tuple[float, float]]:
        """Goals reported unreachable whose exclusion has not expired (as of the last decision)."""
        return [xy for xy, _ in self._unreachable]

    def mark_unreachable(self, goal_xy_m: tuple[float, float], now_s: float) -> None:
        """The planner found no path to ``goal_xy_m``: exclude the cells around it until ``now_s +
        unreachable_retry_s``; if it is the current goal, the next decision picks another one.

        Raises:
            InvalidInputError: a non-finite goal or time.
        """
        x, y = (float(v) for v in goal_xy_m)
        if not all(math.isfinite(v) for v in (x, y, now_s)):
            msg = f"unreachable goal ({x}, {y}) at t={now_s} must be finite"
            raise InvalidInputError(msg)
        until = float(now_s) + self.config.unreachable_retry_s
        self._unreachable = [(xy, t) for xy, t in self._unreachable if math.dist(xy, (x, y)) > 1e-6]
        self._unreachable.append(((x, y), until))

    def _is_unreachable(self, xy_m: tuple[float, float]) -> bool:
        r = self.config.unreachable_radius_m
        return any(math.dist(xy_m, u) <= r for u, _ in self._unreachable)

    def _exclude_unreachable(self, score: FloatGrid, spec: GridSpec) -> FloatGrid:
        """``score`` with NaN within ``unreachable_radius_m`` of every unreachable goal (unchanged if that
        would leave no cell)."""
        if not self._unreachable:
            return score
        r = self.config.unreachable_radius_m
        xs = spec.cell_centers_x_m()
        ys = spec.cell_centers_y_m()
        masked = score.copy()
        for (ux, uy), _ in self._unreachable:
            c0, c1 = np.searchsorted(xs, [ux - r, ux + r], side="left")
            r0, r1 = np.searchsorted(ys, [uy - r, uy + r], side="left")
            c1, r1 = min(int(c1) + 1, len(xs)), min(int(r1) + 1, len(ys))
            if c0 >= c1 or r0 >= r1:
                continue
            close = (xs[None, c0:c1] - ux) ** 2 + (ys[r0:r1, None] - uy) ** 2 <= r * r
            window = masked[r0:r1, c0:c1]
            window[close] = np.nan
        return score if np.isnan(masked).all() else masked

    def select(
        self, features: FeatureMaps, *, drone_xy_m: tuple[float, float] | None, now_s: float | None = None
    ) -> GoalDecision:
        """Score every cell and decide on the goal.

        Args:
            features: the feature maps.
            drone_xy_m: the drone's position (None: unknown; "goal reached" is then never decided).
            now_s: the caller's clock (e.g. ROS time), for expiring unreachable goals; None keeps them.

        Raises:
            InvalidInputError: no cell can be scored.
        """
        if now_s is not None:
            self._unreachable = [(xy, t) for xy, t in self._unreachable if t > now_s]
        spec = features.spec
        raw_score = weighted_score(features.scored(), self._weights)
        score = self._exclude_unreachable(raw_score, spec)
        best = argmax_cell(score)
        previous = self._goal_xy_m
        reason = GoalReasonKind.NEW_BEST
        chosen = best
        current_cell = None if previous is None else spec.cell_of(*previous)
        if previous is None:
            reason = GoalReasonKind.INITIAL
        elif current_cell is None:
            reason = GoalReasonKind.GOAL_OFF_GRID
        elif self._is_unreachable(previous) and score is not raw_score:
            reason = GoalReasonKind.GOAL_UNREACHABLE
        elif self._force is not None:
            reason = self._force
        elif drone_xy_m is not None and math.dist(drone_xy_m, previous) <= self.config.goal_reached_radius_m:
            reason = GoalReasonKind.GOAL_REACHED
            chosen = self._best_away_from(score, spec, previous)
        else:
            current_score = float(score[current_cell])
            best_xy = spec.cell_center_m(*best)
            near = math.dist(best_xy, spec.cell_center_m(*current_cell)) < self.config.min_goal_separation_m
            margin = self.config.clear_improvement_margin if near else self.config.switch_margin
            better = best != current_cell and float(score[best]) >= current_score + margin
            if math.isnan(current_score) or better:
                reason = GoalReasonKind.CLEARLY_BETTER_NEARBY if near else GoalReasonKind.NEW_BEST
            else:
                reason = GoalReasonKind.HYSTERESIS_KEPT
                chosen = current_cell
        self._force = None
        goal_xy = spec.cell_center_m(*chosen)
        changed = previous is None or current_cell != chosen
        self._goal_xy_m = goal_xy
        feats = features.scored()
        values = {name: float(feats[name][chosen]) if name in feats else 0.0 for name in SCORED_FEATURES}
        elevation = features.layers.get("elevation_m")
        elev = float(elevation[chosen]) if elevation is not None else math.nan
        return GoalDecision(
            goal_xy_m=goal_xy,
            cell=chosen,
            spec=spec,
            elevation_m=elev,
            score=float(raw_score[chosen]),
            values=values,
            weights=dict(self._weights),
            reason=reason,
            changed=changed,
        )

    def _best_away_from(self, score: FloatGrid, spec: GridSpec, xy_m: tuple[float, float]) -> tuple[int, int]:
        """Argmax over cells at least ``min_goal_separation_m`` from ``xy_m`` (all cells if none are)."""
        radius = self.config.min_goal_separation_m
        r_cells = math.ceil(radius / spec.resolution_m) + 1
        cell = spec.cell_of(*xy_m)
        if cell is None or radius <= 0.0:
            return argmax_cell(score)
        row, col = cell
        r0, r1 = max(0, row - r_cells), min(spec.height, row + r_cells + 1)
        c0, c1 = max(0, col - r_cells), min(spec.width, col + r_cells + 1)
        xs = spec.cell_centers_x_m()[c0:c1]
        ys = spec.cell_centers_y_m()[r0:r1]
        close = (xs[None, :] - xy_m[0]) ** 2 + (ys[:, None] - xy_m[1]) ** 2 < radius * radius
        if close.all() and (r1 - r0) * (c1 - c0) == score.size:
            return argmax_cell(score)
        masked = score.copy()
        window = masked[r0:r1, c0:c1]
        window[close] = -np.inf
        return argmax_cell(masked)
