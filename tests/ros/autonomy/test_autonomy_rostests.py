"""Run this folder's ``*.rostest`` launch files with rostest (each with its own roscore).

They are not named ``*.test`` because tests/ros/test_rostests.py runs rostest
without ``--package``/``--pkgdir`` (rostest then requires the file to live inside
a ROS package) and with ``--text`` (rostest then exits 0 even when a test node
fails). Here rostest writes its JUnit XML and its exit code is trusted: 1 or 2
means a failure or error in the test node.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from helpers.procs import REPO, artifacts_dir, slug

HERE = Path(__file__).resolve().parent
FILES = sorted(HERE.glob("*.rostest"))
PKG_DIR = REPO / "catkin_ws/src/uav_autonomy"


@pytest.mark.parametrize("rostest_file", FILES, ids=[p.stem for p in FILES])
def test_autonomy_rostest(rostest_file: Path) -> None:
    results = artifacts_dir() / "rostest"
    results.mkdir(exist_ok=True)
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
    )
    log = artifacts_dir() / "logs" / f"rostest_{slug(rostest_file.name)}.log"
    log.parent.mkdir(exist_ok=True)
    xml = (
        sorted((results / "uav_autonomy").glob(f"*{rostest_file.stem}*.xml"))
        if (results / "uav_autonomy").exists()
        else []
    )
    details = "\n".join(p.read_text(errors="replace")[-4000:] for p in xml)
    log.write_text(proc.stdout + "\n--- stderr ---\n" + proc.stderr + "\n--- results ---\n" + details)
    tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-60:])
    assert proc.returncode == 0, f"rostest {rostest_file.name} failed (log: {log}):\n{tail}\n{details[-3000:]}"
