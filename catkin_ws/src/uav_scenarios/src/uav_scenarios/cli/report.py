"""``uav-report BAG``: regenerate a run's report offline from its bag (no ROS needed).

Imports only pure modules and ``rosbags``, so it runs on a machine without ROS.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from uav_scenarios.errors import ScenarioError
from uav_scenarios.report.data import read_run_bag
from uav_scenarios.report.html import build_report
from uav_scenarios.report.text import headline
from uav_scenarios.shell.versions import tool_versions

__all__ = ["main"]


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
