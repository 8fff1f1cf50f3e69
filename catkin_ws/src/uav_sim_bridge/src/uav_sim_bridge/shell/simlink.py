"""The bridge's end of the SITL simulation link: MAVLink 2 over UDP (docs/architecture.md).

:class:`SimLinkClient` owns the socket and the pymavlink codec; :class:`SimLinkTracker`
folds the received messages into the latest :class:`SimLinkSnapshot` (pure: no
socket, no clock).  Malformed datagrams are counted and dropped, never raised.
"""

from __future__ import annotations

import math
import select
import socket
import struct
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from uav_common.geo import GeoPoint
from uav_common.mavlink_parser import reset_parser
from uav_sim_bridge.core.vehicle_state import VehicleState, home_from_fix, state_from_odometry
from uav_sim_bridge.errors import SimLinkError

__all__ = ["SIM_STEP", "LinkCounters", "SimLinkClient", "SimLinkSnapshot", "SimLinkTracker"]

SIM_STEP = 31010  # MAV_CMD_USER_1, the lockstep grant
_FLIGHT_TERMINATION = mavlink.MAV_STATE_FLIGHT_TERMINATION
_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED


@dataclass
class LinkCounters:
    """Traffic counters, for logs and the node's diagnostics."""

    rx_datagrams: int = 0
    rx_messages: int = 0
    rx_bad: int = 0
    rx_invalid_state: int = 0
    rx_foreign: int = 0
    tx_messages: int = 0
    tx_errors: int = 0


@dataclass
class SimLinkSnapshot:
    """What the SITL last told us."""

    state: VehicleState | None = None
    state_serial: int = 0
    armed: bool = False
    crashed: bool = False
    lockstep: bool = False
    motor_outputs: tuple[float, ...] = ()
    home: GeoPoint | None = None
    custom_mode: int = 0
    heartbeats: int = 0
    acks: list[tuple[int, int]] = field(default_factory=list)  # (command, result) in arrival order


class SimLinkTracker:
    """Folds sim-link messages from the SITL (system ``sitl_system_id``) into a snapshot."""

    def __init__(self, sitl_system_id: int = 1, counters: LinkCounters | None = None) -> None:
        self.sitl_system_id = sitl_system_id
        self.counters = counters or LinkCounters()
        self.snapshot = SimLinkSnapshot()
        self._last_odometry: tuple[int, tuple[float, float, float]] | None = None
        self._pending_fix: tuple[int, GeoPoint] | None = None

    def update(self, msg: Any) -> None:
        """Apply one decoded message (other systems' and unknown messages are ignored)."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.counters.rx_bad += 1
            return
        if msg.get_srcSystem() != self.sitl_system_id:
            self.counters.rx_foreign += 1
            return
        self.counters.rx_messages += 1
        snap = self.snapshot
        if kind == "ODOMETRY":
            try:
                state = state_from_odometry(
                    int(msg.time_usec),
                    (msg.x, msg.y, msg.z),
                    tuple(msg.q),
                    (msg.vx, msg.vy, msg.vz),
                    (msg.rollspeed, msg.pitchspeed, msg.yawspeed),
                )
            except ValueError:
                self.counters.rx_invalid_state += 1
                return
            snap.state = state
            snap.state_serial += 1
            self._last_odometry = (int(msg.time_usec), (float(msg.x), float(msg.y), float(msg.z)))
            self._try_home()
        elif kind == "HIL_STATE_QUATERNION":
            fix = GeoPoint(msg.lat * 1e-7, msg.lon * 1e-7, msg.alt * 1e-3)
            if all(math.isfinite(v) for v in (fix.lat_deg, fix.lon_deg, fix.alt_amsl_m)):
                self._pending_fix = (int(msg.time_usec), fix)
                self._try_home()
        elif kind == "HIL_ACTUATOR_CONTROLS":
            snap.armed = bool(int(msg.mode) & _ARMED)
            snap.lockstep = bool(int(msg.flags) & 1)
            snap.motor_outputs = tuple(float(v) for v in msg.controls[:4])
        elif kind == "HEARTBEAT":
            snap.heartbeats += 1
            snap.crashed = int(msg.system_status) == _FLIGHT_TERMINATION
            snap.armed = bool(int(msg.base_mode) & _ARMED)
            snap.custom_mode = int(msg.custom_mode)
        elif kind == "COMMAND_ACK":
            snap.acks.append((int(msg.command), int(msg.result)))

    def _try_home(self) -> None:
        """Home from a HIL_STATE_QUATERNION fix and the ODOMETRY of the same instant (once)."""
        if self.snapshot.home is not None or self._pending_fix is None or self._last_odometry is None:
            return
        t_fix, fix = self._pending_fix
        t_odo, ned = self._last_odometry
        if t_fix == t_odo:
            self.snapshot.home = home_from_fix(fix, ned)


class SimLinkClient:
    """UDP socket + pymavlink codec of the bridge (system 1, component 200 by default).

    Raises:
        SimLinkError: the local port cannot be bound.
    """

    def __init__(
        self,
        host: str,
        port: int,
        *,
        local_port: int = 0,
        system_id: int = 1,
        component_id: int = 200,
        counters: LinkCounters | None = None,
    ) -> None:
        self.remote = (host, port)
        self.counters = counters or LinkCounters()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(("0.0.0.0", local_port))  # any interface: the SITL may run on another host
        except OSError as err:
            self.sock.close()
            msg = f"cannot bind the sim-link UDP port {local_port}: {err.strerror}"
            raise SimLinkError(msg) from err
        self.sock.setblocking(False)
        self.local_port = int(self.sock.getsockname()[1])
        self.mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.mav.robust_parsing = True
        self._target_system = 1
        self._target_component = 1

    def close(self) -> None:
        self.sock.close()

    def fileno(self) -> int:
        return self.sock.fileno()

    # ------------------------------------------------------------------ receive
    def receive(self, timeout_s: float, *, wake_fd: int | None = None) -> list[Any]:
        """Every message pending now, waiting up to ``timeout_s`` for the first datagram (or for ``wake_fd`` to
        become readable: another event the caller waits for, e.g. a lockstep participant's done)."""
        fds: list[Any] = [self.sock] if wake_fd is None else [self.sock, wake_fd]
        ready, _, _ = select.select(fds, [], [], max(0.0, timeout_s))
        out: list[Any] = []
        if self.sock not in ready:
            return out
        for _ in range(1024):
            try:
                data, _ = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                self.counters.rx_bad += 1
                break
            self.counters.rx_datagrams += 1
            reset_parser(self.mav)  # a datagram holds whole messages: never carry a fragment over
            try:
                msgs = self.mav.parse_buffer(data) or []
            except (mavlink.MAVError, ValueError, IndexError, struct.error):
                self.counters.rx_bad += 1
                continue
            if self.mav.buf_len() > 0:
                self.counters.rx_bad += 1  # trailing bytes that are not a whole message
            out.extend(msgs)
        return out

    # ------------------------------------------------------------------ send
    def _send(self, msg: Any) -> None:
        try:
            self.sock.sendto(msg.pack(self.mav), self.remote)
            self.counters.tx_messages += 1
        except OSError:
            self.counters.tx_errors += 1

    def send_heartbeat(self) -> None:
        self._send(
            mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE, 3
            )
        )

    def send_collision(self, instance_id: int, *, horizontal_m: float = 0.0, vertical_m: float = 0.0) -> None:
        self._send(
            mavlink.MAVLink_collision_message(
                mavlink.MAV_COLLISION_SRC_ADSB,
                int(instance_id),
                mavlink.MAV_COLLISION_ACTION_REPORT,
                mavlink.MAV_COLLISION_THREAT_LEVEL_HIGH,
                0.0,
                float(vertical_m),
                float(horizontal_m),
            )
        )

    def send_terrain_report(
        self, lat_deg: float, lon_deg: float, terrain_amsl_m: float, above_terrain_m: float
    ) -> None:
        self._send(
            mavlink.MAVLink_terrain_report_message(
                round(lat_deg * 1e7), round(lon_deg * 1e7), 0, float(terrain_amsl_m), float(above_terrain_m), 0, 0
            )
        )

    def send_sim_step(self, steps: int, *, step: int = 0) -> None:
        """SIM_STEP: run ``steps`` physics steps; ``step`` is the number of this grant (1, 2, ...; 0 = unnumbered),
        which the SITL checks (docs/architecture.md, simulation link)."""
        self._send(
            mavlink.MAVLink_command_long_message(
                self._target_system, self._target_component, SIM_STEP, 0, float(steps), float(step), 0, 0, 0, 0, 0
            )
        )
