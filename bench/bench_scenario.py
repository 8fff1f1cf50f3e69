"""Benchmark of the whole loiter loop (issue 9): SITL + router + sim bridge (two 640x480 cameras) +
map server (OctoMap, 0.5 m) + feature evaluator + goal selector + planner + controller + tracker +
scorer, started by ``uav-run`` exactly as a user would, in lockstep so the simulation runs as fast as
the slowest part of the loop allows.

Two runs over the same simulated time, in the same benchmark run:

* ``config/scenarios/loiter.yaml`` (the MCDM autonomy, default cameras and map);
* ``bench/scenarios/loiter_lawnmower.yaml`` (the baseline: a SCRIPTED lawnmower over a 200 m x 200 m
  box around home, same world, cameras, map and cruise speed, following the terrain 50 m above it).

Results (``bench/results/latest.jsonl``):

* ``scenario.loiter.rtf``: simulated seconds per wall second from the mission start to the stop
  (``pace.json`` written by uav-run); baseline: the lawnmower run's. Target >= 3x on 2 cores.
* ``scenario.loiter.coverage_rate_m2_per_s``: mapped m² per airborne second (metrics.json);
  baseline: the lawnmower's.
* ``scenario.loiter.coverage_efficiency``: that rate over the physical limit (camera swath at the
  flown height x cruise speed, first footprint excluded; docs/scenarios.md); baseline: the
  lawnmower's.
* ``scenario.loiter.clouds_dropped_pct``: nadir clouds the map server dropped because insertion fell
  behind (a loop that only looks fast by losing map data would show here); baseline: the lawnmower's.
* ``scenario.loiter.cpu_s_per_sim_s``: CPU seconds of all the run's processes per simulated second
  (sampled from /proc; the notes break it down per node); on 2 cores 3x real time needs <= 0.67.

Usage: ``scripts/in_env python bench/bench_scenario.py [--sim-seconds 120]``.
"""

from __future__ import annotations

import argparse
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

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

from benchlib import record  # noqa: E402

LOITER = REPO / "config/scenarios/loiter.yaml"
LAWNMOWER = REPO / "bench/scenarios/loiter_lawnmower.yaml"
RTF_TARGET = 3.0


class CpuSampler:
    """CPU seconds per process of one run while simulated time runs: every process whose command line names
    the run folder (roslaunch gives every node a log path inside it; the SITL and router read their config
    from it), sampled from /proc twice a second. Counted from the scorer's first time-series row (the
    mission start: start-up work such as loading the world is excluded) to each process's last sample."""

    def __init__(self, run_dir: Path) -> None:
        self.marker = str(run_dir).encode()
        self.started = run_dir / "timeseries.csv"
        self.tick_s = 1.0 / os.sysconf("SC_CLK_TCK")
        self.cpu_s: dict[int, tuple[str, float]] = {}
        self.at_start: dict[int, float] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> CpuSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        while not self._stop.wait(0.5):
            if self.at_start is None and self.started.exists():
                self.at_start = {pid: cpu for pid, (_, cpu) in self.cpu_s.items()}
            for entry in os.scandir("/proc"):
                if not entry.name.isdigit():
                    continue
                try:
                    cmd = Path(entry.path, "cmdline").read_bytes()
                    stat = Path(entry.path, "stat").read_text()
                except OSError:
                    continue
                if self.marker not in cmd:
                    continue
                fields = stat.rsplit(")", 1)[1].split()
                cpu = (int(fields[11]) + int(fields[12])) * self.tick_s  # utime + stime
                self.cpu_s[int(entry.name)] = (_node_name(cmd), cpu)

    def per_node(self) -> dict[str, float]:
        start = self.at_start or {}
        out: dict[str, float] = {}
        for pid, (name, cpu) in self.cpu_s.items():
            out[name] = out.get(name, 0.0) + cpu - start.get(pid, 0.0)
        return out


def _node_name(cmdline: bytes) -> str:
    args = [a.decode(errors="replace") for a in cmdline.split(b"\0") if a]
    for a in args:
        if a.startswith("__name:="):
            return a.split(":=", 1)[1]
    for a in args:
        base = Path(a).name
        if base.startswith("uav-") or base in ("rosmaster", "roslaunch", "rosout"):
            return base
    return Path(args[0]).name if args else "?"


def run(scenario: Path, run_dir: Path, sim_seconds: float) -> tuple[dict[str, Any], dict[str, float], dict[str, float]]:
    """One uav-run in lockstep without recording; returns (metrics.json, pace.json, CPU s per process)."""
    argv = [
        "uav-run", str(scenario), "--run-dir", str(run_dir), "--lockstep", "--no-record", "--quiet",
        "--time-limit", f"{sim_seconds:g}",
    ]  # fmt: skip
    t0 = time.monotonic()
    with CpuSampler(run_dir) as cpu:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=sim_seconds * 10 + 300, check=False)
    wall = time.monotonic() - t0
    print(f"  {scenario.name}: uav-run exited {proc.returncode} after {wall:.0f} s wall", flush=True)
    if proc.returncode != 0:
        msg = f"uav-run {scenario.name} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        raise RuntimeError(msg)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    pace = json.loads((run_dir / "pace.json").read_text())
    return metrics, pace, cpu.per_node()


def _flight(metrics: dict[str, Any], label: str) -> str:
    """Mean height above ground and collisions: the higher a run flies, the more each frame maps."""
    flight = metrics.get("flight") or {}
    collisions = (metrics.get("collisions") or {}).get("count", 0)
    return f"{label} mean {float(flight.get('agl_mean_m', float('nan'))):.0f} m AGL, {collisions} collisions"


def dropped_pct(metrics: dict[str, Any]) -> float:
    m = metrics.get("map_input") or {}
    received = float(m.get("clouds_received", 0))
    return 100.0 * float(m.get("dropped_queue_full", 0)) / received if received else float("nan")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sim-seconds", type=float, default=120.0, help="simulated seconds per run")
    p.add_argument("--keep", type=Path, help="keep the run folders here (default: a temporary folder)")
    args = p.parse_args()
    if shutil.which("uav-run") is None:
        sys.stderr.write("bench_scenario: uav-run not on PATH; run inside the project environment (scripts/in_env)\n")
        return 2
    parent = args.keep or Path(tempfile.mkdtemp(prefix="bench_scenario_"))
    try:
        loiter, loiter_pace, loiter_cpu = run(LOITER, parent / "loiter", args.sim_seconds)
        mower, mower_pace, mower_cpu = run(LAWNMOWER, parent / "lawnmower", args.sim_seconds)
    finally:
        if args.keep is None:
            shutil.rmtree(parent, ignore_errors=True)
    notes = f"{args.sim_seconds:g} s simulated, lockstep, 2x 640x480 cameras, OctoMap 0.5 m; baseline lawnmower"
    rtf = loiter_pace["real_time_factor"]
    record(
        "scenario.loiter.rtf",
        rtf,
        "x",
        mower_pace["real_time_factor"],
        target=f">= {RTF_TARGET:g}",
        met=rtf >= RTF_TARGET,
        notes=f"{notes} (sim {loiter_pace['sim_s']:.0f} s in {loiter_pace['wall_s']:.0f} s wall); "
        f"{_flight(loiter, 'loiter')}; {_flight(mower, 'lawnmower')}",
    )
    record(
        "scenario.loiter.clouds_dropped_pct",
        dropped_pct(loiter),
        "%",
        dropped_pct(mower),
        notes=f"{notes}; clouds the map server dropped (queue_full) of {loiter['map_input'].get('clouds_received')}",
    )
    sim_s = float(loiter["time"]["duration_s"])
    per_sim = {k: v / sim_s for k, v in sorted(loiter_cpu.items(), key=lambda kv: -kv[1])}
    record(
        "scenario.loiter.cpu_s_per_sim_s",
        sum(per_sim.values()),
        "cpu-s/sim-s",
        sum(mower_cpu.values()) / float(mower["time"]["duration_s"]),
        target="<= 0.67 for 3x on 2 cores",
        met=sum(per_sim.values()) <= 2.0 / RTF_TARGET,
        notes=f"{notes}; per node: " + ", ".join(f"{k} {v:.3f}" for k, v in per_sim.items() if v >= 0.005),
    )
    cov, cov_base = loiter["coverage"], mower["coverage"]
    record(
        "scenario.loiter.coverage_rate_m2_per_s",
        float(cov["rate_m2_per_s"]),
        "m2/s",
        float(cov_base["rate_m2_per_s"]),
        notes=f"{notes}; mapped {cov['mapped_m2']:.0f} m2 vs {cov_base['mapped_m2']:.0f} m2",
    )
    record(
        "scenario.loiter.coverage_efficiency",
        float(cov["efficiency"]),
        "fraction",
        float(cov_base["efficiency"]),
        notes=f"{notes}; rate / (swath x cruise speed); loiter swath {cov.get('swath_m', float('nan')):.0f} m",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
