"""The causal lockstep's bookkeeping (docs/lockstep.md), pure: the step master's barrier, a subscriber's counted
inputs, and the service requests due at step boundaries.

Nothing here reads a clock, owns a thread or talks to ROS: the shells (``uav_common.ros.lockstep`` and the sim
bridge, the C++ twin in ``uav_mapping``) feed it what arrived and ask it what to do. Every decision is a function
of step numbers and counts only, which is what makes a run reproducible whatever the machine's load.

Counts are cumulative from start-up and keyed ``(topic, publisher)``; a participant reports its own as
``{topic: count}`` (the publisher is the participant).
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Generic, TypeVar

from uav_common.errors import UavCommonError

__all__ = [
    "BoundaryQueue",
    "InputLedger",
    "LockstepError",
    "Manifest",
    "Missing",
    "StepBarrier",
    "Tick",
    "Waiting",
]

Key = tuple[str, str]  # (topic, publisher)
M = TypeVar("M")
R = TypeVar("R")


class LockstepError(UavCommonError):
    """The causal lockstep cannot go on reproducibly: a lost or duplicated message, a participant out of step, a
    late join. The message names who and what; the run must stop (a watchdog never lets a step through)."""


@dataclass(frozen=True)
class Manifest:
    """What a participant declares when it joins (docs/lockstep.md, "What each participant declares").
    ``lookahead_steps`` 0 makes it static: its start-up counts are all it ever publishes, nobody waits for it."""

    node: str
    lookahead_steps: int
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    timers: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.node:
            msg = "a participant needs a node name"
            raise LockstepError(msg)
        if self.lookahead_steps < 0:
            msg = f"{self.node}: lookahead_steps must be >= 1 (or 0: static, no steps), got {self.lookahead_steps}"
            raise LockstepError(msg)

    @property
    def static(self) -> bool:
        """A participant that publishes only before the first step and never steps (e.g. static transforms)."""
        return self.lookahead_steps == 0


@dataclass(frozen=True)
class Tick:
    """Step ``step`` at simulation time ``t_s``: each consumer takes, per (topic, publisher), messages up to
    ``counts[(topic, publisher)]``. ``participants`` are the publishers whose messages are counted."""

    step: int
    t_s: float
    counts: Mapping[Key, int]
    participants: frozenset[str]


@dataclass(frozen=True)
class Waiting:
    """A participant the master is waiting for before it may grant the next step."""

    node: str
    needs_step: int
    done_step: int


@dataclass
class _Participant:
    manifest: Manifest
    done_step: int = 0
    #: (step, counts) for the steps a future tick may still need, oldest first; step 0 = the join counts.
    history: deque[tuple[int, dict[str, int]]] = field(default_factory=deque)


class StepBarrier:
    """The step master's side: joins, dones, whether the next step may be granted, and each tick's counts.

    ``step`` is the last step the master has published (0 before the first). The master may grant step
    ``step + 1`` once every participant ``p`` is done with ``step + 1 - L_p`` (:meth:`can_grant`).
    """

    def __init__(self, master: str) -> None:
        self.master = master
        self.step = 0
        self.started = False
        self._parts: dict[str, _Participant] = {}
        self._master_counts: dict[str, int] = {}

    # ---------------------------------------------------------------- membership
    def join(self, manifest: Manifest, published: Mapping[str, int]) -> None:
        """Register a participant with what it published before the first step.

        Raises:
            LockstepError: the run has started, the name is the master's, or counts are negative.
        """
        if self.started:
            msg = (
                f"{manifest.node} asked to join the causal lockstep at step {self.step}, after the run started; "
                "a participant must be up before the first step (list it in /lockstep/participants)"
            )
            raise LockstepError(msg)
        if manifest.node == self.master:
            msg = f"{manifest.node} is the step master; it cannot join as a participant"
            raise LockstepError(msg)
        _check_counts(manifest.node, published)
        self._parts[manifest.node] = _Participant(manifest, 0, deque([(0, dict(published))]))

    def start(self) -> None:
        self.started = True

    @property
    def participants(self) -> tuple[str, ...]:
        return tuple(sorted(self._parts))

    def manifest(self, node: str) -> Manifest:
        return self._parts[node].manifest

    def missing(self, expected: Iterable[str]) -> list[str]:
        """The expected participants that have not joined yet."""
        return sorted(n for n in expected if n not in self._parts)

    # ---------------------------------------------------------------- progress
    def done(self, node: str, step: int, published: Mapping[str, int]) -> None:
        """``node`` finished ``step`` having published ``published`` (cumulative per topic).

        Raises:
            LockstepError: an unknown node, a step out of order or not yet granted, or counts going backwards.
        """
        part = self._parts.get(node)
        if part is None:
            msg = f"a done for step {step} from {node}, which has not joined the causal lockstep"
            raise LockstepError(msg)
        if part.manifest.static or step != part.done_step + 1 or step > self.step:
            msg = (
                f"{node} reported done with step {step}, but its last step was {part.done_step} and the master is "
                f"at step {self.step}: steps must be finished one by one, in order"
            )
            raise LockstepError(msg)
        _check_counts(node, published)
        last = part.history[-1][1]
        back = sorted(t for t, n in last.items() if published.get(t, 0) < n)
        if back:
            msg = f"{node}'s counts went backwards at step {step} on {back}: it restarted or lost its state"
            raise LockstepError(msg)
        part.done_step = step
        part.history.append((step, dict(published)))

    def waiting(self) -> list[Waiting]:
        """Who holds up step ``step + 1`` (empty: it may be granted)."""
        nxt = self.step + 1
        out = []
        for name in sorted(self._parts):
            part = self._parts[name]
            if part.manifest.static:
                continue
            needs = nxt - part.manifest.lookahead_steps
            if part.done_step < needs:
                out.append(Waiting(name, needs, part.done_step))
        return out

    def can_grant(self) -> bool:
        return self.started and not self.waiting()

    def tick(self, t_s: float, master_counts: Mapping[str, int]) -> Tick:
        """The master published step ``step + 1`` (its counts ``master_counts`` include the step's state):
        the tick to publish.

        Raises:
            LockstepError: the step was not grantable (a shell bug) or the master's counts went backwards.
        """
        if not self.can_grant():
            held = ", ".join(f"{w.node} (needs {w.needs_step}, done {w.done_step})" for w in self.waiting())
            msg = f"step {self.step + 1} published while waiting for {held or 'the start'}"
            raise LockstepError(msg)
        back = sorted(t for t, n in self._master_counts.items() if master_counts.get(t, 0) < n)
        if back:
            msg = f"the master's counts went backwards on {back}"
            raise LockstepError(msg)
        self.step += 1
        k = self.step
        self._master_counts = dict(master_counts)
        counts: dict[Key, int] = {(t, self.master): n for t, n in master_counts.items() if n > 0}
        for name, part in self._parts.items():
            want = 0 if part.manifest.static else k - part.manifest.lookahead_steps
            # Drop what no later tick can need (their `want` only grows), keeping the entry at `want`.
            while len(part.history) > 1 and part.history[1][0] <= want:
                part.history.popleft()
            step, published = part.history[0]
            if step > max(want, 0):  # cannot happen: history starts at 0 and keeps every step after it
                msg = f"{name}: no counts for step {want}"
                raise LockstepError(msg)
            counts.update({(t, name): n for t, n in published.items() if n > 0})
        names = frozenset(self._parts) | {self.master}
        return Tick(k, t_s, counts, names)


def _check_counts(node: str, published: Mapping[str, int]) -> None:
    bad = sorted(t for t, n in published.items() if n < 0)
    if bad:
        msg = f"{node} reported negative counts on {bad}"
        raise LockstepError(msg)


# ---------------------------------------------------------------------------------------------- subscriber side


@dataclass(frozen=True)
class Missing:
    """A subscriber is short of messages from one publisher on one topic at a tick."""

    topic: str
    publisher: str
    expected: int
    received: int


class InputLedger(Generic[M]):
    """A participant's counted inputs: one FIFO per (topic, publisher), taken exactly up to each tick's counts.

    ``topics`` are its lockstep input topics in dispatch order (priority topics first). Messages from publishers
    that are not participants (:attr:`Tick.participants`) are "foreign": dispatched after the counted ones, in
    arrival order, at the step in which they are taken.
    """

    def __init__(self, topics: Iterable[str]) -> None:
        self.topics: tuple[str, ...] = tuple(dict.fromkeys(topics))
        self._order = {t: i for i, t in enumerate(self.topics)}
        self._fifo: dict[Key, deque[M]] = {}
        self._taken: dict[Key, int] = {}
        self._foreign: list[tuple[int, str, M]] = []
        self._pending: list[tuple[int, str, str, M]] = []  # unclassified until the first tick names participants
        self._participants: frozenset[str] | None = None
        self._seq = itertools.count()
        self._keys_for: tuple[Key, ...] | None = None
        self._keys_cache: list[Key] = []

    def add_topic(self, topic: str, *, first: bool = False) -> None:
        """Declare one more input topic (``first``: dispatched before the others, like tf)."""
        if topic in self._order:
            return
        self.topics = (topic, *self.topics) if first else (*self.topics, topic)
        self._order = {t: i for i, t in enumerate(self.topics)}
        self._keys_for = None

    def received(self, topic: str, publisher: str, msg: M) -> None:
        """A message arrived (any thread; the shell serialises calls)."""
        if self._participants is None:
            self._pending.append((next(self._seq), topic, publisher, msg))
            return
        self._file(next(self._seq), topic, publisher, msg)

    def _file(self, seq: int, topic: str, publisher: str, msg: M) -> None:
        assert self._participants is not None
        if publisher in self._participants:
            self._fifo.setdefault((topic, publisher), deque()).append(msg)
        else:
            self._foreign.append((seq, topic, msg))

    def _learn(self, tick: Tick) -> None:
        if self._participants == tick.participants:
            return
        self._participants = tick.participants
        pending, self._pending = self._pending, []
        for seq, topic, publisher, msg in pending:
            self._file(seq, topic, publisher, msg)

    def missing(self, tick: Tick) -> list[Missing]:
        """What the inputs lack before ``tick`` can be dispatched (empty: ready).

        Raises:
            LockstepError: more messages taken from a publisher than its count (a duplicate, or a publisher that
                restarted): the run is no longer reproducible.
        """
        self._learn(tick)
        out = []
        for key in self._keys(tick):
            topic, publisher = key
            expected = tick.counts[key]
            taken = self._taken.get(key, 0)
            if expected < taken:
                msg = (
                    f"{topic} from {publisher}: the tick of step {tick.step} counts {expected} messages but "
                    f"{taken} were already taken (a duplicate message, or the publisher restarted)"
                )
                raise LockstepError(msg)
            have = taken + len(self._fifo.get(key, ()))
            if have < expected:
                out.append(Missing(topic, publisher, expected, have))
        return sorted(out, key=lambda m: (m.topic, m.publisher))

    def take(self, tick: Tick) -> list[tuple[str, M]]:
        """The step's inputs in dispatch order: counted ones by topic, publisher, arrival; then foreign ones.

        Raises:
            LockstepError: the inputs are not complete (call :meth:`missing` first) or counts went backwards.
        """
        short = self.missing(tick)
        if short:
            m = short[0]
            msg = f"step {tick.step}: {m.topic} from {m.publisher}: {m.received} of {m.expected} messages"
            raise LockstepError(msg)
        out: list[tuple[str, M]] = []
        for key in self._keys(tick):
            n = tick.counts[key] - self._taken.get(key, 0)
            fifo = self._fifo.get(key)
            for _ in range(n):
                assert fifo is not None
                out.append((key[0], fifo.popleft()))
            self._taken[key] = tick.counts[key]
        foreign, self._foreign = self._foreign, []
        out.extend((topic, msg) for _, topic, msg in foreign)
        return out

    def _keys(self, tick: Tick) -> list[Key]:
        """The tick's (topic, publisher) keys of this subscriber's topics, in dispatch order (cached per key set:
        it changes only when a publisher first publishes on a topic)."""
        ident = tuple(tick.counts)
        if ident != self._keys_for:
            order = self._order
            self._keys_cache = sorted((k for k in tick.counts if k[0] in order), key=lambda k: (order[k[0]], k[1]))
            self._keys_for = ident
        return self._keys_cache

    def held(self) -> int:
        """Messages received and not yet dispatched (a publisher ahead of the ticks)."""
        return sum(len(f) for f in self._fifo.values()) + len(self._foreign) + len(self._pending)


# ---------------------------------------------------------------------------------------------- services


@dataclass(order=True)
class _Request(Generic[R]):
    apply_after: int
    seq: int
    item: R = field(compare=False)


class BoundaryQueue(Generic[R]):
    """Service requests waiting for their step boundary (docs/lockstep.md, "Services between participants").

    A request for boundary ``S | S+1`` is applied once the server has finished step ``S`` and before it starts
    ``S + 1``; requests of one boundary go in arrival order.
    """

    def __init__(self) -> None:
        self._heap: list[_Request[R]] = []
        self._seq = itertools.count()

    def put(self, apply_after: int, item: R) -> None:
        heapq.heappush(self._heap, _Request(apply_after, next(self._seq), item))

    def due(self, finished_step: int) -> list[R]:
        """The requests whose boundary is at or before the end of ``finished_step``, in order."""
        out = []
        while self._heap and self._heap[0].apply_after <= finished_step:
            out.append(heapq.heappop(self._heap).item)
        return out

    def __len__(self) -> int:
        return len(self._heap)
