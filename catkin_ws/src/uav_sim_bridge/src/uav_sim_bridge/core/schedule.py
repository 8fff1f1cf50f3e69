"""Simulation-time schedules: camera frames at their rates, and the lockstep grant pacing."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["LockstepConfig", "LockstepRole", "RateSchedule"]


class RateSchedule:
    """Fires at most once per period of ``rate_hz`` in simulation time, on the grid ``k / rate_hz``.

    A frame is due at the first state at or after each grid instant; a state far past
    several instants fires once (frames are not queued).  Time going backwards (a
    restarted simulator) restarts the schedule.
    """

    def __init__(self, rate_hz: float) -> None:
        if rate_hz <= 0:
            msg = f"rate_hz must be > 0, got {rate_hz}"
            raise ValueError(msg)
        self.period_s = 1.0 / rate_hz
        self._next_s: float | None = None
        self._last_s = -math.inf

    def due(self, sim_time_s: float) -> bool:
        """True (and advance) if a frame is due at ``sim_time_s``."""
        eps = 1e-9
        if sim_time_s < self._last_s - eps:
            self._next_s = None
        self._last_s = sim_time_s
        if self._next_s is None or sim_time_s + eps >= self._next_s:
            k = math.floor(sim_time_s / self.period_s + eps)
            self._next_s = (k + 1) * self.period_s
            return True
        return False


class LockstepRole:
    """Who grants simulation steps."""

    OFF = "off"  # free-running SITL: never grant
    MASTER = "master"  # the bridge grants SIM_STEP after it has published each state
    PARTICIPANT = "participant"  # someone else grants; the bridge processes every state in order


@dataclass(frozen=True)
class LockstepConfig:
    """``lockstep`` section.

    Attributes:
        role: ``off``, ``master`` or ``participant``.
        steps_per_grant: physics steps per SIM_STEP (the SITL steps at 250 Hz: 5 -> 50 Hz states).
        max_real_time_factor: pace grants to at most this many times real time (0 = as fast as possible).
        grant_timeout_s: re-send a grant not answered by a COMMAND_ACK in this wall time.
    """

    role: str = LockstepRole.MASTER
    steps_per_grant: int = 5
    max_real_time_factor: float = 0.0
    grant_timeout_s: float = 1.0

    def __post_init__(self) -> None:
        if self.role not in (LockstepRole.OFF, LockstepRole.MASTER, LockstepRole.PARTICIPANT):
            msg = f"role must be off, master or participant, got {self.role!r}"
            raise ValueError(msg)
        if self.steps_per_grant < 1 or self.max_real_time_factor < 0 or self.grant_timeout_s <= 0:
            msg = "steps_per_grant >= 1, max_real_time_factor >= 0 and grant_timeout_s > 0 are required"
            raise ValueError(msg)
