"""How well a detector's boxes were placed on the ground, against the ground truth.

For every detection matched to a truth object (same image, IoU >= 0.5) that the geolocator placed, the
horizontal error is the distance between the placement and the object's true centre (the truth's z is
the object's mid-height, the placement is on the ground: only x-y is compared), and the stated
uncertainty is checked: ``within_95`` is the share of errors inside the placement's own 95 % ellipse
(horizontal Mahalanobis distance squared <= 5.991, chi-square with 2 degrees of freedom). A calibrated
geolocator scores about 0.95; far less means its covariance is too optimistic.

Every detector detection is also counted by where its position came from (``depth``, ``elevation``,
``terrain``) or why it has none (``unplaced:<reason>``), and every discarded one by reason.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from uav_scenarios.core.scoring.types import Detection, DetectionFrame

__all__ = ["CHI2_2DOF_95", "GeolocationScores"]

#: 95 % quantile of the chi-square distribution with 2 degrees of freedom.
CHI2_2DOF_95 = 5.991464547107979


def _mahalanobis2(err_xy: tuple[float, float], cov: tuple[float, ...]) -> float:
    if len(cov) != 9 or not all(math.isfinite(c) for c in (cov[0], cov[1], cov[3], cov[4])):
        return math.nan
    m = np.array([[cov[0], cov[1]], [cov[3], cov[4]]], dtype=np.float64)
    if np.linalg.det(m) <= 1e-12:
        return math.nan
    e = np.asarray(err_xy, dtype=np.float64)
    return float(e @ np.linalg.solve(m, e))


@dataclass
class _Errors:
    errors_m: list[float] = field(default_factory=list)
    inside: list[bool] = field(default_factory=list)

    def add(self, err_m: float, d2: float) -> None:
        self.errors_m.append(err_m)
        if math.isfinite(d2):
            self.inside.append(d2 <= CHI2_2DOF_95)

    def summary(self) -> dict[str, float]:
        e = np.asarray(self.errors_m, dtype=np.float64)
        if e.size == 0:
            return {"n": 0, "median_m": math.nan, "p90_m": math.nan, "mean_m": math.nan, "within_95": math.nan}
        return {
            "n": int(e.size),
            "median_m": float(np.median(e)),
            "p90_m": float(np.percentile(e, 90)),
            "mean_m": float(e.mean()),
            "within_95": float(np.mean(self.inside)) if self.inside else math.nan,
        }


@dataclass
class GeolocationScores:
    """Counts and errors of the detector's placements over a run."""

    placed: Counter[str] = field(default_factory=Counter)
    unplaced: Counter[str] = field(default_factory=Counter)
    discarded: Counter[str] = field(default_factory=Counter)
    _overall: _Errors = field(default_factory=_Errors)
    _by_source: dict[str, _Errors] = field(default_factory=lambda: defaultdict(_Errors))
    _by_band: dict[str, _Errors] = field(default_factory=lambda: defaultdict(_Errors))

    def add_frame(self, frame: DetectionFrame) -> None:
        """Count one detector frame's placements and discards."""
        for det in frame.detections:
            if det.placed:
                self.placed[det.position_source or "unknown"] += 1
            else:
                src = det.position_source
                self.unplaced[src.split(":", 1)[1] if src.startswith("unplaced:") else (src or "unknown")] += 1
        for reason, count in frame.discarded:
            self.discarded[reason] += int(count)

    def add_match(self, truth: Detection, hyp: Detection, band: str) -> None:
        """A detection matched to a truth object; ``band`` is the truth's range band label."""
        if not (hyp.placed and truth.placed):
            return
        err = (hyp.position_m[0] - truth.position_m[0], hyp.position_m[1] - truth.position_m[1])
        dist = math.hypot(*err)
        d2 = _mahalanobis2(err, hyp.position_cov_m2)
        self._overall.add(dist, d2)
        self._by_source[hyp.position_source].add(dist, d2)
        self._by_band[band].add(dist, d2)

    def summary(self) -> dict[str, Any]:
        total = sum(self.placed.values()) + sum(self.unplaced.values())
        return {
            "detections": total,
            "placed": dict(sorted(self.placed.items())),
            "unplaced": dict(sorted(self.unplaced.items())),
            "unplaced_share": sum(self.unplaced.values()) / total if total else math.nan,
            "discarded": dict(sorted(self.discarded.items())),
            "error": self._overall.summary(),
            "error_by_source": {k: v.summary() for k, v in sorted(self._by_source.items())},
            "error_by_range": {k: v.summary() for k, v in sorted(self._by_band.items())},
        }
