"""The SITL's lockstep peers: MAVLink step markers on the vehicle links (docs/lockstep.md, "SITL").

A peer (a TCP client, a UDP address) becomes a *lockstep peer* when it says HELLO while the SITL runs in
lockstep (``time.mode: lockstep``); the SITL answers STEP(its current step, count 0). From then on:

* every message the peer sends is queued, never handled as it arrives. The peer's STEP(``j``) marker closes
  its step ``j``: its count must be the number of messages (whole frames, handled or not) that came since the
  peer's previous marker, else the run stops (:class:`~sitl.errors.LockstepError`: a lost or duplicated
  message; the run is no longer reproducible);
* before executing grant ``g`` the simulator waits until every lockstep peer has closed step ``g - 1`` (a
  peer registered at step ``r`` has closed ``r``) and handles exactly the messages of the steps it has closed,
  peers in the order they said HELLO, each peer's in arrival order (:meth:`LockstepPeers.release`);
* after the grant's state and telemetry, every lockstep peer gets STEP(``g``, ``t_g``, messages sent to it
  since the previous marker) (:meth:`LockstepPeers.end_step`).

A peer's lookahead (its HELLO) is recorded but the SITL waits for STEP(``g - 1``) from every peer: the router
applies its clients' lookaheads. A TCP peer that disconnects is logged as an error and waited for no more; a
UDP peer that says HELLO again is registered again. In free-running mode a HELLO is answered with nothing
(logged once) and markers are dropped.

This module does no I/O of its own: :class:`PeerIo` sends the markers and reads the links' counters
(:class:`LinkPeerIo` on the real links; the unit tests give a fake).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from sitl.errors import LockstepError
from sitl.shell.links import MavLink, Received, frame_only
from uav_common.lockstep.markers import MESSAGE_TYPE, Marker, MarkerError, decode_payload, encode_payload

__all__ = ["LinkPeerIo", "LockstepPeers", "PeerIo"]

log = logging.getLogger(__name__)


class PeerIo(Protocol):
    """What the bookkeeping needs from the links."""

    def send_marker(self, route: Hashable, marker: Marker, target: tuple[int, int]) -> None: ...
    def sent_count(self, route: Hashable) -> int: ...
    def pin(self, route: Hashable) -> None: ...
    def unpin(self, route: Hashable) -> None: ...
    def describe(self, route: Hashable) -> str: ...


@dataclass
class _Peer:
    route: Hashable
    name: str
    target: tuple[int, int]  # the HELLO's source: where the markers are addressed
    lookahead: int
    registered_at: int
    closed: int  # the last step the peer closed with a marker (its HELLO closes registered_at)
    sent_base: int  # the link's sent counter for this peer right after our previous marker
    current: list[Received] = field(default_factory=list)  # since its previous marker (step closed + 1)
    ready: list[tuple[int, list[Received]]] = field(default_factory=list)  # closed steps not yet handled
    markers_in: int = 0
    markers_out: int = 0


class LockstepPeers:
    """Marker bookkeeping of every lockstep peer (see the module docstring).

    Args:
        lockstep: the SITL runs in lockstep (else HELLO is ignored).
        io: the links.
        t_sim_us: the simulation time now (for the HELLO's answer).
    """

    def __init__(self, *, lockstep: bool, io: PeerIo, t_sim_us: Callable[[], int]) -> None:
        self.lockstep = lockstep
        self.io = io
        self._t_sim_us = t_sim_us
        #: Grants executed (the step whose state is current).
        self.step = 0
        self._peers: dict[Hashable, _Peer] = {}  # in the order they said HELLO
        self._free_hello_logged = False
        self.markers_in = 0
        self.markers_out = 0

    # ------------------------------------------------------------------ inbound
    def offer(self, rx: Received) -> bool:
        """Take ``rx`` if it is a marker or a lockstep peer's message (True); else the caller handles it now.

        Raises:
            LockstepError: a malformed marker, a marker for an unexpected step, or a count that does not balance.
        """
        msg = rx.msg
        marker = _marker(msg, rx.route, self.io)
        if marker is not None:
            self._on_marker(rx.route, marker, (msg.get_srcSystem(), msg.get_srcComponent()))
            return True
        peer = self._peers.get(rx.route)
        if peer is None:
            return False
        peer.current.append(rx)
        return True

    def _on_marker(self, route: Hashable, marker: Marker, source: tuple[int, int]) -> None:
        if marker.is_hello:
            self._hello(route, marker, source)
            return
        peer = self._peers.get(route)
        if peer is None:
            log.warning("%s sent %s without HELLO: ignored", self.io.describe(route), marker.describe())
            return
        expected = peer.closed + 1
        if marker.step != expected:
            msg = (
                f"lockstep peer {peer.name}: expected its STEP({expected}) marker, got {marker.describe()} "
                f"({len(peer.current)} messages since its previous marker)"
            )
            raise LockstepError(msg)
        if marker.count != len(peer.current):
            msg = (
                f"lockstep peer {peer.name}: step {marker.step}: it says it sent {marker.count} messages, "
                f"{len(peer.current)} were received: a message was lost or duplicated, the run is no longer "
                "reproducible"
            )
            raise LockstepError(msg)
        peer.ready.append((marker.step, peer.current))
        peer.current = []
        peer.closed = marker.step
        peer.markers_in += 1
        self.markers_in += 1

    def _hello(self, route: Hashable, marker: Marker, source: tuple[int, int]) -> None:
        name = self.io.describe(route)
        if not self.lockstep:
            if not self._free_hello_logged:
                self._free_hello_logged = True
                log.info("%s said lockstep HELLO: not answered, the SITL runs free (time.mode: free)", name)
            return
        old = self._peers.pop(route, None)
        if old is not None:
            log.warning("lockstep peer %s said HELLO again: registered anew at step %d", name, self.step)
        self.io.pin(route)
        peer = _Peer(route, name, source, marker.lookahead, self.step, self.step, 0)
        self._peers[route] = peer
        self._send(peer, Marker.end_of_step(self.step, self._t_sim_us(), 0))
        log.info("lockstep peer %s registered at step %d (%s)", name, self.step, marker.describe())

    def forget(self, route: Hashable) -> None:
        """``route``'s peer is gone (a TCP client disconnected): never waited for again."""
        peer = self._peers.pop(route, None)
        if peer is not None:
            self.io.unpin(route)
            log.error(
                "lockstep peer %s disconnected after closing step %d: the SITL runs on without it (a run that "
                "needed it is no longer reproducible)",
                peer.name,
                peer.closed,
            )

    # ------------------------------------------------------------------ the grant
    def ready(self, step: int) -> bool:
        """Has every lockstep peer closed ``step``?"""
        return all(p.closed >= step for p in self._peers.values())

    def waiting_for(self, step: int) -> str:
        """Who has not closed ``step`` yet (for the log)."""
        late = [
            f"{p.name} (closed step {p.closed}, {len(p.current)} messages since)"
            for p in self._peers.values()
            if p.closed < step
        ]
        return ", ".join(late) or "nobody"

    def release(self, step: int) -> list[Received]:
        """The messages of every step up to ``step`` the peers have closed, to handle now (see module doc)."""
        out: list[Received] = []
        for peer in self._peers.values():
            keep: list[tuple[int, list[Received]]] = []
            for closed, messages in peer.ready:
                if closed <= step:
                    out.extend(rx for rx in messages if not frame_only(rx.msg))
                else:
                    keep.append((closed, messages))
            peer.ready = keep
        return out

    def end_step(self, step: int, t_sim_us: int) -> None:
        """Grant ``step`` is executed and its telemetry flushed: STEP(``step``) to every lockstep peer."""
        self.step = step
        for peer in list(self._peers.values()):
            count = self.io.sent_count(peer.route) - peer.sent_base
            self._send(peer, Marker.end_of_step(step, t_sim_us, count))

    def _send(self, peer: _Peer, marker: Marker) -> None:
        self.io.send_marker(peer.route, marker, peer.target)
        peer.sent_base = self.io.sent_count(peer.route)  # the marker itself is not counted
        peer.markers_out += 1
        self.markers_out += 1

    # ------------------------------------------------------------------ queries
    def routes(self) -> frozenset[Hashable]:
        """The lockstep peers' routes (nothing timed by the wall clock goes to them)."""
        return frozenset(self._peers)

    def __len__(self) -> int:
        return len(self._peers)

    def summary(self) -> str:
        """One log line: the peers, their last closed step and the markers counted."""
        peers = "; ".join(
            f"{p.name}: closed {p.closed}, markers in {p.markers_in} out {p.markers_out}" for p in self._peers.values()
        )
        return f"lockstep step {self.step}, {len(self._peers)} peer(s){': ' + peers if peers else ''}"


def _marker(msg: Any, route: Hashable, io: PeerIo) -> Marker | None:
    if msg.get_type() != "V2_EXTENSION" or msg.message_type != MESSAGE_TYPE:
        return None
    try:
        return decode_payload(bytes(msg.payload), message_type=msg.message_type)
    except MarkerError as err:
        text = f"malformed lockstep marker from {io.describe(route)}: {err}"
        raise LockstepError(text) from err


class LinkPeerIo:
    """:class:`PeerIo` on the vehicle links (routes ``(link name, peer)``), markers built by ``factory``."""

    def __init__(self, links: Mapping[str, MavLink], factory: Any) -> None:
        self.links = links
        self.factory = factory

    def _link(self, route: Hashable) -> MavLink:
        assert isinstance(route, tuple)
        return self.links[route[0]]

    def send_marker(self, route: Hashable, marker: Marker, target: tuple[int, int]) -> None:
        msg = self.factory.v2_extension_encode(0, target[0], target[1], MESSAGE_TYPE, encode_payload(marker))
        link = self._link(route)
        link.send(msg, route)
        link.flush()

    def sent_count(self, route: Hashable) -> int:
        return self._link(route).sent_count(route)

    def pin(self, route: Hashable) -> None:
        self._link(route).pin(route)

    def unpin(self, route: Hashable) -> None:
        self._link(route).unpin(route)

    def describe(self, route: Hashable) -> str:
        if not isinstance(route, tuple) or len(route) != 2:
            return str(route)
        name, peer = route
        link = self.links.get(name)
        clients = getattr(link, "clients", None)
        if isinstance(clients, dict) and peer in clients:
            host, port = clients[peer].addr
            return f"{name} link TCP client {host}:{port}"
        if isinstance(peer, tuple) and len(peer) == 2:
            return f"{name} link UDP peer {peer[0]}:{peer[1]}"
        return f"{name} link peer {peer}"
