"""Acceptance: the ArduPilot personality (``uav-sitl --autopilot ardupilot``) with the clients ArduPilot users
run: MAVProxy's own commands (``mode GUIDED``, ``arm throttle``, ``takeoff``, ``mode RTL``, ``param``),
and MAVSDK (native and gRPC), which must identify it as ArduPilot and fly it through its ArduPilot paths.
"""

from __future__ import annotations

import asyncio
import math
import time
from importlib.resources import files
from pathlib import Path

import pytest
from e2e.sitl.harness import MavProxy, run_sitl
from helpers.procs import Proc, artifacts_dir, free_port
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.info import InfoAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync
from mavsdk_grpc import System
from mavsdk_grpc.telemetry import FlightMode as GrpcFlightMode
from pymavlink import mavutil

pytestmark = pytest.mark.slow

ARDUPILOT = ["--autopilot", "ardupilot"]


def test_mavproxy_mode_commands_fly_the_ardupilot_personality(tmp_path: Path) -> None:
    workdir = artifacts_dir() / "mavproxy_ardupilot"
    workdir.mkdir(parents=True, exist_ok=True)
    with run_sitl("mavproxy_ardupilot", tmp_path, speed="3", extra=ARDUPILOT) as sitl:
        observer = mavutil.mavlink_connection(f"tcp:127.0.0.1:{sitl.ports.tcp}", dialect="common", source_system=250)
        mp = MavProxy(f"udpin:127.0.0.1:{sitl.ports.gcs}", workdir)
        try:
            mp.expect(r"online system 1")
            mp.expect(r"STABILIZE> ", timeout_s=30)  # MAVProxy's prompt shows ArduCopter's mode names
            mp.expect(r"Received \d+ parameters", 40)
            mark = mp.send("param show WPNAV_SPEED")
            mp.expect(r"WPNAV_SPEED\s+1000", since=mark)
            mp.send("param set RTL_ALT 1200")
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and not sitl.params_file.exists():
                time.sleep(0.1)
            mark = mp.send("param show RTL_ALT")  # MAVProxy's cache follows the vehicle's PARAM_VALUE echo
            mp.expect(r"RTL_ALT\s+1200", since=mark)
            mark = mp.send("mode")
            mp.expect(r"Available modes:.*GUIDED.*RTL", since=mark)
            mark = mp.send("mode GUIDED")
            mp.expect(r"Mode GUIDED|GUIDED> ", since=mark)
            mark = mp.send("arm throttle")
            mp.expect(r"ARMED", since=mark)
            mark = mp.send("takeoff 8")
            msg = observer.recv_match(type="GLOBAL_POSITION_INT", condition="GLOBAL_POSITION_INT.relative_alt > 7700",
                                      blocking=True, timeout=40)  # fmt: skip
            assert msg is not None, "GUIDED takeoff did not reach 8 m"
            hb = observer.recv_match(type="HEARTBEAT", condition="HEARTBEAT.get_srcComponent() == 1", blocking=True,
                                     timeout=5)  # fmt: skip
            assert hb is not None
            assert hb.custom_mode == 4, "the vehicle stays in GUIDED after a GUIDED takeoff"
            mark = mp.send("mode RTL")
            mp.expect(r"Mode RTL|RTL> ", since=mark)
            # RTL climbs to RTL_ALT (the 12 m just set), waits RTL_LOIT_TIME over home, lands and disarms
            msg = observer.recv_match(type="GLOBAL_POSITION_INT", condition="GLOBAL_POSITION_INT.relative_alt > 11500",
                                      blocking=True, timeout=40)  # fmt: skip
            assert msg is not None, "RTL did not climb to RTL_ALT"
            mp.expect(r"DISARMED", since=mark, timeout_s=90)
            mark = mp.send("status")
            mp.expect(r"HEARTBEAT \{type : 2, autopilot : 3", since=mark)
        finally:
            (workdir / "mavproxy_output.txt").write_text("\n".join(mp.lines) + "\n")
            mp.stop()
            observer.close()


async def _mavsdk_native(api_port: int, log: list[str]) -> None:
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://0.0.0.0:{api_port}")
        system = await mavsdk.first_autopilot(timeout_s=30.0)
        assert system is not None
        tel, act, info = TelemetryAsync(system), ActionAsync(system), InfoAsync(system)
        assert (await system.autopilot_type()).name == "ARDUPILOT"
        deadline = time.monotonic() + 20
        while await tel.flight_mode() != FlightMode.STABILIZED:  # ArduCopter's STABILIZE, decoded by its table
            assert time.monotonic() < deadline, await tel.flight_mode()
            await asyncio.sleep(0.1)
        version = await info.get_version()
        assert (version.flight_sw_major, version.flight_sw_minor) == (4, 5)
        while not (await tel.health()).is_global_position_ok:
            assert time.monotonic() < deadline + 20
            await asyncio.sleep(0.2)
        await act.set_takeoff_altitude(6.0)
        await act.arm()
        await act.takeoff()  # MAVSDK's ArduPilot path: GUIDED, then NAV_TAKEOFF with the altitude
        deadline = time.monotonic() + 40
        while (await tel.position()).relative_altitude_m < 5.5:
            assert time.monotonic() < deadline, "no takeoff"
            await asyncio.sleep(0.1)
        assert await tel.flight_mode() == FlightMode.OFFBOARD  # MAVSDK shows ArduCopter's GUIDED as Offboard
        log.append("native MAVSDK: ArduPilot identified, took off through GUIDED")
        await act.return_to_launch()
        deadline = time.monotonic() + 120
        while await tel.armed():
            assert time.monotonic() < deadline, "no landing"
            await asyncio.sleep(0.2)
        pos = await tel.position_velocity_ned()
        assert math.hypot(pos.position.north_m, pos.position.east_m) < 1.5


async def _mavsdk_grpc(grpc_port: int) -> None:
    drone = System(mavsdk_server_address="127.0.0.1", port=grpc_port)
    await drone.connect()
    async for state in drone.core.connection_state():
        if state.is_connected:
            break
    # the vehicle stayed in RTL (6) after landing, as ArduCopter does: decoded with ArduCopter's table (PX4's
    # would read custom_mode 6 as an unknown mode)
    async for mode in drone.telemetry.flight_mode():
        assert mode in (GrpcFlightMode.RETURN_TO_LAUNCH, GrpcFlightMode.UNKNOWN)
        if mode == GrpcFlightMode.RETURN_TO_LAUNCH:
            break
    version = await drone.info.get_version()
    assert version.flight_sw_major == 4


def test_mavsdk_identifies_ardupilot_and_flies_it(tmp_path: Path) -> None:
    log: list[str] = []
    with run_sitl("mavsdk_ardupilot", tmp_path, speed="4", extra=ARDUPILOT) as sitl:
        try:
            asyncio.run(asyncio.wait_for(_mavsdk_native(sitl.ports.api, log), timeout=180))
        except BaseException:
            print("\n".join(log))
            print(sitl.proc.tail(60))
            raise
        grpc_port = free_port()
        server_bin = str(files("mavsdk_grpc.bin") / "mavsdk_server")
        server = Proc("mavsdk_server_ardupilot", [server_bin, "-p", str(grpc_port),
                                                  f"udpin://0.0.0.0:{sitl.ports.api}"])  # fmt: skip
        try:
            asyncio.run(asyncio.wait_for(_mavsdk_grpc(grpc_port), timeout=60))
        finally:
            server.stop()
    print("\n".join(log))
