"""Acceptance: MAVSDK's gRPC API (``mavsdk_server`` + the ``mavsdk_grpc`` client of the ``mavsdk-grpc``
package) against a freshly started PX4-personality ``uav-sitl``, as a user's existing script would fly it.

Right after the connection comes up (no waiting for the vehicle to settle) the client imports a
QGroundControl ``.plan`` (a survey with camera, gimbal and speed items, an inclusion polygon and an
exclusion circle), uploads the mission and the geofence, downloads both back, then flies the mission,
offboard attitude setpoints, an orbit (DO_ORBIT), follow-me, and returns home. Every check reads
MAVSDK's own telemetry.
"""

from __future__ import annotations

import asyncio
import itertools
import math
import time
from collections.abc import Callable
from importlib.resources import files
from pathlib import Path
from typing import Any, TypeVar

import pytest
from e2e.sitl.harness import run_sitl
from helpers.procs import Proc, free_port
from mavsdk_grpc import System
from mavsdk_grpc.action import OrbitYawBehavior
from mavsdk_grpc.follow_me import Config as FollowConfig
from mavsdk_grpc.follow_me import TargetLocation
from mavsdk_grpc.offboard import Attitude
from mavsdk_grpc.telemetry import FlightMode

pytestmark = pytest.mark.slow

T = TypeVar("T")
HOME_LAT, HOME_LON, HOME_ALT = 47.397742, 8.545594, 488.0
PLAN = Path(__file__).resolve().parent / "data" / "survey.plan"
SPEED = "5"


def ll(north_m: float, east_m: float) -> tuple[float, float]:
    lat = HOME_LAT + math.degrees(north_m / 6_371_000.0)
    lon = HOME_LON + math.degrees(east_m / (6_371_000.0 * math.cos(math.radians(HOME_LAT))))
    return lat, lon


def ne(lat: float, lon: float) -> tuple[float, float]:
    return (
        math.radians(lat - HOME_LAT) * 6_371_000.0,
        math.radians(lon - HOME_LON) * 6_371_000.0 * math.cos(math.radians(HOME_LAT)),
    )


async def first(stream: Any) -> Any:
    async for value in stream:
        return value
    msg = "stream ended"
    raise RuntimeError(msg)


async def wait_for(stream_fn: Callable[[], Any], ok: Callable[[T], bool], what: str, timeout_s: float = 60.0) -> T:
    """Read a MAVSDK telemetry stream until ``ok``; fail with the last value."""
    last: Any = None

    async def watch() -> T:
        nonlocal last
        async for value in stream_fn():
            last = value
            if ok(value):
                return value  # type: ignore[no-any-return]
        msg = f"stream of {what} ended"
        raise RuntimeError(msg)

    try:
        return await asyncio.wait_for(watch(), timeout_s)
    except TimeoutError:
        pytest.fail(f"timed out after {timeout_s} s waiting for {what}; last value: {last}")


async def settle(seconds: float) -> None:
    await asyncio.sleep(seconds)


async def fly(grpc_port: int, log: list[str]) -> dict[str, Any]:
    seen: dict[str, Any] = {}
    drone = System(mavsdk_server_address="127.0.0.1", port=grpc_port)
    t0 = time.monotonic()
    await drone.connect()
    await wait_for(drone.core.connection_state, lambda s: s.is_connected, "connection", 30)
    log.append(f"connected after {time.monotonic() - t0:.2f} s")

    # --- at once: import the QGC plan, upload mission and geofence, download them back
    imported = await drone.mission_raw.import_qgroundcontrol_mission(str(PLAN))
    assert len(imported.mission_items) == 10
    assert len(imported.geofence_items) == 5  # 4 polygon vertices + 1 circle
    await drone.mission_raw.upload_geofence(imported.geofence_items)
    await drone.mission_raw.upload_mission(imported.mission_items)
    seen["uploaded_after_s"] = time.monotonic() - t0
    log.append(f"mission and geofence uploaded {seen['uploaded_after_s']:.2f} s after connecting")
    mission_back = await drone.mission_raw.download_mission()
    assert [(i.command, i.x, i.y) for i in mission_back] == [(i.command, i.x, i.y) for i in imported.mission_items]
    fence_back = await drone.mission_raw.download_geofence()
    assert [(i.command, i.param1, i.x, i.y) for i in fence_back] == [
        (i.command, i.param1, i.x, i.y) for i in imported.geofence_items
    ]

    # --- fly the mission
    await wait_for(drone.telemetry.health, lambda h: h.is_armable and h.is_global_position_ok, "health", 30)
    await drone.action.arm()
    await drone.mission_raw.start_mission()
    await wait_for(drone.telemetry.flight_mode, lambda m: m == FlightMode.MISSION, "MISSION mode", 10)
    max_speed = 0.0

    async def track_speed() -> None:
        nonlocal max_speed
        async for pv in drone.telemetry.position_velocity_ned():
            max_speed = max(max_speed, math.hypot(pv.velocity.north_m_s, pv.velocity.east_m_s))

    tracker = asyncio.ensure_future(track_speed())
    progress = await wait_for(
        drone.mission_raw.mission_progress, lambda p: p.total > 0 and p.current == p.total, "mission end", 90
    )
    tracker.cancel()
    pv = await first(drone.telemetry.position_velocity_ned())
    assert math.dist((pv.position.north_m, pv.position.east_m), (-20.0, 10.0)) < 3.0, pv
    assert pv.position.down_m == pytest.approx(-18.0, abs=1.0)
    assert 5.0 < max_speed < 7.0, f"DO_CHANGE_SPEED 6 m/s: flew at up to {max_speed:.1f} m/s"
    log.append(
        f"mission {progress.current}/{progress.total} done at N{pv.position.north_m:.1f} E{pv.position.east_m:.1f}"
    )

    # --- offboard attitude: face north, then nose 5 degrees down with a little more thrust, then level, stop
    await drone.offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.225))
    await drone.offboard.start()
    await wait_for(drone.telemetry.flight_mode, lambda m: m == FlightMode.OFFBOARD, "OFFBOARD", 10)
    await wait_for(drone.telemetry.attitude_euler, lambda a: abs(a.yaw_deg) < 2.0, "facing north", 15)
    await drone.offboard.set_attitude(Attitude(0.0, -5.0, 0.0, 0.235))
    att = await wait_for(drone.telemetry.attitude_euler, lambda a: a.pitch_deg < -4.5, "pitch -5 deg", 10)
    assert abs(att.roll_deg) < 1.0
    vel = await wait_for(drone.telemetry.velocity_ned, lambda v: v.north_m_s > 1.0, "moving north", 10)
    await drone.offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.225))
    await drone.offboard.stop()
    await wait_for(drone.telemetry.flight_mode, lambda m: m == FlightMode.HOLD, "HOLD after offboard", 10)
    log.append(f"offboard attitude: pitched {att.pitch_deg:.1f} deg, {vel.north_m_s:.1f} m/s north")
    await settle(1.0)

    # --- orbit: 15 m around a point 25 m east of home, 3 m/s, nose to the centre
    centre = ll(0.0, 25.0)
    pos = await first(drone.telemetry.position())
    await drone.action.do_orbit(15.0, 3.0, OrbitYawBehavior.HOLD_FRONT_TO_CIRCLE_CENTER, centre[0], centre[1],
                                pos.absolute_altitude_m)  # fmt: skip
    await wait_for(drone.telemetry.flight_mode, lambda m: m == FlightMode.POSCTL, "orbit (PX4 reports POSCTL)", 10)

    def on_circle(p: Any) -> bool:
        n, e = ne(p.latitude_deg, p.longitude_deg)
        return abs(math.hypot(n, e - 25.0) - 15.0) < 0.7

    await wait_for(drone.telemetry.position, on_circle, "on the 15 m circle", 60)
    angles = []
    for _ in range(12):
        p = await first(drone.telemetry.position())
        n, e = ne(p.latitude_deg, p.longitude_deg)
        assert math.hypot(n, e - 25.0) == pytest.approx(15.0, abs=1.0)
        angles.append(math.atan2(e - 25.0, n))
        await asyncio.sleep(0.25)
    turned = sum(math.remainder(b - a, math.tau) for a, b in itertools.pairwise(angles))
    assert turned > 0.3, f"positive radius circles clockwise; turned {turned:.2f} rad"
    log.append(f"orbit: on the circle, turned {math.degrees(turned):.0f} deg in 3 s")

    # --- follow-me: a target walking north-east of the vehicle
    await drone.follow_me.set_config(FollowConfig(8.0, 6.0, 0.1, FollowConfig.FollowAltitudeMode.CONSTANT, 8.0, 180.0))
    await drone.follow_me.start()
    await wait_for(drone.telemetry.flight_mode, lambda m: m == FlightMode.FOLLOW_ME, "FOLLOW_ME", 10)
    for k in range(30):
        lat, lon = ll(10.0 + 0.3 * k, 40.0)
        await drone.follow_me.set_target_location(TargetLocation(lat, lon, HOME_ALT, 1.5, 0.0, 0.0))
        await asyncio.sleep(0.2)
    p = await first(drone.telemetry.position())
    n, e = ne(p.latitude_deg, p.longitude_deg)
    target_n = 10.0 + 0.3 * 29
    assert math.hypot(n - (target_n - 6.0), e - 40.0) < 4.0, (n, e)
    assert p.relative_altitude_m == pytest.approx(8.0, abs=1.0)
    await drone.follow_me.stop()
    log.append(f"follow-me: at N{n:.1f} E{e:.1f}, target at N{target_n:.1f} E40.0")

    # --- home
    await drone.action.return_to_launch()
    await wait_for(drone.telemetry.in_air, lambda a: not a, "landed", 120)
    await wait_for(drone.telemetry.armed, lambda a: not a, "disarmed", 30)
    p = await first(drone.telemetry.position())
    assert math.hypot(*ne(p.latitude_deg, p.longitude_deg)) < 1.5
    seen["total_s"] = time.monotonic() - t0
    return seen


def test_mavsdk_grpc_plan_geofence_mission_offboard_orbit_follow_me(tmp_path: Path) -> None:
    log: list[str] = []
    with run_sitl("mavsdk_grpc", tmp_path, speed=SPEED) as sitl:
        grpc_port = free_port()
        server_bin = str(files("mavsdk_grpc.bin") / "mavsdk_server")
        server = Proc("mavsdk_server", [server_bin, "-p", str(grpc_port), f"udpin://0.0.0.0:{sitl.ports.api}"])
        try:
            seen = asyncio.run(asyncio.wait_for(fly(grpc_port, log), timeout=300))
        except BaseException:
            print("\n".join(log))
            print(server.tail(40))
            print(sitl.proc.tail(60))
            raise
        finally:
            server.stop()
    print("\n".join(log))
    assert seen["uploaded_after_s"] < 5.0
