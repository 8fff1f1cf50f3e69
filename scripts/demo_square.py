"""Foundation demo: start ``uav-sitl``, fly a square with real MAVSDK, print what happened.

Runs on the default PX4 SITL ports (MAVSDK on UDP 14540). Steps: wait for a
healthy vehicle, arm, take off to 10 m, fly a 20 m offboard square, land,
disarm, then print the positions reached, the modes seen and the battery used,
and stop the SITL. Logs: artifacts/demo/.

    scripts/in_env python scripts/demo_square.py [--speed-factor 5] [--side 20]
"""

from __future__ import annotations

import argparse
import asyncio
import math
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

T = TypeVar("T")
REPO = Path(__file__).resolve().parents[1]
OUT = REPO / "artifacts" / "demo"
API_PORT = 14540
# Ports uav-sitl binds with the default config (config/sitl.yaml), and who uses them.
SITL_PORTS = (
    ("UDP", 18570, "GCS link"),
    ("UDP", 14580, "API link"),
    ("TCP", 5760, "TCP server"),
    ("UDP", 4560, "sim link"),
)


class DemoError(Exception):
    """The demo cannot run or the flight went wrong; the message says why."""


@dataclass
class Report:
    modes: list[str] = field(default_factory=list)
    waypoints: list[tuple[str, tuple[float, float, float], float]] = field(default_factory=list)
    battery_start_pct: float = math.nan
    battery_end_pct: float = math.nan
    voltage_start_v: float = math.nan
    voltage_end_v: float = math.nan
    max_altitude_m: float = 0.0


def port_busy(proto: str, port: int) -> bool:
    kind = socket.SOCK_DGRAM if proto == "UDP" else socket.SOCK_STREAM
    with socket.socket(socket.AF_INET, kind) as sock:
        try:
            sock.bind(("0.0.0.0", port))
        except OSError:
            return True
    return False


def check_ports() -> None:
    busy = [f"{proto} {port} ({what})" for proto, port, what in SITL_PORTS if port_busy(proto, port)]
    if port_busy("UDP", API_PORT):
        busy.append(f"UDP {API_PORT} (MAVSDK's listening port)")
    if busy:
        raise DemoError(
            "port(s) already in use: " + ", ".join(busy) + ". Another uav-sitl, PX4 SITL or MAVSDK client is "
            "running; stop it (e.g. `ss -lunp | grep 145`) and retry."
        )


async def wait_for(probe: Callable[[], Awaitable[T]], ok: Callable[[T], bool], what: str, timeout_s: float) -> T:
    deadline = time.monotonic() + timeout_s
    value = await probe()
    while not ok(value):
        if time.monotonic() > deadline:
            msg = f"timed out after {timeout_s:.0f} s waiting for {what} (last: {value})"
            raise DemoError(msg)
        await asyncio.sleep(0.1)
        value = await probe()
    return value


async def fly(side_m: float, altitude_m: float, report: Report) -> None:  # noqa: PLR0915 - one linear script
    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://0.0.0.0:{API_PORT}")
        print("waiting for the vehicle ...", flush=True)
        system = await mavsdk.first_autopilot(timeout_s=30.0)
        if system is None:
            msg = "no autopilot heartbeat on UDP 14540 within 30 s"
            raise DemoError(msg)
        tel, act, off = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)

        async def note_mode() -> FlightMode:
            mode = await tel.flight_mode()
            name = mode.name
            if not report.modes or report.modes[-1] != name:
                report.modes.append(name)
            return mode

        async def reached(label: str, north: float, east: float, down: float) -> None:
            def close(pv: Any) -> bool:
                p, v = pv.position, pv.velocity
                speed = math.sqrt(v.north_m_s**2 + v.east_m_s**2 + v.down_m_s**2)
                return math.dist((p.north_m, p.east_m, p.down_m), (north, east, down)) < 0.2 and speed < 0.2

            pv = await wait_for(tel.position_velocity_ned, close, f"{label} (N{north:.0f} E{east:.0f})", 60)
            p = pv.position
            err = math.dist((p.north_m, p.east_m, p.down_m), (north, east, down))
            report.waypoints.append((label, (p.north_m, p.east_m, -p.down_m), err))
            report.max_altitude_m = max(report.max_altitude_m, -p.down_m)
            await note_mode()
            print(f"  reached {label:<12} N{p.north_m:6.2f} E{p.east_m:6.2f} alt {-p.down_m:5.2f} m", flush=True)

        await wait_for(tel.health_all_ok, bool, "a healthy vehicle (health_all_ok)", 30)
        battery = await tel.battery()
        report.battery_start_pct, report.voltage_start_v = battery.remaining_percent, battery.voltage_v
        await note_mode()
        print("arming and taking off ...", flush=True)
        await act.set_takeoff_altitude(altitude_m)
        await act.arm()
        await act.takeoff()
        await wait_for(note_mode, lambda m: m == FlightMode.TAKEOFF, "TAKEOFF mode", 10)
        await wait_for(note_mode, lambda m: m == FlightMode.HOLD, "the end of the takeoff", 60)
        await reached("takeoff", 0.0, 0.0, -altitude_m)
        print(f"flying a {side_m:.0f} m offboard square ...", flush=True)
        await off.set_position_ned(PositionNedYaw(0.0, 0.0, -altitude_m, 0.0))
        await off.start()
        await wait_for(note_mode, lambda m: m == FlightMode.OFFBOARD, "OFFBOARD mode", 10)
        corners = [(side_m, 0.0, 0.0), (side_m, side_m, 90.0), (0.0, side_m, 180.0), (0.0, 0.0, 270.0)]
        for i, (north, east, yaw) in enumerate(corners, start=1):
            await off.set_position_ned(PositionNedYaw(north, east, -altitude_m, yaw))
            await reached(f"corner {i}", north, east, -altitude_m)
        await off.stop()
        print("landing ...", flush=True)
        await act.land()
        await wait_for(note_mode, lambda m: m == FlightMode.LAND, "LAND mode", 10)
        await wait_for(tel.in_air, lambda a: not a, "touchdown", 90)
        await wait_for(tel.armed, lambda a: not a, "auto-disarm after landing", 30)
        await note_mode()
        battery = await tel.battery()
        report.battery_end_pct, report.voltage_end_v = battery.remaining_percent, battery.voltage_v
        p = (await tel.position_velocity_ned()).position
        report.waypoints.append(("landed", (p.north_m, p.east_m, -p.down_m), math.hypot(p.north_m, p.east_m)))


def print_report(report: Report, wall_s: float, speed: float) -> None:
    print("\n=== demo summary ===")
    print(f"modes seen      : {' -> '.join(report.modes)}")
    print("positions       :")
    for label, (n, e, alt), err in report.waypoints:
        print(f"  {label:<12} N{n:7.2f} m  E{e:7.2f} m  alt {alt:6.2f} m   (error {err:.2f} m)")
    used = report.battery_start_pct - report.battery_end_pct
    print(
        f"battery         : {report.battery_start_pct:.0f}% ({report.voltage_start_v:.2f} V) -> "
        f"{report.battery_end_pct:.0f}% ({report.voltage_end_v:.2f} V), used {used:.1f}%"
    )
    print(f"max altitude    : {report.max_altitude_m:.1f} m")
    print(f"wall time       : {wall_s:.1f} s at speed factor {speed:g}")
    print(f"SITL log        : {OUT / 'sitl.log'}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--speed-factor", type=float, default=5.0, help="SITL speed factor (default 5)")
    ap.add_argument("--side", type=float, default=20.0, help="square side in metres (default 20)")
    ap.add_argument("--altitude", type=float, default=10.0, help="flight altitude in metres (default 10)")
    args = ap.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    try:
        check_ports()
    except DemoError as err:
        print(f"demo: {err}", file=sys.stderr)
        return 1
    log_path = OUT / "sitl.log"
    argv_sitl = [
        "uav-sitl",
        "--speed-factor", f"{args.speed_factor:g}",
        "--params-file", str(OUT / "params.json"),
        "--reset-params",
    ]  # fmt: skip
    print(f"starting {' '.join(argv_sitl)} (log: {log_path})", flush=True)
    t0 = time.monotonic()
    report = Report()
    with log_path.open("wb") as log:
        sitl = subprocess.Popen(argv_sitl, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
        try:
            time.sleep(1.0)
            if sitl.poll() is not None:
                msg = f"uav-sitl exited with {sitl.returncode}: {log_path.read_text()[-800:]}"
                raise DemoError(msg)
            asyncio.run(asyncio.wait_for(fly(args.side, args.altitude, report), timeout=180))
        except (DemoError, TimeoutError) as err:
            print(f"demo: FAILED: {err}", file=sys.stderr)
            return 1
        finally:
            if sitl.poll() is None:
                sitl.send_signal(signal.SIGINT)
                try:
                    sitl.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    sitl.kill()
                    sitl.wait()
    print_report(report, time.monotonic() - t0, args.speed_factor)
    return 0


if __name__ == "__main__":
    sys.exit(main())
