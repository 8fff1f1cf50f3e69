"""Builders for the campaign unit tests: campaign files over the shipped scenarios, run folders with metrics."""

from __future__ import annotations

import csv
import json
import math
import textwrap
from pathlib import Path
from typing import Any

from helpers.paths import REPO

LOITER = REPO / "config" / "scenarios" / "loiter.yaml"
SAR = REPO / "config" / "scenarios" / "search_and_rescue.yaml"


def campaign_file(tmp: Path, body: str, *, name: str = "camp.yaml", scenario: Path = LOITER) -> Path:
    """A campaign file in ``tmp`` whose ``scenario:`` is the given scenario (absolute path)."""
    path = tmp / name
    path.write_text(f"scenario: {scenario}\n" + textwrap.dedent(body))
    return path


def metrics(
    *,
    mapped_pct: float,
    iou: float,
    battery_pct: float,
    collisions: int = 0,
    complete_s: float | None = None,
    stop: str = "time_limit",
) -> dict[str, Any]:
    """A metrics.json as the scorer writes it (the sections the campaign reads)."""
    return {
        "time": {"start_s": 3.0, "end_s": 63.0, "duration_s": 60.0, "airborne_s": 57.0, "complete_s": complete_s},
        "coverage": {"scene_area_m2": 1e6, "mapped_m2": mapped_pct * 1e4, "mapped_pct": mapped_pct},
        "map_accuracy": {"iou": iou, "precision": 0.98, "iou_observed": 0.8},
        "battery": {"used_pct": battery_pct},
        "collisions": {"count": collisions, "events": []},
        "detection": {"precision": 1.0, "recall": 1.0, "by_context": {"range": {"0-25": {"tp": 3}}}},
        "events": [{"t_s": 1.0, "what": "takeoff"}],
        "scenario": "loiter",
        "stop_reason": stop,
        "world": {"name": "default", "seed": 7},
        "versions": {"python": "3.11"},
        "final": True,
    }


def write_run(run_dir: Path, data: dict[str, Any], *, age_slope: float = 1.0, report: bool = True) -> Path:
    """A run folder: metrics.json, a 60 s timeseries.csv whose mean cell age grows at ``age_slope`` s/s."""
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "metrics.json").write_text(json.dumps(data))
    with (run_dir / "timeseries.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t_s", "x_m", "y_m", "mapped_pct", "mean_cell_age_s", "controller_state"])
        for t in range(61):
            age = math.nan if t < 5 else 2.0 + age_slope * t
            w.writerow([t, 10.0 * math.cos(t / 10), 10.0 * math.sin(t / 10), t * 0.1, age, "AUTONOMOUS"])
    if report:
        (run_dir / "report.html").write_text("<html>run report</html>")
    return run_dir
