"""uav-report: offline, from the bag alone, with ROS made unimportable."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from bagkit import REPO, write_synthetic_run

from uav_scenarios.cli.report import headline, main

NO_ROS = """
import runpy, sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('rospy', 'genpy', 'rosbag', 'roslib', 'rosgraph', 'uav_msgs'):
            raise ImportError(f'{name} must not be imported by uav-report')
        return None
sys.meta_path.insert(0, Block())
sys.argv = ['uav-report', *sys.argv[1:]]
runpy.run_path(%r, run_name='__main__')
"""


def test_cli_writes_report_and_prints_summary(tmp_path: Path) -> None:
    bag = tmp_path / "run.bag"
    write_synthetic_run(bag, duration_s=30.0)
    (tmp_path / "metrics.json").write_text(json.dumps({"coverage": {"mapped_pct": 12.5}, "versions": {"git": "abc"}}))
    out = io.StringIO()
    assert main([str(bag)], out=out) == 0
    text = out.getvalue()
    assert f"report: {tmp_path / 'report.html'}" in text
    assert "mapped 12.50 %" in text  # metrics.json beside the bag wins over the bag's summary
    html = (tmp_path / "report.html").read_text()
    assert "run: git" in html
    assert "report: rosbags" in html


def test_cli_fails_clearly_on_missing_bag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path / "missing.bag")]) == 1
    assert "no such bag" in capsys.readouterr().err


def test_runs_with_ros_unimportable(tmp_path: Path) -> None:
    bag = tmp_path / "run.bag"
    write_synthetic_run(bag, duration_s=20.0)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "ROS_PACKAGE_PATH")}
    script = NO_ROS % str(REPO / "bin" / "uav-report")
    proc = subprocess.run(
        [sys.executable, "-c", script, str(bag), "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "out" / "report.html").is_file()


def test_headline_handles_missing_values() -> None:
    lines = headline({"coverage": {"mapped_pct": float("nan")}})
    assert "mapped n/a" in lines[1]
