"""Builders for the SITL unit tests: an in-process vehicle (real JSBSim, no sockets) and fake links."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Hashable
from typing import Any

from sitl.config import SitlConfig, StreamProfile, load_sitl_config
from sitl.core.modes import FlightMode
from sitl.shell.gateway import Gateway
from sitl.shell.links import MavLink, Received, mavlink
from sitl.vehicle import Vehicle, params_for_config


def make_config(**overrides: Any) -> SitlConfig:
    """Built-in defaults + dotted overrides, no config file, no parameter file."""
    return load_sitl_config(None, {"params.file": None, **overrides})


def make_vehicle(**overrides: Any) -> Vehicle:
    cfg = make_config(**overrides)
    return Vehicle(cfg, params_for_config(cfg))


def run(vehicle: Vehicle, seconds: float, *, until: Callable[[Vehicle], bool] | None = None) -> float:
    """Step ``seconds`` of simulation time (wall clock = simulation time); stop early when ``until`` holds."""
    steps = round(seconds / vehicle.dt_s)
    for _ in range(steps):
        vehicle.step(vehicle.t_s)
        if until is not None and until(vehicle):
            break
    return vehicle.t_s


def pos(vehicle: Vehicle) -> tuple[float, float, float]:
    return vehicle.pos_ned_truth_m


def take_off(vehicle: Vehicle, altitude_m: float = 10.0, settle_s: float = 10.0) -> None:
    ap = vehicle.autopilot
    run(vehicle, 0.1)
    assert ap.arm(force=False).name == "ACCEPTED", ap.statustexts
    assert ap.takeoff(alt_amsl_m=vehicle.home.alt_amsl_m + altitude_m, lat_deg=math.nan, lon_deg=math.nan,
                      yaw_deg=math.nan).name == "ACCEPTED"  # fmt: skip
    run(vehicle, 40.0, until=lambda v: v.autopilot.mode is FlightMode.AUTO_LOITER)
    assert ap.mode is FlightMode.AUTO_LOITER
    run(vehicle, settle_s)


class FakeLink(MavLink):
    """A link whose 'socket' is a list: what the gateway sends lands in ``sent``."""

    def __init__(self, name: str = "gcs", signing_key: bytes | None = None) -> None:
        super().__init__(name, system_id=1, component_id=1, signing_key=signing_key, link_id=1)
        self.sent: list[tuple[Any, Hashable | None]] = []
        self.frames: list[bytes] = []

    def send(self, msg: Any, route: Hashable | None = None) -> None:
        self.frames.append(self.pack(msg))
        self.sent.append((msg, route))

    def close(self) -> None:
        pass

    def of_type(self, kind: str) -> list[Any]:
        return [m for m, _ in self.sent if m.get_type() == kind]

    def texts(self) -> list[str]:
        """The STATUSTEXTs sent, MAVLink 2 chunks joined."""
        out: list[str] = []
        parts: dict[int, list[str]] = {}
        for m in self.of_type("STATUSTEXT"):
            if m.id == 0:
                out.append(m.text)
                continue
            parts.setdefault(m.id, []).append(m.text)
            if len(m.text) < 50:
                out.append("".join(parts.pop(m.id)))
        return out

    def clear(self) -> None:
        self.sent.clear()
        self.frames.clear()


class Client:
    """A MAVLink client (sysid 255/190) that builds real wire frames for the parser."""

    def __init__(self, system_id: int = 255, component_id: int = 190, signing_key: bytes | None = None) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        if signing_key is not None:
            self.mav.signing.secret_key = signing_key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = int((time.time() - 1420070400) * 1e5)  # 10 us units since 2015

    def frame(self, msg: Any) -> bytes:
        buf: bytes = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        return buf


PEER = ("127.0.0.1", 14550)


class Rig:
    def __init__(self, *, key: bytes | None = None, **overrides: Any) -> None:
        self.v: Vehicle = make_vehicle(**overrides)
        self.gcs = FakeLink("gcs", signing_key=key)
        self.api = FakeLink("api")
        self.persisted: list[dict[str, float]] = []
        self.gw = Gateway(
            self.v,
            {"gcs": (self.gcs, StreamProfile.NORMAL), "api": (self.api, StreamProfile.ONBOARD)},
            system_id=1,
            component_id=1,
            unix_epoch_s=1.7e9,
            persist_params=self.persisted.append,
        )
        self.client = Client()
        for _ in range(5):
            self.step()

    def step(self) -> None:
        self.v.step(self.v.t_s)
        self.gw.after_step(self.v.t_s)

    def feed(self, msg: Any, *, link: FakeLink | None = None, client: Client | None = None) -> None:
        link = link or self.gcs
        data = (client or self.client).frame(msg)
        route = (link.name, PEER)
        for parsed in link.parse(data, route, datagram=True):
            self.gw.handle(Received(parsed, route), self.v.t_s)

    def cmd(self, command: int, *params: float, target: tuple[int, int] = (1, 1)) -> Any:
        p = [*params, *([0.0] * 7)][:7]
        self.gcs.clear()
        self.feed(self.client.mav.command_long_encode(*target, command, 0, *p))
        acks = self.gcs.of_type("COMMAND_ACK")
        return acks[0] if acks else None
