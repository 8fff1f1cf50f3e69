"""Run every ``tests/ros/**/*.test`` rostest file with a real master.

Each .test file is a roslaunch file with ``<test>`` nodes; ``rostest`` starts its
own roscore on a free port, so files are independent. rostest runs without
``--text`` on purpose: with ``--text`` it exits 0 even when a test fails.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from helpers.procs import artifacts_dir, slug

HERE = Path(__file__).resolve().parent
TEST_FILES = sorted(HERE.rglob("*.test"))


@pytest.mark.parametrize("test_file", TEST_FILES, ids=[str(p.relative_to(HERE)) for p in TEST_FILES])
def test_rostest(test_file: Path) -> None:
    results = artifacts_dir() / "rostest"
    results.mkdir(exist_ok=True)
    proc = subprocess.run(
        [
            "rostest",
            "--package=uav_rostests",
            f"--pkgdir={HERE}",
            f"--results-base-dir={results}",
            str(test_file),
        ],
        capture_output=True,
        text=True,
        timeout=280,
        check=False,
    )
    log = artifacts_dir() / "logs" / f"rostest_{slug(str(test_file.relative_to(HERE)))}.log"
    log.parent.mkdir(exist_ok=True)
    log.write_text(proc.stdout + "\n--- stderr ---\n" + proc.stderr)
    tail = "\n".join((proc.stdout + proc.stderr).splitlines()[-80:])
    assert proc.returncode == 0, f"rostest {test_file.name} failed with {proc.returncode} (full log: {log}):\n{tail}"
    assert "RESULT: SUCCESS" in proc.stdout, f"rostest {test_file.name} did not report success:\n{tail}"
    # a check node that crashes before its first test case leaves rostest reporting success over no test at all
    assert " * TESTS: 0" not in proc.stdout, f"rostest {test_file.name} ran no test case:\n{tail}"
