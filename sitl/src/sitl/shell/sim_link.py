"""The simulation link (docs/architecture.md): ground truth out; collisions, terrain and lockstep grants in.

A UDP socket bound to ``sim_link.port``; whoever sends us anything is a
participant until silent for ``peer_timeout_s`` (wall clock). State messages
are stamped with simulation time.
"""

from __future__ import annotations

import contextlib
import logging
import math
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sitl.core.protocol import SIM_STEP, MavResult, MavSeverity
from sitl.shell.encode import Encoder, sim_time_us
from sitl.shell.links import LinkStats, MavLink, bind_error
from sitl.vehicle import Vehicle

__all__ = ["Grant", "SimLink"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Grant:
    """A lockstep SIM_STEP request waiting to be executed; ``number``: the step it grants (1, 2, ...)."""

    steps: int
    addr: tuple[str, int]
    system_id: int
    component_id: int
    number: int = 0


class SimLink:
    """Ground-truth publisher and lockstep/collision/terrain receiver."""

    EXPIRY_CHECK_S = 0.25

    def __init__(
        self,
        vehicle: Vehicle,
        encoder: Encoder,
        *,
        host: str,
        port: int,
        rate_hz: float,
        peer_timeout_s: float,
        lockstep: bool,
        max_steps_per_grant: int,
        system_id: int,
        component_id: int,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.v = vehicle
        self.encoder = encoder
        self.link = MavLink("sim", system_id=system_id, component_id=component_id, signing_key=None, link_id=0)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, port))
        except OSError as err:
            self.sock.close()
            what = "simulation link (UDP)"
            raise bind_error(what, host, port, err) from err
        self.sock.setblocking(False)
        with contextlib.suppress(OSError):
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.local_port = int(self.sock.getsockname()[1])
        # whole physics steps between state messages (50 Hz at 250 Hz physics: every 5th step,
        # the same steps at which the outer loop samples the state, so the truth is computed once)
        self.period_steps = max(1, round(1.0 / (rate_hz * vehicle.dt_s)))
        self.peer_timeout_s = peer_timeout_s
        self.lockstep = lockstep
        self.max_steps = max_steps_per_grant
        self.system_id = system_id
        self._clock = clock
        self._peers: dict[tuple[str, int], float] = {}
        self._peer_list: list[tuple[str, int]] = []
        self._last_expiry_s = -math.inf
        self._next_heartbeat_s = 0.0
        self._last_status = -1
        self.grants: list[Grant] = []
        #: SIM_STEP grants accepted so far: the next one is number ``granted + 1`` (its ``param2``, when given).
        self.granted = 0
        self.collisions = 0
        self.terrain_reports = 0
        self.terrain_clamped = 0

    @property
    def stats(self) -> LinkStats:
        return self.link.stats

    def fileno(self) -> int:
        return self.sock.fileno()

    # ------------------------------------------------------------------ inbound
    def read(self) -> None:
        now = self._clock()
        for _ in range(256):
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break
            peer = (addr[0], int(addr[1]))
            if peer not in self._peers and len(self._peers) >= 64:
                continue
            self._peers[peer] = now
            for msg in self.link.parse(data, ("sim", peer), datagram=True):
                self._handle(msg, peer)

    def _handle(self, msg: Any, peer: tuple[str, int]) -> None:
        kind = msg.get_type()
        stats = self.link.stats
        if kind == "COLLISION":
            self.collisions += 1
            log.warning("collision reported by %s: world id %s", peer, msg.id)
            self.v.autopilot.collision(int(msg.id))
        elif kind == "TERRAIN_REPORT":
            height = float(msg.terrain_height)
            if not math.isfinite(height) or abs(height) > 10000.0:
                stats.rx_invalid_values += 1
                return
            self.terrain_reports += 1
            if not self.v.set_terrain_amsl(height):
                self.terrain_clamped += 1
        elif kind == "COMMAND_LONG":
            if msg.target_system not in (0, self.system_id):
                stats.rx_other_target += 1
                return
            if msg.command != SIM_STEP:
                self._ack(peer, msg, MavResult.UNSUPPORTED)
                return
            steps = msg.param1
            valid = math.isfinite(steps) and steps == int(steps) and 1 <= steps <= self.max_steps
            if not self.lockstep or not valid:
                if not valid:
                    stats.rx_invalid_values += 1
                self._ack(peer, msg, MavResult.DENIED)
                return
            number = msg.param2
            expected = self.granted + 1
            if number not in (0, expected):
                # param2 = the step this grant is (0: unnumbered, an older master): a lost or repeated grant
                stats.rx_invalid_values += 1
                text = f"SIM_STEP numbered {number:g} refused: the next grant is step {expected}"
                log.error("%s (from %s:%d)", text, *peer)
                for chunk in self.encoder.statustexts(int(MavSeverity.ERROR), text):
                    self._send(chunk, [peer])
                self._ack(peer, msg, MavResult.DENIED)
                return
            self.granted = expected
            self.grants.append(Grant(int(steps), peer, msg.get_srcSystem(), msg.get_srcComponent(), expected))

    def _ack(self, peer: tuple[str, int], msg: Any, result: MavResult) -> None:
        ack = self.encoder.factory.command_ack_encode(
            msg.command, int(result), 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )
        self._send(ack, [peer])

    def ack_grant(self, grant: Grant) -> None:
        ack = self.encoder.factory.command_ack_encode(
            SIM_STEP, int(MavResult.ACCEPTED), 0, 0, grant.system_id, grant.component_id
        )
        self._send(ack, [grant.addr])

    # ------------------------------------------------------------------ outbound
    def _live_peers(self) -> list[tuple[str, int]]:
        now = self._clock()
        if now - self._last_expiry_s >= self.EXPIRY_CHECK_S:  # the state goes out at 50 Hz: check 4 times a second
            self._last_expiry_s = now
            for peer, last in list(self._peers.items()):
                if now - last > self.peer_timeout_s:
                    del self._peers[peer]
                    self.link.forget_peer(("sim", peer))
            self._peer_list = list(self._peers)
        elif len(self._peer_list) != len(self._peers):
            self._peer_list = list(self._peers)
        return self._peer_list

    def _send(self, msg: Any, peers: list[tuple[str, int]]) -> None:
        if not peers:
            return
        buf = self.link.pack(msg)
        for peer in peers:
            try:
                self.sock.sendto(buf, peer)
                self.link.stats.tx_messages += 1
                self.link.stats.tx_bytes += len(buf)
            except OSError:
                self.link.stats.tx_errors += 1

    def after_step(self) -> None:
        """Free-run: state at ``rate_hz``, heartbeat at 1 Hz and on change (simulation time)."""
        t = self.v.t_s
        if not self.lockstep and self.v.steps % self.period_steps == 0:
            self.send_state()
        self._maybe_heartbeat(t)

    def _maybe_heartbeat(self, t: float) -> None:
        version = self.v.autopilot.status_version
        if t >= self._next_heartbeat_s or version != self._last_status:
            self._next_heartbeat_s = t + 1.0
            self._last_status = version
            self.send_heartbeat()

    def send_heartbeat(self) -> None:
        self._send(self.encoder.heartbeat(), self._live_peers())

    def send_state(self) -> None:
        """ODOMETRY, HIL_STATE_QUATERNION and HIL_ACTUATOR_CONTROLS of the present instant."""
        peers = self._live_peers()
        if not peers:
            return
        v = self.v
        s = v.truth()
        vn, ve, vd = s.vel_ned_mps
        g = s.gravity_mps2
        ax, ay, az = s.specific_force_frd_mps2
        speed_cms = round(math.sqrt(vn * vn + ve * ve + vd * vd) * 100.0)
        hil = self.encoder.fast.hil_state_quaternion(
            sim_time_us(s.t_s),
            list(s.q_wxyz),
            *s.rates_frd_radps,
            round(s.lat_deg * 1e7),
            round(s.lon_deg * 1e7),
            round(s.alt_amsl_m * 1000.0),
            _i16(vn * 100.0),
            _i16(ve * 100.0),
            _i16(vd * 100.0),
            min(speed_cms, 65535),
            min(speed_cms, 65535),
            _i16(ax / g * 1000.0),
            _i16(ay / g * 1000.0),
            _i16(az / g * 1000.0),
        )
        ap = v.autopilot
        controls = [*v.duty, *_TWELVE_ZEROS]
        act = self.encoder.fast.hil_actuator_controls(
            sim_time_us(s.t_s), controls, ap.personality.base_mode(ap.mode, armed=ap.armed), 1 if self.lockstep else 0
        )
        # the three messages of one instant share a datagram (a MAVLink parser reads them in turn)
        frames = b"".join(self.link.pack(m) for m in (self.encoder.odometry(truth=True), hil, act))
        for peer in peers:
            try:
                self.sock.sendto(frames, peer)
                self.link.stats.tx_messages += 3
                self.link.stats.tx_bytes += len(frames)
            except OSError:
                self.link.stats.tx_errors += 1
        self._maybe_heartbeat(v.t_s)

    def close(self) -> None:
        self.sock.close()


_TWELVE_ZEROS = (0.0,) * 12


def _i16(value: float) -> int:
    r = round(value)  # min() / max() written out (same result): six of these per state message
    r = 32767 if r > 32767 else r
    return int(-32767 if r < -32767 else r)
