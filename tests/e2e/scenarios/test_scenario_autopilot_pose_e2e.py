"""A loiter flown, mapped and planned on the autopilot's own estimate over a lossy MAVLink link, end to end.

``small_loiter_autopilot.yaml``: ``pose_source: autopilot`` (the autopilot_odometry node turns the SITL's
ODOMETRY into the odometry and the ``map -> odom -> base_link`` tf that the map server, the features, the
planner and the controller's pose watch use; the sim bridge publishes no pose tf), the SITL's noisy
estimator (a per-run bias drawn from its seed, plus a wandering error), and the ``lossy_link`` stress preset
(20 % of the frames lost each way on the controller's link, delay, jitter, reordering) with the odometry
node's link as lossy (the scenario adds it), in the ``gusty`` preset's wind (5 m/s from the west, moderate
Dryden turbulence, flown by the SITL's JSBSim atmosphere). The run must fly, map and score the pose error it flew with;
it must either complete (its time limit) or fail safe with the reason in its events.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from helpers.runs import metrics, uav_run

pytestmark = pytest.mark.slow
HERE = Path(__file__).resolve().parent
#: The SITL's noisy estimator, seed 3, 0.5 m bias sigma: numpy default_rng(3).normal(0, 0.5, 2) = N 1.020, E -1.278.
ESTIMATOR_BIAS_ENU_M = (-1.278, 1.020)


def link_counters(run_dir: Path) -> dict[str, dict[str, dict[str, int]]]:
    stats = json.loads((run_dir / "router" / "router-stats.json").read_text())
    return {e["name"]: e.get("link", {}) for e in stats["endpoints"]}


def test_loiter_on_the_autopilot_estimate_over_a_lossy_link() -> None:
    run_dir, out = uav_run(HERE / "small_loiter_autopilot.yaml", "autopilot_pose_lossy")
    m = metrics(run_dir)
    assert m["final"]
    events = [e["what"] for e in m["events"]]
    # it completed, or it failed safe and said why
    if m["stop_reason"] != "time_limit":
        reasons = [e for e in events if e.startswith("controller IDLE because:")]
        assert reasons, f"stopped on {m['stop_reason']} with no reason recorded: {events}\n{out[-2000:]}"
    effective = (run_dir / "scenario.yaml").read_text()
    assert "stress_applied" in effective
    assert "gusty" in effective
    # the SITL flew in the wind the scenario asked for
    wind_line = "wind: 5 m/s from 270 deg at 10 m (shear exponent 0.14), turbulence moderate, seed 1"
    logs = [p for p in run_dir.rglob("*") if p.is_file() and p.stat().st_size < 50_000_000]
    assert any(wind_line in p.read_text(errors="replace") for p in logs) or wind_line in out, out[-3000:]

    # it flew and mapped, on the estimate
    assert m["time"]["airborne_s"] > 20.0
    assert m["flight"]["distance_m"] > 50.0
    assert m["collisions"]["count"] == 0
    assert m["coverage"]["mapped_pct"] > 5.0
    assert m["map_input"]["clouds_inserted"] > 50
    # every cloud found the estimate's transform in time (map -> odom -> base_link -> camera)
    assert m["map_input"]["dropped_no_transform"] <= 0.05 * m["map_input"]["clouds_received"]

    # the pose error it flew with: the estimator's bias, measured against the ground truth
    pe = m["pose_estimate"]
    assert pe["source"] == "ODOMETRY"
    assert pe["time_sync"] == "shared"
    assert pe["estimates"] > 200
    err = pe["error"]
    assert 0.5 < err["position_rms_m"] < 4.0, err
    bx, by, _ = err["bias_enu_m"]
    assert math.dist((bx, by), ESTIMATOR_BIAS_ENU_M) < 0.6, err
    assert err["yaw_rms_deg"] < 2.0, err
    # the truth against the autopilot's own position target (POSITION_TARGET_LOCAL_NED), per autopilot mode
    at = m["autopilot_tracking"]
    print("autopilot_tracking:", json.dumps(at))
    assert at["samples"] > 100, at
    # in HOLD after the takeoff the autopilot puts its estimate on the hold point: the truth is the bias away
    hold = at["by_mode"]["AUTO.LOITER"]
    assert hold["samples"] >= 10, at
    assert abs(hold["horizontal_rms_m"] - math.hypot(*ESTIMATOR_BIAS_ENU_M)) < 0.6, at
    # in OFFBOARD the controller's carrot leads the vehicle by design: that distance is no tracking error
    assert at["by_mode"]["OFFBOARD"]["samples"] > 100, at
    # ... and the map accuracy that results: a map built on a pose 1.6 m off misses the true surfaces
    acc = m["map_accuracy"]
    assert 0.05 < acc["precision"] < 0.85, acc
    rows = (run_dir / "timeseries.csv").read_text().splitlines()
    assert "pose_error_m" in rows[0]

    # the lossy links did lose what the scenario said, both ways, and the router counted it
    links = link_counters(run_dir)
    for name in ("controller", "odometry"):
        out_c, in_c = links[name]["out"], links[name]["in"]
        assert out_c["offered"] > 2000, links[name]
        assert 0.16 < out_c["dropped"] / out_c["offered"] < 0.24, links[name]
        assert in_c["dropped"] > 0, links[name]
        assert out_c["reordered"] > 0, links[name]
    assert links["mavsdk"] == {}  # no link set for it: untouched
