"""The simulation loop: sockets, the simulation clock, pacing and lockstep.

Free-running: physics steps follow wall time times the speed factor (or run
flat out at ``max``); between steps every socket is polled, so commands are
handled within a fraction of a wall millisecond. If the machine cannot keep
up, the reference is re-based instead of bursting to catch up.

Lockstep: simulation time advances only on SIM_STEP grants from the
simulation link. Before executing a grant every pending inbound message on
all links is processed; then the steps run, the state goes out on the
simulation link and the grant is ACKed. While no grant comes, heartbeats go
out on wall time so clients stay connected (but never to a lockstep peer).

Lockstep peers (docs/lockstep.md: a router or client that said HELLO; see
:mod:`sitl.shell.lockstep_links`): before executing grant ``g`` the loop waits
until each has sent its STEP(``g - 1``) marker (logging every
:attr:`Simulator.LOCKSTEP_LOG_EVERY_S` wall seconds what it waits for) and handles
exactly their messages before it; after the grant's state and telemetry each gets
STEP(``g``). A count that does not balance stops the run (LockstepError).
"""

from __future__ import annotations

import contextlib
import logging
import math
import selectors
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from sitl import compiled_core
from sitl.config import SitlConfig, StreamProfile, TimeMode, params_for_config
from sitl.core.params import ParamTable
from sitl.core.protocol import MavSeverity
from sitl.errors import ParamFileError, SitlConfigError, SitlError
from sitl.shell.encode import sim_time_us
from sitl.shell.gateway import Gateway
from sitl.shell.links import MavLink, Received, TcpServerLink, UdpLink, frame_only, load_signing_key
from sitl.shell.lockstep_links import LinkPeerIo, LockstepPeers
from sitl.shell.param_file import ParamFile
from sitl.shell.sim_link import SimLink
from sitl.vehicle import Vehicle

__all__ = ["RunSummary", "Simulator"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunSummary:
    sim_time_s: float
    wall_time_s: float
    steps: int

    @property
    def real_time_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.inf


class Simulator:
    """Owns the vehicle, the links and the clock. ``run()`` until ``stop()``."""

    POLL_INTERVAL_UNPACED_S = 0.002
    # load and statistics bookkeeping: every this many free-running steps (a few wall milliseconds at most)
    HOUSEKEEPING_EVERY_STEPS = 25
    # telemetry frames are batched into datagrams and flushed at least this often (wall clock)
    FLUSH_INTERVAL_S = 0.002
    # while a grant waits for the lockstep peers' markers, say so this often (wall clock)
    LOCKSTEP_LOG_EVERY_S = 30.0

    def __init__(
        self, cfg: SitlConfig, *, reset_params: bool = False, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.cfg = cfg
        self._clock = clock
        self._stop = threading.Event()
        self.param_file = ParamFile(cfg.params.file) if cfg.params.file is not None else None
        try:
            params = params_for_config(cfg)
        except ValueError as err:
            msg = f"params.defaults / failsafe ({cfg.autopilot.value} personality): {err}"
            raise SitlConfigError(msg) from err
        self._load_params(params, reset=reset_params)
        self.vehicle = Vehicle(cfg, params)
        self.vehicle.autopilot.wall_scale = 0.0 if (cfg.time.mode is TimeMode.LOCKSTEP) else 1.0 / cfg.time.speed
        self.selector = selectors.DefaultSelector()
        self.links: dict[str, tuple[MavLink, StreamProfile]] = {}
        self.sim_link: SimLink | None = None
        self.gateway: Gateway | None = None
        self.peers: LockstepPeers | None = None
        epoch = cfg.time.unix_epoch_s if cfg.time.unix_epoch_s is not None else time.time()
        try:
            self._open_links(epoch)
        except BaseException:
            self.close()
            raise
        self._last_wall_heartbeat = 0.0
        self._last_stats = clock()
        self._idle_s = 0.0
        self._load_window_start = clock()
        self._last_flush = clock()

    # ------------------------------------------------------------------ set-up
    def _load_params(self, params: ParamTable, *, reset: bool) -> None:
        if self.param_file is None:
            return
        if reset:
            self.param_file.reset()
            return
        for problem in params.apply_persisted(self.param_file.load()):
            log.warning("parameter file %s: %s", self.param_file.path, problem)

    def _persist(self, values: dict[str, float]) -> None:
        if self.param_file is None:
            return
        try:
            self.param_file.save(values)
        except ParamFileError as err:
            log.error("%s", err)
            self.vehicle.autopilot.say(MavSeverity.ERROR, "Parameter file could not be saved")

    def _open_links(self, epoch: float) -> None:
        cfg = self.cfg
        mav = cfg.mavlink
        link_id = 0
        for name in ("gcs", "api"):
            lc = getattr(cfg.links, name)
            if not lc.enabled:
                continue
            key = load_signing_key(lc.signing_key_file) if lc.signing_key_file is not None else None
            link_id += 1
            udp = UdpLink(
                name,
                local=(lc.local_host, lc.local_port),
                remote=(lc.remote_host, lc.remote_port),
                system_id=mav.system_id,
                component_id=mav.component_id,
                signing_key=key,
                link_id=link_id,
                clock=self._clock,
            )
            self.links[name] = (udp, lc.profile)
            self.selector.register(udp.sock, selectors.EVENT_READ, ("udp", name))
        tc = cfg.links.tcp
        if tc.enabled:
            key = load_signing_key(tc.signing_key_file) if tc.signing_key_file is not None else None
            link_id += 1
            tcp = TcpServerLink(
                "tcp",
                local=(tc.host, tc.port),
                system_id=mav.system_id,
                component_id=mav.component_id,
                max_clients=tc.max_clients,
                signing_key=key,
                link_id=link_id,
            )
            self.links["tcp"] = (tcp, tc.profile)
            self.selector.register(tcp.server, selectors.EVENT_READ, ("tcp-server", "tcp"))
            tcp.on_drop = self._unregister
            tcp.on_forget = self._forget_peer
        self.gateway = Gateway(
            self.vehicle,
            self.links,
            system_id=mav.system_id,
            component_id=mav.component_id,
            unix_epoch_s=epoch,
            persist_params=self._persist,
        )
        lockstep = cfg.time.mode is TimeMode.LOCKSTEP
        for link, _ in self.links.values():
            link.keep_unknown = lockstep  # a lockstep peer's count includes every frame it sent
        self.peers = LockstepPeers(
            lockstep=lockstep,
            io=LinkPeerIo({name: link for name, (link, _) in self.links.items()}, self.gateway.encoder.factory),
            t_sim_us=lambda: sim_time_us(self.vehicle.t_s),
        )
        sl = cfg.sim_link
        if sl.enabled:
            self.sim_link = SimLink(
                self.vehicle,
                self.gateway.encoder,
                host=sl.host,
                port=sl.port,
                rate_hz=sl.rate_hz,
                peer_timeout_s=sl.peer_timeout_s,
                lockstep=cfg.time.mode is TimeMode.LOCKSTEP,
                max_steps_per_grant=sl.max_steps_per_grant,
                system_id=mav.system_id,
                component_id=mav.component_id,
                clock=self._clock,
            )
            self.selector.register(self.sim_link.sock, selectors.EVENT_READ, ("sim", "sim"))
        elif cfg.time.mode is TimeMode.LOCKSTEP:
            msg = "time.mode lockstep needs the simulation link (sim_link.enabled: true)"
            raise SitlError(msg)

    def _unregister(self, sock: Any) -> None:
        with contextlib.suppress(KeyError, ValueError):
            self.selector.unregister(sock)

    def _forget_peer(self, route: Any) -> None:
        if self.peers is not None:
            self.peers.forget(route)

    def ports(self) -> dict[str, int]:
        """Bound local ports by link name (useful with port 0)."""
        out = {name: int(getattr(link, "local_port", 0)) for name, (link, _) in self.links.items()}
        if self.sim_link is not None:
            out["sim"] = self.sim_link.local_port
        return out

    # ------------------------------------------------------------------ I/O
    def poll(self, timeout_s: float) -> None:
        """Wait up to ``timeout_s`` for input and handle everything that is pending."""
        gateway = self.gateway
        assert gateway is not None
        if timeout_s > 0.0:
            t0 = self._clock()
            events = self.selector.select(timeout_s)
            self._idle_s += self._clock() - t0
        else:
            events = self.selector.select(0.0)
        if not events:
            return
        wall = self._clock()
        try:
            self._dispatch(events, wall)
        finally:
            gateway.flush()

    def _dispatch(self, events: list[tuple[selectors.SelectorKey, int]], wall: float) -> None:
        gateway = self.gateway
        assert gateway is not None
        for key, _ in events:
            kind, name = key.data
            if kind == "udp":
                link = self.links[name][0]
                assert isinstance(link, UdpLink)
                for rx in link.read():
                    self._received(rx, wall)
            elif kind == "tcp-server":
                tcp = self.links[name][0]
                assert isinstance(tcp, TcpServerLink)
                client = tcp.accept()
                if client is not None:
                    cid = tcp.client_id(client)
                    self.selector.register(client.sock, selectors.EVENT_READ, ("tcp-client", cid))
                    log.info("TCP client %s:%d connected", *client.addr)
            elif kind == "tcp-client":
                tcp = self.links["tcp"][0]
                assert isinstance(tcp, TcpServerLink)
                client = tcp.clients.get(name)
                for rx in tcp.read_client(name):
                    self._received(rx, wall)
                if name not in tcp.clients and client is not None:
                    log.info("TCP client %s:%d disconnected", *client.addr)
            elif kind == "sim" and self.sim_link is not None:
                self.sim_link.read()

    def _received(self, rx: Received, wall: float) -> None:
        """One inbound message: a lockstep marker or a lockstep peer's message is queued, the rest handled now."""
        assert self.gateway is not None
        if self.peers is not None and self.peers.offer(rx):
            return
        if not frame_only(rx.msg):
            self.gateway.handle(rx, wall)

    def _step(self, wall_s: float) -> None:
        self.vehicle.step(wall_s)
        assert self.gateway is not None
        self.gateway.after_step(wall_s)
        if wall_s - self._last_flush >= self.FLUSH_INTERVAL_S:
            self.gateway.flush()
            self._last_flush = wall_s
        if self.sim_link is not None:
            self.sim_link.after_step()

    def stop(self) -> None:
        self._stop.set()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    # ------------------------------------------------------------------ loops
    def run(self, *, max_sim_time_s: float | None = None) -> RunSummary:
        """Run until :meth:`stop` (or ``max_sim_time_s`` of simulation time)."""
        wall0 = self._clock()
        t0 = self.vehicle.t_s
        steps0 = self.vehicle.steps
        log.info(
            "simulation running: %s autopilot, %s, ports %s; step modules: %s",
            self.cfg.personality.label,
            self._describe_time(),
            self.ports(),
            compiled_core.active().reason,
        )
        w = self.cfg.wind
        if w.enabled:
            log.info(
                "wind: %g m/s from %g deg at %g m (shear exponent %g), turbulence %s, seed %d",
                w.speed_mps,
                w.from_deg,
                w.reference_height_m,
                w.shear_exponent,
                w.turbulence.value,
                w.seed,
            )
        if self.cfg.time.mode is TimeMode.LOCKSTEP:
            self._run_lockstep(max_sim_time_s)
        else:
            self._run_free(max_sim_time_s)
        wall = self._clock() - wall0
        return RunSummary(self.vehicle.t_s - t0, wall, self.vehicle.steps - steps0)

    def _describe_time(self) -> str:
        tc = self.cfg.time
        if tc.mode is TimeMode.LOCKSTEP:
            return "lockstep (SIM_STEP grants on the simulation link)"
        return f"free-running at speed factor {tc.speed_factor}"

    def _run_free(self, max_sim_time_s: float | None) -> None:
        speed = self.cfg.time.speed
        dt = self.vehicle.dt_s
        max_lag = self.cfg.time.max_lag_s
        clock = self._clock
        ref_wall = clock()
        ref_sim = self.vehicle.t_s
        last_poll = ref_wall
        end = math.inf if max_sim_time_s is None else self.vehicle.t_s + max_sim_time_s
        paced = math.isfinite(speed)
        vehicle = self.vehicle
        stopped = self._stop.is_set
        step = self._step
        housekeeping_every = self.HOUSEKEEPING_EVERY_STEPS
        count = 0
        while not stopped() and vehicle.t_s < end - 1e-9:
            now = clock()
            if paced:
                due = ref_wall + (self.vehicle.t_s + dt - ref_sim) / speed
                if now < due:
                    self.poll(due - now)
                    last_poll = clock()
                    continue
                if now - due > max_lag:
                    ref_wall, ref_sim = now, self.vehicle.t_s
                if now - last_poll >= self.POLL_INTERVAL_UNPACED_S:
                    self.poll(0.0)
                    last_poll = now
            elif now - last_poll >= self.POLL_INTERVAL_UNPACED_S:
                self.poll(0.0)
                last_poll = now
            step(now)
            count += 1
            if count >= housekeeping_every:
                count = 0
                self._housekeeping(now)

    def _run_lockstep(self, max_sim_time_s: float | None) -> None:
        sim = self.sim_link
        assert sim is not None
        gateway = self.gateway
        assert gateway is not None
        peers = self.peers
        assert peers is not None
        end = math.inf if max_sim_time_s is None else self.vehicle.t_s + max_sim_time_s
        while not self._stop.is_set() and self.vehicle.t_s < end - 1e-9:
            self.poll(0.05 if not sim.grants else 0.0)
            # drain everything else that is pending before executing grants
            while sim.grants and self.selector.select(0.0):
                self.poll(0.0)
            now = self._clock()
            grants, sim.grants = sim.grants, []
            for grant in grants:
                if not self._await_peers(grant.number - 1):
                    return
                now = self._clock()
                for rx in peers.release(grant.number - 1):
                    gateway.handle(rx, now)
                for _ in range(grant.steps):
                    self._step(now)
                sim.send_state()
                gateway.flush()
                peers.end_step(grant.number, sim_time_us(self.vehicle.t_s))
                sim.ack_grant(grant)
            if not grants:
                self._wall_heartbeat(now)
            self._housekeeping(now)

    def _await_peers(self, step: int) -> bool:
        """Poll until every lockstep peer has closed ``step`` (False: stopped meanwhile). Never gives up."""
        peers = self.peers
        assert peers is not None
        if peers.ready(step):
            return True
        start = self._clock()
        next_log = start + self.LOCKSTEP_LOG_EVERY_S
        while not peers.ready(step):
            if self._stop.is_set():
                return False
            self.poll(0.05)
            now = self._clock()
            if now >= next_log:
                next_log = now + self.LOCKSTEP_LOG_EVERY_S
                log.warning(
                    "grant %d has waited %.0f s for the STEP(%d) marker of: %s",
                    step + 1,
                    now - start,
                    step,
                    peers.waiting_for(step),
                )
        return True

    def _wall_heartbeat(self, now: float) -> None:
        period = self.cfg.mavlink.paused_heartbeat_period_s
        if now - self._last_wall_heartbeat >= period:
            self._last_wall_heartbeat = now
            assert self.gateway is not None
            self.gateway.send_heartbeat(skip=self.peers.routes() if self.peers is not None else frozenset())
            if self.sim_link is not None:
                self.sim_link.send_heartbeat()

    def _housekeeping(self, now: float) -> None:
        window = now - self._load_window_start
        if window >= 1.0 and self.cfg.time.mode is not TimeMode.LOCKSTEP:  # lockstep: SYS_STATUS load stays 0
            assert self.gateway is not None
            self.gateway.encoder.load_permille = round(1000.0 * max(0.0, 1.0 - self._idle_s / window))
            self._load_window_start = now
            self._idle_s = 0.0
        period = self.cfg.mavlink.stats_period_s
        if period > 0 and now - self._last_stats >= period:
            self._last_stats = now
            self.log_stats()

    def log_stats(self) -> None:
        ap = self.vehicle.autopilot
        b = self.vehicle.battery_reading
        log.info(
            "t_sim=%.1f s mode=%s armed=%s landed=%s battery=%.1f V %.0f%% (%.0f mAh)",
            self.vehicle.t_s,
            ap.mode_name,
            ap.armed,
            ap.landed,
            b.voltage_v,
            100 * b.remaining,
            b.consumed_mah,
        )
        for name, (link, _) in self.links.items():
            log.info("link %s: %s", name, link.stats.summary())
        if self.sim_link is not None:
            log.info("link sim: %s", self.sim_link.stats.summary())
        if self.peers is not None and self.cfg.time.mode is TimeMode.LOCKSTEP:
            log.info("%s", self.peers.summary())

    def link_stats(self) -> dict[str, Any]:
        out: dict[str, Any] = {name: link.stats for name, (link, _) in self.links.items()}
        if self.sim_link is not None:
            out["sim"] = self.sim_link.stats
        return out

    def close(self) -> None:
        if self.gateway is not None:
            self.gateway.flush()
        for link, _ in self.links.values():
            link.close()
        if self.sim_link is not None:
            self.sim_link.close()
        self.selector.close()
