"""Benchmark of campaigns on Dask: ``config/campaigns/smoke.yaml`` (2 arms x 2 seeds, 20 simulated seconds of the
loiter in the small world with 160x120 cameras) through ``uav-campaign``, against the same four runs one after
another with ``uav-run``, on the same cores, in the same benchmark run.

* ``campaign.smoke.sequential``: the baseline: each run's effective scenario (as the campaign plans it) run by
  ``uav-run`` one after another; simulated seconds per wall second over the four.
* ``campaign.smoke.throughput``: ``uav-campaign run`` on its embedded local cluster sized to the machine
  (smoke.yaml says a run keeps one core busy, so two workers on two cores): simulated seconds per wall second of
  the whole command (cluster start, runs, tables and report); baseline the sequential figure. Target: no loss
  (ratio >= 1).
* ``campaign.smoke.identical_to_sequential``: how many of the campaign's runs (two at a time on two workers) have
  the same metrics and time series as the same run flown alone; the runs are deterministic (docs/lockstep.md), so
  the target is all of them.
* ``campaign.smoke.throughput_1_worker``: the same with ``--workers 1``, so the runs go one after another as in
  the baseline and the only difference is the campaign machinery. Target: no loss beyond the overhead below.
* ``campaign.smoke.overhead_per_run_s``: in that one-worker campaign, the wall seconds per run not spent inside
  ``uav-run``, from the manifest's timestamps (first submission to last result, minus the runs' own wall time):
  Dask scheduling, the task start, writing the run's inputs, the manifest. Target < 2 s; baseline the mean
  sequential run's wall time.
* ``campaign.smoke.command_overhead_s``: the one-worker command's wall time minus the sequential runs' wall time,
  per run: the above plus starting the embedded cluster and building the tables and the report.

Usage: ``scripts/in_env python bench/bench_campaign.py [--repeats 1]``. One unmeasured run first fills the world,
surface-voxel and shader caches; the order alternates sequential / campaign between repeats so that the shared
machine's drift hits both.
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

from benchlib import REPO, record

from uav_campaigns.cli.campaign import _plan
from uav_campaigns.core.config import load_campaign
from uav_campaigns.shell.runner import uav_run_argv, write_inputs
from uav_common.config import to_mapping

SMOKE = REPO / "config" / "campaigns" / "smoke.yaml"
OVERHEAD_TARGET_S = 2.0


def sequential(tmp: Path, *, warm_up: bool = False) -> tuple[float, float, list[float], dict[str, Path]]:
    """The smoke campaign's runs one after another with uav-run: (wall s, simulated s, each run's wall s, each run's
    folder by key).

    ``warm_up``: only the first run, unmeasured (world and surface-voxel caches, Mesa's shader cache).
    """
    campaign = load_campaign(SMOKE)
    walls: list[float] = []
    dirs: dict[str, Path] = {}
    sim = 0.0
    t0 = time.monotonic()
    for run in _plan(campaign)[: 1 if warm_up else None]:
        scenario = to_mapping(run.scenario)
        scenario.pop("source", None)
        scenario["name"] = f"{campaign.name}-{run.arm}-s{run.seed}-r{run.repeat}"  # as the campaign names it
        job = {
            "campaign": campaign.name,
            "label": run.label,
            "config_hash": run.config_hash,
            "scenario": scenario,
            "world_text": run.scenario.world_config_path.read_text(),
        }
        run_dir = tmp / "sequential" / run.arm / run.slug
        path = write_inputs(job, run_dir)
        r0 = time.monotonic()
        proc = subprocess.run(uav_run_argv(path, run_dir), capture_output=True, text=True, timeout=900, check=False)
        walls.append(time.monotonic() - r0)
        if proc.returncode != 0:
            msg = f"uav-run {run.label} exited {proc.returncode}:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
            raise RuntimeError(msg)
        sim += float(json.loads((run_dir / "metrics.json").read_text())["time"]["duration_s"])
        dirs[run.key] = run_dir
        print(f"  sequential {run.label}: {walls[-1]:.1f} s wall", flush=True)
    return time.monotonic() - t0, sim, walls, dirs


def same_runs(seq: dict[str, Path], events: list[dict[str, Any]]) -> tuple[int, int]:
    """(runs whose metrics and time series equal the sequential run of the same key, runs compared)."""
    done = {e["key"]: Path(e["run_dir"]) for e in events if e.get("event") == "finished" and e["status"] == "done"}
    same = 0
    for key, run_dir in seq.items():
        other = done.get(key)
        if other is None:
            continue
        a, b = (json.loads((d / "metrics.json").read_text()) for d in (run_dir, other))
        a.pop("versions", None)
        b.pop("versions", None)
        rows = (run_dir / "timeseries.csv").read_text() == (other / "timeseries.csv").read_text()
        same += int(a == b and rows)
    return same, len(seq)


def campaign(tmp: Path, name: str, *extra: str) -> tuple[float, float, list[dict[str, Any]]]:
    """``uav-campaign run smoke.yaml`` on the embedded cluster: (wall s, simulated s, manifest events)."""
    out = tmp / name
    t0 = time.monotonic()
    argv = ["uav-campaign", "run", str(SMOKE), "--out", str(out), "--dashboard-address", ":0", *extra]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=1800, check=False)
    wall = time.monotonic() - t0
    if proc.returncode != 0:
        msg = f"uav-campaign exited {proc.returncode}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        raise RuntimeError(msg)
    events = [json.loads(line) for line in (out / "manifest.jsonl").read_text().splitlines() if line.strip()]
    sim = sum(float(e.get("sim_s") or 0.0) for e in events if e.get("event") == "finished" and e["status"] == "done")
    print(f"  campaign {name}: {wall:.1f} s wall", flush=True)
    return wall, sim, events


def scheduling_overhead(events: list[dict[str, Any]]) -> float:
    """Wall seconds per run outside uav-run, first submission to last result (one worker: runs do not overlap)."""
    submitted = [e["t"] for e in events if e["event"] == "submitted"]
    finished = [e for e in events if e["event"] == "finished" and e["status"] == "done"]
    span = max(e["t"] for e in finished) - min(submitted)
    return (span - sum(float(e["wall_s"]) for e in finished)) / len(finished)


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--repeats", type=int, default=1)
    args = p.parse_args(argv)
    if shutil.which("uav-campaign") is None:
        print("uav-campaign is not on PATH: run inside the project environment (scripts/in_env)", file=sys.stderr)
        return 3
    seq_wall = seq_sim = c1_wall = c1_sim = ca_wall = ca_sim = 0.0
    seq_runs: list[float] = []
    overheads: list[float] = []
    identical = compared = 0
    for i in range(args.repeats):
        with tempfile.TemporaryDirectory(prefix="bench_campaign_") as d:
            tmp = Path(d)
            if i == 0:
                sequential(tmp / "warm_up", warm_up=True)
            order = ("seq", "one", "auto") if i % 2 == 0 else ("auto", "one", "seq")
            seq_dirs: dict[str, Path] = {}
            auto_events: list[dict[str, Any]] = []
            for what in order:
                if what == "seq":
                    w, s, runs, seq_dirs = sequential(tmp)
                    seq_wall, seq_sim = seq_wall + w, seq_sim + s
                    seq_runs += runs
                elif what == "one":
                    w, s, events = campaign(tmp, "one_worker", "--workers", "1")
                    c1_wall, c1_sim = c1_wall + w, c1_sim + s
                    overheads.append(scheduling_overhead(events))
                else:
                    w, s, auto_events = campaign(tmp, "auto")
                    ca_wall, ca_sim = ca_wall + w, ca_sim + s
            same, n = same_runs(seq_dirs, auto_events)
            identical, compared = identical + same, compared + n
    n_runs = len(seq_runs)
    seq_rate = seq_sim / seq_wall
    mean_run = sum(seq_runs) / n_runs
    notes = f"{n_runs} runs of smoke.yaml; sequential {seq_wall:.0f} s wall for {seq_sim:.0f} simulated s"
    record("campaign.smoke.sequential", seq_rate, "sim s/s", seq_rate, notes=notes)
    auto_rate = ca_sim / ca_wall
    record(
        "campaign.smoke.throughput", auto_rate, "sim s/s", seq_rate,
        target=">= 1x sequential", met=auto_rate >= seq_rate,
        notes=f"embedded cluster sized to the machine (cores_per_run 1): {ca_wall:.0f} s wall, whole command; "
        f"deterministic runs (smoke.yaml): {identical} of {compared} identical to the same run one after another",
    )  # fmt: skip
    record(
        "campaign.smoke.identical_to_sequential", float(identical), "runs", float(compared),
        target="every run", met=identical == compared,
        notes="runs of the embedded cluster's campaign (two at once) whose metrics.json (but the software versions) "
        "and timeseries.csv equal the same run's flown alone with uav-run",
    )  # fmt: skip
    one_rate = c1_sim / c1_wall
    record(
        "campaign.smoke.throughput_1_worker", one_rate, "sim s/s", seq_rate,
        notes=f"--workers 1: {c1_wall:.0f} s wall, whole command (cluster start, runs, tables, report)",
    )  # fmt: skip
    overhead = sum(overheads) / len(overheads)
    record(
        "campaign.smoke.overhead_per_run_s", overhead, "s", mean_run, target=f"< {OVERHEAD_TARGET_S:g} s",
        met=overhead < OVERHEAD_TARGET_S,
        notes=f"per run outside uav-run between first submission and last result (one worker); each: {overheads}",
    )  # fmt: skip
    command = (c1_wall - seq_wall) / n_runs
    record(
        "campaign.smoke.command_overhead_s", command, "s", mean_run,
        notes="per run: one-worker command wall minus sequential wall (adds cluster start-up, tables and report)",
    )  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
