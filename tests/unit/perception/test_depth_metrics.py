from __future__ import annotations

import math

import numpy as np
import pytest

from uav_perception.core.depth.config import EvaluatorConfig
from uav_perception.core.depth.metrics import (
    UNKNOWN_CLASS,
    DepthAccumulator,
    band_label,
    class_index_image,
    class_lut,
    evaluate_depth,
)
from uav_perception.errors import DepthInputError

CFG = EvaluatorConfig(abs_tol_m=1.0, rel_tol=0.05, range_bands_m=(0.0, 20.0, 40.0, math.inf), classes=("a", "b"))


def test_known_answer_case() -> None:
    # Ground truth: 10 pixels; one with no return (NaN), so 9 evaluated.
    gt = np.array([[10, 10, 10, 10, 30, 30, 30, 50, 50, np.nan]], dtype=np.float32)
    est = np.array([[10, 10.5, 12, np.nan, 29, 33, np.nan, 50, 80, 7]], dtype=np.float32)
    ev = evaluate_depth(est, gt, CFG)
    o = ev.overall
    # Covered: indices 0,1,2,4,5,7,8 (7 of 9); the estimate on the NaN pixel is spurious.
    assert (o.sums.n_evaluated, o.sums.n_covered, ev.n_spurious, ev.n_pixels) == (9, 7, 1, 10)
    assert o.coverage == pytest.approx(7 / 9)
    err = np.array([0, 0.5, 2, -1, 3, 0, 30])
    g = np.array([10, 10, 10, 30, 30, 50, 50])
    assert o.within_abs == pytest.approx(3 / 7)  # |err| < 1: 0, 0.5, 0
    # |err| / g = 0, 0.05, 0.2, 0.033, 0.1, 0, 0.6: strictly below 0.05 are 3 (0.05 itself is not).
    assert o.within_rel == pytest.approx(3 / 7)
    assert o.abs_rel == pytest.approx(np.mean(np.abs(err) / g))
    assert o.rmse_m == pytest.approx(math.sqrt(np.mean(err**2)))
    assert o.mae_m == pytest.approx(np.mean(np.abs(err)))
    assert o.bias_m == pytest.approx(np.mean(err))
    assert o.median_abs_err_m == pytest.approx(1.0)
    ratio = np.maximum((g + err) / g, g / (g + err))
    assert o.delta1 == pytest.approx(np.mean(ratio < 1.25))  # all but 80 vs 50
    assert o.delta1 == pytest.approx(6 / 7)
    assert o.delta2 == pytest.approx(6 / 7)  # 80 / 50 = 1.6 > 1.25^2
    assert o.delta3 == pytest.approx(7 / 7)
    # Bands by ground truth: [0, 20): 4 evaluated, 3 covered; [20, 40): 3 / 2; >= 40: 2 / 2.
    labels = [b.label for b in ev.range_bands]
    assert labels == ["0-20m", "20-40m", ">=40m"]
    counts = [(b.sums.n_evaluated, b.sums.n_covered) for b in ev.range_bands]
    assert counts == [(4, 3), (3, 2), (2, 2)]
    assert ev.range_bands[2].within_abs == pytest.approx(0.5)
    assert ev.range_bands[1].rmse_m == pytest.approx(math.sqrt((1 + 9) / 2))
    # No class image: class entries exist but are empty (NaN, never 0).
    assert [c.label for c in ev.classes] == ["a", "b"]
    assert math.isnan(ev.classes[0].coverage)


def test_per_class_breakdown_from_instance_ids() -> None:
    gt = np.full((2, 3), 20.0, np.float32)
    est = np.array([[20.0, 25.0, np.nan], [20.2, np.nan, 21.0]], np.float32)
    instances = np.array([[1, 1, 2], [7, 7, 0]], np.uint16)
    lut = class_lut({1: "a", 2: "b", 7: "b", 9: "other"}, CFG.classes)
    assert lut[9] == UNKNOWN_CLASS
    assert lut[0] == UNKNOWN_CLASS
    assert lut[7] == 1
    cls = class_index_image(instances, lut)
    ev = evaluate_depth(est, gt, CFG, cls)
    a, b = ev.classes
    assert (a.sums.n_evaluated, a.sums.n_covered, a.within_abs) == (2, 2, 0.5)
    assert (b.sums.n_evaluated, b.sums.n_covered, b.within_abs) == (3, 1, 1.0)
    assert b.coverage == pytest.approx(1 / 3)
    # The sky/unknown pixel counts overall only.
    assert ev.overall.sums.n_evaluated == 6


def test_perfect_and_empty_estimates() -> None:
    gt = np.linspace(1, 100, 50, dtype=np.float32).reshape(5, 10)
    perfect = evaluate_depth(gt.copy(), gt, CFG).overall
    assert (perfect.coverage, perfect.within_abs, perfect.delta1, perfect.abs_rel, perfect.rmse_m) == (1, 1, 1, 0, 0)
    empty = evaluate_depth(np.full_like(gt, np.nan), gt, CFG).overall
    assert empty.coverage == 0.0
    assert math.isnan(empty.within_abs)
    assert math.isnan(empty.rmse_m)
    assert math.isnan(empty.median_abs_err_m)


def test_evaluation_limits_and_bad_shapes() -> None:
    gt = np.array([[0.05, 5.0, 2000.0, np.inf]], np.float32)
    est = np.array([[0.05, 5.0, 2000.0, 3.0]], np.float32)
    ev = evaluate_depth(est, gt, CFG)  # only the 5 m pixel is inside [0.1, 1000]
    assert ev.overall.sums.n_evaluated == 1
    assert ev.n_spurious == 3
    with pytest.raises(DepthInputError, match="same 2-D shape"):
        evaluate_depth(est, gt.T, CFG)
    with pytest.raises(DepthInputError, match="class image"):
        evaluate_depth(est, gt, CFG, np.zeros((2, 2), np.int16))
    with pytest.raises(DepthInputError, match="65535"):
        class_lut({70000: "a"}, CFG.classes)


def test_accumulator_is_the_pixel_weighted_aggregate() -> None:
    rng = np.random.default_rng(3)
    gts = [rng.uniform(5, 80, (6, 7)).astype(np.float32) for _ in range(3)]
    ests = [g + rng.normal(0, 1.5, g.shape).astype(np.float32) for g in gts]
    ests[1][:3] = np.nan
    acc = DepthAccumulator()
    for e, g in zip(ests, gts, strict=True):
        acc.add(evaluate_depth(e, g, CFG))
    total = evaluate_depth(np.hstack(ests), np.hstack(gts), CFG)
    agg = acc.result()
    assert acc.frames == 3
    for key in ("coverage", "within_abs", "within_rel", "delta1", "abs_rel", "rmse_m", "mae_m", "bias_m"):
        assert getattr(agg.overall, key) == pytest.approx(getattr(total.overall, key)), key
    for a, t in zip(agg.range_bands, total.range_bands, strict=True):
        assert a.label == t.label
        assert (a.sums.n_evaluated, a.sums.n_covered, a.sums.n_within_abs) == (
            t.sums.n_evaluated,
            t.sums.n_covered,
            t.sums.n_within_abs,
        )
        assert a.rmse_m == pytest.approx(t.rmse_m)
    assert math.isnan(agg.overall.median_abs_err_m)
    assert set(agg.as_dict()) == {"overall", "range_bands", "classes", "n_spurious", "n_pixels"}


def test_band_label() -> None:
    assert band_label(0.0, 20.0) == "0-20m"
    assert band_label(12.5, 20.0) == "12.5-20m"
    assert band_label(120.0, math.inf) == ">=120m"
