"""A multi-object tracker on ground positions, and its MOT evaluation.

The tracker never sees ground-truth identities: it associates detections by
position alone (Hungarian assignment on predicted positions, gated in metres),
smooths each track with an alpha-beta (constant-velocity) filter, confirms a
track after ``min_hits`` updates and drops it after ``max_coast_s`` without one.
Time is passed in. The evaluation wraps py-motmetrics (CLEAR MOT and ID
measures) with Euclidean matching of ground positions.

The contract with a detector: positions come from the geolocator (any detector's
boxes placed in ``map``). A detection it could not place (NaN position) or one
scoring below the operating threshold cannot be tracked; the tracker counts each
(:attr:`PositionTracker.unplaced`, :attr:`PositionTracker.below_threshold`) and the
node reports the counts with every track frame: nothing is dropped unseen.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from uav_scenarios.core.scoring.types import Detection, Track
from uav_scenarios.errors import ScoringError

__all__ = ["MotResult", "MotScorer", "PositionTracker", "TrackerConfig"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class TrackerConfig:
    #: Association gate: a detection further than this from a track's prediction starts a new track.
    gate_m: float = 5.0
    #: Updates before a track is reported.
    min_hits: int = 2
    #: A track not updated for this long is deleted.
    max_coast_s: float = 3.0
    #: alpha-beta filter gains (position, velocity).
    alpha: float = 0.6
    beta: float = 0.2
    #: Operating threshold: detections scoring lower are counted, not tracked.
    min_score: float = 0.0

    def __post_init__(self) -> None:
        if self.gate_m <= 0 or self.max_coast_s <= 0 or self.min_hits < 1:
            msg = "gate_m and max_coast_s must be > 0 and min_hits >= 1"
            raise ValueError(msg)
        if not 0.0 <= self.min_score <= 1.0:
            msg = f"min_score must be within [0, 1], got {self.min_score}"
            raise ValueError(msg)
        if not (0 < self.alpha <= 1 and 0 <= self.beta <= 1):
            msg = "alpha must be in (0, 1] and beta in [0, 1]"
            raise ValueError(msg)


@dataclass
class _TrackState:
    track_id: int
    class_name: str
    position: FloatArray
    velocity: FloatArray
    last_update_s: float
    hits: int = 1

    def predict(self, t_s: float) -> FloatArray:
        return self.position + self.velocity * max(0.0, t_s - self.last_update_s)


@dataclass
class PositionTracker:
    """Tracks per class from detections with ground positions (``Detection.position_m``)."""

    config: TrackerConfig = field(default_factory=TrackerConfig)
    _tracks: list[_TrackState] = field(default_factory=list)
    _next_id: int = 1
    _last_t_s: float = -math.inf
    #: Detections fed so far; of those, without a position (not placed) and below ``min_score``.
    received: int = 0
    unplaced: int = 0
    below_threshold: int = 0

    def update(self, t_s: float, detections: Sequence[Detection]) -> tuple[Track, ...]:
        """Feed one frame of detections at simulation time ``t_s``; return the confirmed tracks.

        Detections below ``min_score`` or without a position are counted (``below_threshold``,
        ``unplaced``) and not tracked.

        Raises:
            ScoringError: ``t_s`` is earlier than the previous frame's.
        """
        if t_s < self._last_t_s:
            msg = f"tracker fed out of order: {t_s:.3f} s after {self._last_t_s:.3f} s"
            raise ScoringError(msg)
        self._last_t_s = t_s
        self.received += len(detections)
        scored = [d for d in detections if d.score >= self.config.min_score]
        self.below_threshold += len(detections) - len(scored)
        usable = [d for d in scored if d.placed]
        self.unplaced += len(scored) - len(usable)
        matched: set[int] = set()
        for class_name in sorted({d.class_name for d in usable}):
            dets = [d for d in usable if d.class_name == class_name]
            tracks = [k for k, tr in enumerate(self._tracks) if tr.class_name == class_name]
            matched |= self._associate(t_s, dets, tracks)
        cfg = self.config
        self._tracks = [tr for tr in self._tracks if t_s - tr.last_update_s <= cfg.max_coast_s]
        return tuple(
            Track(
                track_id=tr.track_id,
                class_name=tr.class_name,
                position_m=_vec3(tr.predict(t_s)),
                velocity_mps=_vec3(tr.velocity),
                hits=tr.hits,
            )
            for tr in self._tracks
            if tr.hits >= cfg.min_hits and tr.last_update_s == t_s
        )

    def _associate(self, t_s: float, dets: list[Detection], track_idx: list[int]) -> set[int]:
        cfg = self.config
        det_pos = np.array([d.position_m for d in dets], dtype=np.float64)
        assigned: dict[int, int] = {}
        if track_idx:
            pred = np.array([self._tracks[k].predict(t_s) for k in track_idx])
            cost = np.linalg.norm(det_pos[:, None, :2] - pred[None, :, :2], axis=2)
            rows, cols = linear_sum_assignment(np.where(cost <= cfg.gate_m, cost, 1e9))
            assigned = {int(r): track_idx[int(c)] for r, c in zip(rows, cols, strict=True) if cost[r, c] <= cfg.gate_m}
        for i, d in enumerate(dets):
            if i in assigned:
                tr = self._tracks[assigned[i]]
                dt = t_s - tr.last_update_s
                pred = tr.predict(t_s)
                residual = det_pos[i] - pred
                tr.position = pred + cfg.alpha * residual
                if dt > 0:
                    tr.velocity = tr.velocity + cfg.beta * residual / dt
                tr.last_update_s = t_s
                tr.hits += 1
            else:
                self._tracks.append(_TrackState(self._next_id, d.class_name, det_pos[i].copy(), np.zeros(3), t_s))
                self._next_id += 1
        return set(assigned.values())


def _vec3(v: FloatArray) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


@dataclass(frozen=True)
class MotResult:
    mota: float
    #: Root-mean-square ground distance of matched pairs (motmetrics' MOTP on squared distances).
    motp_rms_m: float
    idf1: float
    id_switches: int
    num_frames: int
    num_objects: int
    num_matches: int
    num_misses: int
    num_false_positives: int
    precision: float
    recall: float

    def as_dict(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items()}


_HOST: list[object] = []


def _metrics_host(mm: object) -> Any:
    """One motmetrics MetricsHost per process (creating one inspects every metric: ~10 ms)."""
    if not _HOST:
        _HOST.append(mm.metrics.create())  # type: ignore[attr-defined]
    return _HOST[0]


class MotScorer:
    """CLEAR-MOT and ID metrics (py-motmetrics) of tracks against true object positions.

    Matching is Euclidean on the ground plane (x, y) with a gate, through
    ``motmetrics.distances.norm2squared_matrix``. Frames are fed in time order.
    """

    def __init__(self, gate_m: float) -> None:
        import motmetrics  # noqa: PLC0415 - deferred: pandas makes the import slow

        if gate_m <= 0:
            msg = f"gate_m must be > 0, got {gate_m}"
            raise ScoringError(msg)
        self._mm = motmetrics
        self._gate_m2 = gate_m * gate_m
        self._acc = motmetrics.MOTAccumulator(auto_id=True)
        self.frames = 0
        self._result: MotResult | None = None

    def update(
        self,
        truth_ids: Sequence[int],
        truth_xy_m: npt.ArrayLike,
        track_ids: Sequence[int],
        track_xy_m: npt.ArrayLike,
    ) -> None:
        """One frame: true objects ``(N, 2)`` with their ids, tracks ``(M, 2)`` with theirs."""
        gt = np.asarray(truth_xy_m, dtype=np.float64).reshape(-1, 2)
        hy = np.asarray(track_xy_m, dtype=np.float64).reshape(-1, 2)
        dist = self._mm.distances.norm2squared_matrix(gt, hy, max_d2=self._gate_m2)
        self._acc.update(list(truth_ids), list(track_ids), dist)
        self.frames += 1
        self._result = None

    def result(self) -> MotResult:
        """Metrics over every frame so far (NaN where undefined, e.g. no objects); cached until the next frame."""
        if self._result is None:
            self._result = self._compute()
        return self._result

    def _compute(self) -> MotResult:
        if self.frames == 0:
            nan = math.nan
            return MotResult(nan, nan, nan, 0, 0, 0, 0, 0, 0, nan, nan)
        names = [
            "mota",
            "motp",
            "idf1",
            "num_switches",
            "num_frames",
            "num_objects",
            "num_matches",
            "num_misses",
            "num_false_positives",
            "precision",
            "recall",
        ]
        row = _metrics_host(self._mm).compute(self._acc, metrics=names, name="run").iloc[0]

        def f(name: str) -> float:
            value = float(row[name])
            return value if math.isfinite(value) else math.nan

        return MotResult(
            mota=f("mota"),
            motp_rms_m=math.sqrt(f("motp")) if math.isfinite(f("motp")) else math.nan,
            idf1=f("idf1"),
            id_switches=int(row["num_switches"]),
            num_frames=int(row["num_frames"]),
            num_objects=int(row["num_objects"]),
            num_matches=int(row["num_matches"]),
            num_misses=int(row["num_misses"]),
            num_false_positives=int(row["num_false_positives"]),
            precision=f("precision"),
            recall=f("recall"),
        )
