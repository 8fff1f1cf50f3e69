"""Routing table and routing decisions, with mavlink-router's semantics (pure).

Each endpoint learns the ``(sysid, compid)`` pairs it has received from. A
message from endpoint *S* is offered to every other endpoint *E*, which
(``Endpoint::accept_msg`` in mavlink-router):

1. rejects it if *E* has seen the message's *source* pair (loop prevention);
2. drops it if *E*'s outgoing filters do not allow it (counted as filtered);
3. accepts it if ``target_system`` is 0 (broadcast) or absent (no target field,
   or an unknown message ID);
4. accepts it if ``target_component > 0`` and *E* has seen exactly
   ``(target_system, target_component)``;
5. accepts it if ``target_component`` is 0 or absent and *E* has seen any
   component of ``target_system``;
6. accepts it if *E* has ``IgnoreCompId`` set and has seen ``target_system``;
7. accepts it if a sniffer system ID is configured and *E* has seen it;
8. otherwise rejects it.

The source endpoint itself is never offered the message (nothing is echoed).
Endpoints in the same *group* share one learned set (redundant links to one
vehicle). Decisions are cached per ``(source, src pair, msgid, targets)``; the
cache is cleared whenever something is learned or an endpoint comes or goes.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

from mavlink_router.core.frames import NO_TARGET

__all__ = ["AcceptState", "Filters", "Learned", "RoutingTable", "accept_msg"]

_CACHE_LIMIT = 16384


@dataclass(frozen=True)
class Filters:
    """Allow/Block lists of one direction of one endpoint (empty = no restriction).

    A message passes if each non-empty allow list contains its value and no
    block list does, for the message ID, the source system and the source
    component (mavlink-router's ``AllowMsgIdOut``/``BlockSrcSysIn``/... keys).
    """

    allow_msg_ids: frozenset[int] = frozenset()
    block_msg_ids: frozenset[int] = frozenset()
    allow_src_systems: frozenset[int] = frozenset()
    block_src_systems: frozenset[int] = frozenset()
    allow_src_comps: frozenset[int] = frozenset()
    block_src_comps: frozenset[int] = frozenset()

    @property
    def empty(self) -> bool:
        return not (
            self.allow_msg_ids
            or self.block_msg_ids
            or self.allow_src_systems
            or self.block_src_systems
            or self.allow_src_comps
            or self.block_src_comps
        )

    def allows(self, msgid: int, src_sys: int, src_comp: int) -> bool:
        if self.allow_msg_ids and msgid not in self.allow_msg_ids:
            return False
        if msgid in self.block_msg_ids:
            return False
        if self.allow_src_comps and src_comp not in self.allow_src_comps:
            return False
        if src_comp in self.block_src_comps:
            return False
        if self.allow_src_systems and src_sys not in self.allow_src_systems:
            return False
        return src_sys not in self.block_src_systems


@dataclass
class Learned:
    """The systems seen behind an endpoint (or a group of endpoints)."""

    pairs: set[int] = field(default_factory=set)
    """``sysid << 8 | compid`` of every source seen."""
    systems: set[int] = field(default_factory=set)

    def has_pair(self, sysid: int, compid: int) -> bool:
        return (sysid << 8 | compid) in self.pairs

    def sorted_pairs(self) -> list[tuple[int, int]]:
        return sorted((pair >> 8, pair & 0xFF) for pair in self.pairs)


class AcceptState(enum.Enum):
    ACCEPTED = "accepted"
    FILTERED = "filtered"
    REJECTED = "rejected"


def accept_msg(  # noqa: PLR0911 - one return per rule, mirroring Endpoint::accept_msg
    learned: Learned,
    out_filter: Filters | None,
    *,
    msgid: int,
    src_sys: int,
    src_comp: int,
    target_sys: int,
    target_comp: int,
    ignore_comp_id: bool = False,
    sniffer_sysid: int = 0,
) -> AcceptState:
    """Would an endpoint with ``learned`` systems take this message? (rules 1-8 above)."""
    if (src_sys << 8 | src_comp) in learned.pairs:
        return AcceptState.REJECTED
    if out_filter is not None and not out_filter.allows(msgid, src_sys, src_comp):
        return AcceptState.FILTERED
    if target_sys in (0, NO_TARGET):
        return AcceptState.ACCEPTED
    if target_comp > 0 and (target_sys << 8 | target_comp) in learned.pairs:
        return AcceptState.ACCEPTED
    if target_comp in (0, NO_TARGET) and target_sys in learned.systems:
        return AcceptState.ACCEPTED
    if ignore_comp_id and target_sys in learned.systems:
        return AcceptState.ACCEPTED
    if sniffer_sysid and sniffer_sysid in learned.systems:
        return AcceptState.ACCEPTED
    return AcceptState.REJECTED


@dataclass
class _Slot:
    learned: Learned
    out_filter: Filters | None
    ignore_comp_id: bool
    group: str


class RoutingTable:
    """Endpoints (by integer slot), what each has learned, and cached decisions."""

    def __init__(self, *, sniffer_sysid: int = 0) -> None:
        self._slots: list[_Slot | None] = []
        self._active: list[int] = []
        self._groups: dict[str, Learned] = {}
        self._cache: dict[tuple[int, int, int, int, int], tuple[tuple[int, ...], tuple[int, ...]]] = {}
        self._sniffer = sniffer_sysid
        self.msg_to_unknown = 0
        """Messages that no endpoint accepted or filtered (mavlink-router's counter)."""

    def add_endpoint(self, *, out_filter: Filters | None = None, group: str = "", ignore_comp_id: bool = False) -> int:
        """Register an endpoint; returns its slot number (reusing freed slots)."""
        learned = self._groups.setdefault(group, Learned()) if group else Learned()
        slot = _Slot(learned, None if out_filter is None or out_filter.empty else out_filter, ignore_comp_id, group)
        try:
            index = self._slots.index(None)
            self._slots[index] = slot
        except ValueError:
            index = len(self._slots)
            self._slots.append(slot)
        self._active = [i for i, s in enumerate(self._slots) if s is not None]
        self._cache.clear()
        return index

    def remove_endpoint(self, index: int) -> None:
        """Forget an endpoint (a TCP client that disconnected) and what it learned."""
        self._slot(index)
        self._slots[index] = None
        self._active = [i for i, s in enumerate(self._slots) if s is not None]
        self._cache.clear()

    def learned(self, index: int) -> Learned:
        return self._slot(index).learned

    def learn(self, index: int, sysid: int, compid: int) -> bool:
        """Record that ``(sysid, compid)`` lives behind endpoint ``index``; ``True`` if new."""
        learned = self._slot(index).learned
        pair = sysid << 8 | compid
        if pair in learned.pairs:
            return False
        learned.pairs.add(pair)
        learned.systems.add(sysid)
        self._cache.clear()
        return True

    def route(  # noqa: PLR0917 - positional on the hot path
        self, source: int, msgid: int, src_sys: int, src_comp: int, target_sys: int, target_comp: int
    ) -> tuple[tuple[int, ...], tuple[int, ...]]:
        """``(destinations, filtered)``: slots that take the message, and slots whose filters dropped it."""
        key = (source, src_sys << 8 | src_comp, msgid, target_sys, target_comp)
        hit = self._cache.get(key)
        if hit is None:
            hit = self._decide(source, msgid, src_sys, src_comp, target_sys, target_comp)
            if len(self._cache) >= _CACHE_LIMIT:
                self._cache.clear()
            self._cache[key] = hit
        if not hit[0] and not hit[1]:
            self.msg_to_unknown += 1
        return hit

    def _decide(  # noqa: PLR0917
        self, source: int, msgid: int, src_sys: int, src_comp: int, target_sys: int, target_comp: int
    ) -> tuple[tuple[int, ...], tuple[int, ...]]:
        dests: list[int] = []
        filtered: list[int] = []
        for index in self._active:
            if index == source:
                continue
            slot = self._slots[index]
            assert slot is not None  # _active lists live slots only
            state = accept_msg(
                slot.learned,
                slot.out_filter,
                msgid=msgid,
                src_sys=src_sys,
                src_comp=src_comp,
                target_sys=target_sys,
                target_comp=target_comp,
                ignore_comp_id=slot.ignore_comp_id,
                sniffer_sysid=self._sniffer,
            )
            if state is AcceptState.ACCEPTED:
                dests.append(index)
            elif state is AcceptState.FILTERED:
                filtered.append(index)
        return tuple(dests), tuple(filtered)

    def _slot(self, index: int) -> _Slot:
        slot = self._slots[index] if 0 <= index < len(self._slots) else None
        if slot is None:
            msg = f"no endpoint in routing slot {index}"
            raise KeyError(msg)
        return slot
