"""Acceptance: a real MAVSDK-Python 4.x flight against ``uav-sitl`` (takeoff, offboard, mission, RTL).

Every step is checked through MAVSDK's telemetry (position, flight mode, armed,
in_air, battery), i.e. exactly what a MAVSDK user would see.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, TypeVar

import pytest
from e2e.sitl.harness import run_sitl
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionItem, MissionPlan
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

pytestmark = pytest.mark.slow

T = TypeVar("T")
HOME_LAT, HOME_LON = 47.397742, 8.545594
SPEED = "6"


async def wait_for(probe: Callable[[], Awaitable[T]], ok: Callable[[T], bool], what: str, timeout_s: float = 60.0) -> T:
    """Poll a MAVSDK getter until ``ok``; fail with the last value."""
    deadline = time.monotonic() + timeout_s
    value = await probe()
    while not ok(value):
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout_s} s waiting for {what}; last value: {value}")
        await asyncio.sleep(0.1)
        value = await probe()
    return value


def offset(north_m: float, east_m: float) -> tuple[float, float]:
    lat = HOME_LAT + math.degrees(north_m / 6_371_000.0)
    lon = HOME_LON + math.degrees(east_m / (6_371_000.0 * math.cos(math.radians(HOME_LAT))))
    return lat, lon


def waypoint(north_m: float, east_m: float, alt_m: float, speed_mps: float) -> MissionItem:
    lat, lon = offset(north_m, east_m)
    return MissionItem(
        latitude_deg=lat,
        longitude_deg=lon,
        relative_altitude_m=alt_m,
        speed_m_s=speed_mps,
        is_fly_through=True,
        gimbal_pitch_deg=float("nan"),
        gimbal_yaw_deg=float("nan"),
        camera_action=MissionItem.CameraAction.NONE,
        loiter_time_s=float("nan"),
        camera_photo_interval_s=float("nan"),
        acceptance_radius_m=1.0,
        yaw_deg=float("nan"),
        camera_photo_distance_m=float("nan"),
        vehicle_action=MissionItem.VehicleAction.NONE,
    )


async def flight(api_port: int, log: list[str]) -> dict[str, Any]:
    seen: dict[str, Any] = {"modes": []}
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://0.0.0.0:{api_port}")
        system = await mavsdk.first_autopilot(timeout_s=30.0)
        assert system is not None, "no autopilot found"
        tel, act, off, mis = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system), MissionAsync(system)

        async def mode() -> FlightMode:
            m = await tel.flight_mode()
            if not seen["modes"] or seen["modes"][-1] != m:
                seen["modes"].append(m)
                log.append(f"mode {m}")
            return m

        await wait_for(tel.health_all_ok, bool, "health_all_ok")
        health = await tel.health()
        assert health.is_armable
        battery0 = await wait_for(tel.battery, lambda b: b.voltage_v > 10.0, "battery telemetry")
        assert 15.0 < battery0.voltage_v < 17.0
        assert battery0.remaining_percent > 95.0
        assert not await tel.armed()
        assert not await tel.in_air()

        # --- takeoff to 10 m
        await act.set_takeoff_altitude(10.0)
        assert await act.get_takeoff_altitude() == pytest.approx(10.0)
        await act.arm()
        await wait_for(tel.armed, bool, "armed")
        await act.takeoff()
        await wait_for(mode, lambda m: m == FlightMode.TAKEOFF, "TAKEOFF mode", 10)
        await wait_for(tel.in_air, bool, "in_air")
        pos = await wait_for(tel.position, lambda p: p.relative_altitude_m > 9.5, "10 m altitude")
        await wait_for(mode, lambda m: m == FlightMode.HOLD, "HOLD after takeoff", 20)
        pos = await tel.position()
        assert 9.2 < pos.relative_altitude_m < 10.8, pos
        log.append(f"took off to {pos.relative_altitude_m:.2f} m")

        # --- offboard to N20/E10, 15 m up, and hold
        await off.set_position_ned(PositionNedYaw(0.0, 0.0, -10.0, 0.0))
        await off.start()
        await wait_for(mode, lambda m: m == FlightMode.OFFBOARD, "OFFBOARD mode", 10)
        await off.set_position_ned(PositionNedYaw(20.0, 10.0, -15.0, 0.0))

        def at_target(pv: Any) -> bool:
            p = pv.position
            return math.dist((p.north_m, p.east_m, p.down_m), (20.0, 10.0, -15.0)) < 0.3

        await wait_for(tel.position_velocity_ned, at_target, "offboard target N20 E10 D-15", 60)
        worst = 0.0
        t_hold = time.monotonic()
        while time.monotonic() - t_hold < 2.0:  # hold (about 12 s simulated at the test's speed factor)
            p = (await tel.position_velocity_ned()).position
            worst = max(worst, math.dist((p.north_m, p.east_m, p.down_m), (20.0, 10.0, -15.0)))
            assert await mode() == FlightMode.OFFBOARD
            await asyncio.sleep(0.05)
        assert worst < 0.3, f"offboard hold wandered {worst:.2f} m"
        seen["offboard_hold_worst_m"] = worst
        log.append(f"offboard hold at N20/E10/15 m, worst deviation {worst:.3f} m")
        await off.stop()
        await wait_for(mode, lambda m: m == FlightMode.HOLD, "HOLD after offboard", 10)

        # --- 4-waypoint mission with a speed change
        plan = MissionPlan(
            [
                waypoint(40.0, 10.0, 15.0, 5.0),
                waypoint(40.0, 40.0, 15.0, 10.0),
                waypoint(10.0, 40.0, 20.0, 10.0),
                waypoint(10.0, 20.0, 20.0, 3.0),
            ]
        )
        await mis.set_return_to_launch_after_mission(False)
        await mis.upload_mission(plan)
        downloaded = await mis.download_mission()
        assert len(downloaded.mission_items) == 4
        for got, sent in zip(downloaded.mission_items, plan.mission_items, strict=True):
            assert got.latitude_deg == pytest.approx(sent.latitude_deg, abs=1e-6)
            assert got.longitude_deg == pytest.approx(sent.longitude_deg, abs=1e-6)
            assert got.relative_altitude_m == pytest.approx(sent.relative_altitude_m, abs=0.01)
            assert got.speed_m_s == pytest.approx(sent.speed_m_s, abs=0.01)
        await mis.start_mission()
        await wait_for(mode, lambda m: m == FlightMode.MISSION, "MISSION mode", 10)
        max_speed = 0.0
        deadline = time.monotonic() + 90.0
        while not await mis.is_mission_finished():
            assert time.monotonic() < deadline, "mission did not finish"
            v = (await tel.position_velocity_ned()).velocity
            max_speed = max(max_speed, math.hypot(v.north_m_s, v.east_m_s))
            await mode()
            await asyncio.sleep(0.05)
        progress = await mis.mission_progress()
        assert (progress.current, progress.total) == (4, 4), progress
        p = (await tel.position_velocity_ned()).position
        assert math.dist((p.north_m, p.east_m), (10.0, 20.0)) < 1.5, p
        assert p.down_m == pytest.approx(-20.0, abs=1.0)
        assert max_speed > 7.0, f"the 10 m/s legs never went faster than {max_speed:.1f} m/s"
        seen["mission_max_speed_mps"] = max_speed
        log.append(f"mission complete at N{p.north_m:.1f}/E{p.east_m:.1f}, max speed {max_speed:.1f} m/s")

        # --- return, land, disarm
        await act.set_return_to_launch_altitude(25.0)
        await act.return_to_launch()
        await wait_for(mode, lambda m: m == FlightMode.RETURN_TO_LAUNCH, "RTL mode", 10)
        await wait_for(tel.position, lambda p: p.relative_altitude_m > 24.0, "RTL climb to 25 m", 30)
        await wait_for(tel.in_air, lambda a: not a, "landed", 120)
        await wait_for(tel.armed, lambda a: not a, "auto-disarm", 30)
        p = (await tel.position_velocity_ned()).position
        assert math.hypot(p.north_m, p.east_m) < 1.0, p
        landed = await tel.position()
        assert abs(landed.relative_altitude_m) < 0.5
        battery1 = await tel.battery()
        seen["battery_used_pct"] = battery0.remaining_percent - battery1.remaining_percent
        assert 1.0 < seen["battery_used_pct"] < 20.0
        assert battery1.voltage_v < battery0.voltage_v
        log.append(f"landed at home and disarmed; battery {battery0.remaining_percent:.0f}% -> "
                   f"{battery1.remaining_percent:.0f}%")  # fmt: skip
        await mode()
    return seen


def test_mavsdk_flight(tmp_path: Path) -> None:
    log: list[str] = []
    with run_sitl("mavsdk_flight", tmp_path, speed=SPEED) as sitl:
        try:
            seen = asyncio.run(asyncio.wait_for(flight(sitl.ports.api, log), timeout=240))
        except BaseException:
            print("\n".join(log))
            print(sitl.proc.tail(60))
            raise
    print("\n".join(log))
    modes = seen["modes"]
    for expected in (FlightMode.TAKEOFF, FlightMode.HOLD, FlightMode.OFFBOARD, FlightMode.MISSION,
                     FlightMode.RETURN_TO_LAUNCH):  # fmt: skip
        assert expected in modes, modes
    assert modes.index(FlightMode.OFFBOARD) < modes.index(FlightMode.MISSION) < modes.index(FlightMode.RETURN_TO_LAUNCH)
