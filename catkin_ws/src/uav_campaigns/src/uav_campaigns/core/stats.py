"""The campaign's statistics: summaries with bootstrap intervals, paired comparisons, success rates.

Pure numpy/SciPy; randomness (the bootstrap's resampling) comes from a ``numpy.random.Generator``
passed in. What each function computes, and why:

* :func:`bootstrap_ci`: the percentile bootstrap interval of the mean (resample the runs with
  replacement, take the mean of each resample, the interval between the ``(1-c)/2`` and ``(1+c)/2``
  quantiles). It assumes nothing about the metric's distribution; with few runs it is a little
  narrow (coverage of a nominal 95 % interval measured on synthetic data: docs/campaigns.md).
* :func:`wilcoxon_signed_rank`: the two-sided Wilcoxon signed-rank test of paired differences
  (zero differences dropped, tied magnitudes get their average rank). Up to ``exact_max_n`` pairs
  the p-value is exact: the null distribution of the positive rank sum is counted over all 2^n sign
  patterns (with ties too, on doubled ranks), so 10 seeds need no normal approximation. Above it,
  the normal approximation with the tie correction (SciPy's ``method="approx"``).
* :func:`wilson_interval`: the Wilson score interval of a success rate; unlike the normal
  ("Wald") interval it stays inside [0, 1] and is not degenerate at 0 or n successes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import special

from uav_campaigns.errors import StatisticsError

__all__ = [
    "PairedComparison",
    "Summary",
    "WilcoxonResult",
    "bootstrap_ci",
    "describe",
    "paired_comparison",
    "wilcoxon_signed_rank",
    "wilson_interval",
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Summary:
    n: int
    mean: float
    std: float
    median: float
    ci_low: float
    ci_high: float


@dataclass(frozen=True)
class WilcoxonResult:
    #: The positive rank sum T+ (zero differences dropped).
    statistic: float
    p_value: float
    #: Pairs with a non-zero difference.
    n: int
    method: str  # "exact" | "approx" | "none" (no non-zero difference)


@dataclass(frozen=True)
class PairedComparison:
    n: int
    #: Mean of (other - reference) over the shared seeds.
    mean_diff: float
    median_diff: float
    ci_low: float
    ci_high: float
    wilcoxon: WilcoxonResult


def _finite(values: Sequence[float] | FloatArray) -> FloatArray:
    arr: FloatArray = np.asarray(values, dtype=np.float64).ravel()
    out: FloatArray = arr[np.isfinite(arr)]
    return out


def _check_confidence(confidence: float) -> None:
    if not 0.0 < confidence < 1.0:
        msg = f"confidence must be within (0, 1), got {confidence}"
        raise StatisticsError(msg)


def z_quantile(p: float) -> float:
    """The standard normal quantile (``ndtri``)."""
    return float(special.ndtri(p))


def bootstrap_ci(
    values: Sequence[float] | FloatArray,
    rng: np.random.Generator,
    *,
    confidence: float = 0.95,
    resamples: int = 10000,
) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of ``values`` (NaN and inf ignored).

    One value gives ``(nan, nan)``: a single run says nothing about the spread.
    """
    _check_confidence(confidence)
    data = _finite(values)
    n = data.size
    if n < 2:
        return (math.nan, math.nan)
    if np.all(data == data[0]):
        return (float(data[0]), float(data[0]))
    means = np.empty(resamples, dtype=np.float64)
    chunk = max(1, 2_000_000 // n)
    for start in range(0, resamples, chunk):
        stop = min(resamples, start + chunk)
        idx = rng.integers(0, n, size=(stop - start, n))
        means[start:stop] = data[idx].mean(axis=1)
    alpha = (1.0 - confidence) / 2.0
    lo, hi = np.quantile(means, [alpha, 1.0 - alpha])
    return (float(lo), float(hi))


def describe(
    values: Sequence[float] | FloatArray,
    rng: np.random.Generator,
    *,
    confidence: float = 0.95,
    resamples: int = 10000,
) -> Summary:
    """n, mean, sample standard deviation, median and the bootstrap interval of the mean (finite values only)."""
    data = _finite(values)
    n = int(data.size)
    if n == 0:
        return Summary(0, math.nan, math.nan, math.nan, math.nan, math.nan)
    lo, hi = bootstrap_ci(data, rng, confidence=confidence, resamples=resamples)
    std = float(np.std(data, ddof=1)) if n > 1 else math.nan
    return Summary(n, float(np.mean(data)), std, float(np.median(data)), lo, hi)


def _average_ranks(values: FloatArray) -> FloatArray:
    """Ranks 1..n of ``values``, ties sharing their average rank."""
    order = np.argsort(values, kind="mergesort")
    sorted_vals = values[order]
    ranks = np.empty(values.size, dtype=np.float64)
    i = 0
    while i < values.size:
        j = i
        while j + 1 < values.size and sorted_vals[j + 1] == sorted_vals[i]:
            j += 1
        ranks[order[i : j + 1]] = (i + j) / 2.0 + 1.0
        i = j + 1
    return ranks


def _exact_rank_sum_distribution(doubled_ranks: npt.NDArray[np.int64]) -> FloatArray:
    """Probability of each value of sum(doubled ranks with a + sign) when every sign is a fair coin."""
    total = int(doubled_ranks.sum())
    counts = np.zeros(total + 1, dtype=np.float64)
    counts[0] = 1.0
    for r in doubled_ranks:
        shifted = np.zeros_like(counts)
        shifted[int(r) :] = counts[: total + 1 - int(r)]
        counts = counts + shifted
    pmf: FloatArray = counts / counts.sum()
    return pmf


def wilcoxon_signed_rank(differences: Sequence[float] | FloatArray, *, exact_max_n: int = 50) -> WilcoxonResult:
    """Two-sided Wilcoxon signed-rank test that the paired differences are centred on 0 (module docstring).

    NaN differences are errors (pair only runs that have the metric); zeros are dropped.
    """
    d = np.asarray(differences, dtype=np.float64).ravel()
    if not np.all(np.isfinite(d)):
        msg = "wilcoxon_signed_rank: differences must be finite (drop the pairs that miss a value)"
        raise StatisticsError(msg)
    d = d[d != 0.0]
    n = int(d.size)
    if n == 0:
        return WilcoxonResult(0.0, 1.0, 0, "none")
    ranks = _average_ranks(np.abs(d))
    t_plus = float(ranks[d > 0].sum())
    if n <= exact_max_n:
        doubled = np.rint(2.0 * ranks).astype(np.int64)
        pmf = _exact_rank_sum_distribution(doubled)
        s = round(2.0 * t_plus)
        p_low = float(pmf[: s + 1].sum())
        p_high = float(pmf[s:].sum())
        return WilcoxonResult(t_plus, min(1.0, 2.0 * min(p_low, p_high)), n, "exact")
    mean = n * (n + 1) / 4.0
    _, tie_counts = np.unique(np.abs(d), return_counts=True)
    var = n * (n + 1) * (2 * n + 1) / 24.0 - float(np.sum(tie_counts**3 - tie_counts)) / 48.0
    z = (t_plus - mean) / math.sqrt(var) if var > 0 else 0.0
    p = float(2.0 * special.ndtr(-abs(z)))
    return WilcoxonResult(t_plus, min(1.0, p), n, "approx")


def wilson_interval(successes: int, n: int, *, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of ``successes / n``; ``(nan, nan)`` for n = 0."""
    _check_confidence(confidence)
    if n < 0 or not 0 <= successes <= n:
        msg = f"wilson_interval needs 0 <= successes <= n, got {successes} of {n}"
        raise StatisticsError(msg)
    if n == 0:
        return (math.nan, math.nan)
    z = z_quantile(0.5 + confidence / 2.0)
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2.0 * n)) / denom
    half = z * math.sqrt(p * (1.0 - p) / n + z * z / (4.0 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def paired_comparison(
    reference: Sequence[float] | FloatArray,
    other: Sequence[float] | FloatArray,
    rng: np.random.Generator,
    *,
    confidence: float = 0.95,
    resamples: int = 10000,
) -> PairedComparison:
    """``other - reference`` over pairs (same seed and repeat): the mean difference, its bootstrap interval
    and the Wilcoxon signed-rank p-value. Pairs where either value is missing (NaN) are dropped.

    Raises:
        StatisticsError: the two samples are not the same length (they must be aligned pair by pair).
    """
    a = np.asarray(reference, dtype=np.float64).ravel()
    b = np.asarray(other, dtype=np.float64).ravel()
    if a.shape != b.shape:
        msg = f"paired samples must be aligned pair by pair, got {a.size} and {b.size} values"
        raise StatisticsError(msg)
    ok = np.isfinite(a) & np.isfinite(b)
    diff = b[ok] - a[ok]
    n = int(diff.size)
    if n == 0:
        return PairedComparison(0, math.nan, math.nan, math.nan, math.nan, WilcoxonResult(0.0, math.nan, 0, "none"))
    lo, hi = bootstrap_ci(diff, rng, confidence=confidence, resamples=resamples)
    return PairedComparison(n, float(diff.mean()), float(np.median(diff)), lo, hi, wilcoxon_signed_rank(diff))
