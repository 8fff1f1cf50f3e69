"""The router's functional core: bytes in, ``(frame, destinations)`` out (pure).

:class:`RouterCore` owns, per endpoint slot, a :class:`~mavlink_router.core.frames.FrameParser`,
the inbound filters, the optional signature verifier and the statistics, plus the
shared :class:`~mavlink_router.core.routing.RoutingTable` and de-duplicator. The shell
(:mod:`mavlink_router.shell.mainloop`) reads sockets, calls :meth:`RouterCore.ingest`
with the bytes and the current time, and writes each returned frame, unchanged,
to the returned destination slots.

Per received frame, in mavlink-router's order: CRC (known IDs) -> de-duplication
-> inbound filters -> signature policy -> learn the source -> route. An endpoint with a
lossy inbound link (:mod:`mavlink_router.core.impairment`) loses, delays and reorders its
frames right after framing, as the radio in front of it would: a lost frame never reached
the router; a held one is processed when :meth:`RouterCore.release_inbound` finds it due.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from mavlink_router.core.dedup import Deduplicator
from mavlink_router.core.frames import Frame, FrameParser, MessageSpec, frame_header
from mavlink_router.core.impairment import LinkImpairment
from mavlink_router.core.routing import Filters, Learned, RoutingTable
from mavlink_router.core.signing import SignatureCheck, SignatureVerifier

__all__ = ["ArmState", "EndpointStats", "Routed", "RouterCore", "SigningPolicy"]

HEARTBEAT_ID = 0
MAV_AUTOPILOT_INVALID = 8
MAV_MODE_FLAG_SAFETY_ARMED = 128

Routed = tuple[bytes, tuple[int, ...]]
"""A frame accepted for routing and the slots to write it to (possibly none)."""


class EndpointStats:
    """Counters of one endpoint. The shell adds the ``tx_*`` counts as it writes."""

    __slots__ = (
        "bad_signature_drops",
        "crc_errors",
        "dedup_drops",
        "garbage_bytes",
        "in_filtered",
        "last_rx_s",
        "out_filtered",
        "replay_drops",
        "rx_bytes",
        "rx_msgs",
        "seq_lost",
        "tx_bytes",
        "tx_drops",
        "tx_msgs",
        "unsigned_drops",
    )

    def __init__(self) -> None:
        self.rx_msgs = 0
        self.rx_bytes = 0
        self.crc_errors = 0
        self.garbage_bytes = 0
        self.seq_lost = 0
        self.dedup_drops = 0
        self.in_filtered = 0
        self.unsigned_drops = 0
        self.bad_signature_drops = 0
        self.replay_drops = 0
        self.out_filtered = 0
        self.tx_msgs = 0
        self.tx_bytes = 0
        self.tx_drops = 0
        self.last_rx_s: float | None = None

    def as_dict(self) -> dict[str, int | float | None]:
        return {name: getattr(self, name) for name in sorted(self.__slots__)}


@dataclass(frozen=True)
class SigningPolicy:
    """Require valid signatures on inbound messages with these IDs (others pass)."""

    key: bytes
    protected_msg_ids: frozenset[int]


@dataclass(frozen=True)
class ArmState:
    """The vehicle's armed flag, as last announced by its autopilot's HEARTBEAT."""

    sysid: int
    armed: bool


class _Endpoint:
    __slots__ = (
        "crc_mark",
        "garbage_mark",
        "idle_mark",
        "in_filter",
        "last_seq",
        "link_in",
        "name",
        "parser",
        "protected",
        "stats",
        "verifier",
    )

    def __init__(
        self,
        name: str,
        parser: FrameParser,
        in_filter: Filters | None,
        signing: SigningPolicy | None,
        link_in: LinkImpairment[Frame] | None = None,
    ) -> None:
        self.name = name
        self.parser = parser
        self.link_in = link_in
        self.in_filter = in_filter
        self.verifier = SignatureVerifier(signing.key) if signing is not None else None
        self.protected: frozenset[int] = signing.protected_msg_ids if signing is not None else frozenset()
        self.stats = EndpointStats()
        self.last_seq: dict[int, int] = {}
        self.crc_mark = 0
        self.garbage_mark = 0
        self.idle_mark = 0


class RouterCore:
    """Parse, check, learn and route; no sockets, no clocks (``now_s`` is passed in).

    Args:
        table: the message table (:func:`mavlink_router.shell.dialect.load_message_table`).
        dedup_period_s: de-duplication window, 0 = off.
        sniffer_sysid: mavlink-router's ``SnifferSysid`` (0 = off).
        log_system_id: the autopilot whose HEARTBEAT gives the armed state; ``None``
            = the first system that sends a HEARTBEAT from component 1 or with an
            autopilot type other than ``MAV_AUTOPILOT_INVALID``.
    """

    def __init__(
        self,
        table: Mapping[int, MessageSpec],
        *,
        dedup_period_s: float = 0.0,
        sniffer_sysid: int = 0,
        log_system_id: int | None = None,
    ) -> None:
        self._table = dict(table)
        self.routing = RoutingTable(sniffer_sysid=sniffer_sysid)
        self._dedup = Deduplicator(dedup_period_s) if dedup_period_s > 0 else None
        self._eps: dict[int, _Endpoint] = {}
        self._log_system_id = log_system_id
        self.arm_state: ArmState | None = None

    # -- endpoints -----------------------------------------------------------------
    def add_endpoint(
        self,
        name: str,
        *,
        stream: bool,
        in_filter: Filters | None = None,
        out_filter: Filters | None = None,
        group: str = "",
        ignore_comp_id: bool = False,
        signing: SigningPolicy | None = None,
        link_in: LinkImpairment[Frame] | None = None,
    ) -> int:
        """Register an endpoint and return its slot (``link_in``: the lossy link its frames arrive over)."""
        index = self.routing.add_endpoint(out_filter=out_filter, group=group, ignore_comp_id=ignore_comp_id)
        parser = FrameParser(self._table, stream=stream)
        in_filter = None if in_filter is None or in_filter.empty else in_filter
        self._eps[index] = _Endpoint(name, parser, in_filter, signing, link_in)
        return index

    def link_in(self, index: int) -> LinkImpairment[Frame] | None:
        """The lossy inbound link of endpoint ``index`` (None: a perfect one)."""
        return self._eps[index].link_in

    def release_inbound(self, index: int, now_s: float, *, link_s: float | None = None) -> list[Routed]:
        """Process the frames held by endpoint ``index``'s lossy inbound link that are due at ``now_s``.

        ``link_s``: the links' clock when it is not ``now_s`` (the simulation time, in lockstep).
        """
        ep = self._eps[index]
        if ep.link_in is None:
            return []
        frames = ep.link_in.due(now_s if link_s is None else link_s)
        return self._route_frames(index, ep, frames, now_s) if frames else []

    def remove_endpoint(self, index: int) -> EndpointStats:
        """Unregister a slot (its learned systems go with it); returns its final stats."""
        ep = self._eps.pop(index)
        self.routing.remove_endpoint(index)
        return ep.stats

    def stats(self, index: int) -> EndpointStats:
        return self._eps[index].stats

    def learned(self, index: int) -> Learned:
        return self.routing.learned(index)

    def pending_bytes(self, index: int) -> int:
        """Bytes of endpoint ``index`` held back waiting for the rest of a frame."""
        return self._eps[index].parser.pending_bytes

    def reset_stream(self, index: int) -> None:
        """Drop a partial frame of a stream endpoint (after a reconnect)."""
        self._eps[index].parser.reset()

    # -- the hot path --------------------------------------------------------------
    def ingest(self, index: int, data: bytes, now_s: float) -> list[Routed]:
        """Process bytes received on endpoint ``index`` at UNIX time ``now_s``.

        Returns every frame accepted for routing (for the telemetry log too) with
        the slots it must be written to.
        """
        return self.process(index, self.parse(index, data), now_s)

    def flush_idle(self, index: int, now_s: float) -> list[Routed]:
        """Call periodically: if no byte arrived on ``index`` since the last call, flush its parser.

        See :meth:`mavlink_router.core.frames.FrameParser.flush` (streams only hold data back).
        """
        return self.process(index, self.flush_parser(index), now_s)

    def parse(self, index: int, data: bytes) -> list[Frame]:
        """The frames in bytes received on endpoint ``index`` (framing and CRC only; :meth:`process` routes them).

        The lockstep (``core/lockstep.py``) takes its markers, and its clients' frames, out in between.
        """
        ep = self._eps[index]
        frames = ep.parser.feed(data)
        self._count_parser(ep)
        return frames

    def flush_parser(self, index: int) -> list[Frame]:
        """:meth:`flush_idle` without processing: the frames a stream's parser held back, if it has been idle."""
        ep = self._eps[index]
        parser = ep.parser
        if parser.pending_bytes == 0 or parser.bytes_in != ep.idle_mark:
            ep.idle_mark = parser.bytes_in
            return []
        frames = parser.flush()
        self._count_parser(ep)
        return frames

    def process(self, index: int, frames: list[Frame], now_s: float, *, link_s: float | None = None) -> list[Routed]:
        """Frames of endpoint ``index`` through its lossy inbound link (at ``link_s``, default ``now_s``), then
        :meth:`route_frames` for those that are due."""
        ep = self._eps[index]
        if ep.link_in is not None and frames:
            frames = ep.link_in.offer_many(frames, now_s if link_s is None else link_s)
        if not frames:
            return []
        return self._route_frames(index, ep, frames, now_s)

    def route_frames(self, index: int, frames: list[Frame], now_s: float) -> list[Routed]:
        """Frames of endpoint ``index`` that have crossed its link: filters, signatures, learning, routing."""
        return self._route_frames(index, self._eps[index], frames, now_s) if frames else []

    @staticmethod
    def _count_parser(ep: _Endpoint) -> None:
        stats = ep.stats
        parser = ep.parser
        if parser.crc_errors != ep.crc_mark:
            stats.crc_errors += parser.crc_errors - ep.crc_mark
            ep.crc_mark = parser.crc_errors
        if parser.garbage_bytes != ep.garbage_mark:
            stats.garbage_bytes += parser.garbage_bytes - ep.garbage_mark
            ep.garbage_mark = parser.garbage_bytes

    def _route_frames(self, index: int, ep: _Endpoint, frames: list[Frame], now_s: float) -> list[Routed]:  # noqa: PLR0912
        stats = ep.stats
        dedup = self._dedup
        in_filter = ep.in_filter
        verifier = ep.verifier
        protected = ep.protected
        routing = self.routing
        learned = routing.learned(index).pairs
        last_seq = ep.last_seq
        out: list[Routed] = []
        for raw, msgid, sysid, compid, seq, tsys, tcomp in frames:
            if dedup is not None and not dedup.is_new(raw, now_s):
                stats.dedup_drops += 1
                continue
            if in_filter is not None and not in_filter.allows(msgid, sysid, compid):
                stats.in_filtered += 1
                continue
            if verifier is not None and msgid in protected:
                check = verifier.check(raw, now_s)
                if check is not SignatureCheck.OK:
                    if check is SignatureCheck.UNSIGNED:
                        stats.unsigned_drops += 1
                    elif check is SignatureCheck.BAD_SIGNATURE:
                        stats.bad_signature_drops += 1
                    else:
                        stats.replay_drops += 1
                    continue
            stats.rx_msgs += 1
            stats.rx_bytes += len(raw)
            pair = sysid << 8 | compid
            previous = last_seq.get(pair)
            if previous is not None:
                gap = (seq - previous - 1) & 0xFF
                if gap:
                    stats.seq_lost += gap
            last_seq[pair] = seq
            if pair not in learned:
                routing.learn(index, sysid, compid)
            if msgid == HEARTBEAT_ID:
                self._watch_heartbeat(raw, sysid, compid)
            dests, filtered = routing.route(index, msgid, sysid, compid, tsys, tcomp)
            for slot in filtered:
                self._eps[slot].stats.out_filtered += 1
            out.append((raw, dests))
        stats.last_rx_s = now_s
        return out

    def _watch_heartbeat(self, raw: bytes, sysid: int, compid: int) -> None:
        _, _, _, _, payload = frame_header(raw)
        plen = raw[1]  # MAVLink 2 may truncate trailing zero bytes of the payload
        autopilot = raw[payload + 5] if plen > 5 else 0
        base_mode = raw[payload + 6] if plen > 6 else 0
        wanted = self._log_system_id
        if wanted is None:
            if self.arm_state is not None:
                wanted = self.arm_state.sysid
            elif compid == 1 or autopilot != MAV_AUTOPILOT_INVALID:
                wanted = sysid
        if sysid != wanted or (compid != 1 and autopilot == MAV_AUTOPILOT_INVALID):
            return
        armed = bool(base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
        if self.arm_state is None or self.arm_state.armed != armed:
            self.arm_state = ArmState(sysid, armed)
