"""Acceptance: MAVSDK's ``failure`` plugin injects compass, baro and GPS failures into a hovering ``uav-sitl`` in wind.

As with PX4: refused while SYS_FAILURE_EN is 0, an unmodelled failure is UNSUPPORTED; compass and baro off leave
the heading to the gyro and the height to the GNSS, the vehicle holds (MAVSDK: magnetometer unhealthy); a stuck
GPS while hovering passes EKF2's innovation gate and changes nothing (GPS_RAW_INT frozen); GPS off makes the
position estimate invalid after EKF2_NOAID_TOUT, the failsafe descends (reported as LAND) without position
control, so the wind carries the vehicle away while it lands, and it disarms.
"""

from __future__ import annotations

import asyncio
import math
from pathlib import Path
from typing import Any

import pytest
from e2e.sitl.harness import run_sitl
from e2e.sitl.test_sitl_mavsdk_flight import wait_for
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.failure import FailureAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync
from mavsdk.plugins.failure import FailureError, FailureResult, FailureType, FailureUnit

pytestmark = pytest.mark.slow


async def gps_off_in_flight(api_port: int, log: list[str]) -> dict[str, Any]:
    seen: dict[str, Any] = {}
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://0.0.0.0:{api_port}")
        system = await mavsdk.first_autopilot(timeout_s=30.0)
        assert system is not None, "no autopilot found"
        tel, act = TelemetryAsync(system), ActionAsync(system)
        param = ParamAsync(system)
        await wait_for(tel.health_all_ok, bool, "health_all_ok")

        # refused while SYS_FAILURE_EN is 0
        assert await param.get_param_int("SYS_FAILURE_EN") == 0
        with pytest.raises(FailureError) as denied:
            await FailureAsync(system).inject(FailureUnit.SENSOR_GPS, FailureType.OFF, 0)
        # MAVSDK's plugin reads SYS_FAILURE_EN when it starts and then refuses by itself (DISABLED); until
        # it has read it, the command goes out and the SITL answers DENIED, as PX4 does
        assert denied.value.result in {FailureResult.DENIED, FailureResult.DISABLED}
        await param.set_param_int("SYS_FAILURE_EN", 1)
        assert await param.get_param_int("SYS_FAILURE_EN") == 1
        failure = FailureAsync(system)  # MAVSDK's plugin reads SYS_FAILURE_EN when it starts
        with pytest.raises(FailureError) as unsupported:
            await failure.inject(FailureUnit.SENSOR_GYRO, FailureType.STUCK, 0)
        assert unsupported.value.result is FailureResult.UNSUPPORTED
        log.append("failure injection: DENIED with SYS_FAILURE_EN 0, gyro stuck UNSUPPORTED")

        await act.set_takeoff_altitude(15.0)
        await act.arm()
        await act.takeoff()
        await wait_for(tel.flight_mode, lambda m: m == FlightMode.HOLD, "HOLD after takeoff", 40)
        await asyncio.sleep(1.0)
        before = (await tel.position_velocity_ned()).position
        log.append(f"holding at N{before.north_m:.2f} E{before.east_m:.2f} D{before.down_m:.2f} in 6 m/s wind")
        assert math.hypot(before.north_m, before.east_m) < 2.0

        # compass and baro off: EKF2 falls back to the gyro heading and the GNSS height, no failsafe
        await failure.inject(FailureUnit.SENSOR_MAG, FailureType.OFF, 0)
        await failure.inject(FailureUnit.SENSOR_BARO, FailureType.OFF, 0)
        await wait_for(tel.health, lambda h: not h.is_magnetometer_calibration_ok, "compass unhealthy", 10)
        await asyncio.sleep(2.0)  # 10 simulated seconds
        health = await tel.health()
        assert health.is_local_position_ok
        assert health.is_global_position_ok
        assert await tel.flight_mode() == FlightMode.HOLD
        held = (await tel.position_velocity_ned()).position
        assert math.hypot(held.north_m - before.north_m, held.east_m - before.east_m) < 2.0
        assert abs(held.down_m + 15.0) < 3.0, "the GNSS height holds it at the takeoff altitude"
        await failure.inject(FailureUnit.SENSOR_MAG, FailureType.OK, 0)
        await failure.inject(FailureUnit.SENSOR_BARO, FailureType.OK, 0)
        await wait_for(tel.health, lambda h: h.is_magnetometer_calibration_ok, "compass healthy again", 10)
        log.append(f"compass and baro off 10 s: still holding (D{held.down_m:.2f}), cleared")

        # a stuck receiver while hovering: EKF2's innovation gate accepts the frozen fix, nothing to notice
        await failure.inject(FailureUnit.SENSOR_GPS, FailureType.STUCK, 0)
        await asyncio.sleep(0.5)
        frozen = await tel.raw_gps()
        await asyncio.sleep(2.0)  # 10 simulated seconds
        later = await tel.raw_gps()
        assert (later.latitude_deg, later.longitude_deg) == (frozen.latitude_deg, frozen.longitude_deg)
        assert (await tel.gps_info()).num_satellites > 0, "a stuck receiver still claims its fix"
        assert (await tel.health()).is_local_position_ok
        assert await tel.flight_mode() == FlightMode.HOLD
        log.append(f"GPS stuck at {frozen.latitude_deg:.7f}, {frozen.longitude_deg:.7f}: still holding")

        await failure.inject(FailureUnit.SENSOR_GPS, FailureType.OFF, 0)  # replaces the stuck one
        gps = await wait_for(tel.gps_info, lambda g: g.num_satellites == 0, "GPS without a fix", 10)
        log.append(f"GPS off: {gps}")
        health = await wait_for(tel.health, lambda h: not h.is_local_position_ok, "local position invalid", 20)
        assert not health.is_global_position_ok
        await wait_for(tel.flight_mode, lambda m: m == FlightMode.LAND, "the position failsafe (LAND)", 10)
        log.append("position estimate lost: failsafe LAND (PX4's Descend)")
        await wait_for(tel.in_air, lambda a: not a, "landed", 60)
        await wait_for(tel.armed, lambda a: not a, "disarmed", 30)
        seen["landed"] = True
    return seen


def test_mavsdk_failure_plugin_gps_off_triggers_the_failsafe(tmp_path: Path) -> None:
    log: list[str] = []
    extra = ("--wind", "6,270")
    with run_sitl("failure_injection", tmp_path, speed="5", extra=extra) as sitl:
        try:
            seen = asyncio.run(asyncio.wait_for(gps_off_in_flight(sitl.ports.api, log), timeout=180))
        except BaseException:
            print("\n".join(log))
            print(sitl.proc.tail(60))
            raise
    print("\n".join(log))
    assert seen["landed"]
