"""Benchmark of the whole loiter loop (issue 9): SITL + router + sim bridge (two 640x480 cameras) +
map server (OctoMap, 0.5 m) + feature evaluator + goal selector + planner + controller + tracker +
scorer, started by ``uav-run`` exactly as a user would, in lockstep so the simulation runs as fast as
the slowest part of the loop allows.

Two runs over the same simulated time, in the same benchmark run:

* ``config/scenarios/loiter.yaml`` (the MCDM autonomy, default cameras and map);
* ``bench/scenarios/loiter_lawnmower.yaml`` (the baseline: a SCRIPTED lawnmower over a 200 m x 200 m
  box around home, same world, cameras, map, altitude and cruise speed).

Results (``bench/results/latest.jsonl``):

* ``scenario.loiter.rtf``: simulated seconds per wall second from the mission start to the stop
  (``pace.json`` written by uav-run); baseline: the lawnmower run's. Target >= 3x on 2 cores.
* ``scenario.loiter.coverage_rate_m2_per_s``: mapped m² per airborne second (metrics.json);
  baseline: the lawnmower's.
* ``scenario.loiter.coverage_efficiency``: that rate over the physical limit (camera swath at the
  flown height x cruise speed, first footprint excluded; docs/scenarios.md); baseline: the
  lawnmower's.

Usage: ``scripts/in_env python bench/bench_scenario.py [--sim-seconds 120]``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

from benchlib import record  # noqa: E402

LOITER = REPO / "config/scenarios/loiter.yaml"
LAWNMOWER = REPO / "bench/scenarios/loiter_lawnmower.yaml"
RTF_TARGET = 3.0


def run(scenario: Path, run_dir: Path, sim_seconds: float) -> tuple[dict[str, Any], dict[str, float]]:
    """One uav-run in lockstep without recording; returns (metrics.json, pace.json)."""
    argv = [
        "uav-run", str(scenario), "--run-dir", str(run_dir), "--lockstep", "--no-record", "--quiet",
        "--time-limit", f"{sim_seconds:g}",
    ]  # fmt: skip
    t0 = time.monotonic()
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=sim_seconds * 10 + 300, check=False)
    wall = time.monotonic() - t0
    print(f"  {scenario.name}: uav-run exited {proc.returncode} after {wall:.0f} s wall", flush=True)
    if proc.returncode != 0:
        msg = f"uav-run {scenario.name} failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        raise RuntimeError(msg)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    pace = json.loads((run_dir / "pace.json").read_text())
    return metrics, pace


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
        loiter, loiter_pace = run(LOITER, parent / "loiter", args.sim_seconds)
        mower, mower_pace = run(LAWNMOWER, parent / "lawnmower", args.sim_seconds)
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
        notes=f"{notes} (sim {loiter_pace['sim_s']:.0f} s in {loiter_pace['wall_s']:.0f} s wall)",
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
