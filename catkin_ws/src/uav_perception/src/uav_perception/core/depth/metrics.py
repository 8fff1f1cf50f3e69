"""Per-frame accuracy of an estimated depth image against ground truth.

Both images are z-depth in metres of the same camera at the same time, NaN where
there is no value. A pixel is *evaluated* when its ground truth is finite and in
``[min_gt_depth_m, max_gt_depth_m]``; it is *covered* when it is evaluated and
has a finite, positive estimate. With ``e`` the estimate and ``g`` the ground
truth of the covered pixels:

* ``coverage = covered / evaluated``
* ``within_abs``: share of covered pixels with ``|e - g| < abs_tol_m``
* ``within_rel``: share of covered pixels with ``|e - g| / g < rel_tol``
* ``delta1, delta2, delta3``: share with ``max(e/g, g/e) < 1.25, 1.25^2, 1.25^3``
* ``abs_rel = mean(|e - g| / g)``, ``rmse_m = sqrt(mean((e - g)^2))``,
  ``mae_m = mean(|e - g|)``, ``bias_m = mean(e - g)``, ``median_abs_err_m``
* ``spurious``: pixels with an estimate but no valid ground truth (e.g. sky).

Fractions of an empty set are NaN, never 0. The same statistics are computed for
every ground-truth range band ``[lo, hi)`` and every class. Counts and sums are
kept so frames can be aggregated exactly (pixel-weighted) by
:class:`DepthAccumulator`; the median is per frame only.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_perception.core.depth.config import EvaluatorConfig
from uav_perception.errors import DepthInputError

__all__ = [
    "UNKNOWN_CLASS",
    "DepthAccumulator",
    "DepthEvaluation",
    "DepthStats",
    "ErrorSums",
    "band_label",
    "class_index_image",
    "class_lut",
    "evaluate_depth",
]

UNKNOWN_CLASS = -1


@dataclass(frozen=True)
class ErrorSums:
    """Additive counts and sums over a set of pixels (see the module docstring)."""

    n_evaluated: int = 0
    n_covered: int = 0
    n_within_abs: int = 0
    n_within_rel: int = 0
    n_delta1: int = 0
    n_delta2: int = 0
    n_delta3: int = 0
    sum_abs_rel: float = 0.0
    sum_sq_m2: float = 0.0
    sum_abs_m: float = 0.0
    sum_signed_m: float = 0.0

    def __add__(self, other: ErrorSums) -> ErrorSums:
        return ErrorSums(*(getattr(self, f.name) + getattr(other, f.name) for f in fields(self)))


@dataclass(frozen=True)
class DepthStats:
    """Metrics over one set of pixels (all, one range band or one class)."""

    label: str
    sums: ErrorSums
    median_abs_err_m: float = math.nan

    def _frac(self, count: int, total: int) -> float:
        return count / total if total > 0 else math.nan

    @property
    def coverage(self) -> float:
        """Covered / evaluated pixels."""
        return self._frac(self.sums.n_covered, self.sums.n_evaluated)

    @property
    def within_abs(self) -> float:
        """Share of covered pixels within the absolute tolerance."""
        return self._frac(self.sums.n_within_abs, self.sums.n_covered)

    @property
    def within_rel(self) -> float:
        """Share of covered pixels within the relative tolerance."""
        return self._frac(self.sums.n_within_rel, self.sums.n_covered)

    @property
    def delta1(self) -> float:
        """Share of covered pixels with ``max(e/g, g/e) < 1.25``."""
        return self._frac(self.sums.n_delta1, self.sums.n_covered)

    @property
    def delta2(self) -> float:
        """... ``< 1.25^2``."""
        return self._frac(self.sums.n_delta2, self.sums.n_covered)

    @property
    def delta3(self) -> float:
        """... ``< 1.25^3``."""
        return self._frac(self.sums.n_delta3, self.sums.n_covered)

    @property
    def abs_rel(self) -> float:
        """Mean absolute relative error."""
        n = self.sums.n_covered
        return self.sums.sum_abs_rel / n if n else math.nan

    @property
    def rmse_m(self) -> float:
        """Root mean square error, metres."""
        n = self.sums.n_covered
        return math.sqrt(self.sums.sum_sq_m2 / n) if n else math.nan

    @property
    def mae_m(self) -> float:
        """Mean absolute error, metres."""
        n = self.sums.n_covered
        return self.sums.sum_abs_m / n if n else math.nan

    @property
    def bias_m(self) -> float:
        """Mean signed error (estimate minus truth), metres."""
        n = self.sums.n_covered
        return self.sums.sum_signed_m / n if n else math.nan

    def as_dict(self) -> dict[str, float | int | str]:
        """Flat, JSON-ready view (NaN stays NaN; callers decide how to serialise it)."""
        return {
            "label": self.label,
            "n_evaluated": self.sums.n_evaluated,
            "n_covered": self.sums.n_covered,
            "coverage": self.coverage,
            "within_abs": self.within_abs,
            "within_rel": self.within_rel,
            "delta1": self.delta1,
            "delta2": self.delta2,
            "delta3": self.delta3,
            "abs_rel": self.abs_rel,
            "rmse_m": self.rmse_m,
            "mae_m": self.mae_m,
            "bias_m": self.bias_m,
            "median_abs_err_m": self.median_abs_err_m,
        }


@dataclass(frozen=True)
class DepthEvaluation:
    """Metrics of one frame (or, from :class:`DepthAccumulator`, of many).

    Attributes:
        overall: all evaluated pixels.
        range_bands: one entry per ``[lo, hi)`` band of ground-truth depth.
        classes: one entry per configured class, in order.
        n_spurious: pixels with an estimate but without valid ground truth.
        n_pixels: pixels in the image(s).
    """

    overall: DepthStats
    range_bands: tuple[DepthStats, ...]
    classes: tuple[DepthStats, ...]
    n_spurious: int
    n_pixels: int

    def as_dict(self) -> dict[str, object]:
        """JSON-ready nested view."""
        return {
            "overall": self.overall.as_dict(),
            "range_bands": [b.as_dict() for b in self.range_bands],
            "classes": [c.as_dict() for c in self.classes],
            "n_spurious": self.n_spurious,
            "n_pixels": self.n_pixels,
        }


def band_label(lo_m: float, hi_m: float) -> str:
    """``"20-40m"``; an infinite upper edge gives ``">=120m"``."""
    if math.isinf(hi_m):
        return f">={lo_m:g}m"
    return f"{lo_m:g}-{hi_m:g}m"


def class_lut(instance_classes: Mapping[int, str], classes: Iterable[str]) -> npt.NDArray[np.int16]:
    """Lookup table instance id -> class index (``UNKNOWN_CLASS`` for ids not listed or not in ``classes``).

    Raises:
        DepthInputError: a negative or > 65535 instance id.
    """
    index = {name: i for i, name in enumerate(classes)}
    ids = list(instance_classes)
    if any(i < 0 or i > 0xFFFF for i in ids):
        msg = "instance ids must be in [0, 65535] (16UC1 instance images)"
        raise DepthInputError(msg)
    lut = np.full(0x10000, UNKNOWN_CLASS, dtype=np.int16)
    for inst, name in instance_classes.items():
        lut[inst] = index.get(name, UNKNOWN_CLASS)
    return lut


def class_index_image(instance_ids: npt.NDArray[np.integer[Any]], lut: npt.NDArray[np.int16]) -> npt.NDArray[np.int16]:
    """Per-pixel class index from a 16-bit instance image."""
    return np.asarray(lut[np.asarray(instance_ids, dtype=np.uint16)], dtype=np.int16)


def _sums(est: npt.NDArray[np.float64], gt: npt.NDArray[np.float64], n_eval: int, cfg: EvaluatorConfig) -> ErrorSums:
    err = est - gt
    abs_err = np.abs(err)
    ratio = np.maximum(est / gt, gt / est)
    return ErrorSums(
        n_evaluated=n_eval,
        n_covered=int(est.size),
        n_within_abs=int(np.count_nonzero(abs_err < cfg.abs_tol_m)),
        n_within_rel=int(np.count_nonzero(abs_err < cfg.rel_tol * gt)),
        n_delta1=int(np.count_nonzero(ratio < 1.25)),
        n_delta2=int(np.count_nonzero(ratio < 1.25**2)),
        n_delta3=int(np.count_nonzero(ratio < 1.25**3)),
        sum_abs_rel=float(np.sum(abs_err / gt)),
        sum_sq_m2=float(np.sum(err * err)),
        sum_abs_m=float(np.sum(abs_err)),
        sum_signed_m=float(np.sum(err)),
    )


def _stats(
    label: str, est: npt.NDArray[np.float64], gt: npt.NDArray[np.float64], n_eval: int, cfg: EvaluatorConfig
) -> DepthStats:
    median = float(np.median(np.abs(est - gt))) if est.size else math.nan
    return DepthStats(label, _sums(est, gt, n_eval, cfg), median)


def evaluate_depth(
    estimate_m: npt.NDArray[np.floating[Any]],
    truth_m: npt.NDArray[np.floating[Any]],
    config: EvaluatorConfig,
    class_index: npt.NDArray[np.integer[Any]] | None = None,
) -> DepthEvaluation:
    """Compare an estimated depth image with ground truth.

    Args:
        estimate_m: ``(H, W)`` estimated z-depth, NaN (or <= 0) = none.
        truth_m: ``(H, W)`` ground-truth z-depth, NaN/inf = no return.
        config: tolerances, bands and classes.
        class_index: optional ``(H, W)`` class index per pixel (into ``config.classes``,
            ``UNKNOWN_CLASS`` = none); without it every class entry is empty.

    Raises:
        DepthInputError: the images do not share one 2-D shape.
    """
    est_all = np.asarray(estimate_m, dtype=np.float64)
    gt_all = np.asarray(truth_m, dtype=np.float64)
    if est_all.ndim != 2 or est_all.shape != gt_all.shape:
        msg = f"estimate {est_all.shape} and ground truth {gt_all.shape} must be the same 2-D shape"
        raise DepthInputError(msg)
    if class_index is not None and class_index.shape != gt_all.shape:
        msg = f"class image {class_index.shape} does not match depth {gt_all.shape}"
        raise DepthInputError(msg)
    with np.errstate(invalid="ignore"):
        evaluated = np.isfinite(gt_all) & (gt_all >= config.min_gt_depth_m) & (gt_all <= config.max_gt_depth_m)
        has_est = np.isfinite(est_all) & (est_all > 0)
    covered = evaluated & has_est
    n_spurious = int(np.count_nonzero(has_est & ~evaluated))

    def stats_for(label: str, mask: npt.NDArray[np.bool_]) -> DepthStats:
        sel = covered & mask
        return _stats(label, est_all[sel], gt_all[sel], int(np.count_nonzero(evaluated & mask)), config)

    overall = stats_for("all", np.ones_like(evaluated))
    edges = config.range_bands_m
    with np.errstate(invalid="ignore"):
        bands = tuple(
            stats_for(band_label(lo, hi), (gt_all >= lo) & (gt_all < hi)) for lo, hi in itertools.pairwise(edges)
        )
    if class_index is None:
        classes = tuple(DepthStats(name, ErrorSums()) for name in config.classes)
    else:
        classes = tuple(stats_for(name, class_index == i) for i, name in enumerate(config.classes))
    return DepthEvaluation(overall, bands, classes, n_spurious, int(est_all.size))


@dataclass
class DepthAccumulator:
    """Pixel-weighted aggregate of many per-frame evaluations."""

    frames: int = 0
    n_spurious: int = 0
    n_pixels: int = 0
    _overall: ErrorSums = field(default_factory=ErrorSums)
    _bands: dict[str, ErrorSums] = field(default_factory=dict)
    _classes: dict[str, ErrorSums] = field(default_factory=dict)

    def add(self, evaluation: DepthEvaluation) -> None:
        """Add one frame."""
        self.frames += 1
        self.n_spurious += evaluation.n_spurious
        self.n_pixels += evaluation.n_pixels
        self._overall = self._overall + evaluation.overall.sums
        for stats in evaluation.range_bands:
            self._bands[stats.label] = self._bands.get(stats.label, ErrorSums()) + stats.sums
        for stats in evaluation.classes:
            self._classes[stats.label] = self._classes.get(stats.label, ErrorSums()) + stats.sums

    def result(self) -> DepthEvaluation:
        """The aggregate (medians are NaN: they do not aggregate)."""
        return DepthEvaluation(
            overall=DepthStats("all", self._overall),
            range_bands=tuple(DepthStats(k, v) for k, v in self._bands.items()),
            classes=tuple(DepthStats(k, v) for k, v in self._classes.items()),
            n_spurious=self.n_spurious,
            n_pixels=self.n_pixels,
        )
