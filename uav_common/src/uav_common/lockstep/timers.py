"""Timers in simulated time, fired from the step (docs/lockstep.md, "Steps and time"), pure.

A timer of period ``P`` fires once at the first step whose time reaches its due time, then its due time moves
on by whole periods past that step: a 20 Hz timer in 10 Hz steps fires once a step, never twice back to back
(rospy's timers fire catch-up calls at the same time, roscpp's skip ticks when time jumps; neither is a
function of the step alone).
"""

from __future__ import annotations

import math

__all__ = ["SimTimer"]


class SimTimer:
    """Due first at ``first_due_s`` (default: one period after time 0), then every ``period_s``."""

    def __init__(self, period_s: float, *, first_due_s: float | None = None, name: str = "") -> None:
        if not (math.isfinite(period_s) and period_s > 0.0):
            msg = f"timer {name or '?'}: period_s must be a positive number of seconds, got {period_s}"
            raise ValueError(msg)
        self.period_s = float(period_s)
        self.name = name
        self.next_due_s = self.period_s if first_due_s is None else float(first_due_s)
        self.fired = 0

    def due(self, t_s: float) -> bool:
        """Fire at ``t_s``? (Advances the timer when it does.) Times must not go backwards."""
        # A small tolerance: step times are sums of float steps, due times sums of float periods.
        if t_s + 1e-9 < self.next_due_s:
            return False
        behind = math.floor((t_s + 1e-9 - self.next_due_s) / self.period_s)
        self.next_due_s += (behind + 1) * self.period_s
        self.fired += 1
        return True

    def describe(self) -> str:
        return f"{self.name or 'timer'} {self.period_s:g}"
