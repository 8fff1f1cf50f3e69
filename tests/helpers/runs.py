"""Scenario runs for the e2e tests: ``uav-run`` to the end, its metrics, and comparing two runs.

Every run gets a private ROS master and free ports (uav-run allocates them), writes into
``artifacts/<group>/<name>/`` and is stopped by uav-run itself (SIGINT to roslaunch, then escalation); a run that
fails still leaves its folder (logs, metrics, bag) behind to look at.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from helpers.procs import Proc, artifacts_dir

__all__ = ["cpu_hogs", "flat", "metrics", "metrics_differences", "start_run", "uav_run", "wait_run"]


def start_run(scenario: Path, run_dir: Path, name: str, *extra: str) -> Proc:
    """Start ``uav-run`` into ``run_dir`` (emptied first); :func:`wait_run` waits for it."""
    shutil.rmtree(run_dir, ignore_errors=True)
    return Proc(f"uav_run_{name}", ["uav-run", str(scenario), "--run-dir", str(run_dir), "--quiet", *extra])


def wait_run(proc: Proc, name: str, timeout_s: float) -> str:
    """Wait for a started run to end; returns its output. A run that fails or takes too long fails the test."""
    try:
        rc = proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.signal(signal.SIGINT)  # uav-run stops its run and still builds the report
        proc.wait(60)
        pytest.fail(f"uav-run {name} took longer than {timeout_s} s:\n{proc.tail()}")
    finally:
        proc.stop()
    out = proc.log_text()
    assert rc == 0, f"uav-run {name} exited {rc}:\n{out[-3000:]}"
    return out


def uav_run(
    scenario: Path, name: str, *extra: str, group: str = "scenario_e2e", timeout_s: float = 240.0
) -> tuple[Path, str]:
    """Run ``uav-run`` to the end; returns the run folder and uav-run's output."""
    run_dir = artifacts_dir() / group / name
    return run_dir, wait_run(start_run(scenario, run_dir, name, *extra), name, timeout_s)


def metrics(run_dir: Path) -> dict[str, Any]:
    return json.loads((run_dir / "metrics.json").read_text())


def flat(data: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A nested mapping as ``{"a.b.c": value}`` (lists left out)."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            out.update(flat(value, f"{prefix}{key}."))
        elif not isinstance(value, list):
            out[prefix + key] = value
    return out


def metrics_differences(a: Path, b: Path) -> dict[str, tuple[Any, Any]]:
    """Every metric of two runs that differs (the software versions aside), lists included (as JSON)."""
    ma, mb = metrics(a), metrics(b)
    ma.pop("versions", None)
    mb.pop("versions", None)
    fa, fb = flat(ma), flat(mb)
    out = {k: (fa.get(k), fb.get(k)) for k in set(fa) | set(fb) if fa.get(k) != fb.get(k)}
    if json.dumps(ma, sort_keys=True) != json.dumps(mb, sort_keys=True) and not out:
        out["(lists)"] = ("differ", "")
    return out


@contextlib.contextmanager
def cpu_hogs(count: int = 2) -> Iterator[None]:
    """``count`` busy loops (one per core of the CI machine) while the block runs."""
    argv = [sys.executable, "-c", "while True: pass"]
    procs = [subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for _ in range(count)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()
