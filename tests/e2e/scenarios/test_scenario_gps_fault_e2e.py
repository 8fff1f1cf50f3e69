"""A GPS failure scripted into a scenario, end to end: the failsafe PX4 would trigger, the autonomy standing down.

``small_gps_fault.yaml``: a loiter on the autopilot's own estimate (``pose_source: autopilot``) with
``faults: [{at_s: 18, unit: gps, type: off}]``. The mission manager sets ``SYS_FAILURE_EN`` and sends
``MAV_CMD_INJECT_FAILURE`` over the router at 18 s of run time, as a test rig would. As PX4: the estimate
dead-reckons for ``EKF2_NOAID_TOUT`` (5 s), then the local position is gone, the position-estimate failsafe
descends (AUTO.LAND) and lands. The controller yields to it at once (it never commands again), the estimate
goes stale and the controller says it will not fly on it; the scorer records the fault and all of that.
"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
from helpers.runs import metrics, uav_run

pytestmark = pytest.mark.slow
HERE = Path(__file__).resolve().parent
OFFBOARD_STATES = ("TAKEOFF", "AUTONOMOUS", "SCRIPTED", "MANUAL", "HOLD")


def test_gps_off_mid_flight_lands_as_px4_and_the_autonomy_stops_on_the_stale_pose() -> None:
    run_dir, out = uav_run(HERE / "small_gps_fault.yaml", "gps_fault", timeout_s=180.0)
    m = metrics(run_dir)
    assert m["final"]
    assert m["stop_reason"] == "time_limit", out[-3000:]
    events = [e["what"] for e in m["events"]]
    assert "fault gps off: ACCEPTED" in events, events

    # the fault: sent at its run time (within a lockstep step or two) and accepted by the autopilot
    (fault,) = m["faults"]
    assert (fault["unit"], fault["type"], fault["instance"], fault["clear"]) == ("gps", "off", 0, False)
    assert fault["result"] == "ACCEPTED", fault
    assert 18.0 - 1e-6 <= fault["run_t_s"] < 19.0, fault
    followed = [(c["after_s"], c["what"]) for c in fault["followed"]]
    text = "\n".join(f"{t:6.1f} {w}" for t, w in followed)

    # what PX4 does: 5 s of dead reckoning, then the position-estimate failsafe descends (AUTO.LAND). The mode
    # is the one the controller read from the autopilot's 1 Hz HEARTBEAT: up to 1 s after the switch, and on a
    # loaded 2-core CI machine the lockstep run (about 10x real time) can take another 2 simulated seconds (a
    # fifth of a wall second) to get it parsed. The fault's send time is on the ROS clock, which can trail the
    # SITL's (idle: a few tenths of a second; 0.6 s once on the loaded CI machine), hence the lower bound.
    modes = [(t, w) for t, w in followed if w.startswith("autopilot ")]
    assert modes, text
    assert modes[0][1] == "autopilot AUTO.LAND", text
    assert 3.8 < modes[0][0] < 9.0, text
    assert all(w == "autopilot AUTO.LAND" for _, w in modes), text  # never back to OFFBOARD

    # the autonomy: yields to the failsafe at once and never commands again...
    # (on a loaded machine the take-off can still be finishing at the fault: the autonomy enters AUTONOMOUS
    # during the dead reckoning; what matters is what it does once the autopilot has taken over)
    ctrl = [(t, w) for t, w in followed if w.startswith("controller ") and t >= modes[0][0] - 1e-6]
    assert ctrl, text
    assert ctrl[0][1].startswith("controller LAND: autopilot left OFFBOARD"), text
    assert ctrl[0][0] - modes[0][0] < 1.5, text
    assert not any(w.split(":")[0].split()[1] in OFFBOARD_STATES for _, w in ctrl), text
    # ... and says why it will not fly on the estimate once it went stale
    assert any(w.startswith("pose estimate STALE") for _, w in followed), text
    assert any("/uav/autopilot/odom cannot be flown on (no fresh estimate" in w for _, w in ctrl), text

    # the vehicle landed (and disarmed) where the failsafe put it down, without hitting anything
    assert any(w == "controller IDLE: LAND complete: landed and disarmed" for _, w in ctrl), text
    assert m["collisions"]["count"] == 0
    with (run_dir / "timeseries.csv").open() as f:
        rows = list(csv.DictReader(f))
    at_fault = [r for r in rows if float(r["t_s"]) >= fault["t_s"]]
    assert float(at_fault[0]["agl_m"]) > 15.0, at_fault[0]  # it was flying when the GPS failed
    assert float(rows[-1]["agl_m"]) < 1.0, rows[-1]
    assert rows[-1]["controller_state"] == "IDLE"
    # the tracking error was scored while it flew the path
    assert m["setpoint_tracking"]["samples"] > 50
    assert 0.0 < m["setpoint_tracking"]["rms_m"] < 10.0
