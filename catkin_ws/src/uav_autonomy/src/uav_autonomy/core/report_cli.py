"""``uav-report BAG``: regenerate a run's report offline from its bag (no ROS needed).

Imports only pure modules and ``rosbags``, so it runs on a machine without ROS.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
from collections.abc import Mapping, Sequence
from importlib import metadata
from pathlib import Path
from typing import Any, TextIO

from uav_autonomy.core.report_data import read_run_bag
from uav_autonomy.core.report_html import build_report
from uav_autonomy.core.scenario_errors import ScenarioError

__all__ = ["headline", "main", "tool_versions"]


def tool_versions() -> dict[str, str]:
    """Versions of the libraries that shape a report's numbers and figures."""
    out = {"python": platform.python_version()}
    for dist in ("numpy", "scipy", "matplotlib", "motmetrics", "rosbags", "pandas"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out


def _get(data: Mapping[str, Any], dotted: str) -> Any:
    cur: Any = data
    for part in dotted.split("."):
        if not isinstance(cur, Mapping):
            return None
        cur = cur.get(part)
    return cur


def headline(summary: Mapping[str, Any]) -> list[str]:
    """The few lines a shell prints after a run."""

    def f(key: str, unit: str = "", digits: int = 1) -> str:
        value = _get(summary, key)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return "n/a"
        return f"{value:.{digits}f}{unit}" if isinstance(value, float | int) else str(value)

    return [
        (
            f"  simulated {f('time.duration_s', ' s')}, airborne {f('time.airborne_s', ' s')}, "
            f"complete at {f('time.complete_s', ' s')}"
        ),
        (
            f"  mapped {f('coverage.mapped_pct', ' %', 2)} of the scene ({f('coverage.mapped_m2', ' m²', 0)}), "
            f"coverage efficiency {f('coverage.efficiency', '', 3)}; map server inserted "
            f"{f('map_input.clouds_inserted', '', 0)} of {f('map_input.clouds_received', '', 0)} clouds "
            f"({f('map_input.dropped_queue_full', '', 0)} dropped: insertion too slow; "
            f"{f('map_input.dropped_unsynchronized', '', 0)} incomplete)"
        ),
        (
            f"  map vs ground truth: IoU {f('map_accuracy.iou', '', 3)} over the scene, "
            f"{f('map_accuracy.iou_observed', '', 3)} where mapped; precision {f('map_accuracy.precision', '', 3)}"
        ),
        (
            f"  flew {f('flight.distance_m', ' m', 0)}, min AGL {f('flight.agl_min_m', ' m')}, "
            f"below floor {f('flight.time_below_floor_s', ' s')}, collisions {f('collisions.count', '', 0)}"
        ),
        f"  battery used {f('battery.used_mah', ' mAh', 0)} ({f('battery.used_pct', ' %')})",
        (
            f"  detection TP/FP/FN {f('detection.tp', '', 0)}/{f('detection.fp', '', 0)}/{f('detection.fn', '', 0)}, "
            f"person first detected {f('detection.person_first_detected.t_s', ' s')} at "
            f"{f('detection.person_first_detected.range_m', ' m', 0)}, tracking MOTA {f('tracking.mota', '', 3)}"
        ),
    ]


def main(argv: Sequence[str] | None = None, out: TextIO = sys.stdout) -> int:
    parser = argparse.ArgumentParser(
        prog="uav-report", description="Regenerate a run's HTML report from its bag, offline (no ROS needed)."
    )
    parser.add_argument("bag", type=Path, help="the run's bag (runs/<name>-<time>/run.bag)")
    parser.add_argument("--out", type=Path, help="output folder (default: the bag's folder)")
    parser.add_argument(
        "--metrics", type=Path, help="metrics.json to prefer over the bag's last summary (default: beside the bag)"
    )
    args = parser.parse_args(argv)
    try:
        run = read_run_bag(args.bag)
        metrics_path = args.metrics or args.bag.parent / "metrics.json"
        if metrics_path.is_file():
            try:
                run.summary = json.loads(metrics_path.read_text())
            except json.JSONDecodeError as err:
                run.notes.append(f"{metrics_path} is not valid JSON ({err}); using the bag's last summary")
        versions = {**{f"run: {k}": str(v) for k, v in (run.summary.get("versions") or {}).items()}}
        versions.update({f"report: {k}": v for k, v in tool_versions().items()})
        report = build_report(run, args.out or args.bag.parent, versions=versions)
    except ScenarioError as err:
        sys.stderr.write(f"uav-report: {err}\n")
        return 1
    out.write(f"report: {report.html_path}\n")
    if report.missing:
        out.write(f"  figures without data: {', '.join(report.missing)}\n")
    out.write("\n".join(headline(run.summary)) + "\n")
    return 0
