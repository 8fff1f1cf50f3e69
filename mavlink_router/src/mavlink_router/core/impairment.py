"""A lossy radio link in front of one endpoint: drop, delay and reorder frames (pure).

A telemetry radio loses packets, often several in a row (a fade), delays them and now and
then delivers them out of order. :class:`LinkImpairment` decides, frame by frame, what
happens to each MAVLink frame that crosses one endpoint's link; the router's shell asks it
what to deliver and when. Nothing here reads a clock or owns randomness: the time is passed
in and the uniform random numbers come from a generator the caller seeds (``uniform``), so
the same seed and the same traffic give the same losses.

The model:

* **Loss** — ``loss_pct`` of the frames are lost on average. With ``loss_burst = 0`` each
  frame is lost independently. With ``loss_burst = L`` losses come in bursts of ``L``
  frames on average (a two-state Gilbert model: in the *bad* state every frame is lost,
  the bad state ends after each frame with probability ``1 / L``, and it begins with the
  probability that keeps the long-run loss at ``loss_pct``).
* **Delay** — every delivered frame is held ``delay_ms`` plus a uniform ``[0, jitter_ms]``.
  Jitter alone can reorder frames, as it does on a real link.
* **Reordering** — ``reorder_pct`` of the delivered frames are held ``reorder_delay_ms`` more,
  so frames sent after them overtake them.

Counters: ``offered``, ``dropped``, ``delayed`` (held for any time > 0), ``reordered``
(delivered after a frame that was offered later: the reordering that actually happened),
``delivered``.
"""

from __future__ import annotations

import enum
import heapq
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Generic, TypeVar

from uav_common.validate import require_in_range

__all__ = ["ImpairmentConfig", "ImpairmentCounters", "LinkDirection", "LinkImpairment"]

T = TypeVar("T")


class LinkDirection(enum.Enum):
    """Which frames of an endpoint cross the impaired link."""

    BOTH = "both"
    IN = "in"  # frames the router receives from the endpoint
    OUT = "out"  # frames the router sends to the endpoint

    @property
    def inbound(self) -> bool:
        return self is not LinkDirection.OUT

    @property
    def outbound(self) -> bool:
        return self is not LinkDirection.IN


@dataclass(frozen=True)
class ImpairmentConfig:
    """One endpoint's link (``LossPercent``, ``LossBurst``, ... in the router's configuration file)."""

    loss_pct: float = 0.0
    loss_burst: float = 0.0
    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    reorder_pct: float = 0.0
    reorder_delay_ms: float = 50.0
    direction: LinkDirection = LinkDirection.BOTH
    seed: int = 0

    def __post_init__(self) -> None:
        """The one check of a link's values (the scenario layer's ``link`` keys are checked by it too).

        Raises:
            ValueError: a value out of range (naming it), or a mean burst too short for the loss rate.
        """
        require_in_range("loss_pct", self.loss_pct, 0.0, 100.0)
        require_in_range("reorder_pct", self.reorder_pct, 0.0, 100.0)
        for name in ("delay_ms", "jitter_ms", "reorder_delay_ms"):
            require_in_range(name, getattr(self, name), 0.0, 60_000.0)
        require_in_range("loss_burst", self.loss_burst, 0.0, 1e6)
        if self.loss_burst > 0.0 and 0.0 < self.loss_pct < 100.0:
            least = max(1.0, self.loss_pct / (100.0 - self.loss_pct))
            if self.loss_burst < least:
                msg = (
                    f"loss_burst {self.loss_burst:g} is too short for loss_pct {self.loss_pct:g}: a mean burst of "
                    f"at least {least:.3g} frames is needed (0 = independent losses)"
                )
                raise ValueError(msg)

    @property
    def active(self) -> bool:
        """Does this link change anything at all?"""
        return self.loss_pct > 0.0 or self.delay_ms > 0.0 or self.jitter_ms > 0.0 or self.reorder_pct > 0.0

    @property
    def holds(self) -> bool:
        """Can a frame be held for later (so the shell must come back for it)?"""
        return self.delay_ms > 0.0 or self.jitter_ms > 0.0 or (self.reorder_pct > 0.0 and self.reorder_delay_ms > 0.0)


@dataclass
class ImpairmentCounters:
    offered: int = 0
    dropped: int = 0
    delayed: int = 0
    reordered: int = 0
    delivered: int = 0

    def as_dict(self) -> dict[str, int]:
        return {
            "offered": self.offered,
            "dropped": self.dropped,
            "delayed": self.delayed,
            "reordered": self.reordered,
            "delivered": self.delivered,
        }


class LinkImpairment(Generic[T]):
    """Decides the fate of each item (a frame, with whatever the shell needs) crossing one link direction.

    Args:
        config: the link's settings.
        uniform: a seeded source of uniform numbers in ``[0, 1)`` (e.g. ``random.Random(seed).random``).
    """

    def __init__(self, config: ImpairmentConfig, uniform: Callable[[], float]) -> None:
        self.config = config
        self._uniform = uniform
        self.counters = ImpairmentCounters()
        self._loss = config.loss_pct / 100.0
        self._reorder = config.reorder_pct / 100.0
        self._delay_s = config.delay_ms / 1000.0
        self._jitter_s = config.jitter_ms / 1000.0
        self._reorder_s = config.reorder_delay_ms / 1000.0
        burst = config.loss_burst
        self._bursty = burst > 0.0 and 0.0 < self._loss < 1.0
        self._end_burst = 1.0 / burst if self._bursty else 1.0
        self._start_burst = self._loss * self._end_burst / (1.0 - self._loss) if self._bursty else 0.0
        self._in_burst = False
        self._queue: list[tuple[float, int, T]] = []
        self._seq = 0
        self._released_seq = -1

    @property
    def next_due_s(self) -> float:
        """When the next held item is due (``inf`` if none)."""
        return self._queue[0][0] if self._queue else math.inf

    @property
    def held(self) -> int:
        return len(self._queue)

    def offer(self, item: T, now_s: float) -> list[T]:
        """``item`` crosses the link at ``now_s``; returns every item due by then (this one included if so)."""
        self._admit(item, now_s)
        return self.due(now_s)

    def offer_many(self, items: Iterable[T], now_s: float) -> list[T]:
        """:meth:`offer` for several items arriving together (in order)."""
        for item in items:
            self._admit(item, now_s)
        return self.due(now_s)

    def due(self, now_s: float) -> list[T]:
        """The held items whose time has come, in delivery order."""
        queue = self._queue
        out: list[T] = []
        while queue and queue[0][0] <= now_s:
            _, seq, item = heapq.heappop(queue)
            self.delivered(seq)
            out.append(item)
        return out

    def judge(self, now_s: float) -> tuple[int, float] | None:
        """Decide the fate of one item crossing the link at ``now_s`` without holding it here.

        Returns ``(seq, due_s)``: its place in the offering order and when it is due, or ``None``: lost. Counts
        it as offered (dropped, delayed); the caller holds it and calls :meth:`delivered` when it delivers it
        (the router's lockstep holds client frames by step as well as by time, see ``core/lockstep.py``).
        The same random numbers are drawn as by :meth:`offer`, in the same order.
        """
        counters = self.counters
        counters.offered += 1
        seq = self._seq
        self._seq += 1
        if self._lost():
            counters.dropped += 1
            return None
        hold = self._delay_s
        if self._jitter_s > 0.0:
            hold += self._jitter_s * self._uniform()
        if self._reorder > 0.0 and self._uniform() < self._reorder:
            hold += self._reorder_s
        if hold > 0.0:
            counters.delayed += 1
        return seq, now_s + hold

    def delivered(self, seq: int) -> None:
        """Count the delivery of the item :meth:`judge` numbered ``seq`` (reordered if a later one went first)."""
        counters = self.counters
        if seq < self._released_seq:
            counters.reordered += 1
        else:
            self._released_seq = seq
        counters.delivered += 1

    def _admit(self, item: T, now_s: float) -> None:
        fate = self.judge(now_s)
        if fate is not None:
            heapq.heappush(self._queue, (fate[1], fate[0], item))

    def _lost(self) -> bool:
        loss = self._loss
        if loss <= 0.0:
            return False
        if loss >= 1.0:
            return True
        if not self._bursty:
            return self._uniform() < loss
        if self._in_burst:
            if self._uniform() < self._end_burst:
                self._in_burst = False
        elif self._uniform() < self._start_burst:
            self._in_burst = True
        return self._in_burst
