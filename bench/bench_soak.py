"""Soak of the causal lockstep (issue 31): 30 simulated minutes of the loiter, deterministic, in the small world with
160x120 cameras (``bench/scenarios/soak_loiter.yaml``), recorded; then the same run again.

* ``soak.loiter.rss_growth``: the largest resident memory of any of the run's processes at the end against its
  level at 5 simulated minutes (after warm-up: the map, the scorer's records and the bag's buffers have started to
  fill); value: that process's RSS at the end (MB), baseline: its RSS at 5 minutes; target ratio <= 1.2. The notes
  give every process's two figures.
* ``soak.loiter.bag_complete``: the recorded bag's ground-truth odometry covers the run: its last stamp against
  the run's simulated duration (the bag is closed, readable, indexed); target >= 0.99.
* ``soak.loiter.rerun_identical``: the rerun's real-time factor against the first run's; ``met`` when its
  metrics and time series are identical.

Usage: ``scripts/in_env python bench/bench_soak.py [--sim-seconds 1800]`` (about 10 wall minutes a run on 2 cores).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from benchlib import REPO, record

SCENARIO = REPO / "bench" / "scenarios" / "soak_loiter.yaml"
WARM_S = 300.0
MAX_GROWTH = 1.2


class RssSampler:
    """Resident memory of every process of one run (its command line names the run folder), with the run's
    simulated time (the scorer's newest time-series row), sampled every 2 wall seconds."""

    def __init__(self, run_dir: Path) -> None:
        self.marker = str(run_dir).encode()
        self.rows = run_dir / "timeseries.csv"
        self.samples: list[tuple[float, dict[str, float]]] = []  # (simulated s, {process: MB})
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._page_mb = os.sysconf("SC_PAGE_SIZE") / 1e6

    def __enter__(self) -> RssSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _sim_s(self) -> float | None:
        try:
            with self.rows.open() as fh:
                rows = list(csv.DictReader(fh))
        except OSError:
            return None
        last = rows[-1] if rows else None
        return float(last["t_s"]) if last and last.get("t_s") else None

    def _run(self) -> None:
        while not self._stop.wait(2.0):
            sim = self._sim_s()
            if sim is None:
                continue
            rss: dict[str, float] = {}
            for entry in os.scandir("/proc"):
                if not entry.name.isdigit():
                    continue
                try:
                    cmd = Path(entry.path, "cmdline").read_bytes()
                    if self.marker not in cmd:
                        continue
                    pages = int(Path(entry.path, "statm").read_text().split()[1])
                except (OSError, ValueError, IndexError):
                    continue
                name = _node_name(cmd)
                rss[name] = rss.get(name, 0.0) + pages * self._page_mb
            if rss:
                self.samples.append((sim, rss))

    def at(self, sim_s: float) -> dict[str, float]:
        """The first sample at or after ``sim_s`` (the last one if none)."""
        for t, rss in self.samples:
            if t >= sim_s:
                return rss
        return self.samples[-1][1] if self.samples else {}


def _node_name(cmdline: bytes) -> str:
    args = [a.decode(errors="replace") for a in cmdline.split(b"\0") if a]
    for a in args:
        if a.startswith("__name:="):
            return a.split(":=", 1)[1]
    for a in args:
        base = Path(a).name
        if base.startswith("uav-") or base in ("rosmaster", "roslaunch", "rosout", "record"):
            return base
    return Path(args[0]).name if args else "?"


def run(run_dir: Path, sim_s: float) -> tuple[dict[str, Any], dict[str, float], RssSampler]:
    argv = ["uav-run", str(SCENARIO), "--run-dir", str(run_dir), "--quiet", "--time-limit", f"{sim_s:g}"]
    with RssSampler(run_dir) as rss:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=sim_s * 3 + 600, check=False)
    if proc.returncode != 0:
        msg = f"uav-run failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        raise RuntimeError(msg)
    return json.loads((run_dir / "metrics.json").read_text()), json.loads((run_dir / "pace.json").read_text()), rss


def bag_coverage(bag: Path, duration_s: float) -> tuple[float, int]:
    """(last ground-truth odometry stamp since the first, over the run's duration; odometry messages)."""
    from rosbags.highlevel import AnyReader  # noqa: PLC0415

    with AnyReader([bag]) as reader:
        conns = [c for c in reader.connections if c.topic == "/uav/ground_truth/odom"]
        stamps = [t for _c, t, _raw in reader.messages(connections=conns)]
    if not stamps:
        return 0.0, 0
    return (stamps[-1] - stamps[0]) * 1e-9 / duration_s, len(stamps)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sim-seconds", type=float, default=1800.0)
    p.add_argument("--keep", type=Path, help="keep the run folders here")
    args = p.parse_args()
    if shutil.which("uav-run") is None:
        sys.stderr.write("bench_soak: uav-run not on PATH; run inside the project environment (scripts/in_env)\n")
        return 2
    parent = args.keep or Path(tempfile.mkdtemp(prefix="bench_soak_"))
    try:
        t0 = time.monotonic()
        first, pace, rss = run(parent / "first", args.sim_seconds)
        wall = time.monotonic() - t0
        again, pace2, _ = run(parent / "again", args.sim_seconds)
        warm, end = rss.at(min(WARM_S, args.sim_seconds / 6)), rss.at(float("inf"))
        growth = {n: end[n] / warm[n] for n in end if n in warm and warm[n] > 0}
        worst = max(growth, key=lambda n: growth[n])
        duration = float(first["time"]["duration_s"])
        coverage, n_odom = bag_coverage(parent / "first" / "run.bag", duration)
        identical = {k: v for k, v in first.items() if k != "versions"} == {
            k: v for k, v in again.items() if k != "versions"
        } and (parent / "first" / "timeseries.csv").read_text() == (parent / "again" / "timeseries.csv").read_text()
    finally:
        if args.keep is None:
            shutil.rmtree(parent, ignore_errors=True)
    record(
        "soak.loiter.rss_growth",
        end[worst],
        "MB",
        warm[worst],
        target=f"ratio <= {MAX_GROWTH:g} for every process",
        met=growth[worst] <= MAX_GROWTH,
        notes=f"{args.sim_seconds:g} s simulated, deterministic lockstep, small world, 160x120 cameras, recorded "
        f"({wall:.0f} s wall, {pace['real_time_factor']:.2f}x); the process that grew most: {worst}; every process "
        f"(MB at {WARM_S:g} s -> end): "
        + ", ".join(f"{n} {warm[n]:.0f}->{end[n]:.0f}" for n in sorted(growth, key=lambda n: -growth[n])),
    )
    record(
        "soak.loiter.bag_complete",
        coverage,
        "fraction",
        1.0,
        target=">= 0.99",
        met=coverage >= 0.99,
        notes=f"run.bag's /uav/ground_truth/odom spans {coverage:.3f} of the run's {duration:.0f} s "
        f"({n_odom} messages)",
    )
    record(
        "soak.loiter.rerun_identical",
        float(pace2["real_time_factor"]),
        "x",
        float(pace["real_time_factor"]),
        target="metrics and time series identical",
        met=identical,
        notes=f"the same soak again: metrics and time series {'identical' if identical else 'DIFFERENT'}",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
