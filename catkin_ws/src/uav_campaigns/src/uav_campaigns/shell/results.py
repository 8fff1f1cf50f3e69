"""The campaign's tables on disk: runs.csv, summary.csv, paired.csv and success.csv.

Rebuilt from the manifest and the run folders alone (``uav-campaign report DIR`` does it offline):
each planned run's row comes from its finished try's ``metrics.json`` and ``timeseries.csv``.
"""

from __future__ import annotations

import csv
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from uav_campaigns.core.config import Campaign
from uav_campaigns.core.manifest import RunState, fold
from uav_campaigns.core.table import (
    ID_COLUMNS,
    PairedRow,
    SuccessRow,
    SummaryRow,
    flatten_metrics,
    freshness,
    paired_table,
    success_table,
    summary_table,
)
from uav_campaigns.shell.store import CampaignDir, PlanEntry

__all__ = ["Tables", "build_tables", "read_series", "run_rows"]


def read_series(path: Path) -> list[dict[str, float]]:
    """``timeseries.csv`` as rows of floats (text cells become NaN); [] if missing or unreadable."""
    try:
        with path.open(newline="") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, csv.Error):
        return []
    out: list[dict[str, float]] = []
    for row in rows:
        parsed: dict[str, float] = {}
        for k, v in row.items():
            try:
                parsed[str(k)] = float(v)
            except (TypeError, ValueError):
                parsed[str(k)] = math.nan
        out.append(parsed)
    return out


def _run_path(cdir: CampaignDir, event: Mapping[str, Any]) -> Path:
    rel = event.get("run_path")
    if isinstance(rel, str) and rel:
        return cdir.path / rel
    return Path(str(event.get("run_dir", "")))


def _status(st: RunState | None, max_attempts: int) -> tuple[str, str]:
    if st is None:
        return "pending", ""
    if st.done is not None:
        return "done", ""
    problem = st.last_problem or {}
    reason = str(problem.get("reason", ""))
    if st.permanent_failure or st.failures >= max_attempts:
        return "failed", reason
    if st.interruptions and not st.failures:
        return "pending", "interrupted"
    return "pending", reason


def run_rows(cdir: CampaignDir, campaign: Campaign, plan: Sequence[PlanEntry]) -> list[dict[str, Any]]:
    """One row per planned run (module docstring), in plan order."""
    states = fold(cdir.events())
    rows: list[dict[str, Any]] = []
    for entry in plan:
        key = str(entry["key"])
        st = states.get(key)
        status, reason = _status(st, campaign.max_attempts)
        row: dict[str, Any] = {
            "arm": entry["arm"],
            "seed": entry["seed"],
            "repeat": entry["repeat"],
            "key": key,
            "config_hash": entry["config_hash"],
            "status": status,
            "reason": reason,
            "attempts": st.tries if st else 0,
            "orphaned": st.orphans if st else 0,
        }
        if st is not None and st.done is not None:
            done = st.done
            run_dir = _run_path(cdir, done)
            row.update(
                worker=done.get("worker", ""),
                wall_s=done.get("wall_s"),
                sim_s=done.get("sim_s"),
                run_dir=os.path.relpath(run_dir, cdir.path),
            )
            report = run_dir / "report.html"
            row["report"] = os.path.relpath(report, cdir.path) if report.is_file() else ""
            try:
                metrics = json.loads((run_dir / "metrics.json").read_text())
            except (OSError, json.JSONDecodeError):
                metrics = {}
                row.update(status="failed", reason=f"metrics.json missing or unreadable in {run_dir}")
            if isinstance(metrics, dict):
                row["stop_reason"] = metrics.get("stop_reason", "")
                row.update({k: v for k, v in flatten_metrics(metrics).items() if k not in row})
            row.update(freshness(read_series(run_dir / "timeseries.csv")))
        rows.append(row)
    return rows


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.6g}"
    return str(value)


def _write_csv(path: Path, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    tmp = path.with_suffix(".csv.tmp")
    with tmp.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in rows:
            w.writerow([_cell(v) for v in row])
    os.replace(tmp, path)


PAIRED_HEADER = (
    "reference", "arm", "metric", "n_pairs", "mean_diff", "median_diff", "ci_low", "ci_high",
    "wilcoxon_t_plus", "wilcoxon_p", "wilcoxon_method",
)  # fmt: skip


def _paired_cells(p: PairedRow) -> list[Any]:
    c = p.comparison
    w = c.wilcoxon
    return [
        p.reference,
        p.arm,
        p.metric,
        c.n,
        c.mean_diff,
        c.median_diff,
        c.ci_low,
        c.ci_high,
        w.statistic,
        w.p_value,
        w.method,
    ]


@dataclass(frozen=True)
class Tables:
    rows: list[dict[str, Any]]
    summary: list[SummaryRow]
    paired: list[PairedRow]
    success: list[SuccessRow]


def build_tables(cdir: CampaignDir, campaign: Campaign, plan: Sequence[PlanEntry]) -> Tables:
    """Compute every table and write runs.csv, summary.csv, paired.csv and success.csv into the directory."""
    rows = run_rows(cdir, campaign, plan)
    metric_names = sorted({k for r in rows for k in r if k not in ID_COLUMNS})
    header = [*ID_COLUMNS, *metric_names]
    _write_csv(cdir.path / "runs.csv", header, [[r.get(c) for c in header] for r in rows])
    summary = summary_table(campaign, rows)
    conf = campaign.statistics.confidence
    _write_csv(
        cdir.path / "summary.csv",
        ["arm", "metric", "n", "mean", "std", "median", "ci_low", "ci_high", "confidence"],
        [
            [
                s.arm,
                s.metric,
                s.summary.n,
                s.summary.mean,
                s.summary.std,
                s.summary.median,
                s.summary.ci_low,
                s.summary.ci_high,
                conf,
            ]
            for s in summary
        ],
    )
    paired = paired_table(campaign, rows)
    _write_csv(
        cdir.path / "paired.csv",
        [*PAIRED_HEADER],
        [_paired_cells(p) for p in paired],
    )
    success = success_table(campaign, rows)
    _write_csv(
        cdir.path / "success.csv",
        ["arm", "criterion", "rule", "successes", "n", "rate", "ci_low", "ci_high"],
        [[s.arm, s.criterion, s.rule, s.successes, s.n, s.rate, s.ci_low, s.ci_high] for s in success],
    )
    return Tables(rows, summary, paired, success)
