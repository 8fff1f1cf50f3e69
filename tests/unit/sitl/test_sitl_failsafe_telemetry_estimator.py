"""Failsafe detection (pure), telemetry scheduling and the estimator model."""

from __future__ import annotations

import math

import numpy as np

from sitl.core.estimator import Estimator, NoiseModel
from sitl.core.failsafe import Action, FailsafeInputs, FailsafeKind, FailsafeMonitor
from sitl.core.modes import FlightMode
from sitl.core.params import ParamTable
from sitl.core.protocol import MavResult, MsgId
from sitl.core.state import VehicleState
from sitl.core.telemetry import NORMAL_RATES_HZ, ONBOARD_RATES_HZ, StreamScheduler
from uav_common.geo import GeoPoint, LocalProjection


def inputs(t: float, **kw: object) -> FailsafeInputs:
    base: dict[str, object] = {
        "t_s": t,
        "wall_s": t,
        "wall_scale": 1.0,
        "armed": True,
        "in_air": True,
        "mode": FlightMode.AUTO_LOITER,
        "battery_remaining": 0.9,
        "distance_from_home_m": 0.0,
        "altitude_above_home_m": 10.0,
    }
    base.update(kw)
    return FailsafeInputs(**base)  # type: ignore[arg-type]


def monitor() -> FailsafeMonitor:
    return FailsafeMonitor(datalink_floor_s=3.0, offboard_floor_s=0.5, manual_floor_s=0.5)


def test_battery_levels_latch() -> None:
    fs, p = monitor(), ParamTable()
    assert fs.update(inputs(0, battery_remaining=0.5), p) == []
    (low,) = fs.update(inputs(1, battery_remaining=0.149), p)
    assert (low.kind, low.action) == (FailsafeKind.BATTERY_LOW, Action.RETURN)
    assert fs.update(inputs(2, battery_remaining=0.14), p) == [], "latched"
    (crit,) = fs.update(inputs(3, battery_remaining=0.069), p)
    assert (crit.kind, crit.action) == (FailsafeKind.BATTERY_CRITICAL, Action.LAND)
    on_ground = monitor()
    (warn,) = on_ground.update(inputs(0, battery_remaining=0.1, in_air=False), p)
    assert warn.action is Action.WARN
    p.set("COM_LOW_BAT_ACT", 0)
    (warn_only,) = monitor().update(inputs(0, battery_remaining=0.1), p)
    assert warn_only.action is Action.WARN


def test_datalink_loss_uses_sim_time_and_wall_floor() -> None:
    fs, p = monitor(), ParamTable()
    p.set("NAV_DLL_ACT", 1)
    assert fs.update(inputs(100), p) == [], "never heard a GCS: no data link to lose"
    fs.gcs.heard(0.0, 0.0)
    assert fs.update(inputs(9.9), p) == []
    (ev,) = fs.update(inputs(10.1), p)
    assert (ev.kind, ev.action) == (FailsafeKind.DATALINK_LOST, Action.HOLD)
    fs.gcs.heard(11.0, 11.0)
    (back,) = fs.update(inputs(11.1), p)
    assert back.text == "Data link regained"
    # at 20x a 1 Hz wall-clock heartbeat is 20 simulated seconds apart: not a loss
    fast = monitor()
    fast.gcs.heard(0.0, 0.0)
    assert fast.update(inputs(20.0, wall_s=1.0, wall_scale=0.05), p) == []
    assert fast.update(inputs(80.0, wall_s=4.0, wall_scale=0.05), p)[0].kind is FailsafeKind.DATALINK_LOST


def test_offboard_loss_only_in_offboard() -> None:
    fs, p = monitor(), ParamTable()
    fs.offboard.heard(0.0, 0.0)
    assert fs.offboard_stream_ok(0.5, 0.5, p, 1.0)
    assert fs.update(inputs(5.0, mode=FlightMode.AUTO_LOITER), p) == []
    assert not fs.offboard_stream_ok(5.0, 5.0, p, 1.0)
    (ev,) = fs.update(inputs(5.0, mode=FlightMode.OFFBOARD), p)
    assert (ev.kind, ev.action) == (FailsafeKind.OFFBOARD_LOST, Action.HOLD)
    p.set("COM_OBL_RC_ACT", 3)
    fs2 = monitor()
    fs2.offboard.heard(0.0, 0.0)
    assert fs2.update(inputs(5.0, mode=FlightMode.OFFBOARD), p)[0].action is Action.RETURN


def test_geofence_radius_and_altitude() -> None:
    fs, p = monitor(), ParamTable()
    p.set("GF_MAX_HOR_DIST", 100.0)
    p.set("GF_MAX_VER_DIST", 50.0)
    assert fs.update(inputs(0, distance_from_home_m=99.0), p) == []
    (ev,) = fs.update(inputs(1, distance_from_home_m=101.0), p)
    assert (ev.kind, ev.action) == (FailsafeKind.GEOFENCE, Action.RETURN)
    assert fs.update(inputs(2, distance_from_home_m=120.0), p) == []
    assert fs.update(inputs(3, distance_from_home_m=50.0), p) == []
    (again,) = fs.update(inputs(4, altitude_above_home_m=51.0), p)
    assert "alt 51 m > 50 m" in again.text
    p.set("GF_ACTION", 0)
    assert monitor().update(inputs(0, distance_from_home_m=500.0), p) == []


def test_stream_scheduler_rates_and_intervals() -> None:
    s = StreamScheduler(NORMAL_RATES_HZ, max_rate_hz=250.0)
    counts: dict[int, int] = {}
    for k in range(2500):  # 10 s at 250 Hz
        for m in s.due(k * 0.004):
            counts[m] = counts.get(m, 0) + 1
    assert counts[MsgId.HEARTBEAT] == 10
    assert counts[MsgId.ATTITUDE] == 150
    assert counts[MsgId.HOME_POSITION] == 5
    assert MsgId.HIGHRES_IMU not in counts
    assert s.set_interval(MsgId.HIGHRES_IMU, 20_000, 10.0) is MavResult.ACCEPTED
    assert s.interval_us(MsgId.HIGHRES_IMU) == 20_000
    assert s.set_interval(MsgId.ATTITUDE, -1, 10.0) is MavResult.ACCEPTED
    assert s.interval_us(MsgId.ATTITUDE) == -1
    assert s.set_interval(MsgId.ATTITUDE, 0, 10.0) is MavResult.ACCEPTED
    assert s.interval_us(MsgId.ATTITUDE) == round(1e6 / 15)
    assert s.set_interval(12345, 1000, 10.0) is MavResult.UNSUPPORTED
    assert s.set_interval(MsgId.ATTITUDE, -7, 10.0) is MavResult.DENIED
    assert s.set_interval(MsgId.ATTITUDE, math.nan, 10.0) is MavResult.DENIED
    assert s.set_interval(MsgId.ATTITUDE, 1, 10.0) is MavResult.ACCEPTED
    assert s.interval_us(MsgId.ATTITUDE) == 4000, "capped at the physics rate"
    assert ONBOARD_RATES_HZ[MsgId.ATTITUDE] == 100.0


def truth(t: float) -> VehicleState:
    return VehicleState(t, 47.0, 8.0, 410.0, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                        (0.0, 0.0, -9.8), 10.0)  # fmt: skip


def test_estimator_truth_and_seeded_noise() -> None:
    proj = LocalProjection(GeoPoint(47.0, 8.0, 400.0))
    exact = Estimator(proj, None).update(truth(0.0))
    assert exact.pos_ned_m == (0.0, 0.0, -10.0)
    assert exact.gps_ok
    noise = NoiseModel(0.1, 0.1, 0.05, 0.01, 1.0, 0.5, 0.5, 3600.0 * 10, 2.0, 1.0)
    runs = []
    for _ in range(2):
        est = Estimator(proj, noise, seed=42)
        runs.append([est.update(truth(k * 0.02)).pos_ned_m for k in range(500)])
    assert runs[0] == runs[1], "same seed, same noise"
    other = Estimator(proj, noise, seed=43)
    assert [other.update(truth(k * 0.02)).pos_ned_m for k in range(500)] != runs[0]
    errors = np.array(runs[0]) - np.array([0.0, 0.0, -10.0])
    assert 0.0 < np.abs(errors).max() < 10.0
    est = Estimator(proj, noise, seed=1)
    flags = [est.update(truth(k * 0.02)).gps_ok for k in range(2000)]
    assert est.dropouts > 0
    assert not all(flags), "dropouts happen"
    assert any(flags), "and end"


def test_failsafe_texts_fit_one_statustext() -> None:
    """Announcements fit the 50 characters of one STATUSTEXT, so every GCS shows them whole."""
    p = ParamTable()
    for key, value in (("NAV_DLL_ACT", 3), ("GF_MAX_HOR_DIST", 1000.0), ("GF_MAX_VER_DIST", 120.0)):
        p.set(key, value)
    fs = monitor()
    fs.gcs.heard(0.0, 0.0)
    fs.offboard.heard(0.0, 0.0)
    fs.manual.heard(0.0, 0.0)
    events = fs.update(inputs(100.0, battery_remaining=0.05, mode=FlightMode.OFFBOARD, distance_from_home_m=12345.0), p)
    events += fs.update(inputs(101.0, mode=FlightMode.POSCTL, altitude_above_home_m=1234.0), p)
    kinds = {e.kind for e in events}
    assert {FailsafeKind.BATTERY_CRITICAL, FailsafeKind.DATALINK_LOST, FailsafeKind.OFFBOARD_LOST,
            FailsafeKind.MANUAL_CONTROL_LOST, FailsafeKind.GEOFENCE} <= kinds  # fmt: skip
    for event in events:
        assert len(event.text.encode()) <= 50, event.text
