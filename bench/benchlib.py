"""Helpers for benchmark scripts: timing and the one JSON-lines result format.

Each result is one line in ``bench/results/latest.jsonl``::

    {"name": "sitl.rtf.hover", "value": 83.1, "unit": "x", "baseline": 1.0, "ratio": 83.1,
     "target": ">= 50", "met": true, "notes": "...", "time": "2026-11-22T17:00:00Z"}

``baseline`` is measured in the same run (never a remembered number) and
``ratio = value / baseline``.
"""

from __future__ import annotations

import json
import os
import statistics
import sys
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

from uav_common.paths import repo_root

_root = repo_root(Path(__file__))
if _root is None:  # pragma: no cover - benchmarks run from a checkout
    msg = f"{__file__} is not inside a checkout of the project"
    raise RuntimeError(msg)
#: The checkout the benchmarks run from; its tests/ holds the shared harness (``helpers``).
REPO: Path = _root
if str(REPO / "tests") not in sys.path:
    sys.path.append(str(REPO / "tests"))

RESULTS = Path(os.environ.get("UAV_BENCH_RESULTS", Path(__file__).resolve().parent / "results" / "latest.jsonl"))


def record(
    name: str,
    value: float,
    unit: str,
    baseline: float,
    *,
    target: str = "",
    met: bool | None = None,
    notes: str = "",
) -> dict[str, object]:
    """Append one result line and echo it; returns the record."""
    ratio = value / baseline if baseline else float("nan")
    rec: dict[str, object] = {
        "name": name,
        "value": round(value, 6),
        "unit": unit,
        "baseline": round(baseline, 6),
        "ratio": round(ratio, 4),
    }
    if target:
        rec["target"] = target
    if met is not None:
        rec["met"] = bool(met)
    if notes:
        rec["notes"] = notes
    rec["time"] = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    with RESULTS.open("a") as fh:
        fh.write(json.dumps(rec) + "\n")
    flag = "" if met is None else ("  [target met]" if met else "  [TARGET MISSED]")
    print(f"{name:48s} {value:12.4g} {unit:8s} baseline {baseline:10.4g}  ratio {ratio:8.3g}{flag}")
    return rec


def time_it(fn: Callable[[], object], *, repeat: int = 5, warmup: int = 1) -> list[float]:
    """Wall-clock seconds of ``repeat`` calls after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return out


def median(values: list[float]) -> float:
    return statistics.median(values)


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    k = max(0, min(len(ordered) - 1, round(q / 100.0 * (len(ordered) - 1))))
    return ordered[k]
