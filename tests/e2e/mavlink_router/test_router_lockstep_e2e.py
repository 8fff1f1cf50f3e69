"""The lockstep's MAVLink path end to end: the real ``uav-sitl --lockstep``, the real router with ``Lockstep = true``.

* Deterministic lockstep: a Python step master on the simulation link grants numbered steps (SIM_STEP
  ``param2``); a controller-like pymavlink client says HELLO through the router (``LockstepClient``), and in
  every step reads its link up to the router's STEP marker, streams position setpoints, switches to OFFBOARD,
  arms, and ends the step with its own marker, over a lossy link (loss, delay, jitter, reordering). The same 35
  simulated seconds flown twice, the second time beside a CPU hog on each core, must give the client the same
  messages at every step, the same final ground truth, and the router the same loss and delay counters.
* Plain lockstep (no lockstep client): a 300 ms link delay is 300 ms of simulated time, i.e. three 0.1 s steps
  each way, whether the steps are granted slowly or as fast as the machine can.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from e2e.sitl.harness import Sitl, run_sitl
from helpers.procs import Proc, free_port, free_udp_port, wait_for_port
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink2

from uav_common.shell.mavlink_lockstep import LockstepClient

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

M = mavlink2
SIM_STEP = 31010
STEP_S = 0.1
PHYSICS_PER_STEP = 25  # 4 ms physics steps
OFFBOARD = 6 << 16
#: What makes the SITL a function of its inputs only: no wall-clock floors, a fixed SYSTEM_TIME epoch.
DETERMINISTIC_SITL = [
    "--lockstep",
    "--set", "time.datalink_wall_floor_s=0",
    "--set", "time.stream_wall_floor_s=0",
    "--set", "time.unix_epoch_s=0",
]  # fmt: skip


class StepMaster:
    """The lockstep master on the simulation link (what the sim bridge does), numbering its grants."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", dialect="common", source_system=1, source_component=200
        )
        self.conn.mav.heartbeat_send(M.MAV_TYPE_GENERIC, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        self.granted = 0
        self.odometry: Any = None
        self.texts: list[str] = []

    def send(self, number: int) -> Any:
        """SIM_STEP numbered ``number``; the SITL's COMMAND_ACK (the state's ODOMETRY is kept)."""
        self.conn.mav.command_long_send(1, 1, SIM_STEP, 0, PHYSICS_PER_STEP, number, 0, 0, 0, 0, 0)
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(blocking=True, timeout=0.5)
            if msg is None:
                continue
            if msg.get_type() == "ODOMETRY":
                self.odometry = msg
            if msg.get_type() == "STATUSTEXT":
                self.texts.append(msg.text)
            if msg.get_type() == "COMMAND_ACK" and msg.command == SIM_STEP:
                return msg
        pytest.fail(f"no SIM_STEP ACK for step {number} within 30 s")

    def grant(self) -> int:
        ack = self.send(self.granted + 1)
        assert ack.result == M.MAV_RESULT_ACCEPTED, f"grant {self.granted + 1} refused"
        self.granted += 1
        return self.granted

    def close(self) -> None:
        self.conn.close()


def router_conf(sitl_tcp: int, controller: int, log_dir: Path, controller_keys: str) -> str:
    return (
        f"[General]\nLockstep = true\nLog = {log_dir}\nLogTelemetry = false\nStatsInterval = 1\n"
        f"[TcpEndpoint sitl]\nAddress = 127.0.0.1\nPort = {sitl_tcp}\nRetryTimeout = 1\nLockstep = autopilot\n"
        f"[UdpEndpoint controller]\nMode = Normal\nAddress = 127.0.0.1\nPort = {controller}\n{controller_keys}"
    )


@dataclass
class Rig:
    sitl: Sitl
    router: Proc
    controller_port: int
    stats_file: Path


@contextmanager
def rig(tmp_path: Path, name: str, controller_keys: str) -> Iterator[Rig]:
    """The SITL (lockstep, deterministic settings) and the router in lockstep, the controller endpoint as given."""
    run_dir = tmp_path / name
    run_dir.mkdir()
    with run_sitl(f"{name}_sitl", run_dir, extra=DETERMINISTIC_SITL) as sitl:
        controller = free_udp_port()
        conf = run_dir / "router.conf"
        conf.write_text(router_conf(sitl.ports.tcp, controller, run_dir / "router", controller_keys))
        (run_dir / "conf.d").mkdir()
        tcp = free_port()
        router = Proc(
            f"{name}_router", ["uav-mavlink-router", "-c", str(conf), "-d", str(run_dir / "conf.d"), "-t", str(tcp)]
        )
        try:
            wait_for_port(tcp, timeout_s=20.0, proc=router)
            yield Rig(sitl, router, controller, run_dir / "router" / "router-stats.json")
        finally:
            router.stop()


@contextmanager
def cpu_hogs(n: int) -> Iterator[list[subprocess.Popen[bytes]]]:
    """``n`` busy loops (one per core), stopped by their own pids."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield hogs
    finally:
        for hog in hogs:
            hog.kill()
        for hog in hogs:
            hog.wait(timeout=10)


@dataclass
class Flight:
    steps: list[list[tuple[str, bytes]]]  # per step: (type, payload) of every message the client received
    odometry: tuple[float, ...]
    links: dict[str, dict[str, int]]
    armed_at: int | None
    offboard_at: int | None


LOSSY = "LossPercent = 10\nDelayMs = 120\nJitterMs = 60\nReorderPercent = 5\nReorderDelayMs = 100\nLinkSeed = 7\n"
FLIGHT_STEPS = 350  # 35 simulated seconds
QUIET_STEPS = 6  # at the end: the client sends nothing, so everything it sent has reached the SITL


def fly(tmp_path: Path, name: str) -> Flight:
    """A controller's 35 s over the lossy link: setpoints 10 m up at every step, OFFBOARD, arm (both retried
    every second until the heartbeat shows them), a heartbeat every second."""
    with rig(tmp_path, name, "Lockstep = client\n" + LOSSY) as r:
        conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{r.controller_port}", dialect="common", source_system=1, source_component=191
        )
        client = LockstepClient(conn, name="controller")
        master = StepMaster(r.sitl.ports.sim)
        try:
            assert client.hello(2, watchdog_s=30.0) == 0, "registered before the first grant"
            steps: list[list[tuple[str, bytes]]] = []
            armed_at = offboard_at = None
            base_mode = custom_mode = 0
            for _ in range(FLIGHT_STEPS + QUIET_STEPS):
                k = master.grant()
                msgs = client.read_step(k, watchdog_s=30.0)
                steps.append([(m.get_type(), bytes(m.get_payload())) for m in msgs])
                for m in msgs:
                    if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1:
                        base_mode, custom_mode = m.base_mode, m.custom_mode
                if custom_mode == OFFBOARD and offboard_at is None:
                    offboard_at = k
                if base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and armed_at is None:
                    armed_at = k
                if k <= FLIGHT_STEPS:
                    if k % 10 == 0:
                        conn.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                    conn.mav.set_position_target_local_ned_send(
                        k * 100, 1, 1, M.MAV_FRAME_LOCAL_NED, 2552, 0.0, 0.0, -10.0, 0, 0, 0, 0, 0, 0, 0.0, 0
                    )
                    if k >= 20 and k % 10 == 0 and custom_mode != OFFBOARD:
                        conn.mav.command_long_send(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0)
                    elif k >= 20 and k % 10 == 5 and not base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED:
                        conn.mav.command_long_send(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
                client.end_step(k, k * STEP_S)
            odo = master.odometry
            odometry = (odo.time_usec, odo.x, odo.y, odo.z, *odo.q, odo.vx, odo.vy, odo.vz)
        finally:
            master.close()
            conn.close()
        time.sleep(1.0)  # the router takes the client's last marker
        r.router.stop()
        assert r.router.popen.returncode == 0, r.router.tail()
        stats = json.loads(r.stats_file.read_text())
        (controller,) = [e for e in stats["endpoints"] if e["name"] == "controller"]
        assert stats["lockstep"]["steps_seen"] >= FLIGHT_STEPS
        assert controller["lockstep"]["markers_in"] == FLIGHT_STEPS + QUIET_STEPS
        return Flight(steps, odometry, controller["link"], armed_at, offboard_at)


def test_a_lockstep_run_over_a_lossy_link_is_the_same_beside_a_cpu_hog(tmp_path: Path) -> None:
    t0 = time.monotonic()
    first = fly(tmp_path, "lockstep_quiet")
    quiet_s = time.monotonic() - t0
    with cpu_hogs(os.cpu_count() or 2):
        t0 = time.monotonic()
        second = fly(tmp_path, "lockstep_loaded")
        loaded_s = time.monotonic() - t0
    print(f"quiet {quiet_s:.1f} s wall, beside CPU hogs {loaded_s:.1f} s wall")
    # it flew: OFFBOARD and armed through the lossy link, 10 m up
    assert first.offboard_at is not None
    assert first.armed_at is not None
    assert first.odometry[3] == pytest.approx(-10.0, abs=1.0), first.odometry
    # and the link was lossy both ways
    for direction in ("in", "out"):
        counters = first.links[direction]
        assert counters["dropped"] > 0, first.links
        assert counters["delayed"] == counters["offered"] - counters["dropped"], first.links
    assert first.links["out"]["reordered"] > 0, first.links
    # the same run, message for message and step for step
    assert len(first.steps) == len(second.steps)
    for k, (a, b) in enumerate(zip(first.steps, second.steps, strict=True), start=1):
        assert a == b, f"step {k}: {[t for t, _ in a]} != {[t for t, _ in b]}"
    assert (first.offboard_at, first.armed_at) == (second.offboard_at, second.armed_at)
    assert first.odometry == second.odometry
    assert first.links == second.links


# ---------------------------------------------------------------------------------------------- plain lockstep


def command_round_trip(tmp_path: Path, name: str, wall_per_step_s: float) -> tuple[int, int, int]:
    """A plain client sends a command after step g0; returns (g0, the step of the telemetry the ACK came with,
    the grants executed when the ACK arrived)."""
    with rig(tmp_path, name, "DelayMs = 300\n") as r:
        conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{r.controller_port}", dialect="common", source_system=255, source_component=190
        )
        master = StepMaster(r.sitl.ports.sim)
        try:
            # a grant numbered out of turn is refused, and says why
            ack = master.send(5)
            assert ack.result == M.MAV_RESULT_DENIED
            assert "".join(master.texts) == "SIM_STEP numbered 5 refused: the next grant is step 1"
            for _ in range(10):  # telemetry reaches the client (300 ms later): now it can answer
                master.grant()
            time.sleep(0.3)
            while conn.recv_match(blocking=False) is not None:
                pass
            g0 = master.granted
            conn.mav.command_long_send(
                1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0
            )
            last_attitude_ms = 0
            for _ in range(30):
                master.grant()
                time.sleep(wall_per_step_s)
                deadline = time.monotonic() + 0.05
                while time.monotonic() < deadline:
                    msg = conn.recv_match(blocking=True, timeout=0.01)
                    if msg is None:
                        continue
                    if msg.get_type() == "ATTITUDE":
                        last_attitude_ms = msg.time_boot_ms
                    if msg.get_type() == "COMMAND_ACK" and msg.command == M.MAV_CMD_REQUEST_MESSAGE:
                        # the telemetry right after it is of the step the SITL handled the command in
                        nxt = conn.recv_match(type="ATTITUDE", blocking=True, timeout=5)
                        assert nxt is not None
                        handled_step = math.ceil(nxt.time_boot_ms / 100)
                        # ... and the telemetry right before it is of the step before
                        assert (handled_step - 2) * 100 < last_attitude_ms <= (handled_step - 1) * 100
                        return g0, handled_step, master.granted
            pytest.fail("no COMMAND_ACK within 30 steps")
        finally:
            master.close()
            conn.close()


@pytest.mark.parametrize("wall_per_step_s", [0.0, 0.25])
def test_plain_lockstep_delays_count_in_simulated_time(tmp_path: Path, wall_per_step_s: float) -> None:
    """300 ms each way at 0.1 s steps: the command (stamped with the router's time t_g0) is taken before grant
    g0 + 4 (0.3 s later, then the next grant), and its ACK reaches the client with that step's telemetry 0.3 s
    of simulated time later, at the router's marker g0 + 7, whether steps take 0.25 wall seconds or almost none."""
    g0, handled, granted = command_round_trip(tmp_path, f"plain_lockstep_{wall_per_step_s:g}", wall_per_step_s)
    assert handled == g0 + 4
    assert granted in (g0 + 7, g0 + 8)  # released at marker g0 + 7; seen after that grant (or the next)


def test_a_lockstep_client_straight_on_the_sitl(tmp_path: Path) -> None:
    """Without the router: a client on the SITL's API link (UDP) says HELLO to the SITL itself. Every step's
    count balances, its commands are taken before the next grant, and while time is paused (1.5 s of wall time
    between two grants) no wall-clock heartbeat reaches it."""
    with run_sitl("lockstep_direct_sitl", tmp_path, extra=DETERMINISTIC_SITL) as sitl:
        conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{sitl.ports.api}", dialect="common", source_system=1, source_component=191
        )
        client = LockstepClient(conn, name="api link")
        master = StepMaster(sitl.ports.sim)
        try:
            assert client.hello(1, watchdog_s=30.0) == 0  # the paused heartbeats told it where the SITL is
            acked_at = None
            for k in range(1, 31):
                if k == 5:
                    time.sleep(1.5)  # paused: no heartbeat on wall time for a lockstep peer
                master.grant()
                msgs = client.read_step(k, watchdog_s=30.0)
                kinds = [m.get_type() for m in msgs]
                if k == 5:
                    assert "HEARTBEAT" not in kinds, kinds  # t 0.4-0.5 s: no heartbeat due in simulated time
                if k == 10:
                    assert kinds.count("HEARTBEAT") == 1, kinds  # the 1 Hz one at t = 1 s
                    conn.mav.command_long_send(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, 148, 0, 0, 0, 0, 0, 0)
                if any(m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_REQUEST_MESSAGE for m in msgs):
                    acked_at = k
                client.end_step(k, k * STEP_S)
            assert acked_at == 11  # sent in step 10, handled before grant 11, answered in step 11
        finally:
            master.close()
            conn.close()
        log = sitl.proc.tail(200)
        assert "lockstep peer api link UDP peer 127.0.0.1" in log, log
