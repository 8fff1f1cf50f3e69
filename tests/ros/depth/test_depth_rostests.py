"""Run this folder's ``*.rostest`` files with rostest, each with its own roscore.

Named ``*.rostest`` (not ``*.test``) for the reason given in
tests/ros/autonomy/test_autonomy_rostests.py: rostest is run here with
``--package``/``--pkgdir`` and without ``--text``, so its exit code reports a
failing test node.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
from helpers.procs import REPO, artifacts_dir, slug

HERE = Path(__file__).resolve().parent
FILES = sorted(HERE.glob("*.rostest"))
PKG_DIR = REPO / "catkin_ws/src/uav_autonomy"


@pytest.mark.parametrize("rostest_file", FILES, ids=[p.stem for p in FILES])
def test_depth_rostest(rostest_file: Path) -> None:
    results = artifacts_dir() / "rostest"
    results.mkdir(exist_ok=True)
    run_dir = artifacts_dir() / f"depth_{rostest_file.stem}_run"
    shutil.rmtree(run_dir, ignore_errors=True)
    proc = subprocess.run(
        [
            "rostest",
            "--package=uav_autonomy",
            f"--pkgdir={PKG_DIR}",
            f"--results-base-dir={results}",
            str(rostest_file),
        ],
        capture_output=True,
        text=True,
        timeout=150,
        check=False,
        env={**os.environ, "UAV_DEPTH_RUN_DIR": str(run_dir)},
    )
    log = artifacts_dir() / "logs" / f"rostest_{slug(rostest_file.name)}.log"
    log.parent.mkdir(exist_ok=True)
    xml_dir = results / "uav_autonomy"
    xml = sorted(xml_dir.glob(f"*{rostest_file.stem}*.xml")) if xml_dir.exists() else []
    details = "\n".join(p.read_text(errors="replace")[-4000:] for p in xml)
    log.write_text(proc.stdout + "\n--- stderr ---\n" + proc.stderr + "\n--- results ---\n" + details)
    tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-60:])
    assert proc.returncode == 0, f"rostest {rostest_file.name} failed (log: {log}):\n{tail}\n{details[-3000:]}"
    # The evaluator wrote its per-frame log and, at shutdown, the summary.
    assert (run_dir / "depth_metrics.jsonl").stat().st_size > 0
    assert (run_dir / "depth_summary.json").exists()
