"""Search and rescue with the learned detector against the ground truth's boxes, over 10 person placements in a world
the detector never trained on: ``config/campaigns/sar_detectors.yaml`` through ``uav-campaign`` (issue 22).

Both arms fly ``config/scenarios/sar_learned_detector.yaml`` (the default world, seed 7; the detector trained on
seeds 11-16) with the person placed by seeds 1-10; the ``ground_truth`` arm swaps the learned detector for the
bridge's boxes (search_and_rescue.yaml's detector), so the baseline is measured in the same run of the benchmark.

* ``detector.sar.found_rate``: placements where the learned detector's search confirmed the person within 600 s
  (the candidate check accepts only the person searched for), over 10; baseline the ground truth's rate. Target:
  >= 0.8 (8 of 10).
* ``detector.sar.time_to_confirm_s``: median simulated seconds to confirmation over the placements both arms
  found; baseline the ground truth's median over the same placements.

The campaign folder (``runs/campaigns/sar_detectors``) is kept: ``uav-campaign run`` skips runs already done, so
running the benchmark again after an interruption finishes the campaign; ``--fresh`` starts over (needed after
the model or the scenario changed: the campaign refuses a folder made by another campaign file).

Usage: ``scripts/in_env python bench/bench_sar_detectors.py [--fresh] [--out DIR]``. About 20-40 minutes on
2 cores (20 runs of up to 600 simulated seconds, one at a time).
"""

from __future__ import annotations

import argparse
import csv
import math
import shutil
import subprocess
import sys
import time
from pathlib import Path

from benchlib import REPO, median, record

CAMPAIGN = REPO / "config" / "campaigns" / "sar_detectors.yaml"
OUT = REPO / "runs" / "campaigns" / "sar_detectors"


def _float(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        return math.nan


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, default=OUT, help="the campaign folder (kept; resumed)")
    ap.add_argument("--fresh", action="store_true", help="delete the campaign folder first")
    args = ap.parse_args(argv)
    if args.fresh:
        shutil.rmtree(args.out, ignore_errors=True)
    if shutil.which("uav-campaign") is None:
        print("uav-campaign is not on PATH: run inside the project environment (scripts/in_env)", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    cmd = ["uav-campaign", "run", str(CAMPAIGN), "--out", str(args.out), "--dashboard-address", ":0"]
    rc = subprocess.run(cmd, cwd=REPO, check=False).returncode
    wall_s = time.perf_counter() - t0
    runs_csv = args.out / "runs.csv"
    if not runs_csv.is_file():
        print(f"bench_sar_detectors: {' '.join(cmd)} exited {rc} and wrote no {runs_csv}", file=sys.stderr)
        return 1
    with runs_csv.open() as fh:
        rows = [r for r in csv.DictReader(fh) if r.get("status") == "done"]
    by_arm: dict[str, dict[int, float]] = {"ground_truth": {}, "learned": {}}
    for r in rows:
        if r["arm"] in by_arm:
            by_arm[r["arm"]][int(r["seed"])] = _float(r.get("time.complete_s", ""))
    # the rates as the campaign computed them (success.csv, criterion "found"), not counted again here
    with (args.out / "success.csv").open() as fh:
        found_rows = {r["arm"]: r for r in csv.DictReader(fh) if r["criterion"] == "found"}
    if set(found_rows) != set(by_arm):
        print(f"bench_sar_detectors: success.csv has 'found' for {sorted(found_rows)} (rc {rc}); see {args.out}",
              file=sys.stderr)  # fmt: skip
        return 1
    n = {arm: int(found_rows[arm]["n"]) for arm in by_arm}
    found = {arm: int(found_rows[arm]["successes"]) for arm in by_arm}
    rate = {arm: float(found_rows[arm]["rate"]) for arm in by_arm}
    learned_found = {s: t for s, t in by_arm["learned"].items() if math.isfinite(t)}
    missed = sorted(s for s, t in by_arm["learned"].items() if not math.isfinite(t))
    ci = {arm: f"{float(found_rows[arm]['ci_low']):.2f}-{float(found_rows[arm]['ci_high']):.2f}" for arm in by_arm}
    notes = (
        f"learned found {found['learned']}/{n['learned']} placements (missed seeds {missed or 'none'}), ground truth "
        f"{found['ground_truth']}/{n['ground_truth']} (Wilson 95 % intervals: learned {ci['learned']}, ground truth "
        f"{ci['ground_truth']}); config/campaigns/sar_detectors.yaml, default world "
        f"seed 7 (held "
        f"out), person placement seeds 1-10, 600 s limit, lockstep; campaign command rc {rc}, {wall_s:.0f} s wall "
        f"this invocation (runs already done are not run again); {args.out}"
    )
    record(
        "detector.sar.found_rate",
        rate["learned"],
        "fraction",
        rate["ground_truth"],
        target="learned >= 0.8 (8 of 10 placements)",
        met=rate["learned"] >= 0.8 and n["learned"] >= 10,
        notes=notes,
    )
    both = sorted(s for s in learned_found if math.isfinite(by_arm["ground_truth"].get(s, math.nan)))
    if both:
        record(
            "detector.sar.time_to_confirm_s",
            median([learned_found[s] for s in both]),
            "s",
            median([by_arm["ground_truth"][s] for s in both]),
            notes=f"medians over the {len(both)} placements both arms found (seeds {both}); simulated seconds",
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
