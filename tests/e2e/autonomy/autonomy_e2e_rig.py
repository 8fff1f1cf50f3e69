"""Pieces of the autonomy e2e rig: SITL telemetry on the GCS link, a cuttable MAVLink link, the ROS client.

* :class:`SitlMonitor`: a pymavlink ground station on the SITL's GCS link (its own port), in a thread.
  It is the test's independent view of the vehicle: position, mode, armed and landed state, the
  setpoint the autopilot is following (POSITION_TARGET_LOCAL_NED echo) and STATUSTEXTs.
* :class:`MavRelay`: the link between the SITL's API link and the controller, a UDP relay that
  forwards both ways, counts and remembers every SET_POSITION_TARGET_LOCAL_NED the controller
  sends, and can be cut (everything dropped both ways) and restored, like a radio link going away.
* :class:`RosClient`: talks to ``autonomy_e2e_ros_client.py`` (a separate process, so that this
  pytest process never calls rospy.init_node) through JSON datagrams.
"""

from __future__ import annotations

import json
import math
import os
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

os.environ["MAVLINK20"] = "1"

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

T = TypeVar("T")

PX4_OFFBOARD = 6 << 16
PX4_RTL = (4 << 16) | (5 << 24)
PX4_LOITER = (4 << 16) | (3 << 24)


def wait_for(
    what: str, probe: Callable[[], T], pred: Callable[[T], bool], timeout_s: float, check: Callable[[], None]
) -> T:
    """Poll ``probe`` until ``pred`` holds; ``check`` raises if a process died. Wall-clock timeout."""
    deadline = time.monotonic() + timeout_s
    value = probe()
    while time.monotonic() < deadline:
        value = probe()
        if pred(value):
            return value
        check()
        time.sleep(0.05)
    msg = f"timed out after {timeout_s:.0f} s waiting for {what}; last: {str(value)[:400]}"
    raise AssertionError(msg)


@dataclass
class VehicleView:
    """The latest of what the SITL said on the GCS link (positions ENU, metres from home)."""

    position_enu_m: tuple[float, float, float] | None = None
    custom_mode: int | None = None
    armed: bool = False
    landed_state: int | None = None
    target_enu_m: tuple[float, float, float] | None = None
    target_s: float = 0.0
    texts: list[str] = field(default_factory=list)


class SitlMonitor:
    """Ground station on the SITL's GCS link (``udpin`` on the port the SITL sends to)."""

    def __init__(self, gcs_port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{gcs_port}", dialect="common", source_system=255, source_component=190
        )
        if self.conn.wait_heartbeat(timeout=30) is None:
            msg = f"no SITL heartbeat on UDP {gcs_port}"
            raise TimeoutError(msg)
        self._lock = threading.Lock()
        self._view = VehicleView()
        self._acks: list[Any] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        # Faster position and setpoint echo than the "normal" stream profile (simulated rates).
        for msg_id in (mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED, mavlink2.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED):
            self.command(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 50_000)

    def _run(self) -> None:
        last_hb = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now - last_hb >= 1.0:
                self.conn.mav.heartbeat_send(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                last_hb = now
            msg = self.conn.recv_match(blocking=True, timeout=0.05)
            if msg is None or msg.get_srcSystem() != 1 or msg.get_srcComponent() != 1:
                continue
            kind = msg.get_type()
            with self._lock:
                v = self._view
                if kind == "HEARTBEAT":
                    v.custom_mode = int(msg.custom_mode)
                    v.armed = bool(msg.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
                elif kind == "LOCAL_POSITION_NED":
                    v.position_enu_m = (float(msg.y), float(msg.x), -float(msg.z))
                elif kind == "EXTENDED_SYS_STATE":
                    v.landed_state = int(msg.landed_state)
                elif kind == "POSITION_TARGET_LOCAL_NED":
                    v.target_enu_m = (float(msg.y), float(msg.x), -float(msg.z))
                    v.target_s = time.monotonic()
                elif kind == "STATUSTEXT":
                    v.texts.append(str(msg.text))
                elif kind == "COMMAND_ACK":
                    self._acks.append(msg)

    def view(self) -> VehicleView:
        with self._lock:
            v = self._view
            return VehicleView(
                v.position_enu_m, v.custom_mode, v.armed, v.landed_state, v.target_enu_m, v.target_s, list(v.texts)
            )

    def command(self, command: int, *params: float, timeout_s: float = 10.0) -> int:
        p = [*params, *([0.0] * 7)][:7]
        with self._lock:
            self._acks = []
        self.conn.mav.command_long_send(1, 1, command, 0, *p)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                for ack in self._acks:
                    if ack.command == command:
                        return int(ack.result)
            time.sleep(0.02)
        msg = f"no COMMAND_ACK for command {command}"
        raise TimeoutError(msg)

    def set_param(self, name: str, value: float) -> None:
        """PARAM_SET of a REAL32 parameter (sent three times: UDP may drop one; the value is idempotent)."""
        for _ in range(3):
            self.conn.mav.param_set_send(1, 1, name.encode(), float(value), mavlink2.MAV_PARAM_TYPE_REAL32)
            time.sleep(0.05)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.conn.close()


@dataclass(frozen=True)
class SentSetpoint:
    wall_s: float
    position_enu_m: tuple[float, float, float]


class MavRelay:
    """UDP relay SITL API link <-> controller; cuttable; records the controller's setpoints.

    ``sitl_port`` is where the SITL's API link must send (its ``--api-port``); the relay forwards to
    the controller on ``controller_port`` and sends the controller's replies to the SITL's local API
    port.
    """

    def __init__(self, controller_port: int) -> None:
        self.controller_port = controller_port
        self._sitl_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sitl_side.bind(("127.0.0.1", 0))
        self._ctrl_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._ctrl_side.bind(("127.0.0.1", 0))
        self.sitl_port = int(self._sitl_side.getsockname()[1])
        self.sitl_local_port: int | None = None
        self._parser = mavlink2.MAVLink(None)
        self._parser.robust_parsing = True
        self._lock = threading.Lock()
        self._cut = False
        self.setpoints: list[SentSetpoint] = []
        self.dropped = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def cut(self, cut: bool) -> None:
        with self._lock:
            self._cut = cut

    def setpoints_since(self, wall_s: float) -> list[SentSetpoint]:
        with self._lock:
            return [s for s in self.setpoints if s.wall_s >= wall_s]

    def _run(self) -> None:
        socks = [self._sitl_side, self._ctrl_side]
        while not self._stop.is_set():
            ready, _, _ = select.select(socks, [], [], 0.1)
            for sock in ready:
                try:
                    data, addr = sock.recvfrom(65536)
                except OSError:
                    continue
                with self._lock:
                    cut = self._cut
                if sock is self._sitl_side:
                    self.sitl_local_port = addr[1]
                    if cut:
                        self.dropped += 1
                        continue
                    self._ctrl_side.sendto(data, ("127.0.0.1", self.controller_port))
                else:
                    self._record(data)
                    if cut or self.sitl_local_port is None:
                        self.dropped += 1
                        continue
                    self._sitl_side.sendto(data, ("127.0.0.1", self.sitl_local_port))

    def _record(self, data: bytes) -> None:
        try:
            msgs = self._parser.parse_buffer(data) or []
        except mavlink2.MAVError:
            return
        now = time.monotonic()
        for m in msgs:
            if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
                with self._lock:
                    self.setpoints.append(SentSetpoint(now, (float(m.y), float(m.x), -float(m.z))))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sitl_side.close()
        self._ctrl_side.close()


class RosClient:
    """Commands to and reports from ``autonomy_e2e_ros_client.py``."""

    def __init__(self) -> None:
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self.report_port = int(self._sock.getsockname()[1])
        probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        probe.bind(("127.0.0.1", 0))
        self.listen_port = int(probe.getsockname()[1])
        probe.close()
        self._lock = threading.Lock()
        self.ready = False
        self.states: list[dict[str, Any]] = []
        self.paths: list[list[list[float]]] = []
        self._replies: dict[int, dict[str, Any]] = {}
        self._next_id = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        self._sock.settimeout(0.1)
        while not self._stop.is_set():
            try:
                data, _ = self._sock.recvfrom(1 << 20)
            except TimeoutError:
                continue
            msg = json.loads(data)
            with self._lock:
                kind = msg["type"]
                if kind == "ready":
                    self.ready = True
                elif kind == "state":
                    msg["wall_s"] = time.monotonic()
                    self.states.append(msg)
                elif kind == "path":
                    self.paths.append(msg["points"])
                elif kind == "reply":
                    self._replies[int(msg["id"])] = msg

    def _send(self, payload: dict[str, Any]) -> None:
        self._sock.sendto(json.dumps(payload).encode(), ("127.0.0.1", self.listen_port))

    def state(self) -> dict[str, Any]:
        with self._lock:
            return dict(self.states[-1]) if self.states else {}

    def events_since(self, wall_s: float) -> list[str]:
        with self._lock:
            return [s["last_event"] for s in self.states if s["wall_s"] >= wall_s]

    def n_paths(self) -> int:
        with self._lock:
            return len(self.paths)

    def last_path(self) -> list[list[float]]:
        with self._lock:
            return list(self.paths[-1]) if self.paths else []

    def set_state(
        self, state: str, points: list[tuple[float, float, float]] = (), timeout_s: float = 30.0
    ) -> dict[str, Any]:  # type: ignore[assignment]
        with self._lock:
            self._next_id += 1
            rid = self._next_id
        self._send({"cmd": "set_state", "id": rid, "state": state, "points": [list(p) for p in points]})
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                if rid in self._replies:
                    return self._replies.pop(rid)
            time.sleep(0.02)
        msg = f"no reply to set_state {state}"
        raise TimeoutError(msg)

    def goal(self, x: float, y: float) -> None:
        self._send({"cmd": "goal", "x": x, "y": y})

    def manual(self, x: float, y: float, z: float) -> None:
        self._send({"cmd": "manual", "x": x, "y": y, "z": z})

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._sock.close()


def horizontal_m(a: tuple[float, float, float] | None, b: tuple[float, float, float]) -> float:
    return math.inf if a is None else math.hypot(a[0] - b[0], a[1] - b[1])


def dist_m(a: tuple[float, float, float] | None, b: tuple[float, float, float]) -> float:
    return math.inf if a is None else math.dist(a, b)
