"""Telemetry scheduling: PX4's default stream rates per link profile, SET_MESSAGE_INTERVAL.

Rates are in simulation time (as PX4's streams are in lockstep SITL): at a speed
factor of 10 a 50 Hz stream leaves the process 500 times per wall second.
"""

from __future__ import annotations

import heapq
import math

from sitl.core.protocol import MavResult, MsgId

__all__ = ["NORMAL_RATES_HZ", "ONBOARD_RATES_HZ", "PRODUCIBLE", "StreamScheduler"]

# PX4 mavlink_main.cpp configure_streams_to_default(): "normal" (GCS) and "onboard" (API) modes.
NORMAL_RATES_HZ: dict[int, float] = {
    MsgId.HEARTBEAT: 1.0,
    MsgId.SYS_STATUS: 1.0,
    MsgId.EXTENDED_SYS_STATE: 1.0,
    MsgId.GLOBAL_POSITION_INT: 5.0,
    MsgId.LOCAL_POSITION_NED: 1.0,
    MsgId.ATTITUDE: 15.0,
    MsgId.ATTITUDE_QUATERNION: 10.0,
    MsgId.GPS_RAW_INT: 1.0,
    MsgId.HOME_POSITION: 0.5,
    MsgId.BATTERY_STATUS: 0.5,
    MsgId.VFR_HUD: 4.0,
    MsgId.ALTITUDE: 1.0,
    MsgId.MISSION_CURRENT: 1.0,
    MsgId.POSITION_TARGET_LOCAL_NED: 1.5,
}
ONBOARD_RATES_HZ: dict[int, float] = {
    MsgId.HEARTBEAT: 1.0,
    MsgId.SYS_STATUS: 5.0,
    MsgId.EXTENDED_SYS_STATE: 5.0,
    MsgId.GLOBAL_POSITION_INT: 50.0,
    MsgId.LOCAL_POSITION_NED: 30.0,
    MsgId.ATTITUDE: 100.0,
    MsgId.ATTITUDE_QUATERNION: 50.0,
    MsgId.GPS_RAW_INT: 10.0,
    MsgId.HOME_POSITION: 0.5,
    MsgId.BATTERY_STATUS: 0.5,
    MsgId.VFR_HUD: 10.0,
    MsgId.SYSTEM_TIME: 1.0,
    MsgId.HIGHRES_IMU: 50.0,
    MsgId.ODOMETRY: 30.0,
    MsgId.POSITION_TARGET_LOCAL_NED: 10.0,
    MsgId.ALTITUDE: 10.0,
    MsgId.MISSION_CURRENT: 1.0,
}
PRODUCIBLE: frozenset[int] = frozenset(
    {
        MsgId.HEARTBEAT,
        MsgId.SYS_STATUS,
        MsgId.SYSTEM_TIME,
        MsgId.GPS_RAW_INT,
        MsgId.ATTITUDE,
        MsgId.ATTITUDE_QUATERNION,
        MsgId.LOCAL_POSITION_NED,
        MsgId.GLOBAL_POSITION_INT,
        MsgId.MISSION_CURRENT,
        MsgId.GPS_GLOBAL_ORIGIN,
        MsgId.VFR_HUD,
        MsgId.POSITION_TARGET_LOCAL_NED,
        MsgId.HIGHRES_IMU,
        MsgId.ALTITUDE,
        MsgId.BATTERY_STATUS,
        MsgId.AUTOPILOT_VERSION,
        MsgId.HOME_POSITION,
        MsgId.EXTENDED_SYS_STATE,
        MsgId.ODOMETRY,
    }
)
# Messages that make sense on request but not as a periodic stream.
_ON_REQUEST_ONLY = frozenset({MsgId.AUTOPILOT_VERSION, MsgId.GPS_GLOBAL_ORIGIN})


class StreamScheduler:
    """Which messages are due on one link, in simulation time (a heap of next send times)."""

    def __init__(self, defaults_hz: dict[int, float], max_rate_hz: float) -> None:
        self._defaults = dict(defaults_hz)
        self._max_rate_hz = max_rate_hz
        self._period_s: dict[int, float] = {m: 1.0 / r for m, r in defaults_hz.items() if r > 0.0}
        self._generation: dict[int, int] = dict.fromkeys(self._period_s, 0)
        # (next time, stable order, message id, generation); stale generations are skipped
        self._heap: list[tuple[float, int, int, int]] = [(0.0, i, m, 0) for i, m in enumerate(sorted(self._period_s))]
        heapq.heapify(self._heap)

    def copy(self) -> StreamScheduler:
        """An independent scheduler in the same state (same next send times)."""
        other = StreamScheduler.__new__(StreamScheduler)
        other._defaults = dict(self._defaults)
        other._max_rate_hz = self._max_rate_hz
        other._period_s = dict(self._period_s)
        other._generation = dict(self._generation)
        other._heap = list(self._heap)
        return other

    def set_interval(self, msg_id: int, interval_us: float, t_s: float) -> MavResult:
        """MAV_CMD_SET_MESSAGE_INTERVAL: 0 restores the default, -1 stops the stream."""
        if msg_id not in PRODUCIBLE or msg_id in _ON_REQUEST_ONLY:
            return MavResult.UNSUPPORTED
        if not math.isfinite(interval_us) or (interval_us < 0.0 and interval_us != -1.0):
            return MavResult.DENIED
        if interval_us == 0.0:
            rate = self._defaults.get(msg_id, 0.0)
        elif interval_us == -1.0:
            rate = 0.0
        else:
            rate = min(1e6 / interval_us, self._max_rate_hz)
        generation = self._generation.get(msg_id, 0) + 1
        self._generation[msg_id] = generation
        if rate <= 0.0:
            self._period_s.pop(msg_id, None)
        else:
            self._period_s[msg_id] = 1.0 / rate
            heapq.heappush(self._heap, (t_s, msg_id, msg_id, generation))
        return MavResult.ACCEPTED

    def interval_us(self, msg_id: int) -> int:
        """For MESSAGE_INTERVAL: the interval, -1 if stopped, 0 if not available."""
        if msg_id not in PRODUCIBLE:
            return 0
        period = self._period_s.get(msg_id)
        return -1 if period is None else round(period * 1e6)

    @property
    def next_due_s(self) -> float:
        """Earliest simulation time at which :meth:`due` can return something."""
        return self._heap[0][0] if self._heap else math.inf

    def due(self, t_s: float) -> list[int]:
        """Message ids to send now; their next times are scheduled (phase kept, no bursts after a stall)."""
        heap = self._heap
        out: list[int] = []
        while heap and heap[0][0] <= t_s:
            when, order, msg_id, generation = heapq.heappop(heap)
            if generation != self._generation[msg_id] or msg_id not in self._period_s:
                continue
            out.append(msg_id)
            period = self._period_s[msg_id]
            nxt = when + period
            if nxt <= t_s:
                nxt = t_s + period
            heapq.heappush(heap, (nxt, order, msg_id, generation))
        return out
