"""The router process: one ``selectors`` event loop around :class:`RouterCore` (shell).

:class:`Router` opens the configured endpoints and the TCP server, feeds every
read to the core, writes the routed frames, logs them to the ``.tlog``, prints
and saves statistics, retries endpoints that fail, and on :meth:`Router.request_stop`
(SIGINT/SIGTERM from the CLI) flushes queues, the log and the stats file.
With ``[General] Lockstep = true`` every input goes through
:class:`~mavlink_router.shell.lockstep.LockstepRouting` first, and the lossy links
run on the autopilot's simulated time (docs/mavlink_router.md, "Lockstep").
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import json
import logging
import math
import os
import random
import selectors
import socket
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from mavlink_router.core.config import LockstepRole, LogMode, RouterConfig, as_dict
from mavlink_router.core.engine import EndpointStats, Routed, RouterCore, SigningPolicy
from mavlink_router.core.frames import Frame, MessageSpec
from mavlink_router.core.impairment import ImpairmentConfig, LinkImpairment
from mavlink_router.core.lockstep import DUE_TOLERANCE_S
from mavlink_router.core.routing import Filters
from mavlink_router.core.signing import STATE_CHANGING_MESSAGES, parse_key_text
from mavlink_router.errors import ConfigError
from mavlink_router.shell.dialect import message_ids
from mavlink_router.shell.endpoints import (
    Endpoint,
    TcpClientEndpoint,
    TcpConnection,
    TcpServer,
    UartEndpoint,
    UdpEndpoint,
    check_serial_available,
)
from mavlink_router.shell.lockstep import INVITE_EVERY_S, LockstepRouting
from mavlink_router.shell.tlog import TelemetryLog

__all__ = ["Router", "format_stats_line", "load_signing_key"]

_LOG = logging.getLogger("mavlink_router")
_STATS_LOG = logging.getLogger("mavlink_router.stats")
TICK_S = 0.25
TLOG_FLUSH_S = 1.0
STATS_FILE_NAME = "router-stats.json"
MAX_CLOSED_KEPT = 32


class _Timer:
    __slots__ = ("callback", "cancelled", "due")

    def __init__(self, due: float, callback: Callable[[], None]) -> None:
        self.due = due
        self.callback = callback
        self.cancelled = False

    def cancel(self) -> None:
        self.cancelled = True


def load_signing_key(path: Path) -> bytes:
    """Read a signing key file (see :func:`mavlink_router.core.signing.parse_key_text`)."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        msg = f"{path}: signing key file not found; create it (64 hex digits or a passphrase) or fix SigningKeyFile"
        raise ConfigError(msg) from None
    except (OSError, UnicodeDecodeError) as err:
        msg = f"{path}: cannot read the signing key file ({err})"
        raise ConfigError(msg) from err
    mode = path.stat().st_mode
    if mode & 0o077:
        _LOG.warning("signing key file %s is readable by other users (mode %o); chmod 600 it", path, mode & 0o777)
    return parse_key_text(text, source=str(path))


def format_stats_line(
    name: str,
    address: str,
    stats: EndpointStats,
    now_s: float,
    link: dict[str, dict[str, int]] | None = None,
    *,
    lockstep: dict[str, int] | None = None,
) -> str:
    """One console line of per-endpoint statistics (``link``: the lossy link's counters per direction;
    ``lockstep``: the endpoint's lockstep counters)."""
    seen = "never" if stats.last_rx_s is None else f"{max(0.0, now_s - stats.last_rx_s):.1f} s ago"
    drops = stats.tx_drops + stats.unsigned_drops + stats.bad_signature_drops + stats.replay_drops
    line = (
        f"{name} ({address}): rx {stats.rx_msgs} msgs {stats.rx_bytes / 1000:.1f} kB, "
        f"tx {stats.tx_msgs} msgs {stats.tx_bytes / 1000:.1f} kB, drops {drops}, "
        f"crc errors {stats.crc_errors}, seq lost {stats.seq_lost}, last seen {seen}"
    )
    for direction, c in (link or {}).items():
        line += (
            f"; link {direction}: lost {c['dropped']}/{c['offered']}, delayed {c['delayed']}, "
            f"reordered {c['reordered']}, held {c['held']}"
        )
    if lockstep:
        line += "; lockstep: " + ", ".join(f"{key.replace('_', ' ')} {value}" for key, value in lockstep.items())
    return line


def _uniform(config: ImpairmentConfig, name: str, direction: str) -> random.Random:
    """The seeded generator of one endpoint's link in one direction (independent streams, same every run)."""
    return random.Random(f"{config.seed}:{name}:{direction}")


class Router:
    """The imperative shell. Build it, :meth:`run` it, stop it with :meth:`request_stop`."""

    def __init__(
        self,
        config: RouterConfig,
        table: Mapping[int, MessageSpec],
        *,
        clock: Callable[[], float] = time.time,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        general = config.general
        self.config = config
        self._clock = clock
        self._monotonic = monotonic
        self._protected = message_ids(table, STATE_CHANGING_MESSAGES)
        self.core = RouterCore(
            table,
            dedup_period_s=general.dedup_period_ms / 1000.0,
            sniffer_sysid=general.sniffer_sysid,
            log_system_id=general.log_system_id,
        )
        self._keys: dict[Path, bytes] = {}
        self._server_signing = self._signing(general.tcp_server_require_signing, general.signing_key_file)
        if config.uart:
            check_serial_available()
        self._sel = selectors.DefaultSelector()
        self._timers: list[tuple[float, int, _Timer]] = []
        self._seq = itertools.count()
        self._slots: list[Endpoint | None] = []
        #: Lossy links: frames sent to a slot cross ``_link_out[slot]`` (those received cross the core's ``link_in``).
        self._link_out: dict[int, LinkImpairment[tuple[bytes, int]]] = {}
        self._link_in: dict[int, LinkImpairment[Frame]] = {}
        self._held_links = False  # some link can hold frames for later
        self.endpoints: list[Endpoint] = []
        self._closed_stats: list[dict[str, object]] = []
        self._stop = False
        self._shut_down = False
        self._dirty: list[Endpoint] = []
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self.tcp_server: TcpServer | None = None
        self.tlog: TelemetryLog | None = None
        if general.log_dir is not None and general.log_telemetry:
            self.tlog = TelemetryLog(
                general.log_dir, max_files=general.max_log_files, min_free_space_bytes=general.min_free_space_bytes
            )
        self.stats_path = general.stats_file
        if self.stats_path is None and general.log_dir is not None:
            self.stats_path = general.log_dir / STATS_FILE_NAME
        self._armed_logging = general.log_mode is LogMode.WHILE_ARMED
        self._arm_seen: object = None
        self._started_s = 0.0
        self._roles: dict[int, LockstepRole] = {}
        self._lockstep: LockstepRouting | None = None
        self._build_endpoints()
        if general.lockstep:
            (autopilot,) = [slot for slot, role in self._roles.items() if role is LockstepRole.AUTOPILOT]
            self._lockstep = LockstepRouting(self, autopilot_slot=autopilot, clock=clock)
            self._lockstep.invited = {slot for slot, role in self._roles.items() if role is LockstepRole.CLIENT}

    # -- construction -------------------------------------------------------------------
    def _signing(self, required: bool, key_file: Path | None) -> SigningPolicy | None:
        if not required:
            return None
        assert key_file is not None  # config validation guarantees it
        key = self._keys.get(key_file)
        if key is None:
            key = self._keys[key_file] = load_signing_key(key_file)
        return SigningPolicy(key, self._protected)

    def _build_endpoints(self) -> None:
        cfg = self.config
        for udp in cfg.udp:
            self._add(UdpEndpoint(udp, self), stream=False, options=udp.options)
        for tcp in cfg.tcp:
            self._add(TcpClientEndpoint(tcp, self), stream=True, options=tcp.options)
        for uart in cfg.uart:
            self._add(UartEndpoint(uart, self), stream=True, options=uart.options)
        if cfg.general.tcp_server_port:
            self.tcp_server = TcpServer(cfg.general.tcp_server_port, self, self._accept)

    def _add(self, endpoint: Endpoint, *, stream: bool, options: Any = None) -> None:
        in_filter: Filters | None = None
        out_filter: Filters | None = None
        group = ""
        ignore = False
        signing = None
        link: ImpairmentConfig | None = None
        if options is not None:
            in_filter, out_filter = options.in_filter, options.out_filter
            group, ignore = options.group, options.ignore_comp_id
            signing = self._signing(options.require_signing, options.signing_key_file)
            link = options.link if options.link is not None and options.link.active else None
        elif endpoint.dynamic:
            signing = self._server_signing
        link_in: LinkImpairment[Frame] | None = None
        if link is not None and link.direction.inbound:
            link_in = LinkImpairment(link, _uniform(link, endpoint.name, "in").random)
        slot = self.core.add_endpoint(
            endpoint.name,
            stream=stream,
            in_filter=in_filter,
            out_filter=out_filter,
            group=group,
            ignore_comp_id=ignore,
            signing=signing,
            link_in=link_in,
        )
        if link is not None:
            _LOG.info(
                "endpoint %s: lossy link (%s): loss %g %% (burst %g), delay %g ms + jitter %g ms, "
                "reorder %g %%, seed %d",
                endpoint.name, link.direction.value, link.loss_pct, link.loss_burst, link.delay_ms, link.jitter_ms,
                link.reorder_pct, link.seed,
            )  # fmt: skip
            if link_in is not None:
                self._link_in[slot] = link_in
            if link.direction.outbound:
                self._link_out[slot] = LinkImpairment(link, _uniform(link, endpoint.name, "out").random)
            self._held_links = self._held_links or link.holds
        endpoint.bind_slot(slot, self.core.stats(slot))
        if options is not None and options.lockstep is not None:
            self._roles[slot] = options.lockstep
        while len(self._slots) <= slot:
            self._slots.append(None)
        self._slots[slot] = endpoint
        self.endpoints.append(endpoint)

    def _accept(self, sock: socket.socket, peer: tuple[Any, ...]) -> None:
        conn = TcpConnection(sock, peer, self, self.config.general.tx_queue_limit)
        self._add(conn, stream=True)
        conn.start()

    # -- Host protocol (used by endpoints) ------------------------------------------------
    def watch(self, fileobj: Any, events: int, handler: Callable[[int], None]) -> None:
        try:
            self._sel.modify(fileobj, events, handler)
        except KeyError:
            self._sel.register(fileobj, events, handler)

    def unwatch(self, fileobj: Any) -> None:
        with contextlib.suppress(KeyError, ValueError):
            self._sel.unregister(fileobj)

    def call_later(self, delay_s: float, callback: Callable[[], None]) -> _Timer:
        timer = _Timer(self._monotonic() + delay_s, callback)
        heapq.heappush(self._timers, (timer.due, next(self._seq), timer))
        return timer

    def monotonic(self) -> float:
        return self._monotonic()

    def reset_stream(self, slot: int) -> None:
        self.core.reset_stream(slot)

    def mark_dirty(self, endpoint: Endpoint) -> None:
        """``endpoint`` collected frames; it is flushed once the current event is handled."""
        self._dirty.append(endpoint)

    def _flush_dirty(self) -> None:
        while self._dirty:
            dirty, self._dirty = self._dirty, []
            for endpoint in dirty:
                endpoint.flush()

    def connection_lost(self, endpoint: Endpoint) -> None:
        """A dynamic endpoint closed: free its slot, keep its final numbers for the stats file."""
        if not endpoint.dynamic or endpoint.slot < 0 or self._slots[endpoint.slot] is not endpoint:
            return
        if self._lockstep is not None:
            self._lockstep.lost(endpoint)
        stats = self.core.remove_endpoint(endpoint.slot)
        self._slots[endpoint.slot] = None
        self.endpoints.remove(endpoint)
        record = {**endpoint.status(), **stats.as_dict(), "closed_at": self._clock()}
        self._closed_stats = [*self._closed_stats, record][-MAX_CLOSED_KEPT:]

    def endpoint_connected(self, endpoint: Endpoint) -> None:
        """An endpoint (re)connected (the lockstep says HELLO to its autopilot then)."""
        if self._lockstep is not None:
            self._lockstep.connected(endpoint)

    def endpoint_at(self, slot: int) -> Endpoint | None:
        return self._slots[slot] if 0 <= slot < len(self._slots) else None

    def links_of(self, slot: int) -> tuple[LinkImpairment[Frame] | None, LinkImpairment[tuple[bytes, int]] | None]:
        """Endpoint ``slot``'s lossy links (inbound, outbound)."""
        return self._link_in.get(slot), self._link_out.get(slot)

    def deliver(self, slot: int, data: bytes) -> None:
        """The hot path: route what endpoint ``slot`` read and write it out."""
        if self._lockstep is not None:
            self._lockstep.deliver(slot, data)
            return
        now = self._clock()
        routed = self.core.ingest(slot, data, now)
        if routed:
            self._dispatch(slot, routed, now)

    def dispatch(self, slot: int, routed: list[Routed], now: float, *, link_s: float | None = None) -> None:
        """Write routed frames out (``link_s``: the lossy links' clock when it is not ``now``, in lockstep)."""
        if routed:
            self._dispatch(slot, routed, now, link_s=link_s)

    def _dispatch(self, slot: int, routed: list[Routed], now: float, *, link_s: float | None = None) -> None:
        if self._armed_logging and self.core.arm_state is not self._arm_seen:
            self._on_arm_change()
        tlog = self.tlog
        slots = self._slots
        link_out = self._link_out
        lockstep = self._lockstep
        link_now = now if link_s is None else link_s
        for frame, dests in routed:
            if tlog is not None:
                tlog.write(frame, now)
            for dest in dests:
                endpoint = slots[dest]
                if endpoint is None:
                    continue
                if lockstep is not None and lockstep.take(slot, dest, frame):
                    continue
                link = link_out.get(dest) if link_out else None
                if link is None:
                    endpoint.send(frame, slot)
                else:
                    for held_frame, source in link.offer((frame, slot), link_now):
                        endpoint.send(held_frame, source)

    def _release_held(self) -> None:
        """Deliver what the lossy links held and is now due, both ways (wall clock)."""
        self.release_held(self._clock())

    def release_held(self, link_s: float, *, all_held: bool = False) -> None:
        """Deliver what the lossy links held and is due by ``link_s`` on their clock (everything: ``all_held``);
        a registered lockstep client's links are its scheduler's."""
        now = self._clock()
        due_s = math.inf if all_held else link_s if self._lockstep is None else link_s + DUE_TOLERANCE_S
        lockstep = self._lockstep
        for slot in list(self._link_in):
            if lockstep is not None and lockstep.is_client_slot(slot):
                continue
            routed = self.core.release_inbound(slot, now, link_s=due_s)
            if routed:
                self._dispatch(slot, routed, now, link_s=link_s)
        slots = self._slots
        for slot, link in list(self._link_out.items()):
            if lockstep is not None and lockstep.is_client_slot(slot):
                continue
            endpoint = slots[slot] if slot < len(slots) else None
            for frame, source in link.due(due_s):
                if endpoint is not None:
                    endpoint.send(frame, source)

    def release_held_of(self, slot: int) -> None:
        """Everything endpoint ``slot``'s lossy links hold, now (it is becoming a lockstep client)."""
        now = self._clock()
        if slot in self._link_in:
            routed = self.core.release_inbound(slot, now, link_s=math.inf)
            if routed:
                self._dispatch(slot, routed, now)
        link = self._link_out.get(slot)
        endpoint = self.endpoint_at(slot)
        if link is not None:
            for frame, source in link.due(math.inf):
                if endpoint is not None:
                    endpoint.send(frame, source)

    def _next_held_s(self) -> float:
        """Seconds until the next frame a lossy link holds is due (inf if none; and once the lockstep runs on
        simulated time, the autopilot's markers release them instead)."""
        if self._lockstep is not None and self._lockstep.scheduler.synced:
            return math.inf
        due = min((link.next_due_s for link in self._link_in.values()), default=math.inf)
        due = min(due, min((link.next_due_s for link in self._link_out.values()), default=math.inf))
        return due - self._clock()

    def link_counters(self, slot: int) -> dict[str, dict[str, int]]:
        """The lossy link's counters of endpoint ``slot`` per direction (empty for a perfect link)."""
        out: dict[str, dict[str, int]] = {}
        lockstep = self._lockstep
        for direction, links in (("in", self._link_in), ("out", self._link_out)):
            link = links.get(slot)
            if link is not None:
                held = link.held
                if direction == "in" and lockstep is not None:  # a lockstep client's frames wait in its scheduler
                    endpoint = self.endpoint_at(slot)
                    counters = None if endpoint is None else lockstep.endpoint_counters(endpoint.name)
                    held += int(counters.get("held_in", 0)) if counters else 0
                out[direction] = {**link.counters.as_dict(), "held": held}
        return out

    # -- lifecycle ----------------------------------------------------------------------
    def start(self) -> None:
        """Open everything (failures are retried in the background)."""
        self._started_s = self._clock()
        self._sel.register(self._wake_r, selectors.EVENT_READ, self._on_wake)
        _LOG.info(
            "starting with %d endpoints%s",
            len(self.endpoints),
            f" and a TCP server on port {self.tcp_server.port}" if self.tcp_server else " (TCP server off)",
        )
        _LOG.debug("configuration: %s", json.dumps(as_dict(self.config), default=str))
        if self.tlog is not None and not self._armed_logging:
            self.tlog.start(self._clock())
        for endpoint in list(self.endpoints):
            endpoint.start()
        if self.tcp_server is not None:
            self.tcp_server.start()
        self._schedule_periodic(TICK_S, self._tick)
        if self._lockstep is not None and self._lockstep.invited:
            self._schedule_periodic(INVITE_EVERY_S, self._lockstep.invite)
        self._schedule_periodic(TLOG_FLUSH_S, self._flush_log)
        self._schedule_periodic(self.config.general.stats_interval_s, self._report_stats)

    def run(self) -> None:
        """Start (if needed) and loop until :meth:`request_stop`; then shut down cleanly."""
        if not self._started_s:
            self.start()
        try:
            while not self._stop:
                self.run_once()
        finally:
            self.shutdown()

    def run_once(self, max_wait_s: float = TICK_S) -> None:
        """One iteration: wait for I/O or the next timer, handle it."""
        timers = self._timers
        now = self._monotonic()
        timeout = max_wait_s
        if timers:
            timeout = min(timeout, max(0.0, timers[0][0] - now))
        if self._held_links:
            timeout = min(timeout, max(0.0, self._next_held_s()))
        for key, mask in self._sel.select(timeout):
            try:
                key.data(mask)
            except OSError as err:  # an I/O error the endpoint did not expect: keep routing
                _LOG.exception("I/O error while handling %s: %s", key.fileobj, err)
            if self._dirty:
                self._flush_dirty()
        now = self._monotonic()
        while timers and timers[0][0] <= now:
            _, _, timer = heapq.heappop(timers)
            if not timer.cancelled:
                timer.callback()
        if self._held_links and self._next_held_s() <= 0.0:
            self._release_held()
        if self._dirty:
            self._flush_dirty()

    def request_stop(self) -> None:
        """Ask the loop to stop (safe from a signal handler)."""
        self._stop = True
        with contextlib.suppress(OSError):
            self._wake_w.send(b"\0")

    @property
    def wakeup_fd(self) -> int:
        """A descriptor for ``signal.set_wakeup_fd`` so a signal ends ``select`` at once."""
        return self._wake_w.fileno()

    def _on_wake(self, mask: int) -> None:
        with contextlib.suppress(OSError):
            self._wake_r.recv(4096)

    def shutdown(self) -> None:
        """Flush and close every endpoint, the log and the stats file (idempotent)."""
        if self._shut_down:
            return
        self._shut_down = True
        _LOG.info("shutting down")
        self._flush_dirty()
        for endpoint in list(self.endpoints):
            endpoint.close()
        if self.tcp_server is not None:
            self.tcp_server.close()
        if self.tlog is not None:
            self.tlog.stop()
        self._report_stats(final=True)
        self._sel.close()
        self._wake_r.close()
        self._wake_w.close()

    # -- periodic work ------------------------------------------------------------------
    def _schedule_periodic(self, period_s: float, work: Callable[[], None]) -> None:
        def again() -> None:
            work()
            self.call_later(period_s, again)

        self.call_later(period_s, again)

    def _tick(self) -> None:
        now = self._monotonic()
        for endpoint in list(self.endpoints):
            endpoint.tick(now)
            if endpoint.stream and endpoint.slot >= 0:
                if self._lockstep is not None:
                    self._lockstep.frames(endpoint.slot, self.core.flush_parser(endpoint.slot))
                    continue
                wall = self._clock()
                routed = self.core.flush_idle(endpoint.slot, wall)
                if routed:
                    self._dispatch(endpoint.slot, routed, wall)

    def _flush_log(self) -> None:
        if self.tlog is not None:
            self.tlog.flush()

    def _on_arm_change(self) -> None:
        state = self.core.arm_state
        self._arm_seen = state
        if self.tlog is None or state is None:
            return
        if state.armed and not self.tlog.active:
            _LOG.info("system %d armed: starting a telemetry log", state.sysid)
            self.tlog.start(self._clock())
        elif not state.armed and self.tlog.active:
            _LOG.info("system %d disarmed: closing the telemetry log", state.sysid)
            self.tlog.stop()

    def snapshot(self) -> dict[str, object]:
        """Statistics of every endpoint as a JSON-friendly mapping."""
        now = self._clock()
        endpoints = []
        for endpoint in self.endpoints:
            stats = self.core.stats(endpoint.slot)
            learned = self.core.learned(endpoint.slot).sorted_pairs()
            entry: dict[str, object] = {
                **endpoint.status(),
                **stats.as_dict(),
                "last_seen_age_s": None if stats.last_rx_s is None else round(now - stats.last_rx_s, 3),
                "systems": [f"{s}/{c}" for s, c in learned],
            }
            link = self.link_counters(endpoint.slot)
            if link:
                entry["link"] = link
            lockstep = None if self._lockstep is None else self._lockstep.endpoint_counters(endpoint.name)
            if lockstep is not None:
                entry["lockstep"] = lockstep
            endpoints.append(entry)
        out: dict[str, object] = {
            "time": now,
            "uptime_s": round(now - self._started_s, 3),
            "msg_to_unknown": self.core.routing.msg_to_unknown,
            "tcp_server": None
            if self.tcp_server is None
            else {"port": self.tcp_server.port, "listening": self.tcp_server.listening},
            "tlog": None
            if self.tlog is None
            else {"path": str(self.tlog.path) if self.tlog.path else None, "frames": self.tlog.frames},
            "endpoints": endpoints,
            "closed_endpoints": self._closed_stats,
        }
        if self._lockstep is not None:
            out["lockstep"] = self._lockstep.snapshot()
        return out

    def _report_stats(self, *, final: bool = False) -> None:
        if self.config.general.report_stats or final:
            now = self._clock()
            for endpoint in self.endpoints:
                _STATS_LOG.info(
                    "%s%s",
                    "final: " if final else "",
                    format_stats_line(
                        endpoint.name,
                        endpoint.describe(),
                        self.core.stats(endpoint.slot),
                        now,
                        self.link_counters(endpoint.slot),
                        lockstep=None if self._lockstep is None else self._lockstep.endpoint_counters(endpoint.name),
                    ),
                )
        if self.stats_path is not None:
            self._write_stats_file(self.stats_path)

    def _write_stats_file(self, path: Path) -> None:
        tmp = path.with_name(path.name + ".tmp")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp.write_text(json.dumps(self.snapshot(), indent=2, default=str) + "\n", encoding="utf-8")
            os.replace(tmp, path)
        except OSError as err:
            _LOG.error("cannot write the stats file %s: %s", path, err)
