"""The statistics against known answers: bootstrap coverage, Wilcoxon against SciPy and brute force, Wilson."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import stats

from uav_campaigns.core.stats import (
    bootstrap_ci,
    describe,
    paired_comparison,
    wilcoxon_signed_rank,
    wilson_interval,
)
from uav_campaigns.errors import StatisticsError


def coverage(draw, true_mean: float, n: int, trials: int, seed: int) -> float:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    hits = 0
    for _ in range(trials):
        lo, hi = bootstrap_ci(draw(rng, n), rng, resamples=2000)
        hits += lo <= true_mean <= hi
    return hits / trials


def test_bootstrap_intervals_cover_the_true_mean_about_95_percent_of_the_time() -> None:
    normal = coverage(lambda rng, n: rng.normal(5.0, 2.0, n), 5.0, n=30, trials=400, seed=1)
    assert 0.91 <= normal <= 0.98, normal
    # skewed data (an exponential, like times to find): a little under nominal, never far
    skewed = coverage(lambda rng, n: rng.exponential(3.0, n), 3.0, n=30, trials=400, seed=2)
    assert 0.88 <= skewed <= 0.97, skewed
    # and the interval is not trivially wide: it shrinks like 1/sqrt(n)
    rng = np.random.default_rng(3)
    w10 = np.diff(bootstrap_ci(rng.normal(0, 1, 10), rng))[0]
    w1000 = np.diff(bootstrap_ci(rng.normal(0, 1, 1000), rng))[0]
    assert w1000 < w10 / 5


def test_bootstrap_edge_cases() -> None:
    rng = np.random.default_rng(0)
    assert all(math.isnan(v) for v in bootstrap_ci([4.0], rng))
    assert bootstrap_ci([2.0, 2.0, 2.0], rng) == (2.0, 2.0)
    assert bootstrap_ci([1.0, float("nan"), 3.0, float("inf")], rng)[0] >= 1.0
    with pytest.raises(StatisticsError):
        bootstrap_ci([1.0, 2.0], rng, confidence=1.5)
    # the same generator seed gives the same interval (campaign reports are reproducible)
    data = np.arange(20.0)
    assert bootstrap_ci(data, np.random.default_rng(7)) == bootstrap_ci(data, np.random.default_rng(7))


def test_describe() -> None:
    s = describe([1.0, 2.0, 3.0, 4.0, float("nan")], np.random.default_rng(0))
    assert (s.n, s.mean, s.median) == (4, 2.5, 2.5)
    assert s.std == pytest.approx(np.std([1, 2, 3, 4], ddof=1))
    assert s.ci_low < 2.5 < s.ci_high
    empty = describe([], np.random.default_rng(0))
    assert empty.n == 0
    assert math.isnan(empty.mean)


@pytest.mark.parametrize("seed", range(8))
def test_wilcoxon_exact_matches_scipy_without_ties(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(5, 26))
    d = rng.normal(0.3 * (seed % 3), 1.0, n)
    ours = wilcoxon_signed_rank(d)
    ref = stats.wilcoxon(d, method="exact")
    assert ours.method == "exact"
    assert ours.p_value == pytest.approx(ref.pvalue, rel=1e-9, abs=1e-12)
    assert ours.n == n


def test_wilcoxon_large_samples_use_scipys_normal_approximation() -> None:
    rng = np.random.default_rng(11)
    d = np.round(rng.normal(0.2, 1.0, 80), 1)  # rounding makes ties: the tie correction matters
    ours = wilcoxon_signed_rank(d)
    ref = stats.wilcoxon(d, method="approx", correction=False)
    assert ours.method == "approx"
    assert ours.p_value == pytest.approx(ref.pvalue, rel=1e-9)


def test_wilcoxon_with_ties_and_zeros_is_the_exact_permutation_p_value() -> None:
    d = np.array([1.0, -1.0, 2.0, 2.0, 3.0, -3.0, 3.0, 4.0, 0.0, 5.0, -0.5, 6.0, 0.0])
    ours = wilcoxon_signed_rank(d)
    nz = d[d != 0]
    ranks = stats.rankdata(np.abs(nz))
    t_obs = ranks[nz > 0].sum()
    sums = np.array(
        [
            sum(r for r, s in zip(ranks, signs, strict=True) if s)
            for signs in itertools.product((False, True), repeat=nz.size)
        ]
    )
    mean = ranks.sum() / 2
    brute = np.mean(np.abs(sums - mean) >= abs(t_obs - mean) - 1e-9)  # two-sided, symmetric null
    assert ours.statistic == t_obs
    assert ours.n == nz.size
    assert ours.p_value == pytest.approx(brute, rel=1e-12)


def test_wilcoxon_degenerate_and_bad_input() -> None:
    assert wilcoxon_signed_rank([0.0, 0.0]).p_value == 1.0
    assert wilcoxon_signed_rank([1.0, 2.0, 3.0, 4.0, 5.0]).p_value == pytest.approx(2 / 32)
    with pytest.raises(StatisticsError, match="finite"):
        wilcoxon_signed_rank([1.0, float("nan")])


@pytest.mark.parametrize(
    ("k", "n", "lo", "hi"),
    [
        # textbook values (Newcombe 1998, Table I; Agresti & Coull 1998)
        (0, 10, 0.0, 0.2775),
        (8, 10, 0.4902, 0.9433),
        (10, 10, 0.7225, 1.0),
        (81, 263, 0.2553, 0.3662),
        (15, 148, 0.0624, 0.1605),
    ],
)
def test_wilson_intervals_match_published_values(k: int, n: int, lo: float, hi: float) -> None:
    got = wilson_interval(k, n)
    assert got[0] == pytest.approx(lo, abs=6e-5)
    assert got[1] == pytest.approx(hi, abs=6e-5)


def test_wilson_edge_cases() -> None:
    assert all(math.isnan(v) for v in wilson_interval(0, 0))
    with pytest.raises(StatisticsError):
        wilson_interval(3, 2)
    lo90, hi90 = wilson_interval(5, 10, confidence=0.9)
    lo95, hi95 = wilson_interval(5, 10)
    assert lo95 < lo90 < 0.5 < hi90 < hi95


def test_paired_comparison_on_shared_pairs() -> None:
    ref = np.array([10.0, 12.0, 9.0, 11.0, 10.5, 13.0, 8.0, 9.5, 10.0, 11.5])
    better = ref - np.array([1.0, 1.5, 0.5, 1.2, 0.8, 2.0, 0.7, 1.1, 0.9, 1.3])
    c = paired_comparison(ref, better, np.random.default_rng(0))
    assert c.n == 10
    assert c.mean_diff == pytest.approx(-1.1)
    assert c.ci_low < c.mean_diff < c.ci_high < 0.0
    assert c.wilcoxon.p_value == pytest.approx(stats.wilcoxon(better - ref, method="exact").pvalue)
    assert c.wilcoxon.p_value < 0.01
    # a pair with a missing value is dropped, not counted as zero
    with_gap = paired_comparison(np.append(ref, 5.0), np.append(better, np.nan), np.random.default_rng(0))
    assert with_gap.n == 10
    with pytest.raises(StatisticsError, match="aligned"):
        paired_comparison([1.0, 2.0], [1.0], np.random.default_rng(0))
