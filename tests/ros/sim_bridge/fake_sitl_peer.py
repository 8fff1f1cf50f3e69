"""A small SITL stand-in for the simulation link (pymavlink over UDP), for the bridge's tests.

It speaks the contract of docs/architecture.md from the SITL's side: it binds a UDP
port, treats whoever sends to it as a participant, sends ODOMETRY,
HIL_STATE_QUATERNION and HIL_ACTUATOR_CONTROLS for a scripted trajectory (free-run
at ``rate_hz`` of wall time, or one state per SIM_STEP grant in lockstep, acked with
COMMAND_ACK), HEARTBEAT at 1 Hz, and records what participants send (TERRAIN_REPORT,
COLLISION, grants) in arrival order.
"""

from __future__ import annotations

import math
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink

from uav_common.geo import GeoPoint, LocalProjection

SIM_STEP = 31010
HOME = GeoPoint(47.397742, 8.545594, 488.0)

# trajectory(t_s) -> (north_m, east_m, down_m, yaw_ned_rad)
Trajectory = Callable[[float], tuple[float, float, float, float]]


def hover_east(altitude_m: float = 30.0, speed_mps: float = 2.0) -> Trajectory:
    """At ``altitude_m`` over home, heading north, drifting east at ``speed_mps``."""
    return lambda t: (0.0, speed_mps * t, -altitude_m, 0.0)


@dataclass
class Received:
    kind: str
    sim_time_s: float
    fields: dict[str, float] = field(default_factory=dict)


class FakeSitl:
    def __init__(
        self,
        *,
        port: int = 0,
        lockstep: bool = False,
        rate_hz: float = 50.0,
        dt_s: float = 0.004,
        trajectory: Trajectory | None = None,
        home: GeoPoint = HOME,
    ) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.port = int(self.sock.getsockname()[1])
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.mav.robust_parsing = True
        self.lockstep = lockstep
        self.rate_hz = rate_hz
        self.dt_s = dt_s
        self.trajectory = trajectory or hover_east()
        self.proj = LocalProjection(home)
        self.t_s = 0.0
        self.peers: set[tuple[str, int]] = set()
        self.received: list[Received] = []
        self.states_sent = 0
        self.crashed = False
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self) -> FakeSitl:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.sock.close()

    def __enter__(self) -> FakeSitl:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def of_kind(self, kind: str) -> list[Received]:
        with self.lock:
            return [r for r in self.received if r.kind == kind]

    # ------------------------------------------------------------------ wire
    def _send(self, msg: object, peers: list[tuple[str, int]] | None = None) -> None:
        buf = msg.pack(self.mav)  # type: ignore[attr-defined]
        for p in peers if peers is not None else list(self.peers):
            self.sock.sendto(buf, p)

    def send_raw(self, data: bytes) -> None:
        for p in list(self.peers):
            self.sock.sendto(data, p)

    def send_state(self) -> None:
        n, e, d, yaw = self.trajectory(self.t_s)
        usec = round(self.t_s * 1e6)
        q = [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]
        unknown = [math.nan] + [0.0] * 20
        odo = mavlink.MAVLink_odometry_message(
            usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD, n, e, d, q,
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, unknown, unknown, 0, mavlink.MAV_ESTIMATOR_TYPE_NAIVE, 100,
        )  # fmt: skip
        geo = self.proj.to_geo(n, e, d)
        hil = mavlink.MAVLink_hil_state_quaternion_message(
            usec, q, 0.0, 0.0, 0.0, round(geo.lat_deg * 1e7), round(geo.lon_deg * 1e7),
            round(geo.alt_amsl_m * 1000), 0, 0, 0, 0, 0, 0, 0, -1000,
        )  # fmt: skip
        act = mavlink.MAVLink_hil_actuator_controls_message(
            usec, [0.55, 0.55, 0.55, 0.55] + [0.0] * 12, 128 | 1, 1 if self.lockstep else 0
        )
        for m in (odo, hil, act):
            self._send(m)
        self.states_sent += 1

    def send_heartbeat(self) -> None:
        status = mavlink.MAV_STATE_FLIGHT_TERMINATION if self.crashed else mavlink.MAV_STATE_ACTIVE
        self._send(mavlink.MAVLink_heartbeat_message(2, 12, 128 | 1, 0, status, 3))

    # ------------------------------------------------------------------ loop
    def _handle(self, msg: object, peer: tuple[str, int]) -> None:
        kind = msg.get_type()  # type: ignore[attr-defined]
        rec = Received(kind, self.t_s)
        if kind == "TERRAIN_REPORT":
            rec.fields = {"lat": msg.lat * 1e-7, "lon": msg.lon * 1e-7, "terrain_height": msg.terrain_height,  # type: ignore[attr-defined]
                          "current_height": msg.current_height}  # type: ignore[attr-defined]  # fmt: skip
        elif kind == "COLLISION":
            rec.fields = {"id": msg.id, "action": msg.action, "threat_level": msg.threat_level}  # type: ignore[attr-defined]
            self.crashed = True
        elif kind == "COMMAND_LONG":
            rec.fields = {"command": msg.command, "param1": msg.param1}  # type: ignore[attr-defined]
        with self.lock:
            self.received.append(rec)
        if kind == "COMMAND_LONG" and msg.command == SIM_STEP:  # type: ignore[attr-defined]
            steps = msg.param1  # type: ignore[attr-defined]
            if not self.lockstep or steps < 1 or steps != int(steps):
                self._send(
                    mavlink.MAVLink_command_ack_message(SIM_STEP, mavlink.MAV_RESULT_DENIED, 0, 0, 1, 200), [peer]
                )
                return
            self.t_s += int(steps) * self.dt_s
            self.send_state()
            self._send(mavlink.MAVLink_command_ack_message(SIM_STEP, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 1, 200), [peer])

    def _run(self) -> None:
        next_state = time.monotonic()
        next_hb = 0.0
        while not self._stop.is_set():
            ready, _, _ = select.select([self.sock], [], [], 0.002)
            if ready:
                try:
                    data, addr = self.sock.recvfrom(65535)
                except OSError:
                    continue
                peer = (addr[0], int(addr[1]))
                self.peers.add(peer)
                for msg in self.mav.parse_buffer(data) or []:
                    if msg.get_type() != "BAD_DATA":
                        self._handle(msg, peer)
            now = time.monotonic()
            if now >= next_hb and self.peers:
                self.send_heartbeat()
                next_hb = now + 1.0
            if not self.lockstep and self.peers and now >= next_state:
                self.t_s += 1.0 / self.rate_hz
                self.send_state()
                next_state += 1.0 / self.rate_hz
                if next_state < now:
                    next_state = now + 1.0 / self.rate_hz
