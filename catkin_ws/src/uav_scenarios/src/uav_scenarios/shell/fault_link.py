"""The test rig's MAVLink link to the autopilot: scripted faults as ``MAV_CMD_INJECT_FAILURE``.

What a field test rig (QGroundControl, a MAVSDK script with the ``failure`` plugin) does, over the run's router
(its TCP server: every message gets there, whatever the scenario's lossy links do): set ``SYS_FAILURE_EN`` to 1
(confirmed by the PARAM_VALUE echo), then at each fault's time send ``MAV_CMD_INJECT_FAILURE`` (COMMAND_LONG 420:
param1 FAILURE_UNIT, param2 FAILURE_TYPE, param3 instance) and wait for its COMMAND_ACK, re-sending up to
:data:`SEND_ATTEMPTS` times (incrementing ``confirmation``), as MAVSDK does.

One thread owns the connection. Between commands it drops what the router sends it unparsed (the whole
telemetry stream, thousands of messages a wall second in a fast lockstep run: parsing it in Python would take
CPU from the run's nodes) and resets the parser before it listens for an answer.

Time: the schedule is on the caller's clock (ROS time: simulated seconds), so in lockstep a fault is sent during
the step in which it falls due (within one lockstep step, ``time.step_s``); the SITL applies it before the next
grant it executes if the command got there first (it reads every pending message before a grant). The
COMMAND_ACK's arrival is stamped on that clock too. Only the answer timeouts are wall-clock seconds.

In the causal lockstep (docs/lockstep.md) :class:`StepFaultLink` does the same from the caller's steps, on
simulated time only, over a lockstep MAVLink client: the same faults are answered at the same step of every run.
"""

from __future__ import annotations

import logging
import math
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink import mavutil

from uav_common.mavlink_parser import reset_parser
from uav_common.shell.mavlink_lockstep import LockstepClient
from uav_common.shell.sockets import connected_to_itself
from uav_scenarios.core.faults import FaultAction, FaultSchedule

__all__ = ["FaultLink", "FaultResult", "StepFaultLink"]

log = logging.getLogger(__name__)

MAV_CMD_INJECT_FAILURE = 420
MAV_PARAM_TYPE_INT32 = 6
#: COMMAND_LONG re-sends without an answer (MAVSDK's default: 3), each after :data:`ANSWER_TIMEOUT_S` wall s.
SEND_ATTEMPTS = 3
ANSWER_TIMEOUT_S = 1.5
_RESULTS = {0: "ACCEPTED", 1: "TEMPORARILY_REJECTED", 2: "DENIED", 3: "UNSUPPORTED", 4: "FAILED", 5: "IN_PROGRESS"}


@dataclass(frozen=True)
class FaultResult:
    """What became of one action: sent at ``sent_s`` (caller's clock), answered ``result`` at ``answered_s``."""

    action: FaultAction
    sent_s: float
    result: str
    detail: str = ""
    answered_s: float = math.nan


class FaultLink:
    """Sends a fault schedule to the autopilot from a thread of its own.

    Args:
        url: pymavlink connection string, e.g. ``tcp:127.0.0.1:5790`` (the router's TCP server).
        schedule: the actions to send.
        elapsed_s: the run's elapsed time on the caller's clock, ``None`` before the mission started.
        now_s: the caller's clock (stamps of the results).
        on_result: called (from the link's thread) with each action's result.
        target_system: the autopilot's system id.
    """

    def __init__(
        self,
        url: str,
        schedule: FaultSchedule,
        *,
        elapsed_s: Callable[[], float | None],
        now_s: Callable[[], float],
        on_result: Callable[[FaultResult], None],
        target_system: int = 1,
        target_component: int = 1,
    ) -> None:
        self.url = url
        self.schedule = schedule
        self.elapsed_s = elapsed_s
        self.now_s = now_s
        self.on_result = on_result
        self.target = (target_system, target_component)
        self.enabled = False
        self.problem = ""
        self._stop = threading.Event()
        self._conn: mavutil.mavfile | None = None
        self._parser_dirty = False
        self._thread = threading.Thread(target=self._run, name="fault-link", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        if self._conn is not None:
            self._conn.close()

    # ---------------------------------------------------------------------------------- the thread
    def _run(self) -> None:
        try:
            self._connect()
            self._enable()
            while not self._stop.is_set() and self.schedule.next_at_s is not None:
                elapsed = self.elapsed_s()
                if elapsed is None:
                    self._drain(0.01)
                    continue
                for action in self.schedule.due(elapsed):
                    self._send(action)
                self._drain(0.005)
        except Exception as err:
            self.problem = f"fault link failed: {err}"
            log.exception("fault link failed")
        for action in self.schedule.due(math.inf):
            self.on_result(FaultResult(action, self.now_s(), "NOT_SENT", self.problem or "the run ended first"))

    def _connect(self) -> None:
        while not self._stop.is_set():
            try:
                conn = mavutil.mavlink_connection(
                    self.url, source_system=255, source_component=190, autoreconnect=True, retries=1
                )
            except (OSError, mavutil.mavlink.MAVError) as err:
                self.problem = f"cannot connect to the autopilot at {self.url}: {err}"
                self._stop.wait(0.5)
                continue
            if isinstance(getattr(conn, "port", None), socket.socket) and connected_to_itself(conn.port):
                conn.close()  # the router's TCP server is not up yet (see connected_to_itself)
                self.problem = f"the autopilot's router at {self.url} is not listening yet"
                self._stop.wait(0.5)
                continue
            self._conn = conn
            deadline = time.monotonic() + 30.0
            while not self._stop.is_set() and time.monotonic() < deadline:
                msg = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
                if (
                    msg is not None
                    and msg.get_srcSystem() == self.target[0]
                    and msg.get_srcComponent() == self.target[1]
                ):
                    self.problem = ""
                    return
            self.problem = f"no heartbeat from the autopilot at {self.url} in 30 s"
            return

    def _enable(self) -> None:
        """PARAM_SET SYS_FAILURE_EN = 1 (INT32, bytewise as PX4 wants), until the PARAM_VALUE echo says 1."""
        conn = self._conn
        if conn is None or self.problem:
            return
        value = struct.unpack("<f", struct.pack("<i", 1))[0]
        for _ in range(5):
            if self._stop.is_set():
                return
            conn.mav.param_set_send(*self.target, b"SYS_FAILURE_EN", value, MAV_PARAM_TYPE_INT32)
            deadline = time.monotonic() + ANSWER_TIMEOUT_S
            while time.monotonic() < deadline:
                msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
                if msg is None or msg.param_id != "SYS_FAILURE_EN":
                    continue
                got = struct.unpack("<i", struct.pack("<f", msg.param_value))[0]
                if got == 1 or msg.param_value == 1.0:
                    self.enabled = True
                    return
        self.problem = "the autopilot did not confirm SYS_FAILURE_EN = 1"

    def _drain(self, wait_s: float) -> None:
        """Drop what arrives unparsed, so the socket never backs up; wait up to ``wait_s`` for it."""
        conn = self._conn
        if conn is None or self.problem:
            self._stop.wait(wait_s)
            return
        sock = conn.port
        if not select.select([sock], [], [], wait_s)[0]:
            return
        self._parser_dirty = True
        while True:
            try:
                data = sock.recv(65536)
            except BlockingIOError:
                return
            except OSError as err:
                data = b""
                log.warning("fault link: %s", err)
            if not data:  # the router closed the connection: dial again
                conn.close()
                self._conn = None
                self._connect()
                return
            if len(data) < 65536:
                return

    def _send(self, action: FaultAction) -> None:
        conn = self._conn
        sent_s = self.now_s()
        if conn is None or self.problem:
            self.on_result(FaultResult(action, sent_s, "NOT_SENT", self.problem or "no link to the autopilot"))
            return
        if self._parser_dirty:  # the dropped bytes may have ended in the middle of a frame
            reset_parser(conn.mav)
            self._parser_dirty = False
        for attempt in range(SEND_ATTEMPTS):
            conn.mav.command_long_send(
                *self.target, MAV_CMD_INJECT_FAILURE, attempt,
                float(action.unit_code), float(action.type_code), float(action.instance), 0, 0, 0, 0,
            )  # fmt: skip
            deadline = time.monotonic() + ANSWER_TIMEOUT_S
            detail = ""
            while time.monotonic() < deadline and not self._stop.is_set():
                msg = conn.recv_match(type=["COMMAND_ACK", "STATUSTEXT"], blocking=True, timeout=0.1)
                if msg is None:
                    continue
                if msg.get_type() == "STATUSTEXT":
                    if "ailure" in msg.text:  # "Failure injected: ...", "Failure injection: ... not simulated"
                        detail = str(msg.text)
                    continue
                if msg.command != MAV_CMD_INJECT_FAILURE or msg.result == 5:
                    continue
                result = _RESULTS.get(msg.result, f"RESULT_{msg.result}")
                self.on_result(FaultResult(action, sent_s, result, detail, self.now_s()))
                return
        self.on_result(FaultResult(action, sent_s, "NO_ANSWER", f"no COMMAND_ACK after {SEND_ATTEMPTS} sends"))


class StepFaultLink:
    """The same test rig in the causal lockstep (docs/lockstep.md): no thread, driven by the caller's steps.

    Its link to the router's TCP server is a lockstep MAVLink client: each step it reads the autopilot's
    messages up to the router's step marker (:meth:`before_step`), then acts and ends its own step
    (:meth:`after_step`). Every decision is on simulated time, so the same faults reach the autopilot in the
    same step and are answered in the same step of every run: enable ``SYS_FAILURE_EN`` once the autopilot's
    heartbeat is seen (re-sent every :data:`ANSWER_TIMEOUT_S` simulated seconds, at most five times), then each
    action in turn when it falls due, re-sent up to :data:`SEND_ATTEMPTS` times without an answer.

    Args:
        url: pymavlink connection string of the router's TCP server.
        schedule, elapsed_s, now_s, on_result, target_system, target_component: as :class:`FaultLink`.
        lookahead_steps: the caller's lookahead (its messages of step k reach the autopilot at grant k + L).
        watchdog_s: wall seconds a read may wait for the router's marker before it is an error.
        should_stop: asked while waiting for the router: True ends the wait (``StopRequestedError``).
    """

    def __init__(
        self,
        url: str,
        schedule: FaultSchedule,
        *,
        elapsed_s: Callable[[], float | None],
        now_s: Callable[[], float],
        on_result: Callable[[FaultResult], None],
        lookahead_steps: int,
        watchdog_s: float,
        target_system: int = 1,
        target_component: int = 1,
        should_stop: Callable[[], bool] | None = None,
    ) -> None:
        self.url = url
        self.schedule = schedule
        self.elapsed_s = elapsed_s
        self.now_s = now_s
        self.on_result = on_result
        self.should_stop = should_stop
        self.lookahead_steps = lookahead_steps
        self.watchdog_s = watchdog_s
        self.target = (target_system, target_component)
        self.enabled = False
        self.problem = ""
        self._conn: mavutil.mavfile | None = None
        self._client: LockstepClient | None = None
        self._heard = False
        self._enable_sent: list[float] = []
        self._queue: list[FaultAction] = []
        #: The action in flight: (action, first sent at, attempts, last sent at, STATUSTEXT detail).
        self._flight: tuple[FaultAction, float, int, float, str] | None = None

    def start(self) -> None:
        """Connect and say HELLO (before the first step: the caller joins the lockstep after this).

        Raises:
            MarkerError, WaitTimeoutError: the router did not register the link.
        """
        deadline = time.monotonic() + 30.0
        while True:
            try:
                conn = mavutil.mavlink_connection(
                    self.url, source_system=255, source_component=190, autoreconnect=True, retries=1
                )
            except (OSError, mavutil.mavlink.MAVError) as err:
                conn, self.problem = None, f"cannot connect to the autopilot at {self.url}: {err}"
            if conn is not None:
                port = getattr(conn, "port", None)
                if not (isinstance(port, socket.socket) and connected_to_itself(port)):
                    break
                conn.close()  # the router's TCP server is not up yet (see connected_to_itself)
                self.problem = f"the autopilot's router at {self.url} is not listening yet"
            if time.monotonic() > deadline:
                log.error("fault link: %s", self.problem)
                return
            time.sleep(0.5)
        self.problem = ""
        self._conn = conn
        self._client = LockstepClient(
            conn, name=f"fault link {self.url}", target_system=self.target[0], should_stop=self.should_stop
        )
        self._client.hello(self.lookahead_steps, watchdog_s=self.watchdog_s)

    def before_step(self, step: int, t_s: float) -> None:
        """The autopilot's messages of this step (up to the router's marker)."""
        if self._client is None:
            return
        for msg in self._client.read_step(step, watchdog_s=self.watchdog_s):
            self._handle(msg, t_s)

    def after_step(self, step: int, t_s: float) -> None:
        """Send what is due at this step, then end it."""
        if self._client is None:
            return
        self._act(t_s)
        self._client.end_step(step, t_s)

    def stop(self) -> None:
        for action in [*self._queue, *self.schedule.due(math.inf)]:
            self.on_result(FaultResult(action, self.now_s(), "NOT_SENT", self.problem or "the run ended first"))
        self._queue = []
        if self._conn is not None:
            self._conn.close()

    # ---------------------------------------------------------------------------------- per step
    def _handle(self, msg: Any, t_s: float) -> None:
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.target:
            return
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self._heard = True
        elif kind == "PARAM_VALUE" and msg.param_id == "SYS_FAILURE_EN" and not self.enabled:
            got = struct.unpack("<i", struct.pack("<f", msg.param_value))[0]
            if got == 1 or msg.param_value == 1.0:
                self.enabled = True
        elif kind == "STATUSTEXT" and self._flight is not None and "ailure" in msg.text:
            action, sent_s, attempts, last_s, _ = self._flight
            self._flight = (action, sent_s, attempts, last_s, str(msg.text))
        elif kind == "COMMAND_ACK" and self._flight is not None:
            if msg.command != MAV_CMD_INJECT_FAILURE or msg.result == 5:  # IN_PROGRESS: the answer comes later
                return
            action, sent_s, _, _, detail = self._flight
            self._flight = None
            result = _RESULTS.get(msg.result, f"RESULT_{msg.result}")
            self.on_result(FaultResult(action, sent_s, result, detail, t_s))

    def _act(self, t_s: float) -> None:
        conn = self._conn
        if conn is None or self.problem:
            return
        if not self.enabled:
            if self._heard and (not self._enable_sent or t_s - self._enable_sent[-1] >= ANSWER_TIMEOUT_S):
                if len(self._enable_sent) >= 5:
                    self.problem = "the autopilot did not confirm SYS_FAILURE_EN = 1"
                    return
                value = struct.unpack("<f", struct.pack("<i", 1))[0]
                conn.mav.param_set_send(*self.target, b"SYS_FAILURE_EN", value, MAV_PARAM_TYPE_INT32)
                self._enable_sent.append(t_s)
            return
        elapsed = self.elapsed_s()
        if elapsed is not None:
            self._queue.extend(self.schedule.due(elapsed))
        if self._flight is not None:
            action, sent_s, attempts, last_s, detail = self._flight
            if t_s - last_s < ANSWER_TIMEOUT_S:
                return
            if attempts >= SEND_ATTEMPTS:
                self._flight = None
                self.on_result(FaultResult(action, sent_s, "NO_ANSWER", f"no COMMAND_ACK after {SEND_ATTEMPTS} sends"))
            else:
                self._send(action, attempts)
                self._flight = (action, sent_s, attempts + 1, t_s, detail)
                return
        if self._flight is None and self._queue:
            action = self._queue.pop(0)
            self._send(action, 0)
            self._flight = (action, t_s, 1, t_s, "")

    def _send(self, action: FaultAction, confirmation: int) -> None:
        assert self._conn is not None
        self._conn.mav.command_long_send(
            *self.target, MAV_CMD_INJECT_FAILURE, confirmation,
            float(action.unit_code), float(action.type_code), float(action.instance), 0, 0, 0, 0,
        )  # fmt: skip
