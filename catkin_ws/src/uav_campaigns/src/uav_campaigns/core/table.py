"""Runs -> tables: one row per run, the per-arm summary, the paired comparisons, the success rates.

Pure. A run's row holds its identity (arm, seed, repeat, key, configuration hash), what happened
to it (status, attempts, run folder) and every metric of its ``metrics.json`` flattened to dotted
names (``coverage.mapped_pct``), plus ``freshness.*`` derived from its time series
(:func:`freshness`). The summary, the comparisons and the rates are computed over the runs whose
status is ``done``.
"""

from __future__ import annotations

import hashlib
import math
import operator
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_campaigns.core.config import Campaign, parse_success
from uav_campaigns.core.stats import (
    PairedComparison,
    Summary,
    describe,
    paired_comparison,
    wilson_interval,
)

__all__ = [
    "ID_COLUMNS",
    "PairedRow",
    "SuccessRow",
    "SummaryRow",
    "flatten_metrics",
    "freshness",
    "metric_columns",
    "paired_table",
    "success_table",
    "summary_table",
]

FloatArray = npt.NDArray[np.float64]

#: The identity and bookkeeping columns of runs.csv, before the metrics.
ID_COLUMNS = (
    "arm", "seed", "repeat", "key", "config_hash", "status", "reason", "attempts", "orphaned",
    "worker", "wall_s", "sim_s", "stop_reason", "run_dir", "report",
)  # fmt: skip

#: Metric names that are bookkeeping or identity, not results (left out of the statistics).
_NOT_RESULTS = ("versions.", "world.", "time.start_s", "time.end_s", "final", "scenario", "coverage.scene_area_m2")


def flatten_metrics(data: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``metrics.json`` -> ``{"coverage.mapped_pct": 12.3, ...}``: scalars only (lists and per-context
    breakdowns are left out; booleans become 0/1)."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        name = f"{prefix}{key}"
        if key == "by_context":
            continue
        if isinstance(value, Mapping):
            out.update(flatten_metrics(value, name + "."))
        elif isinstance(value, bool):
            out[name] = int(value)
        elif isinstance(value, int | float | str) or value is None:
            out[name] = value
    return out


def _slope(t: FloatArray, y: FloatArray) -> float:
    ok = np.isfinite(t) & np.isfinite(y)
    if np.count_nonzero(ok) < 3 or np.ptp(t[ok]) <= 0:
        return math.nan
    return float(np.polyfit(t[ok], y[ok], 1)[0])


def freshness(series: Sequence[Mapping[str, float]]) -> dict[str, float]:
    """What the time series says about keeping the map fresh (rows of ``timeseries.csv`` as numbers).

    * ``freshness.mean_cell_age_s``: the last mean age of the observed map columns.
    * ``freshness.age_growth``: the slope of that mean age over the run's second half, in seconds per
      simulated second: 1 means nothing is being refreshed, 0 that the mean age has settled.
    * ``freshness.mapped_pct_per_min``: the slope of % mapped over the second half, per minute.
    * ``freshness.max_home_distance_m``, ``freshness.mean_home_distance_m``: horizontal distance from
      home, the largest over the run and the mean over its second half (is the area bounded?).
    """
    nan = math.nan
    keys = ("mean_cell_age_s", "age_growth", "mapped_pct_per_min", "max_home_distance_m", "mean_home_distance_m")
    if len(series) < 3:
        return {f"freshness.{k}": nan for k in keys}

    def col(name: str) -> FloatArray:
        return np.array([float(r.get(name, nan)) for r in series], dtype=np.float64)

    t = col("t_s")
    age = col("mean_cell_age_s")
    mapped = col("mapped_pct")
    dist = np.hypot(col("x_m"), col("y_m"))
    half = t >= (np.nanmin(t) + np.nanmax(t)) / 2.0 if np.isfinite(t).any() else np.zeros(t.shape, bool)
    finite_age = age[np.isfinite(age)]
    with np.errstate(all="ignore"):
        out = {
            "mean_cell_age_s": float(finite_age[-1]) if finite_age.size else nan,
            "age_growth": _slope(t[half], age[half]),
            "mapped_pct_per_min": 60.0 * _slope(t[half], mapped[half]),
            "max_home_distance_m": float(np.nanmax(dist)) if np.isfinite(dist).any() else nan,
            "mean_home_distance_m": float(np.nanmean(dist[half])) if np.isfinite(dist[half]).any() else nan,
        }
    return {f"freshness.{k}": v for k, v in out.items()}


def _number(value: Any) -> float:
    if isinstance(value, bool):
        return float(value)
    if isinstance(value, int | float):
        return float(value)
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return math.nan
    return math.nan


def metric_columns(rows: Iterable[Mapping[str, Any]]) -> list[str]:
    """The numeric result columns of ``rows`` (every column with a number in some done run), sorted."""
    names: set[str] = set()
    for row in rows:
        if row.get("status") != "done":
            continue
        for k, v in row.items():
            if k in ID_COLUMNS or k.startswith(_NOT_RESULTS):
                continue
            if math.isfinite(_number(v)):
                names.add(k)
    return sorted(names)


def _rng(seed: int, *names: str) -> np.random.Generator:
    """A generator per (arm, metric): the interval of one metric does not depend on which others exist."""
    digest = hashlib.sha256("\0".join(names).encode()).digest()
    return np.random.default_rng([seed, int.from_bytes(digest[:8], "little")])


@dataclass(frozen=True)
class SummaryRow:
    arm: str
    metric: str
    summary: Summary


def summary_table(campaign: Campaign, rows: Sequence[Mapping[str, Any]]) -> list[SummaryRow]:
    """Per arm and per metric: n, mean, std, median and the bootstrap interval of the mean (done runs)."""
    spec = campaign.statistics
    metrics = metric_columns(rows)
    out: list[SummaryRow] = []
    for arm in campaign.arm_names:
        arm_rows = [r for r in rows if r.get("arm") == arm and r.get("status") == "done"]
        for metric in metrics:
            values = [_number(r.get(metric)) for r in arm_rows]
            s = describe(values, _rng(spec.seed, arm, metric), confidence=spec.confidence, resamples=spec.resamples)
            out.append(SummaryRow(arm, metric, s))
    return out


@dataclass(frozen=True)
class PairedRow:
    reference: str
    arm: str
    metric: str
    comparison: PairedComparison


def paired_table(campaign: Campaign, rows: Sequence[Mapping[str, Any]]) -> list[PairedRow]:
    """Every other arm against the reference arm, metric by metric, paired on (seed, repeat)."""
    spec = campaign.statistics
    ref = campaign.reference_arm
    metrics = metric_columns(rows)

    def by_pair(arm: str) -> dict[tuple[int, int], Mapping[str, Any]]:
        return {
            (int(r["seed"]), int(r["repeat"])): r for r in rows if r.get("arm") == arm and r.get("status") == "done"
        }

    ref_rows = by_pair(ref)
    out: list[PairedRow] = []
    for arm in campaign.arm_names:
        if arm == ref:
            continue
        other = by_pair(arm)
        shared = sorted(set(ref_rows) & set(other))
        for metric in metrics:
            a = [_number(ref_rows[p].get(metric)) for p in shared]
            b = [_number(other[p].get(metric)) for p in shared]
            cmp = paired_comparison(
                a, b, _rng(spec.seed, ref, arm, metric), confidence=spec.confidence, resamples=spec.resamples
            )
            out.append(PairedRow(ref, arm, metric, cmp))
    return out


_OPS: dict[str, Callable[[float, float], bool]] = {
    ">=": operator.ge,
    ">": operator.gt,
    "<=": operator.le,
    "<": operator.lt,
    "==": operator.eq,
    "!=": operator.ne,
}

#: Success criteria every campaign reports besides its own.
BUILTIN_SUCCESS = {"no_collision": "collisions.count == 0"}


def is_success(row: Mapping[str, Any], rule: str) -> bool:
    """Whether a run meets ``metric op number``; a missing metric (e.g. never found) is not a success."""
    metric, op, value = parse_success(rule)
    x = _number(row.get(metric))
    return math.isfinite(x) and _OPS[op](x, value)


@dataclass(frozen=True)
class SuccessRow:
    arm: str
    criterion: str
    rule: str
    successes: int
    n: int
    rate: float
    ci_low: float
    ci_high: float


def success_table(campaign: Campaign, rows: Sequence[Mapping[str, Any]]) -> list[SuccessRow]:
    """Per arm and criterion: successes of n done runs, the rate and its Wilson interval."""
    rules = {**BUILTIN_SUCCESS, **campaign.success}
    out: list[SuccessRow] = []
    for arm in campaign.arm_names:
        arm_rows = [r for r in rows if r.get("arm") == arm and r.get("status") == "done"]
        n = len(arm_rows)
        for name, rule in rules.items():
            k = sum(is_success(r, rule) for r in arm_rows)
            lo, hi = wilson_interval(k, n, confidence=campaign.statistics.confidence)
            out.append(SuccessRow(arm, name, rule, k, n, k / n if n else math.nan, lo, hi))
    return out
