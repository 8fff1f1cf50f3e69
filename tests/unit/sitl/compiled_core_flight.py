"""A scripted flight through the SITL (JSBSim, autopilot, gateway) that prints hashes of everything it produced.

``python compiled_core_flight.py px4|ardupilot`` prints one JSON line: which core ran
(``sitl.compiled_core.active()``), the vehicle's true trajectory and every frame the gateway
sent on a GCS (normal profile) and an API (onboard profile) link, hashed. The compiled core
must give the pure-Python core's output bit for bit; ``test_sitl_compiled_core.py`` runs this
twice, once with ``SITL_PURE_PYTHON=1``. It drives the vehicle through commands and setpoints as
clients send them: takeoff, offboard position / velocity / attitude, DO_ORBIT, a mission,
the sticks, RTL (PX4, noisy estimator with a heading error, GPS stuck / intermittent / garbage
for a few seconds each during the mission, compass and baro off / stuck / garbage /
intermittent); GUIDED takeoff, position targets, AUTO and RTL (ArduPilot).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import struct
import sys
from typing import Any

os.environ.setdefault("MAVLINK20", "1")

from pymavlink.dialects.v20 import common as mavlink

from sitl import compiled_core
from sitl.config import StreamProfile, load_sitl_config
from sitl.core.mission import MissionItem
from sitl.core.protocol import MavCmd, MavFrame
from sitl.shell.gateway import Gateway
from sitl.shell.links import MavLink, Received
from sitl.vehicle import Vehicle, params_for_config
from uav_common.geo import LocalProjection

M = mavlink
PEER = ("gcs", ("127.0.0.1", 14550))


class HashLink(MavLink):
    """A link that hashes every frame it is given."""

    def __init__(self, name: str) -> None:
        super().__init__(name, system_id=1, component_id=1, signing_key=None, link_id=1)
        self.digest = hashlib.sha256()
        self.frames = 0

    def send(self, msg: Any, route: object = None) -> None:
        self.digest.update(self.pack(msg))
        self.frames += 1

    def close(self) -> None:
        pass


class Flight:
    def __init__(self, autopilot: str, estimator: str) -> None:
        overrides: dict[str, object] = {"params.file": None, "autopilot": autopilot, "estimator.mode": estimator}
        if estimator == "noisy":  # the heading error and GPS failure injection run in the compiled estimator too
            overrides |= {"estimator.heading_bias_deg": 3.0, "estimator.heading_noise_deg": 1.0,
                          "params.defaults": {"SYS_FAILURE_EN": 1}}  # fmt: skip
        cfg = load_sitl_config(None, overrides)
        self.v = Vehicle(cfg, params_for_config(cfg))
        self.gcs, self.api = HashLink("gcs"), HashLink("api")
        links = {"gcs": (self.gcs, StreamProfile.NORMAL), "api": (self.api, StreamProfile.ONBOARD)}
        self.gw = Gateway(self.v, links, system_id=1, component_id=1, unix_epoch_s=1.7e9)
        self.client = M.MAVLink(None, srcSystem=255, srcComponent=190)
        self.trajectory = hashlib.sha256()
        self.proj = LocalProjection(self.v.home)
        self.modes: list[str] = []

    def run(self, seconds: float) -> None:
        v, ap = self.v, self.v.autopilot
        for _ in range(round(seconds / v.dt_s)):
            v.step(v.t_s)
            self.gw.after_step(v.t_s)
            s = v.truth()
            self.trajectory.update(struct.pack("<8d", s.lat_deg, s.lon_deg, s.alt_amsl_m, *s.vel_ned_mps, *v.duty[:2]))
            self.trajectory.update(struct.pack("<d", ap.thrust))
            if not self.modes or self.modes[-1] != ap.mode.name:
                self.modes.append(ap.mode.name)

    def feed(self, msg: Any) -> None:
        data = msg.pack(self.client)
        self.client.seq = (self.client.seq + 1) % 256
        for parsed in self.gcs.parse(data, PEER, datagram=True):
            self.gw.handle(Received(parsed, PEER), self.v.t_s)

    def cmd(self, command: int, *params: float) -> None:
        p = [*params, *([0.0] * 7)][:7]
        self.feed(self.client.command_long_encode(1, 1, command, 0, *p))

    def heartbeat(self) -> None:
        self.feed(self.client.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0))

    def position(self, n: float, e: float, d: float, yaw: float = 0.0) -> None:
        self.feed(self.client.set_position_target_local_ned_encode(0, 1, 1, 1, 2552 - 1024, n, e, d, 0, 0, 0, 0, 0, 0,
                                                                   yaw, 0))  # fmt: skip

    def mission(self, legs: list[tuple[float, float]], *, home_item: bool) -> None:
        items = []
        if home_item:
            h = self.v.home
            items.append(MissionItem(0, MavFrame.GLOBAL, MavCmd.NAV_WAYPOINT, 0, 1, 0.0, 0.0, 0.0, 0.0,
                                     round(h.lat_deg * 1e7), round(h.lon_deg * 1e7), h.alt_amsl_m))  # fmt: skip
        items.append(MissionItem(len(items), MavFrame.MISSION, MavCmd.DO_CHANGE_SPEED, 0, 1, 1.0, 8.0, -1.0, 0.0, 0, 0,
                                 0.0))  # fmt: skip
        for n, e in legs:
            g = self.proj.to_geo(n, e, 0.0)
            items.append(MissionItem(len(items), MavFrame.GLOBAL_RELATIVE_ALT_INT, MavCmd.NAV_WAYPOINT, 0, 1, 1.0, 2.0,
                                     0.0, math.nan, round(g.lat_deg * 1e7), round(g.lon_deg * 1e7), 18.0))  # fmt: skip
        ap = self.v.autopilot
        ap.mission_store.replace(tuple(items))
        ap.mission_uploaded()


def fly_px4(f: Flight) -> None:
    f.heartbeat()
    f.run(0.5)
    f.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    f.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, f.v.home.alt_amsl_m + 15.0)
    f.run(14.0)
    for k in range(120):  # offboard at 20 Hz: a moving position, then a velocity, then an attitude
        f.heartbeat()
        f.position(0.2 * k, 0.1 * k, -15.0 - 0.02 * k, 0.3)
        if k == 20:
            f.cmd(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6)  # OFFBOARD
        f.run(0.05)
    for _ in range(20):
        f.feed(f.client.set_position_target_local_ned_encode(0, 1, 1, 1, 0b0000_1100_0111, 0, 0, 0, 2.0, -1.0, 0.0,
                                                             0, 0, 0, 0, 0.2))  # fmt: skip
        f.run(0.05)
    q = (math.cos(0.05), 0.0, math.sin(0.05), 0.0)  # 5.7 degrees nose down
    for _ in range(30):
        f.feed(f.client.set_attitude_target_encode(0, 1, 1, 7, q, 0, 0, 0, 0.45))
        f.run(0.05)
    centre = f.proj.to_geo(30.0, 10.0, 0.0)
    f.cmd(M.MAV_CMD_DO_ORBIT, 12.0, 3.0, 0, math.nan, centre.lat_deg, centre.lon_deg, math.nan)
    f.run(10.0)
    f.mission([(50.0, 0.0), (50.0, 40.0), (0.0, 40.0)], home_item=False)
    f.cmd(M.MAV_CMD_MISSION_START, 0, 0)
    gps, mag, baro = M.FAILURE_UNIT_SENSOR_GPS, M.FAILURE_UNIT_SENSOR_MAG, M.FAILURE_UNIT_SENSOR_BARO
    faults = {10: [(gps, M.FAILURE_TYPE_STUCK)], 12: [(mag, M.FAILURE_TYPE_STUCK), (baro, M.FAILURE_TYPE_INTERMITTENT)],
              14: [(gps, M.FAILURE_TYPE_OK)], 16: [(mag, M.FAILURE_TYPE_GARBAGE)],
              18: [(gps, M.FAILURE_TYPE_INTERMITTENT), (baro, M.FAILURE_TYPE_STUCK)],
              21: [(mag, M.FAILURE_TYPE_INTERMITTENT)], 24: [(gps, M.FAILURE_TYPE_GARBAGE), (baro, M.FAILURE_TYPE_OFF)],
              26: [(gps, M.FAILURE_TYPE_OK)], 28: [(mag, M.FAILURE_TYPE_OFF)],
              32: [(mag, M.FAILURE_TYPE_OK), (baro, M.FAILURE_TYPE_OK)]}  # fmt: skip
    for k in range(40):
        # short GPS failures during the mission (each shorter than EKF2_NOAID_TOUT), compass and baro failures
        for unit, kind in faults.get(k, []):
            f.cmd(M.MAV_CMD_INJECT_FAILURE, unit, kind, 0)
        f.heartbeat()
        f.run(1.0)
    for k in range(60):  # POSCTL on the sticks
        f.feed(f.client.manual_control_encode(1, 600, -300, 700, 200, 0))
        if k == 2:
            f.cmd(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3)
        f.run(0.05)
    f.cmd(M.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    for _ in range(60):
        f.heartbeat()
        f.run(1.0)


def fly_ardupilot(f: Flight) -> None:
    f.heartbeat()
    f.run(0.5)
    f.cmd(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)  # GUIDED
    f.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    f.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, 12.0)
    f.run(12.0)
    for k in range(100):  # GUIDED position targets at 10 Hz
        f.heartbeat()
        f.position(0.3 * k, -0.2 * k, -12.0)
        f.run(0.1)
    f.mission([(40.0, 0.0), (40.0, 30.0)], home_item=True)
    f.cmd(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 3)  # AUTO
    for _ in range(30):
        f.heartbeat()
        f.run(1.0)
    f.cmd(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6)  # RTL
    for _ in range(60):
        f.heartbeat()
        f.run(1.0)


def main() -> int:
    autopilot = sys.argv[1]
    flight = Flight(autopilot, "noisy" if autopilot == "px4" else "truth")
    (fly_px4 if autopilot == "px4" else fly_ardupilot)(flight)
    ap = flight.v.autopilot
    print(json.dumps({
        "compiled": compiled_core.active().compiled,
        "core": compiled_core.active().reason,
        "t_s": round(flight.v.t_s, 3),
        "mode": ap.mode.name,
        "armed": ap.armed,
        "modes": flight.modes,
        "personality": ap.personality.label,
        "trajectory": flight.trajectory.hexdigest(),
        "gcs": [flight.gcs.frames, flight.gcs.digest.hexdigest()],
        "api": [flight.api.frames, flight.api.digest.hexdigest()],
    }))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
