"""A PX4-like MAVLink peer for controller tests: real pymavlink over UDP on a free port.

It behaves like PX4 SITL instance 0 toward an offboard client: HEARTBEAT with PX4
custom modes (sysid 1, compid 1), LOCAL_POSITION_NED, ATTITUDE, EXTENDED_SYS_STATE,
BATTERY_STATUS; MAV_CMD_DO_SET_MODE and ARM with COMMAND_ACKs; OFFBOARD is refused
unless setpoints arrived at > 2 Hz over the last 0.5 s; offboard loss after 0.5 s
without setpoints falls back to AUTO.LOITER; AUTO.RTL flies home and lands, AUTO.LAND
lands, and it disarms on the ground. Kinematics: straight-line at ``speed_mps``.

With ``estimate_port`` it also serves a second client (the autopilot odometry node) as PX4's onboard
link does: ODOMETRY (with a covariance), LOCAL_POSITION_NED, ATTITUDE_QUATERNION and HEARTBEAT at
50 Hz, TIMESYNC answers and MAV_CMD_SET_MESSAGE_INTERVAL acknowledgements, all stamped on its own
clock (``boot_offset_s`` seconds behind the test's). ``estimate_mode`` makes that estimate ``nan``,
``paused`` (nothing sent) or ``no_odometry`` (only the LOCAL_POSITION_NED + ATTITUDE_QUATERNION fallback).
"""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import dataclass

os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil

mavutil.set_dialect("common")
MAV = mavutil.mavlink

PX4_MODES = {
    "MANUAL": (1, 0), "POSCTL": (3, 0), "AUTO.LOITER": (4, 3), "AUTO.RTL": (4, 5), "AUTO.LAND": (4, 6),
    "OFFBOARD": (6, 0),
}  # fmt: skip


def custom_mode(name: str) -> int:
    main, sub = PX4_MODES[name]
    return (main << 16) | (sub << 24)


@dataclass
class Setpoint:
    t: float
    ned: tuple[float, float, float]
    yaw: float
    type_mask: int
    frame: int
    target: tuple[int, int]


class FakePx4:
    def __init__(
        self, port: int, *, speed_mps: float = 10.0, estimate_port: int = 0, boot_offset_s: float = 0.0
    ) -> None:
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
        self.est_conn = (
            mavutil.mavlink_connection(f"udpout:127.0.0.1:{estimate_port}", source_system=1, source_component=1)
            if estimate_port
            else None
        )
        self.boot_offset_s = boot_offset_s
        self.estimate_mode = "ok"
        self.timesync_answers = 0
        self.interval_requests: list[tuple[float, float]] = []
        self.speed_mps = speed_mps
        self.mode = "AUTO.LOITER"
        self.armed = False
        self.pos = [0.0, 0.0, 0.0]  # NED
        self.setpoints: list[Setpoint] = []
        self.mode_requests: list[tuple[float, str, bool]] = []
        self.arm_requests: list[float] = []
        self.controller_heartbeats = 0
        self.reject_offboard = 0
        self.paused = False
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    # ------------------------------------------------------------ control
    def start(self) -> FakePx4:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.conn.close()
        if self.est_conn is not None:
            self.est_conn.close()

    def force_mode(self, name: str) -> None:
        with self.lock:
            self.mode = name

    def pos_enu(self) -> tuple[float, float, float]:
        with self.lock:
            n, e, d = self.pos
        return (e, n, -d)

    def setpoints_between(self, t0: float, t1: float) -> list[Setpoint]:
        with self.lock:
            return [s for s in self.setpoints if t0 <= s.t <= t1]

    # --------------------------------------------------------------- loop
    def _run(self) -> None:
        last_hb = last_slow = 0.0
        last = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            dt, last = now - last, now
            if not self.paused:
                self._receive(now)
            else:
                while self.conn.recv_match(blocking=False) is not None:
                    pass  # the link is down: drop what arrives (counting nothing)
            with self.lock:
                self._physics(now, dt)
            if self.est_conn is not None:
                self._serve_estimate(now)
            if not self.paused:
                if now - last_hb >= 0.5:
                    last_hb = now
                    self._heartbeat()
                self._fast_telemetry(now)
                if now - last_slow >= 0.5:
                    last_slow = now
                    self._slow_telemetry()
            time.sleep(0.02)

    def _receive(self, now: float) -> None:
        while (msg := self.conn.recv_match(blocking=False)) is not None:
            mtype = msg.get_type()
            if mtype == "HEARTBEAT" and msg.get_srcComponent() == 191:
                self.controller_heartbeats += 1
            elif mtype == "SET_POSITION_TARGET_LOCAL_NED":
                with self.lock:
                    self.setpoints.append(
                        Setpoint(now, (msg.x, msg.y, msg.z), msg.yaw, msg.type_mask, msg.coordinate_frame,
                                 (msg.target_system, msg.target_component))
                    )  # fmt: skip
            elif mtype == "COMMAND_LONG":
                self._command(now, msg)

    def _command(self, now: float, msg: object) -> None:
        result = MAV.MAV_RESULT_ACCEPTED
        with self.lock:
            if msg.command == MAV.MAV_CMD_DO_SET_MODE:
                wanted = next((k for k, v in PX4_MODES.items() if v == (int(msg.param2), int(msg.param3))), None)
                recent = [s for s in self.setpoints if now - s.t <= 0.5]
                ok = wanted is not None
                if wanted == "OFFBOARD" and (len(recent) < 2 or self.reject_offboard > 0):
                    self.reject_offboard -= 1
                    ok = False
                self.mode_requests.append((now, str(wanted), ok))
                if ok:
                    self.mode = wanted
                else:
                    result = MAV.MAV_RESULT_TEMPORARILY_REJECTED
            elif msg.command == MAV.MAV_CMD_COMPONENT_ARM_DISARM:
                self.arm_requests.append(now)
                self.armed = msg.param1 > 0.5
            else:
                result = MAV.MAV_RESULT_UNSUPPORTED
        self.conn.mav.command_ack_send(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def _physics(self, now: float, dt: float) -> None:
        target = None
        if self.mode == "OFFBOARD":
            fresh = self.setpoints and now - self.setpoints[-1].t <= 0.5
            if not fresh:
                self.mode = "AUTO.LOITER"  # offboard loss failsafe
            elif self.armed:
                target = list(self.setpoints[-1].ned)
        elif self.mode == "AUTO.RTL" and self.armed:
            target = [0.0, 0.0, self.pos[2]] if math.hypot(self.pos[0], self.pos[1]) > 0.5 else [0.0, 0.0, 0.0]
        elif self.mode == "AUTO.LAND" and self.armed:
            target = [self.pos[0], self.pos[1], 0.0]
        if target is not None:
            delta = [t - p for t, p in zip(target, self.pos, strict=True)]
            dist = math.sqrt(sum(d * d for d in delta))
            step = self.speed_mps * dt
            self.pos = target if dist <= step else [p + d / dist * step for p, d in zip(self.pos, delta, strict=True)]
        if self.armed and self.pos[2] > -0.05 and self.mode in ("AUTO.RTL", "AUTO.LAND"):
            self.armed = False

    def _heartbeat(self) -> None:
        base = MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        self.conn.mav.heartbeat_send(MAV.MAV_TYPE_QUADROTOR, MAV.MAV_AUTOPILOT_PX4, base, custom_mode(self.mode),
                                     MAV.MAV_STATE_ACTIVE)  # fmt: skip

    def _fast_telemetry(self, now: float) -> None:
        ms = int(now * 1000) & 0xFFFFFFFF
        with self.lock:
            n, e, d = self.pos
        self.conn.mav.local_position_ned_send(ms, n, e, d, 0.0, 0.0, 0.0)
        self.conn.mav.attitude_send(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    def _slow_telemetry(self) -> None:
        landed = MAV.MAV_LANDED_STATE_IN_AIR if self.pos[2] < -0.5 else MAV.MAV_LANDED_STATE_ON_GROUND
        self.conn.mav.extended_sys_state_send(MAV.MAV_VTOL_STATE_UNDEFINED, landed)
        cells = [4000, 4000, 4000, 4000] + [0xFFFF] * 6
        self.conn.mav.battery_status_send(0, 0, 0, 2500, cells, 1200, 350, -1, 87)

    # ------------------------------------------------------------ the onboard estimate link
    def _serve_estimate(self, now: float) -> None:
        conn = self.est_conn
        assert conn is not None
        boot_s = now - self.boot_offset_s  # the autopilot's clock: time since its boot
        while (msg := conn.recv_match(blocking=False)) is not None:
            mtype = msg.get_type()
            if mtype == "TIMESYNC" and msg.tc1 == 0:
                self.timesync_answers += 1
                conn.mav.timesync_send(int(boot_s * 1e9), msg.ts1)
            elif mtype == "COMMAND_LONG" and msg.command == MAV.MAV_CMD_SET_MESSAGE_INTERVAL:
                self.interval_requests.append((msg.param1, msg.param2))
                conn.mav.command_ack_send(msg.command, MAV.MAV_RESULT_ACCEPTED, 0, 0,
                                          msg.get_srcSystem(), msg.get_srcComponent())  # fmt: skip
        if self.estimate_mode == "paused":
            return
        with self.lock:
            n, e, d = self.pos
        base = MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        conn.mav.heartbeat_send(MAV.MAV_TYPE_QUADROTOR, MAV.MAV_AUTOPILOT_PX4, base, custom_mode(self.mode),
                                MAV.MAV_STATE_ACTIVE)  # fmt: skip
        if self.estimate_mode == "nan":
            n = e = d = math.nan
        ms = int(boot_s * 1000) & 0xFFFFFFFF
        # heading east (NED yaw 90 deg): q = [cos 45, 0, 0, sin 45]
        q = [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)]
        conn.mav.attitude_quaternion_send(ms, *q, 0.0, 0.0, 0.0)
        conn.mav.local_position_ned_send(ms, n, e, d, 0.0, 0.0, 0.0)
        if self.estimate_mode != "no_odometry":
            # the upper triangle row by row: x, y, z variances 0.25 (N), 1.0 (E), 2.25 (D); small attitude terms
            cov = [0.0] * 21
            for k, v in zip((0, 6, 11, 15, 18, 20), (0.25, 1.0, 2.25, 1e-4, 1e-4, 1e-4), strict=True):
                cov[k] = v
            conn.mav.odometry_send(int(boot_s * 1e6), MAV.MAV_FRAME_LOCAL_NED, MAV.MAV_FRAME_BODY_FRD, n, e, d, q,
                                   0.0, 0.0, 0.0, 0.0, 0.0, 0.0, cov, [math.nan] + [0.0] * 20, 0,
                                   MAV.MAV_ESTIMATOR_TYPE_GPS, 100)  # fmt: skip
