"""Benchmark of the whole loiter loop: SITL + router + sim bridge (two 640x480 cameras, nadir 5 Hz and
forward 10 Hz) + map server (OctoMap, 0.5 m) + feature evaluator + goal selector + planner + controller + tracker +
scorer, started by ``uav-run`` exactly as a user would, in lockstep so the simulation runs as fast as
the slowest part of the loop allows.

Two scenarios over the same simulated time, in the same benchmark run:

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
* ``scenario.loiter.clouds_dropped_pct``: nadir frames the map server dropped because insertion fell
  behind, or received incomplete (depth, colour and camera info of one stamp; a loop that only looks fast
  by losing map data would show here); baseline: the lawnmower's.
* ``scenario.loiter.cpu_s_per_sim_s``: CPU seconds of all the run's processes per simulated second
  (sampled from /proc; the notes break it down per node); on 2 cores 3x real time needs <= 0.67.
* ``scenario.loiter.rtf_moving_objects``: the loiter as shipped (walkers and drivers in the default world) against
  the same loiter with nobody moving (``actors: {people: {moving: 0}, vehicles: {moving: 0}}``), same run; target:
  a drop of no more than 10 %. ``--skip-static`` leaves it out.
* ``scenario.loiter.rtf_nadir_10hz``: the same loiter with the nadir (mapping) camera at 10 Hz, its default
  until stop 17 (config/sim_bridge.yaml says why it is 5 Hz now); baseline: the default loiter's. Its notes
  give the frames the map server dropped and the CPU per simulated second. ``--skip-nadir-10hz`` leaves it out.
* ``scenario.loiter.rtf_autopilot_lossy``: the same loiter flown, mapped and planned on the autopilot's own
  estimate (``pose_source: autopilot``: the autopilot odometry node, ODOMETRY over the router, tf
  ``map -> odom -> base_link``) over the ``lossy_link`` stress preset (20 % of the frames lost each way on the
  controller's link, 30 ms delay, 20 ms jitter, 1 % reordered; the GCS link fading); baseline: the default
  loiter's in the same run. Its notes give the pose error, the map precision of both, the frames dropped and the
  CPU per node. It flies in the
  ``gusty`` preset's wind (5 m/s from the west at 10 m, shear 0.14, moderate seeded Dryden turbulence), so the
  SITL's wind model is in the loop too. No target: on its own estimate in the wind the autonomy flies another
  path and sees other objects, and plain lockstep's paths move with the machine's load: in two benchmark runs of
  stop 31 the default loiter's forward camera scored 144 and 1078 detections, the lossy loiter's 1021 and 682, and
  the ratio was 0.75 and 0.94. It mixes the path's work with the estimate's; the notes break the CPU down per
  node, both ways.
* ``scenario.lawnmower.rtf_autopilot_lossy``: the same change on one path: the scripted lawnmower on the autopilot's
  estimate over ``lossy_link`` in the ``gusty`` wind against the lawnmower on the ground truth. Issue 23 allows it
  to lose at most 10 % (ratio >= 0.9). ``--skip-autopilot-lossy`` leaves both out.
* ``scenario.loiter.rtf_deterministic_ratio``: the default loiter in deterministic (causal) lockstep
  (``uav-run --deterministic``, docs/lockstep.md), alternated with the plain lockstep loiter in the same run;
  baseline the plain loiter's real-time factor; target ratio >= 0.8 (issue 31). Its notes say whether the
  deterministic runs were identical, the map frames each dropped (0 in deterministic lockstep) and the CPU.
* ``scenario.loiter.deterministic_beside_cpu_hog``: the deterministic loiter once more beside a busy loop on every
  core: its real-time factor (baseline: the deterministic runs alone) and whether its metrics and time series are
  identical to the first run alone (``met``). ``--skip-deterministic`` leaves both out.

Usage: ``scripts/in_env python bench/bench_scenario.py [--sim-seconds 120] [--repeats 2]``. The machine's
speed and the loiter's path (it depends on the map, which depends on the frames the map server had time for)
vary from run to run (2.9x-3.4x for the loiter on this shared 2-core VM, whose speed drifts by up to ~1.45x):
each scenario runs ``--repeats`` times, alternated, and the figures are the means, with every run's
real-time factor in the notes. Before each run a fixed probe times a memory-bound numpy workload and a pure
Python loop (best of 3): the notes give both, so figures from different times can be told apart from the
machine's own drift (on this VM the numpy probe has varied by ~1.5x within an hour, with JSBSim's speed
unchanged).
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from benchlib import REPO, record
from helpers.runs import cpu_hogs

LOITER = REPO / "config/scenarios/loiter.yaml"
LAWNMOWER = REPO / "bench/scenarios/loiter_lawnmower.yaml"
RTF_TARGET = 3.0
#: Deterministic (causal) lockstep must keep at least this share of plain lockstep's real-time factor (issue 31).
DETERMINISTIC_MIN_RATIO = 0.8
#: The autopilot-pose, lossy-link loop may lose at most this share of the clean loop's real-time factor.
AUTOPILOT_LOSSY_MAX_LOSS = 0.10


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
        self._other: dict[str, float] = {}  # pid -> when to look at it again (the sampler must stay cheap)
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
            now = time.monotonic()
            for entry in os.scandir("/proc"):
                if not entry.name.isdigit() or self._other.get(entry.name, -1.0) > now:
                    continue
                try:
                    cmd = Path(entry.path, "cmdline").read_bytes()
                    stat = Path(entry.path, "stat").read_text()
                except OSError:
                    continue
                if self.marker not in cmd:
                    # not the run's: look again in a while (a forked process may exec into one of its nodes)
                    self._other[entry.name] = now + 5.0
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


def machine_probe() -> tuple[float, float]:
    """(memory-bound numpy ms, pure Python ms), best of 3: how fast the machine is right now."""
    import numpy as np  # noqa: PLC0415 - only the probe needs it

    a = np.ones(8_000_000, np.float32)
    b = np.empty_like(a)
    best_np = best_py = float("inf")
    gc.collect()
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(10):
            np.multiply(a, 1.0001, out=b)
            np.add(b, a, out=b)
        best_np = min(best_np, time.perf_counter() - t0)
        t0 = time.perf_counter()
        total = 0
        for k in range(1_000_000):
            total += k & 7
        best_py = min(best_py, time.perf_counter() - t0)
    return 1000.0 * best_np, 1000.0 * best_py


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


def run(
    scenario: Path, run_dir: Path, sim_seconds: float, *, deterministic: bool = False
) -> tuple[dict[str, Any], dict[str, float], dict[str, float]]:
    """One uav-run in plain (or deterministic) lockstep without recording; returns (metrics.json, pace.json, CPU s
    per process)."""
    argv = [
        "uav-run", str(scenario), "--run-dir", str(run_dir), "--deterministic" if deterministic else "--lockstep",
        "--no-record", "--quiet", "--time-limit", f"{sim_seconds:g}",
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
    lost = float(m.get("dropped_queue_full", 0)) + float(m.get("dropped_unsynchronized", 0))
    return 100.0 * lost / received if received else float("nan")


@dataclass
class Runs:
    """The repeated runs of one scenario, alternated with the other's so both see the same machine."""

    metrics: list[dict[str, Any]] = field(default_factory=list)
    pace: list[dict[str, float]] = field(default_factory=list)
    cpu: list[dict[str, float]] = field(default_factory=list)
    #: machine_probe() before each run
    probes: list[tuple[float, float]] = field(default_factory=list)

    def mean(self, value: Callable[[int], float]) -> float:
        return statistics.fmean(value(i) for i in range(len(self.metrics)))

    def rtf(self) -> float:
        return self.mean(lambda i: float(self.pace[i]["real_time_factor"]))

    def rtfs(self) -> str:
        return ", ".join(f"{p['real_time_factor']:.2f}x" for p in self.pace)

    def probe_notes(self) -> str:
        return ", ".join(f"{n:.0f}/{py:.0f} ms" for n, py in self.probes)

    def sim_s(self, i: int) -> float:
        return float(self.metrics[i]["time"]["duration_s"])

    def cpu_per_sim_s(self) -> float:
        return self.mean(lambda i: sum(self.cpu[i].values()) / self.sim_s(i))

    def per_node(self) -> dict[str, float]:
        total_sim = sum(self.sim_s(i) for i in range(len(self.metrics)))
        out: dict[str, float] = {}
        for cpu in self.cpu:
            for k, v in cpu.items():
                out[k] = out.get(k, 0.0) + v / total_sim
        return dict(sorted(out.items(), key=lambda kv: -kv[1]))

    def dropped_pct(self) -> float:
        return self.mean(lambda i: dropped_pct(self.metrics[i]))

    def coverage(self, key: str) -> float:
        return self.mean(lambda i: float(self.metrics[i]["coverage"][key]))


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sim-seconds", type=float, default=120.0, help="simulated seconds per run")
    p.add_argument("--repeats", type=int, default=2, help="runs of each scenario (figures are their means)")
    p.add_argument("--keep", type=Path, help="keep the run folders here (default: a temporary folder)")
    p.add_argument("--skip-nadir-10hz", action="store_true", help="no runs with the nadir camera at 10 Hz")
    p.add_argument("--skip-static", action="store_true", help="no runs of the loiter without moving objects")
    p.add_argument(
        "--skip-autopilot-lossy", action="store_true", help="no runs on the autopilot's estimate over the lossy link"
    )
    p.add_argument(
        "--skip-deterministic", action="store_true", help="no deterministic runs (and no run beside a CPU hog)"
    )
    return p.parse_args()


@dataclass
class Variants:
    """The runs of each scenario variant, and which variants run."""

    loiter: Runs = field(default_factory=Runs)
    mower: Runs = field(default_factory=Runs)
    det: Runs = field(default_factory=Runs)
    static: Runs = field(default_factory=Runs)
    nadir10: Runs = field(default_factory=Runs)
    lossy: Runs = field(default_factory=Runs)
    mower_lossy: Runs = field(default_factory=Runs)
    order: list[tuple[Runs, Path, str]] = field(default_factory=list)


def variants_for(args: argparse.Namespace, parent: Path) -> Variants:
    v = Variants()
    v.order = [(v.loiter, LOITER, "loiter"), (v.mower, LAWNMOWER, "lawnmower")]
    if not args.skip_deterministic:
        v.order.insert(1, (v.det, LOITER, "loiter_deterministic"))
    if not args.skip_static:
        v.order.append((v.static, static_world_scenario(parent / "loiter_static.yaml"), "loiter_static"))
    if not args.skip_nadir_10hz:
        v.order.append((v.nadir10, nadir_10hz_scenario(parent / "loiter_nadir_10hz.yaml"), "loiter_nadir_10hz"))
    if not args.skip_autopilot_lossy:
        v.order.append((v.lossy, autopilot_lossy_scenario(parent / "loiter_autopilot_lossy.yaml"), "autopilot_lossy"))
        v.order.append(
            (
                v.mower_lossy,
                autopilot_lossy_scenario(parent / "lawnmower_autopilot_lossy.yaml", LAWNMOWER),
                "lawnmower_autopilot_lossy",
            )
        )
    return v


def main() -> int:
    args = parse_args()
    if shutil.which("uav-run") is None:
        sys.stderr.write("bench_scenario: uav-run not on PATH; run inside the project environment (scripts/in_env)\n")
        return 2
    if args.repeats < 1:
        sys.stderr.write("bench_scenario: --repeats must be >= 1\n")
        return 2
    parent = args.keep or Path(tempfile.mkdtemp(prefix="bench_scenario_"))
    parent.mkdir(parents=True, exist_ok=True)
    v = variants_for(args, parent)
    loiter, mower, nadir10, static, lossy, det, variants = (
        v.loiter,
        v.mower,
        v.nadir10,
        v.static,
        v.lossy,
        v.det,
        v.order,
    )
    mower_lossy = v.mower_lossy
    try:
        run_all(variants, det, parent, args.sim_seconds, args.repeats)
        if det.metrics:
            # the deterministic loiter once more beside a CPU hog on every core: slower, and identical
            with cpu_hogs(os.cpu_count() or 2):
                hog_probe = machine_probe()
                hog = run(LOITER, parent / "loiter_deterministic_hog", args.sim_seconds, deterministic=True)
    finally:
        if args.keep is None:
            shutil.rmtree(parent, ignore_errors=True)
    notes = (
        f"{args.sim_seconds:g} s simulated, lockstep, 2x 640x480 cameras (nadir 5 Hz, forward 10 Hz), OctoMap 0.5 m; "
        "baseline lawnmower; "
        f"mean of {args.repeats} runs each (loiter {loiter.rtfs()}; lawnmower {mower.rtfs()})"
    )
    probe = (
        f"machine probe before each run, numpy/python (lower is faster): loiter {loiter.probe_notes()}; "
        f"lawnmower {mower.probe_notes()}"
    )
    rtf = loiter.rtf()
    record(
        "scenario.loiter.rtf",
        rtf,
        "x",
        mower.rtf(),
        target=f">= {RTF_TARGET:g}",
        met=rtf >= RTF_TARGET,
        notes=f"{notes}; last runs: {_flight(loiter.metrics[-1], 'loiter')}; "
        f"{_flight(mower.metrics[-1], 'lawnmower')}; {probe}",
    )
    record(
        "scenario.loiter.clouds_dropped_pct",
        loiter.dropped_pct(),
        "%",
        mower.dropped_pct(),
        notes=(
            f"{notes}; frames the map server dropped of those it received: insertion too slow (queue_full) "
            "or incomplete (unsynchronized)"
        ),
    )
    cpu = loiter.cpu_per_sim_s()
    record(
        "scenario.loiter.cpu_s_per_sim_s",
        cpu,
        "cpu-s/sim-s",
        mower.cpu_per_sim_s(),
        target="<= 0.67 for 3x on 2 cores",
        met=cpu <= 2.0 / RTF_TARGET,
        notes=f"{notes}; per node: "
        + ", ".join(f"{k} {v:.3f}" for k, v in loiter.per_node().items() if v >= 0.005)
        + f"; {probe}",
    )
    record(
        "scenario.loiter.coverage_rate_m2_per_s",
        loiter.coverage("rate_m2_per_s"),
        "m2/s",
        mower.coverage("rate_m2_per_s"),
        notes=f"{notes}; mapped {loiter.coverage('mapped_m2'):.0f} m2 vs {mower.coverage('mapped_m2'):.0f} m2",
    )
    record(
        "scenario.loiter.coverage_efficiency",
        loiter.coverage("efficiency"),
        "fraction",
        mower.coverage("efficiency"),
        notes=f"{notes}; rate / (swath x cruise speed); loiter swath {loiter.coverage('swath_m'):.0f} m",
    )
    if nadir10.metrics:
        record(
            "scenario.loiter.rtf_nadir_10hz",
            nadir10.rtf(),
            "x",
            rtf,
            notes=f"the loiter with the nadir camera at 10 Hz (runs {nadir10.rtfs()}); baseline: the default loiter "
            f"(5 Hz nadir) in the same run; map server dropped "
            f"{nadir10.dropped_pct():.1f} % of its frames (default "
            f"{loiter.dropped_pct():.1f} %); CPU {nadir10.cpu_per_sim_s():.3f} "
            f"cpu-s/sim-s (default {cpu:.3f}); coverage efficiency {nadir10.coverage('efficiency'):.2f} (default "
            f"{loiter.coverage('efficiency'):.2f}); machine probe {nadir10.probe_notes()}",
        )
    if static.metrics:
        drop = 1.0 - rtf / static.rtf() if static.rtf() else float("nan")
        record(
            "scenario.loiter.rtf_moving_objects",
            rtf,
            "x",
            static.rtf(),
            target="ratio >= 0.9",
            met=rtf >= 0.9 * static.rtf(),
            notes=f"the loiter as shipped (the default world's 8 walkers and 5 drivers, posed from simulation time, "
            f"published on /sim/object_states, scored for the map's clearing) against the same loiter with nobody "
            f"moving (actors: people.moving 0, vehicles.moving 0), same run: real-time factor "
            f"{rtf:.2f}x vs {static.rtf():.2f}x ({100 * drop:+.1f} % drop; static runs {static.rtfs()}); CPU "
            f"{cpu:.3f} vs {static.cpu_per_sim_s():.3f} cpu-s/sim-s; map server dropped {loiter.dropped_pct():.1f} % "
            f"vs {static.dropped_pct():.1f} % of its frames; per node (moving vs static): "
            + ", ".join(
                f"{k} {v:.3f}/{static.per_node().get(k, 0.0):.3f}" for k, v in loiter.per_node().items() if v >= 0.005
            )
            + f"; machine probe {static.probe_notes()}",
        )
    if det.metrics:
        record_deterministic(det, loiter, hog, hog_probe)
    if lossy.metrics:
        ratio = lossy.rtf() / rtf
        pose = [m["pose_estimate"]["error"] for m in lossy.metrics]
        record(
            "scenario.loiter.rtf_autopilot_lossy",
            lossy.rtf(),
            "x",
            rtf,
            notes=f"no target: the autonomy flies another path on the autopilot's estimate in the wind, seeing other "
            f"objects (the work per simulated second follows; the target is on the scripted path, "
            f"scenario.lawnmower.rtf_autopilot_lossy); ratio {ratio:.3f}; the loiter on the autopilot's estimate "
            f"(pose_source: autopilot) over the lossy_link preset in the gusty preset's wind (runs "
            f"{lossy.rtfs()}); baseline: the default loiter in the same run ({loiter.rtfs()}); pose error rms "
            + ", ".join(f"{e['position_rms_m']:.2f} m / {e['yaw_rms_deg']:.2f} deg" for e in pose)
            + f"; map precision {lossy.mean(lambda i: float(lossy.metrics[i]['map_accuracy']['precision'])):.3f} "
            f"(default {loiter.mean(lambda i: float(loiter.metrics[i]['map_accuracy']['precision'])):.3f}); map server "
            f"dropped {lossy.dropped_pct():.1f} % of its frames (default {loiter.dropped_pct():.1f} %); CPU "
            f"{lossy.cpu_per_sim_s():.3f} cpu-s/sim-s (default {cpu:.3f}), per node (lossy vs default): "
            + ", ".join(
                f"{k} {v:.3f}/{loiter.per_node().get(k, 0.0):.3f}" for k, v in lossy.per_node().items() if v >= 0.005
            )
            + f"; detections scored {lossy.mean(lambda i: float(lossy.metrics[i]['detection']['tp'])):.0f} "
            f"(default {loiter.mean(lambda i: float(loiter.metrics[i]['detection']['tp'])):.0f}); machine probe "
            f"{lossy.probe_notes()}",
        )
    if mower_lossy.metrics:
        record_mower_lossy(mower_lossy, mower)
    return 0


def record_mower_lossy(lossy: Runs, mower: Runs) -> None:
    """The cost of the autopilot's estimate over a lossy link in wind on one path: the scripted lawnmower both ways."""
    ratio = lossy.rtf() / mower.rtf()
    pose = [m["pose_estimate"]["error"] for m in lossy.metrics]
    record(
        "scenario.lawnmower.rtf_autopilot_lossy",
        lossy.rtf(),
        "x",
        mower.rtf(),
        target=f"ratio >= {1.0 - AUTOPILOT_LOSSY_MAX_LOSS:.2f} (loses at most {AUTOPILOT_LOSSY_MAX_LOSS:.0%})",
        met=ratio >= 1.0 - AUTOPILOT_LOSSY_MAX_LOSS,
        notes=f"the scripted lawnmower on the autopilot's estimate (pose_source: autopilot) over the lossy_link preset "
        f"in the gusty preset's wind (runs {lossy.rtfs()}); baseline: the lawnmower on the ground truth, no stress "
        f"(runs {mower.rtfs()}), same run: one path, so the difference is the estimate's chain (autopilot odometry, "
        f"ODOMETRY over the router's lossy link, tf map -> odom -> base_link) and the wind; pose error rms "
        + ", ".join(f"{e['position_rms_m']:.2f} m / {e['yaw_rms_deg']:.2f} deg" for e in pose)
        + f"; CPU {lossy.cpu_per_sim_s():.3f} cpu-s/sim-s (lawnmower {mower.cpu_per_sim_s():.3f}), per node (lossy vs "
        "clean): "
        + ", ".join(
            f"{k} {v:.3f}/{mower.per_node().get(k, 0.0):.3f}" for k, v in lossy.per_node().items() if v >= 0.005
        )
        + f"; detections scored {lossy.mean(lambda i: float(lossy.metrics[i]['detection']['tp'])):.0f} "
        f"(clean {mower.mean(lambda i: float(mower.metrics[i]['detection']['tp'])):.0f}); machine probe "
        f"{lossy.probe_notes()}",
    )


def run_all(variants: list[tuple[Runs, Path, str]], det: Runs, parent: Path, sim_s: float, repeats: int) -> None:
    """Every variant ``repeats`` times, alternated (the machine's drift hits them all); ``det`` runs deterministic."""
    for i in range(repeats):
        for runs, scenario, name in variants:
            runs.probes.append(machine_probe())
            metrics, pace, cpu = run(scenario, parent / f"{name}_{i}", sim_s, deterministic=runs is det)
            runs.metrics.append(metrics)
            runs.pace.append(pace)
            runs.cpu.append(cpu)


RunResult = tuple[dict[str, Any], dict[str, float], dict[str, float]]


def record_deterministic(det: Runs, loiter: Runs, hog: RunResult, hog_probe: tuple[float, float]) -> None:
    """``scenario.loiter.rtf_deterministic_ratio`` and ``scenario.loiter.deterministic_beside_cpu_hog``."""
    rtf, cpu = loiter.rtf(), loiter.cpu_per_sim_s()
    ratio = det.rtf() / rtf
    same = [k for k in range(len(det.metrics)) if _same_run(det.metrics[k], det.metrics[0])]
    record(
        "scenario.loiter.rtf_deterministic_ratio",
        det.rtf(),
        "x",
        rtf,
        target=f">= {DETERMINISTIC_MIN_RATIO:g} of plain lockstep",
        met=ratio >= DETERMINISTIC_MIN_RATIO,
        notes=f"the default loiter in deterministic (causal) lockstep (runs {det.rtfs()}) against plain lockstep in "
        f"the same run ({loiter.rtfs()}), alternated; deterministic runs identical to the first: "
        f"{len(same)} of {len(det.metrics)}; map frames dropped {det.dropped_pct():.1f} % (plain "
        f"{loiter.dropped_pct():.1f} %); CPU {det.cpu_per_sim_s():.3f} cpu-s/sim-s (plain {cpu:.3f}), per node: "
        + ", ".join(f"{k} {v:.3f}" for k, v in det.per_node().items() if v >= 0.005)
        + f"; machine probe {det.probe_notes()}",
    )
    hog_metrics, hog_pace, _ = hog
    identical = _same_run(hog_metrics, det.metrics[0])
    record(
        "scenario.loiter.deterministic_beside_cpu_hog",
        float(hog_pace["real_time_factor"]),
        "x",
        det.rtf(),
        target="identical to the run alone",
        met=identical,
        notes=f"the deterministic loiter beside {os.cpu_count() or 2} busy loops (one per core): metrics and time "
        f"series {'identical to' if identical else 'DIFFERENT from'} the first deterministic run alone; baseline: the "
        f"deterministic runs alone; machine probe under the hogs {hog_probe[0]:.0f}/{hog_probe[1]:.0f} ms",
    )


def _same_run(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """Two runs' metrics equal (the software versions aside)."""
    return {k: v for k, v in a.items() if k != "versions"} == {k: v for k, v in b.items() if k != "versions"}


def static_world_scenario(path: Path) -> Path:
    """config/scenarios/loiter.yaml with nobody walking or driving (``actors``), written to ``path``."""
    scenario = yaml.safe_load(LOITER.read_text())
    world = scenario.get("world") or {}
    if "config" in world:
        world["config"] = str((LOITER.parent / world["config"]).resolve())
    scenario["actors"] = {"people": {"moving": 0}, "vehicles": {"moving": 0}}
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    return path


def autopilot_lossy_scenario(path: Path, base: Path = LOITER) -> Path:
    """``base`` (the loiter) on the autopilot's estimate over the lossy_link stress preset, in the gusty
    preset's wind (5 m/s from the west, moderate Dryden turbulence), written to ``path``
    (the world file and the preset made absolute so the copy can live anywhere)."""
    scenario = yaml.safe_load(base.read_text())
    world = scenario.get("world") or {}
    if "config" in world:
        world["config"] = str((base.parent / world["config"]).resolve())
    scenario["pose_source"] = "autopilot"
    scenario["stress"] = [str(REPO / "config" / "stress" / name) for name in ("lossy_link.yaml", "gusty.yaml")]
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    return path


def nadir_10hz_scenario(path: Path) -> Path:
    """config/scenarios/loiter.yaml with the nadir camera at 10 Hz (a sim_bridge node_params override), written to
    ``path``; the world file is made absolute so the copy can live anywhere."""
    scenario = yaml.safe_load(LOITER.read_text())
    world = scenario.get("world") or {}
    if "config" in world:
        world["config"] = str((LOITER.parent / world["config"]).resolve())
    bridge = scenario.setdefault("node_params", {}).setdefault("sim_bridge", {})
    bridge.setdefault("cameras", {}).setdefault("nadir", {})["rate_hz"] = 10.0
    path.write_text(yaml.safe_dump(scenario, sort_keys=False))
    return path


if __name__ == "__main__":
    sys.exit(main())
