"""The router's lockstep mode (``[General] Lockstep = true``): the shell around ``core/lockstep.py``.

:class:`LockstepRouting` sits between the endpoints and the routing core when the lockstep is on. It takes
the step markers out of every input (they are consumed, never routed nor written to the ``.tlog``; logged at
debug level), keeps the autopilot's frames of a step until its STEP marker (then routes them with the links'
clock at that step's simulation time), keeps the lockstep clients' frames for the scheduler, and executes the
scheduler's actions: deliveries and markers to the clients, releases of their frames, STEP markers upstream.
It says HELLO to the autopilot endpoint on every (re)connect, and invites the endpoints declared
``Lockstep = client`` (a HELLO every :data:`INVITE_EVERY_S` wall seconds until they say HELLO).

Every frame sent to a lockstep peer (the autopilot, a registered client) goes through one queue of its
endpoint (source :data:`LOCKSTEP_SOURCE`), so nothing overtakes a marker on a stream that backs up.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, Protocol

from mavlink_router.core.engine import Routed, RouterCore
from mavlink_router.core.frames import Frame
from mavlink_router.core.impairment import LinkImpairment
from mavlink_router.core.lockstep import (
    Deliver,
    LockstepScheduler,
    MarkerToClient,
    MarkerUpstream,
    Release,
    marker_frame,
    marker_in,
)
from mavlink_router.errors import LockstepError
from mavlink_router.shell.endpoints import Endpoint
from uav_common.lockstep.markers import Marker, WireMarker

__all__ = ["INVITE_EVERY_S", "LOCKSTEP_SOURCE", "LockstepRouting"]

_LOG = logging.getLogger("mavlink_router.lockstep")

#: Wall seconds between the router's HELLO invitations to a ``Lockstep = client`` endpoint.
INVITE_EVERY_S = 1.0
#: The source slot of every frame the router queues for a lockstep peer (one FIFO per endpoint).
LOCKSTEP_SOURCE = -1
#: The router's own lookahead (docs/lockstep.md: 1).
ROUTER_LOOKAHEAD = 1
_BROADCAST = (0, 0)

Outbound = tuple[bytes, int]  # (frame, source slot), what Endpoint.send takes


class LockstepHost(Protocol):
    """What the lockstep needs from the main loop (:class:`~mavlink_router.shell.mainloop.Router`)."""

    core: RouterCore

    def endpoint_at(self, slot: int) -> Endpoint | None: ...
    def dispatch(self, slot: int, routed: list[Routed], now: float, *, link_s: float | None = None) -> None: ...
    def release_held(self, link_s: float, *, all_held: bool = False) -> None: ...
    def release_held_of(self, slot: int) -> None: ...
    def links_of(self, slot: int) -> tuple[LinkImpairment[Any] | None, LinkImpairment[Outbound] | None]: ...


class LockstepRouting:
    """The lockstep's routing (see the module docstring). ``clock``: the wall clock (UNIX seconds)."""

    def __init__(self, host: LockstepHost, *, autopilot_slot: int, clock: Callable[[], float]) -> None:
        self.host = host
        self.autopilot_slot = autopilot_slot
        self.invited: set[int] = set()
        self.scheduler: LockstepScheduler[Frame, Outbound] = LockstepScheduler()
        self._clock = clock
        self.upstream_sent = 0  # frames sent to the autopilot since the router's previous marker (its HELLO)
        self.markers_upstream = 0
        self.hellos_upstream = 0
        self._autopilot_ids = _BROADCAST
        self._step_frames: list[Frame] = []  # the autopilot's frames of its current step (once synced)
        self._seq: dict[int, int] = {}  # per destination slot: the sequence numbers of the router's markers
        self._slot_of: dict[str, int] = {}

    # ------------------------------------------------------------------ queries
    @property
    def link_s(self) -> float | None:
        """The lossy links' clock: the simulation time of the autopilot's last STEP (None before it: wall time)."""
        return self.scheduler.t_sim_s if self.scheduler.synced else None

    def is_client_slot(self, slot: int) -> bool:
        endpoint = self.host.endpoint_at(slot)
        return endpoint is not None and self.scheduler.is_client(endpoint.name)

    def snapshot(self) -> dict[str, object]:
        s = self.scheduler
        return {
            "synced": s.synced,
            "autopilot_step": s.autopilot_step,
            "upstream_step": s.upstream_step,
            "steps_seen": s.steps_seen,
            "t_sim_s": s.t_sim_s,
            "markers_upstream": self.markers_upstream,
            "hellos_upstream": self.hellos_upstream,
            "waiting_for": s.waiting_for(),
            "clients": {name: vars(stats) for name, stats in s.clients().items()},
        }

    def endpoint_counters(self, name: str) -> dict[str, int] | None:
        """The lockstep counters of endpoint ``name`` for its stats entry (None: not a lockstep peer)."""
        if name == self._autopilot_name():
            return {"steps_seen": self.scheduler.steps_seen, "markers_sent": self.markers_upstream}
        stats = self.scheduler.clients().get(name)
        return None if stats is None else dict(vars(stats))

    def _autopilot_name(self) -> str:
        endpoint = self.host.endpoint_at(self.autopilot_slot)
        return "" if endpoint is None else endpoint.name

    # ------------------------------------------------------------------ input
    def deliver(self, slot: int, data: bytes) -> None:
        """Bytes read on endpoint ``slot`` (instead of ``RouterCore.ingest``)."""
        self.frames(slot, self.host.core.parse(slot, data))

    def frames(self, slot: int, frames: list[Frame]) -> None:
        """Parsed frames of endpoint ``slot``, in order: markers, the autopilot's and the clients' frames are
        taken; runs of other frames are routed as usual (lossy links on simulated time once synced).

        Raises:
            LockstepError: a marker or a count that breaks the lockstep (the message names the endpoint).
        """
        if not frames:
            return
        endpoint = self.host.endpoint_at(slot)
        if endpoint is None:
            return
        name = endpoint.name
        scheduler = self.scheduler
        batch: list[Frame] = []
        try:
            for frame in frames:
                wire = marker_in(frame)
                if wire is not None:
                    self._route_batch(slot, batch)
                    batch = []
                    self._on_marker(slot, name, frame, wire)
                elif slot == self.autopilot_slot and scheduler.synced:
                    scheduler.autopilot_frame()
                    self._step_frames.append(frame)
                elif not scheduler.client_frame(name, frame):
                    batch.append(frame)
        except LockstepError as err:
            msg = f"lockstep broken on endpoint {name}: {err}"
            raise LockstepError(msg) from err
        self._route_batch(slot, batch)

    def _route_batch(self, slot: int, batch: list[Frame]) -> None:
        if batch:
            now = self._clock()
            link_s = self.link_s
            self.host.dispatch(slot, self.host.core.process(slot, batch, now, link_s=link_s), now, link_s=link_s)

    def _on_marker(self, slot: int, name: str, frame: Frame, wire: WireMarker) -> None:
        marker = wire.marker
        _LOG.debug("%s: %s", name, marker.describe())
        scheduler = self.scheduler
        if slot == self.autopilot_slot:
            if not marker.is_step:
                return
            self._autopilot_ids = (frame[2], frame[3])
            was_synced = scheduler.synced
            if was_synced:  # the autopilot's frames of this step, stamped with its time
                frames, self._step_frames = self._step_frames, []
                now = self._clock()
                routed = self.host.core.route_frames(slot, frames, now)
                self.host.dispatch(slot, routed, now, link_s=marker.t_sim_us / 1e6)
            self._execute(scheduler.autopilot_marker(marker))
            if not was_synced:
                _LOG.info("lockstep: the autopilot (%s) is at step %d: routing on simulated time", name, marker.step)
                self.host.release_held(scheduler.t_sim_s, all_held=True)  # what wall-clock links held goes now
            else:
                self.host.release_held(scheduler.t_sim_s)
            self._execute(scheduler.upstream())
            return
        if marker.is_hello:
            registered = scheduler.synced
            self._slot_of[name] = slot
            self.host.release_held_of(slot)
            link_in, link_out = self.host.links_of(slot)
            self._execute(
                scheduler.client_hello(name, marker, (frame[2], frame[3]), link_in=link_in, link_out=link_out)
            )
            if registered:
                _LOG.info(
                    "lockstep client %s: %s, registered at step %d", name, marker.describe(), scheduler.autopilot_step
                )
            else:
                _LOG.info("lockstep client %s: %s, registered at the autopilot's first step", name, marker.describe())
            return
        if not scheduler.is_client(name):
            _LOG.warning("%s sent %s without HELLO: ignored", name, marker.describe())
            return
        self._execute(scheduler.client_marker(name, marker))

    # ------------------------------------------------------------------ output
    def take(self, source: int, dest: int, frame: bytes) -> bool:
        """A frame routed from ``source`` to ``dest``: True when the lockstep takes it (the caller sends nothing).

        To the autopilot it goes at once, counted, in its FIFO; to a registered client it waits for the next
        autopilot STEP; from one registered client to another it is dropped (they do not hear each other).
        """
        if dest == self.autopilot_slot:
            endpoint = self.host.endpoint_at(dest)
            if endpoint is not None:
                endpoint.send(frame, LOCKSTEP_SOURCE)
                self.upstream_sent += 1
            return True
        endpoint = self.host.endpoint_at(dest)
        if endpoint is None or not self.scheduler.is_client(endpoint.name):
            return False
        if self.is_client_slot(source):
            return True
        self.scheduler.to_client(endpoint.name, (frame, source))
        return True

    def _execute(self, actions: list[Any]) -> None:
        for action in actions:
            if isinstance(action, Deliver):
                endpoint = self._client(action.client)
                if endpoint is not None:
                    for frame, _source in action.frames:
                        endpoint.send(frame, LOCKSTEP_SOURCE)
            elif isinstance(action, MarkerToClient):
                endpoint = self._client(action.client)
                if endpoint is not None:
                    self._send_marker(endpoint, action.marker, action.target)
            elif isinstance(action, Release):
                slot = self._slot_of.get(action.client)
                if slot is not None and self.host.endpoint_at(slot) is not None:
                    now = self._clock()
                    routed = self.host.core.route_frames(slot, list(action.frames), now)
                    self.host.dispatch(slot, routed, now, link_s=self.scheduler.t_sim_s)
            elif isinstance(action, MarkerUpstream):
                self._upstream(action)

    def _upstream(self, action: MarkerUpstream) -> None:
        endpoint = self.host.endpoint_at(self.autopilot_slot)
        if endpoint is None:
            return
        marker = Marker.end_of_step(action.step, action.t_sim_us, self.upstream_sent)
        self._send_marker(endpoint, marker, self._autopilot_ids)
        self.upstream_sent = 0
        self.markers_upstream += 1

    def _send_marker(self, endpoint: Endpoint, marker: Marker, target: tuple[int, int]) -> None:
        seq = self._seq.get(endpoint.slot, 0)
        self._seq[endpoint.slot] = (seq + 1) & 0xFF
        endpoint.send(marker_frame(marker, seq=seq, target=target), LOCKSTEP_SOURCE)
        _LOG.debug("to %s: %s", endpoint.name, marker.describe())

    def _client(self, name: str) -> Endpoint | None:
        slot = self._slot_of.get(name)
        return None if slot is None else self.host.endpoint_at(slot)

    # ------------------------------------------------------------------ lifecycle
    def connected(self, endpoint: Endpoint) -> None:
        """An endpoint (re)connected: the autopilot gets the router's HELLO (and the lockstep starts anew)."""
        if endpoint.slot != self.autopilot_slot:
            return
        affected = self.scheduler.reset_autopilot()
        if affected:
            _LOG.error(
                "lockstep: the autopilot endpoint %s reconnected: the steps of the lockstep clients %s will jump "
                "(their runs are no longer reproducible)",
                endpoint.name,
                ", ".join(affected),
            )
        self._step_frames = []
        self._send_marker(endpoint, Marker.hello(ROUTER_LOOKAHEAD), _BROADCAST)
        self.upstream_sent = 0
        self.hellos_upstream += 1
        _LOG.info("lockstep: said HELLO to the autopilot endpoint %s", endpoint.name)

    def invite(self) -> None:
        """HELLO to every connected ``Lockstep = client`` endpoint that has not said HELLO (called every second)."""
        for slot in sorted(self.invited):
            endpoint = self.host.endpoint_at(slot)
            if endpoint is not None and endpoint.connected and not self.scheduler.said_hello(endpoint.name):
                self._send_marker(endpoint, Marker.hello(ROUTER_LOOKAHEAD), _BROADCAST)

    def lost(self, endpoint: Endpoint) -> None:
        """A dynamic endpoint (a TCP server client) closed: a lockstep client among them is waited for no more."""
        if self.scheduler.said_hello(endpoint.name):
            _LOG.error("lockstep client %s disconnected: no longer waited for", endpoint.name)
            self._execute(self.scheduler.remove_client(endpoint.name))
            self._slot_of.pop(endpoint.name, None)
