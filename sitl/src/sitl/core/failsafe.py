"""Failsafe detection: battery, data link, offboard stream, manual control, geofence.

:meth:`FailsafeMonitor.update` looks at one :class:`FailsafeInputs` snapshot and
returns the failsafes that *started* now, each with its action and the
STATUSTEXT that announces it. Each trigger latches until its condition clears
(battery levels latch for the whole flight), like PX4's commander.

Link and stream losses are judged on simulation time, with a wall-clock floor:
a client that lives in wall time (MAVSDK's 1 Hz heartbeat, a 20 Hz offboard
stream) is only declared lost when it has also been silent for
``max(timeout / speed_factor, floor)`` wall seconds, so speed factors > 1 do
not cause false alarms.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from sitl.core.modes import FlightMode
from sitl.core.params import ParamTable
from sitl.core.protocol import MavSeverity

__all__ = [
    "Action",
    "FailsafeEvent",
    "FailsafeInputs",
    "FailsafeKind",
    "FailsafeMonitor",
    "LinkActivity",
]


class FailsafeKind(enum.Enum):
    BATTERY_LOW = "battery_low"
    BATTERY_CRITICAL = "battery_critical"
    DATALINK_LOST = "datalink_lost"
    OFFBOARD_LOST = "offboard_lost"
    MANUAL_CONTROL_LOST = "manual_control_lost"
    GEOFENCE = "geofence"


class Action(enum.Enum):
    WARN = "warn"
    HOLD = "hold"
    RETURN = "return"
    LAND = "land"
    POSITION = "position"


@dataclass(frozen=True)
class FailsafeEvent:
    kind: FailsafeKind
    action: Action
    severity: MavSeverity
    text: str


class LinkActivity:
    """When something was last heard, in simulation and wall time."""

    __slots__ = ("last_sim_s", "last_wall_s")

    def __init__(self) -> None:
        self.last_sim_s: float | None = None
        self.last_wall_s: float | None = None

    def heard(self, t_s: float, wall_s: float) -> None:
        self.last_sim_s = t_s
        self.last_wall_s = wall_s

    @property
    def ever(self) -> bool:
        return self.last_sim_s is not None

    def silent_for(
        self, timeout_s: float, t_s: float, wall_s: float, *, wall_scale: float, wall_floor_s: float
    ) -> bool:
        """True when silent for ``timeout_s`` of sim time and the scaled wall time (never heard: False)."""
        if self.last_sim_s is None or self.last_wall_s is None:
            return False
        wall_needed = max(timeout_s * wall_scale, wall_floor_s)
        return t_s - self.last_sim_s > timeout_s and wall_s - self.last_wall_s > wall_needed


@dataclass(frozen=True)
class FailsafeInputs:
    t_s: float
    wall_s: float
    wall_scale: float  # 1 / speed factor (0 when unpaced or lockstep)
    armed: bool
    in_air: bool
    mode: FlightMode
    battery_remaining: float
    distance_from_home_m: float
    altitude_above_home_m: float


_DLL_ACTIONS = {1: Action.HOLD, 2: Action.RETURN, 3: Action.LAND}
_OBL_ACTIONS = {0: Action.POSITION, 3: Action.RETURN, 4: Action.LAND, 5: Action.HOLD}
_RCL_ACTIONS = {0: Action.HOLD, 1: Action.HOLD, 2: Action.RETURN, 3: Action.LAND}
_GF_ACTIONS = {1: Action.WARN, 2: Action.HOLD, 3: Action.RETURN, 5: Action.LAND}


class FailsafeMonitor:
    """Edge-triggered failsafe detection over the link activity trackers it owns."""

    def __init__(self, *, datalink_floor_s: float, offboard_floor_s: float, manual_floor_s: float) -> None:
        self.gcs = LinkActivity()
        self.offboard = LinkActivity()
        self.manual = LinkActivity()
        self._floors = (datalink_floor_s, offboard_floor_s, manual_floor_s)
        self._active: set[FailsafeKind] = set()

    @property
    def active(self) -> frozenset[FailsafeKind]:
        return frozenset(self._active)

    def clear(self, kind: FailsafeKind) -> None:
        self._active.discard(kind)

    def offboard_stream_ok(self, t_s: float, wall_s: float, params: ParamTable, wall_scale: float) -> bool:
        if not self.offboard.ever:
            return False
        return not self.offboard.silent_for(
            params["COM_OF_LOSS_T"], t_s, wall_s, wall_scale=wall_scale, wall_floor_s=self._floors[1]
        )

    def update(self, x: FailsafeInputs, params: ParamTable) -> list[FailsafeEvent]:
        events: list[FailsafeEvent] = []
        flying = x.armed and x.in_air
        self._battery(x, params, events)
        dl_floor, _, rc_floor = self._floors
        # data link: any GCS/SDK heartbeat keeps it alive; only after one was heard
        lost = self.gcs.silent_for(
            params["COM_DL_LOSS_T"], x.t_s, x.wall_s, wall_scale=x.wall_scale, wall_floor_s=dl_floor
        )
        action = _DLL_ACTIONS.get(int(params["NAV_DLL_ACT"]))
        if lost and FailsafeKind.DATALINK_LOST not in self._active:
            self._active.add(FailsafeKind.DATALINK_LOST)
            if flying and action is not None:
                events.append(
                    FailsafeEvent(
                        FailsafeKind.DATALINK_LOST,
                        action,
                        MavSeverity.CRITICAL,
                        f"Data link lost: {_describe(action)}",
                    )
                )
            else:
                events.append(
                    FailsafeEvent(FailsafeKind.DATALINK_LOST, Action.WARN, MavSeverity.WARNING, "Data link lost")
                )
        elif not lost and FailsafeKind.DATALINK_LOST in self._active:
            self._active.discard(FailsafeKind.DATALINK_LOST)
            events.append(
                FailsafeEvent(FailsafeKind.DATALINK_LOST, Action.WARN, MavSeverity.INFO, "Data link regained")
            )
        # offboard stream, only while in OFFBOARD
        if x.mode is FlightMode.OFFBOARD:
            stream_lost = not self.offboard_stream_ok(x.t_s, x.wall_s, params, x.wall_scale)
            if stream_lost and FailsafeKind.OFFBOARD_LOST not in self._active:
                self._active.add(FailsafeKind.OFFBOARD_LOST)
                act = _OBL_ACTIONS.get(int(params["COM_OBL_RC_ACT"]), Action.HOLD)
                events.append(
                    FailsafeEvent(
                        FailsafeKind.OFFBOARD_LOST,
                        act,
                        MavSeverity.CRITICAL,
                        f"Offboard setpoints lost: {_describe(act)}",
                    )
                )
        else:
            self._active.discard(FailsafeKind.OFFBOARD_LOST)
        # manual control, only while flying on the sticks
        if x.mode in (FlightMode.MANUAL, FlightMode.POSCTL) and self.manual.ever:
            rc_lost = self.manual.silent_for(
                params["COM_RC_LOSS_T"], x.t_s, x.wall_s, wall_scale=x.wall_scale, wall_floor_s=rc_floor
            )
            if rc_lost and FailsafeKind.MANUAL_CONTROL_LOST not in self._active:
                self._active.add(FailsafeKind.MANUAL_CONTROL_LOST)
                act = _RCL_ACTIONS.get(int(params["NAV_RCL_ACT"]), Action.HOLD) if flying else Action.WARN
                events.append(
                    FailsafeEvent(
                        FailsafeKind.MANUAL_CONTROL_LOST,
                        act,
                        MavSeverity.CRITICAL,
                        f"Manual control lost: {_describe(act)}",
                    )
                )
            elif not rc_lost:
                self._active.discard(FailsafeKind.MANUAL_CONTROL_LOST)
        else:
            self._active.discard(FailsafeKind.MANUAL_CONTROL_LOST)
        self._geofence(x, params, events)
        return events

    def _battery(self, x: FailsafeInputs, params: ParamTable, events: list[FailsafeEvent]) -> None:
        act_enabled = int(params["COM_LOW_BAT_ACT"]) == 3
        flying = x.armed and x.in_air
        remaining = x.battery_remaining
        if not math.isfinite(remaining):
            return
        if remaining <= params["BAT_CRIT_THR"] and FailsafeKind.BATTERY_CRITICAL not in self._active:
            self._active.update((FailsafeKind.BATTERY_CRITICAL, FailsafeKind.BATTERY_LOW))
            action = Action.LAND if (act_enabled and flying) else Action.WARN
            events.append(
                FailsafeEvent(
                    FailsafeKind.BATTERY_CRITICAL,
                    action,
                    MavSeverity.EMERGENCY,
                    f"Critical battery ({100 * remaining:.0f}%): {_describe(action)}",
                )
            )
        elif remaining <= params["BAT_LOW_THR"] and FailsafeKind.BATTERY_LOW not in self._active:
            self._active.add(FailsafeKind.BATTERY_LOW)
            action = Action.RETURN if (act_enabled and flying) else Action.WARN
            events.append(
                FailsafeEvent(
                    FailsafeKind.BATTERY_LOW,
                    action,
                    MavSeverity.CRITICAL,
                    f"Low battery ({100 * remaining:.0f}%): {_describe(action)}",
                )
            )

    def _geofence(self, x: FailsafeInputs, params: ParamTable, events: list[FailsafeEvent]) -> None:
        radius, max_alt = params["GF_MAX_HOR_DIST"], params["GF_MAX_VER_DIST"]
        outside_h = radius > 0.0 and x.distance_from_home_m > radius
        outside_v = max_alt > 0.0 and x.altitude_above_home_m > max_alt
        action = _GF_ACTIONS.get(int(params["GF_ACTION"]))
        if (outside_h or outside_v) and x.armed and x.in_air and action is not None:
            if FailsafeKind.GEOFENCE not in self._active:
                self._active.add(FailsafeKind.GEOFENCE)
                what = (
                    f"{x.distance_from_home_m:.0f} m > {radius:.0f} m"
                    if outside_h
                    else f"alt {x.altitude_above_home_m:.0f} m > {max_alt:.0f} m"
                )
                events.append(
                    FailsafeEvent(
                        FailsafeKind.GEOFENCE,
                        action,
                        MavSeverity.CRITICAL,
                        f"Geofence ({what}): {_describe(action)}",
                    )
                )
        elif not (outside_h or outside_v):
            self._active.discard(FailsafeKind.GEOFENCE)


def _describe(action: Action) -> str:
    return {
        Action.WARN: "warning only",
        Action.HOLD: "holding position",
        Action.RETURN: "returning home",
        Action.LAND: "landing",
        Action.POSITION: "position mode",
    }[action]
