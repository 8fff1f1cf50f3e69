"""The router's lockstep: the deterministic schedule of the MAVLink step markers (pure).

docs/lockstep.md ("Router") and docs/mavlink_router.md ("Lockstep"). With ``[General] Lockstep = true`` the
autopilot endpoint's STEP markers are the router's clock: the step ``g`` and its simulation time ``t_g``.
:class:`LockstepScheduler` decides, from the markers alone (no clock, no socket; the shell executes the
:data:`Action` s it returns, in order):

* **Towards a lockstep client** (an endpoint that said HELLO(``L_c``); registered at the autopilot's current
  step ``r``, it gets STEP(``r``) back): what was routed to it during the autopilot's step ``g`` (between the
  autopilot's markers ``g - 1`` and ``g``) crosses its outbound lossy link at ``t_g``; at the autopilot's
  STEP(``g``) it gets what is due by ``t_g``, then STEP(``g``, ``t_g``, count). Clients in name order.
* **From a lockstep client**: its frames between its markers ``j - 1`` and ``j`` are its step ``j``; at its
  STEP(``j``) (count checked) each crosses its inbound lossy link at ``t_j`` (lost, or due at ``t_j`` plus the
  link's delay, jitter and reordering; decided in arrival order from the link's seeded generator).
* **Upstream**: the router sends the autopilot STEP(``g``) once it has the autopilot's STEP(``g``) and every
  client ``c`` has sent STEP(``g + 1 - L_c``) (a client registered at ``r`` has sent STEP(``r``)); just before,
  it releases every held client frame of a step ``j <= g + 1 - L_c`` due by ``t_g``, clients in name order,
  each client's in (due, arrival) order. Without clients (plain lockstep) STEP(``g``) goes up at once.

So which frames a client sees at step ``k``, and which of its frames the autopilot takes before grant ``g``,
are functions of the steps, the simulation times and the links' seeds only. Due times are compared with
:data:`DUE_TOLERANCE_S` of slack: simulation times are whole microseconds, and a delay added in floating point
(0.1 + 0.2) must not miss the step it lands on.

Also here: recognising a marker in a raw frame (:func:`marker_in`) and framing the router's own markers
(:func:`marker_frame`).
"""

from __future__ import annotations

import bisect
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

from mavlink_router.core.frames import MAVLINK2_HEADER_LEN, STX_V2, Frame, frame_header, x25_crc
from mavlink_router.core.impairment import LinkImpairment
from mavlink_router.errors import LockstepError
from uav_common.lockstep.markers import (
    MESSAGE_TYPE,
    V2_EXTENSION_ID,
    Marker,
    MarkerError,
    WireMarker,
    decode_wire_payload,
    encode_payload,
)

__all__ = [
    "DUE_TOLERANCE_S",
    "MAX_FRAMES_PER_STEP",
    "ROUTER_COMPONENT_ID",
    "ROUTER_SYSTEM_ID",
    "Action",
    "ClientStats",
    "Deliver",
    "LockstepScheduler",
    "MarkerToClient",
    "MarkerUpstream",
    "Release",
    "marker_frame",
    "marker_in",
]

FrameIn = TypeVar("FrameIn")  # a frame from a client (the shell's parsed frame)
FrameOut = TypeVar("FrameOut")  # a frame for a client (the shell's routed frame)

#: Who the router's own markers come from: system 1, MAV_COMP_ID_UDP_BRIDGE (they are consumed, never routed).
ROUTER_SYSTEM_ID = 1
ROUTER_COMPONENT_ID = 240
#: Slack on "due by t_g" (simulation times are whole microseconds).
DUE_TOLERANCE_S = 0.5e-6
#: A client that sends more frames than this without a STEP marker is broken (bounds what is kept).
MAX_FRAMES_PER_STEP = 100_000
_V2_EXTENSION_CRC_EXTRA = 8


# ---------------------------------------------------------------------------------------------- frames


def marker_in(frame: Frame) -> WireMarker | None:
    """The step marker a frame carries (``None``: any other frame).

    Raises:
        LockstepError: a malformed marker of ours (right message type and magic).
    """
    raw, msgid = frame[0], frame[1]
    if msgid != V2_EXTENSION_ID:
        return None
    _, _, _, _, offset = frame_header(raw)
    plen = raw[1]
    payload = raw[offset : offset + plen]
    if len(payload) < 2 or (payload[0] | payload[1] << 8) != MESSAGE_TYPE:
        return None
    try:
        return decode_wire_payload(payload)
    except MarkerError as err:
        msg = f"malformed lockstep marker from system {frame[2]} component {frame[3]}: {err}"
        raise LockstepError(msg) from err


def marker_frame(
    marker: Marker,
    *,
    seq: int,
    target: tuple[int, int],
    source: tuple[int, int] = (ROUTER_SYSTEM_ID, ROUTER_COMPONENT_ID),
) -> bytes:
    """A MAVLink 2 ``V2_EXTENSION`` frame carrying ``marker`` (trailing zero bytes truncated, as MAVLink 2 does)."""
    body = bytes((MESSAGE_TYPE & 0xFF, MESSAGE_TYPE >> 8, 0, target[0], target[1])) + encode_payload(marker)
    body = body.rstrip(b"\0") or body[:1]
    header = bytes(
        (STX_V2, len(body), 0, 0, seq & 0xFF, source[0], source[1], V2_EXTENSION_ID & 0xFF, V2_EXTENSION_ID >> 8, 0)
    )
    assert len(header) == MAVLINK2_HEADER_LEN
    crc = x25_crc(bytes((_V2_EXTENSION_CRC_EXTRA,)), x25_crc(header[1:] + body))
    return header + body + crc.to_bytes(2, "little")


# ---------------------------------------------------------------------------------------------- actions


@dataclass(frozen=True)
class Deliver(Generic[FrameOut]):
    """Send these frames to the lockstep client ``client`` (in this order)."""

    client: str
    frames: tuple[FrameOut, ...]


@dataclass(frozen=True)
class MarkerToClient:
    """Send ``marker`` to the lockstep client ``client``, addressed to ``target``."""

    client: str
    marker: Marker
    target: tuple[int, int]


@dataclass(frozen=True)
class Release(Generic[FrameIn]):
    """Route these frames of the lockstep client ``client`` now (to the autopilot and non-lockstep endpoints)."""

    client: str
    frames: tuple[FrameIn, ...]


@dataclass(frozen=True)
class MarkerUpstream:
    """Send the autopilot STEP(``step``, ``t_sim_us``); its count is what the shell sent it since its last one."""

    step: int
    t_sim_us: int


Action = Release[FrameIn] | Deliver[FrameOut] | MarkerToClient | MarkerUpstream


@dataclass
class ClientStats:
    """Counters of one lockstep client (the stats file)."""

    registered_at: int
    lookahead: int
    closed: int  # the last step it ended
    markers_in: int = 0
    markers_out: int = 0
    frames_in: int = 0  # frames of closed steps, offered to its inbound link
    frames_out: int = 0  # frames delivered to it
    held_in: int = 0  # its frames held now (a step not yet released, or not yet due)


@dataclass
class _Client(Generic[FrameIn, FrameOut]):
    name: str
    target: tuple[int, int]
    lookahead: int
    link_in: LinkImpairment[Any] | None
    link_out: LinkImpairment[FrameOut] | None
    stats: ClientStats
    inbound: list[FrameIn] = field(default_factory=list)  # since its previous marker
    held: list[tuple[float, int, int, int, FrameIn]] = field(default_factory=list)  # (due, seq, step, link seq, frame)
    pending_out: list[FrameOut] = field(default_factory=list)  # routed to it during the autopilot's current step
    next_seq: int = 0


class LockstepScheduler(Generic[FrameIn, FrameOut]):
    """The router's lockstep bookkeeping (see the module docstring); no clock, no socket.

    ``synced`` once the autopilot's first STEP marker (the answer to the router's HELLO) has arrived; before
    that the router routes as it always does, and clients that say HELLO wait to be registered.
    """

    def __init__(self) -> None:
        self.synced = False
        #: The autopilot's last STEP, and the last STEP sent upstream (the router's HELLO counts as the first).
        self.autopilot_step = 0
        self.upstream_step = 0
        self.steps_seen = 0  # autopilot STEP markers taken
        self.autopilot_frames = 0  # frames from the autopilot since its previous marker
        self._t_us: dict[int, int] = {}
        self._clients: dict[str, _Client[FrameIn, FrameOut]] = {}
        self._waiting: dict[str, _Client[FrameIn, FrameOut]] = {}  # said HELLO before the router was synced

    # ------------------------------------------------------------------ queries
    @property
    def t_sim_s(self) -> float:
        """The router's clock: the simulation time of the autopilot's last STEP (0 before any)."""
        return self._t_us.get(self.autopilot_step, 0) / 1e6

    def is_client(self, name: str) -> bool:
        """Is ``name`` a registered lockstep client?"""
        return name in self._clients

    def said_hello(self, name: str) -> bool:
        """Registered, or waiting for the router to be synced."""
        return name in self._clients or name in self._waiting

    def clients(self) -> dict[str, ClientStats]:
        """Every lockstep client's counters (registered ones), by name."""
        for client in self._clients.values():
            client.stats.held_in = len(client.held) + len(client.inbound)
        return {name: self._clients[name].stats for name in sorted(self._clients)}

    def waiting_for(self) -> list[str]:
        """The clients the next upstream STEP waits for, with the step it needs from each."""
        g = self.upstream_step + 1
        return [
            f"{c.name} (needs its STEP({g + 1 - c.lookahead}), has ended {c.stats.closed})"
            for c in self._ordered()
            if c.stats.closed < g + 1 - c.lookahead
        ]

    # ------------------------------------------------------------------ the autopilot
    def reset_autopilot(self) -> list[str]:
        """The autopilot connection is new (a reconnect): wait for its first STEP again. Registered clients are
        registered anew then, and see their steps jump (a gap: their error); returns their names."""
        dropped = sorted(self._clients)
        self._waiting.update(self._clients)
        for client in self._clients.values():
            client.inbound.clear()
            client.held.clear()
            client.pending_out.clear()
        self._clients.clear()
        self.synced = False
        self.autopilot_frames = 0
        self._t_us.clear()
        return dropped

    def autopilot_frame(self) -> None:
        """One frame (not a marker) came from the autopilot: it belongs to its next step."""
        self.autopilot_frames += 1

    def to_client(self, name: str, frame: FrameOut) -> bool:
        """Queue a frame routed to ``name`` for the next autopilot STEP (False: not a registered client)."""
        client = self._clients.get(name)
        if client is None:
            return False
        client.pending_out.append(frame)
        return True

    def autopilot_marker(self, marker: Marker) -> list[Action[FrameIn, FrameOut]]:
        """The autopilot's marker: the clients' deliveries and markers, in name order (then call :meth:`upstream`).

        Raises:
            LockstepError: a STEP for an unexpected step, or a count that does not balance.
        """
        if not marker.is_step:
            return []
        g = marker.step
        if not self.synced:
            return self._sync(g, marker.t_sim_us)
        expected = self.autopilot_step + 1
        if g != expected:
            msg = f"the autopilot sent {marker.describe()}, expected its STEP({expected})"
            raise LockstepError(msg)
        if marker.count != self.autopilot_frames:
            msg = (
                f"the autopilot says it sent {marker.count} messages in step {g}, {self.autopilot_frames} were "
                "received: a message was lost or duplicated (the run is no longer reproducible)"
            )
            raise LockstepError(msg)
        self.autopilot_frames = 0
        self.autopilot_step = g
        self.steps_seen += 1
        self._t_us[g] = marker.t_sim_us
        t_s = marker.t_sim_us / 1e6
        actions: list[Action[FrameIn, FrameOut]] = []
        for client in self._ordered():
            frames, client.pending_out = client.pending_out, []
            link = client.link_out
            if link is not None:
                out = link.offer_many(frames, t_s)
                out += link.due(t_s + DUE_TOLERANCE_S)
            else:
                out = frames
            if out:
                actions.append(Deliver(client.name, tuple(out)))
            client.stats.frames_out += len(out)
            actions.append(self._marker_to(client, Marker.end_of_step(g, marker.t_sim_us, len(out))))
        return actions

    def _sync(self, step: int, t_sim_us: int) -> list[Action[FrameIn, FrameOut]]:
        self.synced = True
        self.autopilot_step = self.upstream_step = step
        self.autopilot_frames = 0
        self._t_us = {step: t_sim_us}
        actions: list[Action[FrameIn, FrameOut]] = []
        for name in sorted(self._waiting):
            actions.extend(self._register(self._waiting.pop(name)))
        return actions

    def upstream(self) -> list[Action[FrameIn, FrameOut]]:
        """The client frames to release and the upstream STEP markers that are due now (possibly none)."""
        actions: list[Action[FrameIn, FrameOut]] = []
        while self.synced and self.upstream_step < self.autopilot_step:
            g = self.upstream_step + 1
            clients = self._ordered()
            if any(c.stats.closed < g + 1 - c.lookahead for c in clients):
                break
            t_s = self._t_us[g] / 1e6 + DUE_TOLERANCE_S
            for client in clients:
                released = self._release(client, g + 1 - client.lookahead, t_s)
                if released:
                    actions.append(Release(client.name, released))
            actions.append(MarkerUpstream(g, self._t_us[g]))
            self.upstream_step = g
            self._forget_times()
        return actions

    def _release(self, client: _Client[FrameIn, FrameOut], last_step: int, t_s: float) -> tuple[FrameIn, ...]:
        out: list[FrameIn] = []
        keep: list[tuple[float, int, int, int, FrameIn]] = []
        for entry in client.held:  # sorted by (due, seq)
            due, _, step, link_seq, frame = entry
            if step <= last_step and due <= t_s:
                out.append(frame)
                if client.link_in is not None:
                    client.link_in.delivered(link_seq)
            else:
                keep.append(entry)
        client.held = keep
        return tuple(out)

    def _forget_times(self) -> None:
        oldest = min([self.upstream_step, *(c.stats.closed for c in self._clients.values())])
        for step in [s for s in self._t_us if s < oldest]:
            del self._t_us[step]

    # ------------------------------------------------------------------ the clients
    def client_frame(self, name: str, frame: FrameIn) -> bool:
        """A frame (not a marker) from ``name``: kept for its next STEP (False: ``name`` did not say HELLO).

        Raises:
            LockstepError: more than :data:`MAX_FRAMES_PER_STEP` frames without a marker.
        """
        client = self._clients.get(name) or self._waiting.get(name)
        if client is None:
            return False
        if len(client.inbound) >= MAX_FRAMES_PER_STEP:
            msg = f"lockstep client {name} sent more than {MAX_FRAMES_PER_STEP} messages without a STEP marker"
            raise LockstepError(msg)
        client.inbound.append(frame)
        return True

    def client_hello(
        self,
        name: str,
        marker: Marker,
        target: tuple[int, int],
        *,
        link_in: LinkImpairment[Any] | None = None,
        link_out: LinkImpairment[FrameOut] | None = None,
    ) -> list[Action[FrameIn, FrameOut]]:
        """HELLO(``L``) from ``name`` (its frame's source is ``target``): registered at the autopilot's current
        step, which it gets back as STEP; before the router is synced, at its first STEP. A second HELLO
        registers it anew. ``link_in``/``link_out``: its lossy link (None: a perfect one)."""
        self._clients.pop(name, None)
        stats = ClientStats(registered_at=0, lookahead=marker.lookahead, closed=0)
        client: _Client[FrameIn, FrameOut] = _Client(name, target, marker.lookahead, link_in, link_out, stats)
        if not self.synced:
            self._waiting[name] = client
            return []
        return self._register(client)

    def _register(self, client: _Client[FrameIn, FrameOut]) -> list[Action[FrameIn, FrameOut]]:
        r = self.autopilot_step
        client.stats.registered_at = client.stats.closed = r
        self._clients[client.name] = client
        return [self._marker_to(client, Marker.end_of_step(r, self._t_us[r], 0))]

    def client_marker(self, name: str, marker: Marker) -> list[Action[FrameIn, FrameOut]]:
        """STEP(``j``) from ``name``: its step ``j`` is complete; returns what :meth:`upstream` now allows.

        Raises:
            LockstepError: a STEP for an unexpected step (a gap, a repeat, a step the router has not sent), or a
                count that does not balance.
        """
        client = self._clients.get(name)
        if client is None or not marker.is_step:
            return []
        j = marker.step
        expected = client.stats.closed + 1
        if j != expected:
            msg = f"lockstep client {name} sent {marker.describe()}, expected its STEP({expected})"
            raise LockstepError(msg)
        if j not in self._t_us:
            msg = f"lockstep client {name} sent STEP({j}) before the router sent it STEP({j})"
            raise LockstepError(msg)
        if marker.count != len(client.inbound):
            msg = (
                f"lockstep client {name}: step {j}: it says it sent {marker.count} messages, "
                f"{len(client.inbound)} were received: a message was lost or duplicated (the run is no longer "
                "reproducible)"
            )
            raise LockstepError(msg)
        t_s = self._t_us[j] / 1e6
        for frame in client.inbound:
            if client.link_in is None:
                entry = (t_s, client.next_seq, j, 0, frame)
            else:
                fate = client.link_in.judge(t_s)
                if fate is None:
                    continue
                entry = (fate[1], client.next_seq, j, fate[0], frame)
            client.next_seq += 1
            bisect.insort(client.held, entry)  # (due, seq) first: seq is unique, the frame is never compared
        client.stats.frames_in += len(client.inbound)
        client.inbound = []
        client.stats.closed = j
        client.stats.markers_in += 1
        return self.upstream()

    def remove_client(self, name: str) -> list[Action[FrameIn, FrameOut]]:
        """``name`` is gone (a TCP client disconnected): never waited for again; what :meth:`upstream` allows."""
        self._waiting.pop(name, None)
        if self._clients.pop(name, None) is None:
            return []
        return self.upstream()

    # ------------------------------------------------------------------ helpers
    def _ordered(self) -> list[_Client[FrameIn, FrameOut]]:
        return [self._clients[name] for name in sorted(self._clients)]

    def _marker_to(self, client: _Client[FrameIn, FrameOut], marker: Marker) -> MarkerToClient:
        client.stats.markers_out += 1
        return MarkerToClient(client.name, marker, client.target)

    def client_links(self) -> Mapping[str, tuple[LinkImpairment[Any] | None, LinkImpairment[FrameOut] | None]]:
        """Each registered client's lossy links (their counters are the endpoint's ``link`` statistics)."""
        return {c.name: (c.link_in, c.link_out) for c in self._clients.values()}
