"""Acceptance: wind of a known speed pushes a vehicle in HOLD by less than PX4's position tolerance, and the
scorer's tracking error grows with it.

Three real ``uav-sitl`` processes (calm, 4 m/s and 8 m/s from the west with light Dryden turbulence) take off to
10 m and hold. A pymavlink ground station streams LOCAL_POSITION_NED (the truth: the estimator is ``truth``) and
POSITION_TARGET_LOCAL_NED (the autopilot's own hold point), converts them as ``autopilot_odometry`` does
(``uav_autonomy.core.pose_estimate``) and feeds the scenario scorer (``RunScorer``), whose
``autopilot_tracking`` is what a scenario run reports.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
from e2e.sitl.harness import Gcs, run_sitl
from e2e.sitl.test_sitl_failsafes import take_off
from pymavlink.dialects.v20 import common as mavlink2

from uav_autonomy.core.pose_estimate import target_from_position_target
from uav_common.frames import ned_to_enu
from uav_scenarios.core.config import ScoringSpec
from uav_scenarios.core.scoring.run import RunScorer
from uav_scenarios.core.scoring.types import PoseSample, SceneTruth, TargetSample

pytestmark = pytest.mark.slow

M = mavlink2
SPEED = "10"
#: Simulated seconds of HOLD scored, after this long to settle (the takeoff's overshoot).
SETTLE_S = 8.0
HOLD_S = 40.0
KINDS = ["LOCAL_POSITION_NED", "POSITION_TARGET_LOCAL_NED"]


def _param(gcs: Gcs, name: str) -> float:
    gcs.conn.mav.param_request_read_send(1, 1, name.encode(), -1)
    msg = gcs.wait("PARAM_VALUE", lambda m: m.param_id == name)
    return float(msg.param_value)  # type: ignore[attr-defined]


def hold_in_wind(tmp_path: Path, wind_mps: float) -> dict[str, Any]:
    turbulence = "light" if wind_mps > 0.0 else "none"
    extra = ("--wind", f"{wind_mps},270", "--turbulence", turbulence, "--set", "wind.seed=3")
    with run_sitl(f"hold_wind_{wind_mps:g}", tmp_path, speed=SPEED, extra=extra) as sitl:
        gcs = Gcs.listen(sitl.ports.gcs)
        tolerance_m = _param(gcs, "NAV_ACC_RAD")
        streams = ((M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 20.0), (M.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED, 10.0))
        for msg_id, rate_hz in streams:
            assert gcs.cmd(M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / rate_hz) == M.MAV_RESULT_ACCEPTED
        take_off(gcs, 10.0)
        scorer = RunScorer(spec=ScoringSpec(), truth=SceneTruth(bounds_m=(-500.0, -500.0, 500.0, 500.0)))
        hold_point: tuple[float, float, float] | None = None
        first_s: float | None = None
        last_hb = 0.0
        poses = 0
        horizontal_m: list[float] = []
        deadline = time.monotonic() + 60.0
        while time.monotonic() < deadline:
            if time.monotonic() - last_hb > 0.2:  # the GCS link stays alive at 10x (COM_DL_LOSS_T is sim time)
                gcs.heartbeat()
                last_hb = time.monotonic()
            msg = gcs.conn.recv_match(type=KINDS, blocking=True, timeout=0.1)
            if msg is None:
                continue
            t_s = msg.time_boot_ms * 1e-3
            first_s = t_s if first_s is None else first_s
            if t_s - first_s < SETTLE_S:
                continue
            if t_s - first_s > SETTLE_S + HOLD_S:
                break
            if msg.get_type() == "POSITION_TARGET_LOCAL_NED":
                target = target_from_position_target(msg.time_boot_ms, msg.type_mask, (msg.x, msg.y, msg.z))
                assert target is not None, f"HOLD without a position target: {msg}"
                hold_point = hold_point or target.position_enu_m
                moved_m = max(abs(a - b) for a, b in zip(target.position_enu_m, hold_point, strict=True))
                assert moved_m < 1e-3, "the hold point moved"
                scorer.add_target(TargetSample(target.t_autopilot_s, target.position_enu_m))
            else:
                e, n, u = ned_to_enu((msg.x, msg.y, msg.z))
                scorer.add_pose(PoseSample(t_s, (float(e), float(n), float(u))))
                poses += 1
                if hold_point is not None:
                    horizontal_m.append(((e - hold_point[0]) ** 2 + (n - hold_point[1]) ** 2) ** 0.5)
        assert poses > 0.8 * HOLD_S * 20.0, f"only {poses} positions in {HOLD_S} s of HOLD"
        mode = gcs.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1)
        assert mode.custom_mode == (4 << 16) | (3 << 24), "left HOLD"  # type: ignore[attr-defined]
        gcs.close()
    tracking = scorer.summary(SETTLE_S + HOLD_S)["autopilot_tracking"]
    return {"tolerance_m": tolerance_m, "max_push_m": max(horizontal_m), "tracking": tracking}


def test_wind_pushes_a_holding_vehicle_within_tolerance_and_the_tracking_error_grows(tmp_path: Path) -> None:
    runs = {w: hold_in_wind(tmp_path, w) for w in (0.0, 4.0, 8.0)}
    for w, r in runs.items():
        t = r["tracking"]
        print(
            f"wind {w:g} m/s: pushed at most {r['max_push_m']:.2f} m (tolerance {r['tolerance_m']:.1f} m); "
            f"tracking rms {t['rms_m']:.3f} m, horizontal rms {t['horizontal_rms_m']:.3f} m, "
            f"max {t['horizontal_max_m']:.3f} m over {t['samples']} samples"
        )
        assert t["samples"] >= 0.8 * HOLD_S * 10.0
        assert r["max_push_m"] < r["tolerance_m"], f"{w} m/s pushed the vehicle out of NAV_ACC_RAD"
    calm, mid, strong = (runs[w]["tracking"]["horizontal_rms_m"] for w in (0.0, 4.0, 8.0))
    assert calm < 0.01, "still air: the vehicle sits on its hold point"
    assert mid > calm + 0.01
    # light turbulence has the same gust intensity in both winds and rotor drag is linear in the airspeed, so
    # the gusts push about as hard in either; the stronger wind adds the body's quadratic drag on top (1.38x)
    assert strong > 1.2 * mid
