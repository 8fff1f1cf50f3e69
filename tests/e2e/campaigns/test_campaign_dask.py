"""Campaigns on a real Dask cluster: a ``dask scheduler`` and two ``dask worker`` processes over TCP on localhost.

``config/campaigns/smoke.yaml`` (2 arms x 2 seeds, 20 simulated seconds each) goes to the cluster with
``uav-campaign run --scheduler``. While the first run is flying, its worker is killed (SIGKILL to the
worker process): the run is recorded as orphaned with its logs, its ``uav-run`` stops (nothing is left
running), Dask gives it to the other worker, and the campaign ends with all four runs done and their
statistics. A run flown on a worker (beside another run: the runs are deterministic) equals the same run flown
alone. A second invocation runs nothing. Bad input (an unreachable scheduler, a directory made by another campaign
file) is refused before anything starts.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers.procs import REPO, Proc, artifacts_dir, free_port
from helpers.runs import metrics_differences, uav_run

pytestmark = pytest.mark.slow
SMOKE = REPO / "config" / "campaigns" / "smoke.yaml"


def manifest(out: Path) -> list[dict[str, Any]]:
    path = out / "manifest.jsonl"
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def processes_mentioning(text: str) -> list[str]:
    """Command lines of live processes that mention ``text`` (a run folder)."""
    out = []
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit():
            continue
        try:
            cmd = Path(entry.path, "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if text in cmd:
            out.append(f"{entry.name}: {cmd[:160]}")
    return out


@pytest.fixture(scope="module")
def cluster() -> Iterator[dict[str, Any]]:
    """A scheduler and two single-threaded workers, separate processes, TCP on 127.0.0.1."""
    logs = artifacts_dir() / "campaign_e2e" / "cluster"
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    scheduler = Proc(
        "dask_scheduler",
        [
            "dask",
            "scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--dashboard-address",
            f"127.0.0.1:{free_port()}",
        ],
        log_dir=logs,
    )
    workers: dict[str, Proc] = {}
    try:
        deadline = time.monotonic() + 60
        while "Scheduler at" not in scheduler.log_text() and time.monotonic() < deadline:
            assert scheduler.alive(), scheduler.tail()
            time.sleep(0.2)
        for name in ("w1", "w2"):
            wport = free_port()
            workers[f"tcp://127.0.0.1:{wport}"] = Proc(
                f"dask_worker_{name}",
                ["dask", "worker", address, "--name", name, "--nthreads", "1", "--no-nanny", "--host", "127.0.0.1",
                 "--worker-port", str(wport), "--no-dashboard", "--local-directory", str(logs / name)],
                log_dir=logs,
            )  # fmt: skip
        for w in workers.values():
            while "Registered to" not in w.log_text():
                assert w.alive(), w.tail()
                assert time.monotonic() < deadline, w.tail()
                time.sleep(0.2)
        yield {"address": address, "workers": workers, "scheduler": scheduler}
    finally:
        for w in workers.values():
            w.stop()
        scheduler.stop()


def test_a_killed_worker_s_run_completes_on_the_other_and_a_rerun_runs_nothing(cluster: dict[str, Any]) -> None:
    out = artifacts_dir() / "campaign_e2e" / "smoke"
    if out.exists():
        subprocess.run(["rm", "-rf", str(out)], check=True)
    argv = ["uav-campaign", "run", str(SMOKE), "--out", str(out), "--scheduler", cluster["address"]]
    campaign = Proc("uav_campaign_smoke", argv)
    killed: dict[str, Any] = {}
    try:
        deadline = time.monotonic() + 300
        while not killed and time.monotonic() < deadline:
            assert campaign.alive(), campaign.tail()
            for ev in manifest(out):
                # the first run to get going: wait until its roslaunch is up, then kill its worker
                if ev.get("event") == "started" and (Path(ev["run_dir"]) / "logs" / "roslaunch.log").exists():
                    time.sleep(5.0)
                    victim = cluster["workers"][ev["worker"]]
                    victim.signal(signal.SIGKILL)
                    victim.wait(10)
                    killed = ev
                    break
            time.sleep(0.5)
        assert killed, f"no run started within 300 s:\n{campaign.tail()}"
        rc = campaign.wait(900)
    finally:
        campaign.stop()
    text = campaign.log_text()
    assert rc == 0, text[-4000:]
    events = manifest(out)
    key = killed["key"]
    orphaned = [e for e in events if e["event"] == "orphaned" and e["key"] == key]
    assert orphaned, f"the killed worker's run was not recorded as orphaned:\n{text[-3000:]}"
    assert killed["worker"] in orphaned[0]["reason"]
    # its logs are kept where the manifest says, and nothing of it is left running
    orphan_dir = Path(killed["run_dir"])
    assert (orphan_dir / "uav-run.log").is_file()
    assert (orphan_dir / "logs" / "roslaunch.log").is_file()
    deadline = time.monotonic() + 60
    while processes_mentioning(str(orphan_dir)) and time.monotonic() < deadline:
        time.sleep(1.0)
    assert not processes_mentioning(str(orphan_dir)), processes_mentioning(str(orphan_dir))
    # the run was completed by the other worker
    done = [e for e in events if e["event"] == "finished" and e["key"] == key and e["status"] == "done"]
    assert len(done) == 1
    assert done[0]["worker"] != killed["worker"]
    assert done[0]["worker"] in cluster["workers"]
    assert done[0]["run_dir"] != killed["run_dir"]
    # all four runs, their statistics and their reports
    with (out / "runs.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["arm"], r["seed"], r["status"]) for r in rows] == [
        ("equal_weights", "1", "done"), ("equal_weights", "2", "done"), ("stale_first", "1", "done"),
        ("stale_first", "2", "done"),
    ]  # fmt: skip
    assert {r["orphaned"] for r in rows if r["key"] == key} == {str(len(orphaned))}
    for r in rows:
        assert r["stop_reason"] == "time_limit"
        assert float(r["time.duration_s"]) == pytest.approx(20.0, abs=1.0)
        assert float(r["coverage.mapped_pct"]) > 0.0
        assert (out / r["report"]).is_file()
    with (out / "summary.csv").open(newline="") as fh:
        summary = [s for s in csv.DictReader(fh) if s["metric"] == "coverage.mapped_pct"]
    assert [(s["arm"], s["n"]) for s in summary] == [("equal_weights", "2"), ("stale_first", "2")]
    html = (out / "report.html").read_text()
    assert "orphaned" in html
    assert "data:image/png;base64," in html
    assert "dashboard:" in text
    assert " done, " in text  # the progress line: [####....] 3/4 done, 0 failed, 1 running, ...
    # deterministic runs (smoke.yaml's time): a run flown on a Dask worker beside another run is the run flown alone
    other = next(e for e in events if e["event"] == "finished" and e["status"] == "done" and e["key"] != key)
    on_worker = Path(other["run_dir"])
    alone, _ = uav_run(on_worker / "campaign_scenario.yaml", "alone", group="campaign_e2e")
    differ = metrics_differences(on_worker, alone)
    assert not differ, f"the run on the Dask worker and the same run alone differ: {dict(list(differ.items())[:8])}"
    assert (on_worker / "timeseries.csv").read_text() == (alone / "timeseries.csv").read_text()
    # the second invocation runs nothing new
    n_events = len(events)
    again = subprocess.run(argv, capture_output=True, text=True, timeout=300, check=False)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "4 done already, 0 to run" in again.stdout
    assert not [e for e in manifest(out)[n_events:] if e["event"] in ("submitted", "started")]
    # a directory made by another campaign file is refused, and left as it was
    other = out.parent / "other.yaml"
    other.write_text(SMOKE.read_text().replace("seeds: [1, 2]", "seeds: [1, 2, 3]").replace(
        "../scenarios/loiter.yaml", str(REPO / "config/scenarios/loiter.yaml")
    ).replace("../worlds/small.yaml", str(REPO / "config/worlds/small.yaml")))  # fmt: skip
    before = (out / "manifest.jsonl").read_bytes()
    proc = subprocess.run(
        ["uav-campaign", "run", str(other), "--out", str(out), "--scheduler", cluster["address"]],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "never mixed" in proc.stderr
    assert (out / "manifest.jsonl").read_bytes() == before


def test_bad_input_is_refused_before_anything_starts(cluster: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "never"
    t0 = time.monotonic()
    dead = f"tcp://127.0.0.1:{free_port()}"
    proc = subprocess.run(
        ["uav-campaign", "run", str(SMOKE), "--out", str(out), "--scheduler", dead],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert f"cannot reach the Dask scheduler at {dead}" in proc.stderr
    assert "dask scheduler" in proc.stderr
    assert time.monotonic() - t0 < 60
    assert not out.exists()
    other = tmp_path / "other.yaml"
    other.write_text(
        SMOKE.read_text()
        .replace("../scenarios/loiter.yaml", str(REPO / "config/scenarios/loiter.yaml"))
        .replace("../worlds/small.yaml", str(REPO / "config/worlds/small.yaml"))
    )
    # an arm override the scenario schema lacks: exit 2, naming the arm and the key
    bad = tmp_path / "bad.yaml"
    bad.write_text(other.read_text().replace("autonomy.weights.age: -1.0", "autonomy.wieghts.age: -1.0"))
    proc = subprocess.run(
        ["uav-campaign", "run", str(bad), "--out", str(tmp_path / "bad_out"), "--scheduler", cluster["address"]],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "arm 'stale_first'" in proc.stderr
    assert "'wieghts'" in proc.stderr
    assert not (tmp_path / "bad_out").exists()
    # a setting the sim bridge would refuse (camera extrinsics belong in config/robot.yaml) and one the SITL
    # would: exit 2 before any run starts, naming the arm and the key (every run used to die at its start)
    for override, says in (
        ("stale_first: {node_params.sim_bridge.cameras.nadir.mount: {rpy_deg: [0, 90, 0]}}", "cameras.nadir.mount"),
        ("stale_first: {node_params.sitl.battery.capacity_mahh: 100}", "capacity_mahh"),
    ):
        refused = tmp_path / "refused.yaml"
        refused.write_text(other.read_text().replace("stale_first: {autonomy.weights.age: -1.0}", override))
        argv = ["uav-campaign", "run", str(refused), "--out", str(tmp_path / "refused_out")]
        proc = subprocess.run(
            [*argv, "--scheduler", cluster["address"]],
            capture_output=True, text=True, timeout=120, check=False,
        )  # fmt: skip
        assert proc.returncode == 2, proc.stdout + proc.stderr
        assert "arm 'stale_first'" in proc.stderr, proc.stderr
        assert says in proc.stderr, proc.stderr
        assert not (tmp_path / "refused_out").exists()


def test_ctrl_c_stops_the_runs_cleanly_and_the_next_invocation_resumes() -> None:
    """The embedded cluster (one worker): Ctrl-C to the whole process group, as a terminal sends it."""
    out = artifacts_dir() / "campaign_e2e" / "interrupted"
    if out.exists():
        subprocess.run(["rm", "-rf", str(out)], check=True)
    argv = ["uav-campaign", "run", str(SMOKE), "--out", str(out), "--workers", "1", "--dashboard-address", ":0"]
    campaign = Proc("uav_campaign_interrupted", argv)
    started: dict[str, Any] = {}
    try:
        deadline = time.monotonic() + 240
        while not started and time.monotonic() < deadline:
            assert campaign.alive(), campaign.tail()
            for ev in manifest(out):
                if ev.get("event") == "started" and (Path(ev["run_dir"]) / "logs" / "roslaunch.log").exists():
                    started = ev
            time.sleep(0.5)
        assert started, f"no run started within 240 s:\n{campaign.tail()}"
        time.sleep(3.0)
        campaign.signal(signal.SIGINT)
        rc = campaign.wait(240)
    finally:
        campaign.stop()
    text = campaign.log_text()
    assert rc == 130, text[-3000:]
    assert "stopping:" in text
    assert "run the same command again to resume" in text
    events = manifest(out)
    stopped = [e for e in events if e["event"] == "finished" and e["key"] == started["key"]]
    assert [e["status"] for e in stopped] == ["interrupted"], stopped
    assert not [e for e in events if e["event"] == "orphaned"], "the worker died on Ctrl-C"
    # the run was stopped by uav-run itself (SIGINT: it stops roslaunch and builds what it can), nothing is left running
    assert "interrupted: stopping the run" in (Path(started["run_dir"]) / "uav-run.log").read_text()
    assert not processes_mentioning(str(out))
    assert (out / "runs.csv").is_file()
    # the next invocation resumes: the interrupted run is not a failure and runs again (a new try)
    plan = subprocess.run([*argv, "--dry-run"], capture_output=True, text=True, timeout=120, check=False)
    assert plan.returncode == 0, plan.stderr
    assert "0 given up" in plan.stdout
    assert f"{started['try'] + 1})" in plan.stdout  # "(try 2)"
