"""Scenario runs end to end: uav-run (SITL, router, bridge, map server, autonomy, scorer, rosbag) in the
small scenario world, then the report and a replay without the simulator (determinism:
test_scenario_determinism_e2e.py).

Every run gets a private ROS master and free ports (uav-run allocates them), writes into
``artifacts/scenario_e2e/`` and is stopped by uav-run itself (SIGINT to roslaunch, then escalation);
a test that fails still leaves the run folder (logs, metrics, bag) behind to look at.
"""

from __future__ import annotations

import csv
import itertools
import math
import os
import re
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
from helpers.procs import REPO, Proc, artifacts_dir, free_port
from helpers.runs import flat, metrics, uav_run

from uav_scenarios.report.data import read_run_bag

pytestmark = pytest.mark.slow
HERE = Path(__file__).resolve().parent
FIGURES = ("cameras", "maps", "topdown", "voxels", "battery_altitude", "detections", "pr_curves", "gallery")


def runs_dir() -> Path:
    return artifacts_dir() / "scenario_e2e"


def assert_box_only_search(run_dir: Path, m: dict[str, Any], source: str) -> None:
    """What the mission and the tracker used were the detector's boxes (``source``) as the geolocator placed them
    (on the elevation layer or the terrain, within 3 m of the truth at the median): no instance ids, no true
    positions."""
    geo = m["detection"]["geolocation"]
    assert sum(geo["placed"].values()) > 0
    assert set(geo["placed"]) <= {"elevation", "terrain"}
    assert geo["error"]["median_m"] < 3.0
    run = read_run_bag(run_dir / "run.bag")
    placed = [f for f in run.detections if f.source == source]
    assert placed
    assert all(d.instance_id == 0 for f in placed for d in f.detections)


def test_sar_finds_the_person_and_the_report_has_every_figure() -> None:
    run_dir, out = uav_run(HERE / "small_sar.yaml", "sar")
    m = metrics(run_dir)
    assert m["final"]
    assert m["stop_reason"] == "target_found", out
    complete = m["time"]["complete_s"]
    assert complete is not None
    assert 0 < complete < 120
    det = m["detection"]
    assert det["person_first_detected"]["t_s"] <= complete
    assert det["person_first_detected"]["range_m"] <= 100.5  # the forward camera's 100 m rule
    # the person confirmed is the one the scenario placed, and the drone then held and stared
    status_target = read_run_bag(run_dir / "run.bag").target_position_m
    assert status_target is not None
    assert math.dist(status_target, (m["person"]["x_m"], m["person"]["y_m"])) < 3.0
    assert m["search"]["correct"] is True
    # the ground truth as a box-only detector: every box geolocated, scored against the truth by COCO
    assert det["source"] == "ground_truth_boxes"
    assert det["fp"] == 0
    assert det["fn"] == 0
    assert det["coco"]["AP50"] == 1.0
    assert det["geolocation"]["unplaced_share"] == 0.0
    events = [e["what"] for e in m["events"]]
    assert "complete: person confirmed" in events
    assert "controller HOLD" in events
    assert m["collisions"]["count"] == 0
    for section in ("coverage", "map_accuracy", "flight", "battery", "detection", "tracking"):
        assert section in m
    assert m["map_accuracy"]["precision"] > 0.8
    assert m["tracking"]["mota"] is not None
    assert m["detection"]["by_context"]["range"], "no range breakdown"
    # the time series and the report
    rows = list(csv.DictReader((run_dir / "timeseries.csv").open()))
    assert len(rows) > 10
    html = (run_dir / "report.html").read_text()
    for fig in FIGURES:
        section = re.search(rf'<section id="{fig}">(.*?)</section>', html, re.S)
        assert section is not None, f"no section {fig}"
        assert "data:image/png;base64," in section.group(1), f"figure {fig} has no image"
        if fig != "gallery":  # the ground truth makes no mistake: its gallery is one line saying so
            assert (run_dir / "figures" / f"{fig}.png").stat().st_size > 10_000
    assert "Scenario configuration" in html
    assert "small_sar" in html
    # uav-report regenerates it offline from the bag alone
    offline = run_dir / "offline"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "ROS_PACKAGE_PATH", "ROS_MASTER_URI")}
    rep = subprocess.run(
        [str(REPO / ".venv/bin/python"), str(REPO / "bin/uav-report"), str(run_dir / "run.bag"), "--out", str(offline)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=False,
    )
    assert rep.returncode == 0, rep.stderr
    assert (offline / "report.html").is_file()
    assert "figures without data" not in rep.stdout


def test_sar_with_box_only_detections_finds_the_person() -> None:
    """The stand-in detector (a test instrument: the truth's boxes missed, jittered, padded with false boxes; no ids,
    no positions) feeds the geolocator; the tracker and the confirmation see only its placements, and the search
    still ends on the person placed by the scenario."""
    run_dir, out = uav_run(HERE / "small_sar_degraded.yaml", "sar_degraded")
    m = metrics(run_dir)
    assert m["final"]
    assert m["stop_reason"] == "target_found", out
    search = m["search"]
    assert search["correct"] is True, search
    assert search["error_m"] < 3.0
    det = m["detection"]
    assert det["source"] == "degraded_truth"
    assert det["fp"] > 0  # not the ground truth in disguise
    assert det["fn"] > 0
    assert 0.0 < det["coco"]["AP50"] < 0.9
    # the person came into view before the search ended on them; the scorer's first *correct* box (IoU >= 0.5
    # with the truth's) can come after the confirmation: the stand-in's jitter spoils the IoU of a person a few
    # pixels tall while its placement still lands on them (one CI run: in view 24.4 s, confirmed 25.0 s, first
    # box at IoU >= 0.5 25.1 s)
    in_view_s = det["person_first_in_view"]["t_s"]
    assert in_view_s <= m["time"]["complete_s"], (det["person_first_in_view"], m["time"])
    first_s = det["person_first_detected"]["t_s"]
    assert math.isnan(first_s) or first_s >= in_view_s, det["person_first_detected"]
    assert_box_only_search(run_dir, m, "degraded_truth")
    assert m["tracking"]["hota"] is not None
    html = (run_dir / "report.html").read_text()
    for fig in ("pr_curves", "gallery"):
        section = re.search(rf'<section id="{fig}">(.*?)</section>', html, re.S)
        assert section is not None
        assert "data:image/png;base64," in section.group(1), f"figure {fig} has no image"
    assert (run_dir / "figures" / "gallery.png").stat().st_size > 10_000  # crops of its mistakes


def replay(run_dir: Path, out_dir: Path) -> None:
    port = free_port()
    env = {"ROS_MASTER_URI": f"http://127.0.0.1:{port}", "ROS_IP": "127.0.0.1"}
    argv = [
        "roslaunch",
        "-p",
        str(port),
        "uav_scenarios",
        "replay.launch",
        f"run_dir:={run_dir}",
        f"out_dir:={out_dir}",
    ]
    proc = Proc("scenario_replay", argv, env=env)
    try:
        proc.wait(240)
    finally:
        proc.stop()
    assert (out_dir / "metrics.json").is_file(), proc.tail()


def map_input_stamps(bag_path: Path) -> dict[str, list[int]]:
    """Header stamps (ns) of the nadir camera's depth, colour and camera_info messages in a bag."""
    import rosbag  # noqa: PLC0415

    topics = [f"/cameras/nadir/{t}" for t in ("depth/image_raw", "color/image_raw", "depth/camera_info")]
    stamps: dict[str, list[int]] = {t: [] for t in topics}
    with rosbag.Bag(str(bag_path)) as bag:
        for topic, msg, _t in bag.read_messages(topics=topics):
            stamps[topic].append(msg.header.stamp.to_nsec())
    return {t: sorted(v) for t, v in stamps.items()}


def test_sar_with_the_ardupilot_personality_finds_the_person() -> None:
    """The same autonomy against ``autopilot: ardupilot``: the controller takes off through GUIDED and
    MAV_CMD_NAV_TAKEOFF, flies GUIDED position targets, and holds over the person."""
    scenario = runs_dir() / "small_sar_ardupilot.yaml"
    scenario.parent.mkdir(parents=True, exist_ok=True)
    text = (HERE / "small_sar.yaml").read_text()
    text = text.replace("name: small_sar\n", "name: small_sar_ardupilot\nautopilot: ardupilot\n")
    text = text.replace("config: small_world.yaml", f"config: {HERE / 'small_world.yaml'}")
    scenario.write_text(text)
    run_dir, out = uav_run(scenario, "sar_ardupilot")
    m = metrics(run_dir)
    assert m["stop_reason"] == "target_found", out
    assert 0 < m["time"]["complete_s"] < 120
    assert m["collisions"]["count"] == 0
    events = [e["what"] for e in m["events"]]
    assert "complete: person confirmed" in events
    controller_log = "\n".join(p.read_text() for p in (run_dir / "logs").rglob("waypoint_controller*.log"))
    assert "autopilot confirmed GUIDED" in controller_log
    assert "autopilot in STABILIZE" in controller_log  # ArduCopter's boot mode, named by its own table
    sitl_log = "\n".join(p.read_text() for p in (run_dir / "logs").rglob("*.log"))
    assert "ArduPilot autopilot" in sitl_log


def test_replay_reproduces_the_live_metrics() -> None:
    run_dir, _ = uav_run(HERE / "small_loiter.yaml", "replay_live", "--time-limit", "25")
    # the bag holds every frame of the map camera (10 Hz): all three topics, one per 0.1 s, stamps exact
    stamps = map_input_stamps(run_dir / "run.bag")
    assert len({tuple(v) for v in stamps.values()}) == 1, {k: len(v) for k, v in stamps.items()}
    frames_ns = next(iter(stamps.values()))
    assert len(frames_ns) > 200
    assert {b - a for a, b in itertools.pairwise(frames_ns)} == {100_000_000}
    out_dir = run_dir / "replay"
    replay(run_dir, out_dir)
    live, again = flat(metrics(run_dir)), flat(metrics(out_dir))
    assert again["final"]
    exact = [
        k
        for k in live
        if k.split(".")[0] in ("time", "flight", "battery", "collisions", "detection", "tracking")
        and ".by_context." not in k
    ]
    assert len(exact) > 30
    differ = {k: (live[k], again.get(k)) for k in exact if live[k] != again.get(k)}
    assert not differ, f"the replay scored differently: {differ}"
    # the map is rebuilt by the map server from the recorded clouds (the live run is deterministic, so its
    # map server inserted every cloud too); insertion threads and the map export's timing allow a little slack
    for key in ("coverage.mapped_pct", "map_accuracy.iou", "map_accuracy.precision", "map_accuracy.recall"):
        assert again[key] == pytest.approx(live[key], rel=0.05), key
    assert live["map_accuracy.precision"] > 0.9


def test_bad_inputs_say_what_to_do(tmp_path: Path) -> None:
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: x\nmission: loiter\nstop: {time_limt_s: 3}\n")
    res = subprocess.run(["uav-run", str(broken)], capture_output=True, text=True, timeout=60, check=False)
    assert res.returncode == 2
    assert "time_limt_s" in res.stderr
    nowhere = tmp_path / "nowhere.yaml"
    nowhere.write_text("name: x\nmission: loiter\nworld: {config: no_such_world.yaml}\n")
    t0 = time.monotonic()
    res = subprocess.run(
        ["uav-run", str(nowhere), "--runs-dir", str(tmp_path / "runs")],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert res.returncode != 0
    assert "no_such_world.yaml" in res.stdout + res.stderr
    assert time.monotonic() - t0 < 90
    import rosbag  # noqa: PLC0415
    from nav_msgs.msg import Odometry  # noqa: PLC0415

    whole = tmp_path / "whole.bag"
    with rosbag.Bag(str(whole), "w") as bag:
        for k in range(2000):
            msg = Odometry()
            msg.header.stamp.secs = k
            bag.write("/uav/ground_truth/odom", msg, msg.header.stamp)
    truncated = tmp_path / "cut.bag"
    truncated.write_bytes(whole.read_bytes()[: whole.stat().st_size // 3])
    res = subprocess.run(["uav-report", str(truncated)], capture_output=True, text=True, timeout=60, check=False)
    assert res.returncode == 1
    assert "reindex" in res.stderr
