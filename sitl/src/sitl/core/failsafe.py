"""Failsafe detection: battery, data link, offboard stream, manual control, geofence.

:meth:`FailsafeMonitor.update` looks at one :class:`FailsafeInputs` snapshot and
returns the failsafes that *started* now, each with its action and the
STATUSTEXT that announces it. Each trigger latches until its condition clears
(battery levels latch for the whole flight), like PX4's commander.

Thresholds, timeouts and actions come from the personality's
:class:`~sitl.core.settings.FlightSettings` (``params.settings``): the same
rules serve PX4's parameters and ArduCopter's, where ArduCopter also disarms a
vehicle that is armed on the ground when a battery or GCS failsafe triggers,
judges its battery on remaining capacity and (optionally) voltage, and has no
offboard-stream failsafe.

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

from sitl.core.params import ParamTable
from sitl.core.protocol import MavSeverity
from sitl.core.settings import Action, FlightSettings
from uav_common.autopilot_modes import FlightMode

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
    POSITION_LOST = "position_lost"


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
    battery_voltage_v: float = math.nan
    fence_breach: str | None = None
    """What an uploaded fence zone says is breached (None: inside, or no uploaded fence)."""
    position_valid: bool = True
    """The estimator still has a horizontal position (false after a GPS failure outlasts EKF2_NOAID_TOUT)."""
    needs_position: bool = False
    """The present mode flies on the position estimate."""


class FailsafeMonitor:
    """Edge-triggered failsafe detection over the link activity trackers it owns."""

    def __init__(self, *, datalink_floor_s: float, offboard_floor_s: float, manual_floor_s: float) -> None:
        self.gcs = LinkActivity()
        self.offboard = LinkActivity()
        self.manual = LinkActivity()
        self._floors = (datalink_floor_s, offboard_floor_s, manual_floor_s)
        self._active: set[FailsafeKind] = set()
        self._low_voltage_since: float | None = None
        self._critical_voltage_since: float | None = None

    @property
    def active(self) -> frozenset[FailsafeKind]:
        return frozenset(self._active)

    def clear(self, kind: FailsafeKind) -> None:
        self._active.discard(kind)

    def offboard_stream_ok(self, t_s: float, wall_s: float, params: ParamTable, wall_scale: float) -> bool:
        if not self.offboard.ever:
            return False
        return not self.offboard.silent_for(
            params.settings.offboard_timeout_s, t_s, wall_s, wall_scale=wall_scale, wall_floor_s=self._floors[1]
        )

    def update(self, x: FailsafeInputs, params: ParamTable) -> list[FailsafeEvent]:
        s = params.settings
        events: list[FailsafeEvent] = []
        flying = x.armed and x.in_air
        self._battery(x, s, events)
        dl_floor, _, rc_floor = self._floors
        # data link: the GCS's heartbeat keeps it alive; only after one was heard
        lost = self.gcs.silent_for(
            s.datalink_timeout_s, x.t_s, x.wall_s, wall_scale=x.wall_scale, wall_floor_s=dl_floor
        )
        action = s.datalink_action
        if lost and FailsafeKind.DATALINK_LOST not in self._active:
            self._active.add(FailsafeKind.DATALINK_LOST)
            if action is not None and x.armed and not x.in_air and s.disarm_on_ground_failsafe:
                events.append(
                    FailsafeEvent(
                        FailsafeKind.DATALINK_LOST, Action.DISARM, MavSeverity.CRITICAL, "Data link lost: disarming"
                    )
                )
            elif flying and action is not None:
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
        # offboard stream, only while in OFFBOARD (PX4; ArduCopter's GUIDED keeps its last target)
        if x.mode is FlightMode.OFFBOARD and s.offboard_loss_action is not None:
            stream_lost = not self.offboard_stream_ok(x.t_s, x.wall_s, params, x.wall_scale)
            if stream_lost and FailsafeKind.OFFBOARD_LOST not in self._active:
                self._active.add(FailsafeKind.OFFBOARD_LOST)
                act = s.offboard_loss_action
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
        if x.mode in _STICK_MODES and self.manual.ever:
            rc_lost = self.manual.silent_for(
                s.manual_timeout_s, x.t_s, x.wall_s, wall_scale=x.wall_scale, wall_floor_s=rc_floor
            )
            if rc_lost and FailsafeKind.MANUAL_CONTROL_LOST not in self._active:
                self._active.add(FailsafeKind.MANUAL_CONTROL_LOST)
                act = s.manual_loss_action if flying else Action.WARN
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
        self._geofence(x, s, events)
        self._position(x, events)
        return events

    def _position(self, x: FailsafeInputs, events: list[FailsafeEvent]) -> None:
        """PX4's position-estimate failsafe: without RC (none here), a position mode descends (Descend)."""
        if x.position_valid:
            if FailsafeKind.POSITION_LOST in self._active:
                self._active.discard(FailsafeKind.POSITION_LOST)
                events.append(
                    FailsafeEvent(
                        FailsafeKind.POSITION_LOST, Action.WARN, MavSeverity.INFO, "Position estimate regained"
                    )
                )
            return
        if FailsafeKind.POSITION_LOST in self._active:
            return
        self._active.add(FailsafeKind.POSITION_LOST)
        if x.armed and x.in_air and x.needs_position:
            events.append(
                FailsafeEvent(
                    FailsafeKind.POSITION_LOST,
                    Action.LAND,
                    MavSeverity.CRITICAL,
                    "Failsafe: no local position estimate (GPS lost): descending",
                )
            )
        else:
            events.append(
                FailsafeEvent(
                    FailsafeKind.POSITION_LOST, Action.WARN, MavSeverity.WARNING, "No local position estimate"
                )
            )

    def _voltage_low(self, x: FailsafeInputs, s: FlightSettings, *, critical: bool) -> bool:
        """ArduCopter's voltage trigger: below the threshold for ``BATT_LOW_TIMER`` (0 V: off)."""
        threshold = s.battery_critical_voltage_v if critical else s.battery_low_voltage_v
        below = threshold > 0.0 and math.isfinite(x.battery_voltage_v) and x.battery_voltage_v < threshold
        since = self._critical_voltage_since if critical else self._low_voltage_since
        if not below:
            since = None
        elif since is None:
            since = x.t_s
        if critical:
            self._critical_voltage_since = since
        else:
            self._low_voltage_since = since
        return since is not None and x.t_s - since >= s.battery_voltage_timer_s

    def _battery(self, x: FailsafeInputs, s: FlightSettings, events: list[FailsafeEvent]) -> None:
        flying = x.armed and x.in_air
        on_ground_disarm = s.disarm_on_ground_failsafe and x.armed and not x.in_air
        remaining = x.battery_remaining
        if not math.isfinite(remaining):
            return
        volt_critical = self._voltage_low(x, s, critical=True)
        volt_low = self._voltage_low(x, s, critical=False)
        critical = remaining <= s.battery_critical_remaining or volt_critical
        if critical and FailsafeKind.BATTERY_CRITICAL not in self._active:
            self._active.update((FailsafeKind.BATTERY_CRITICAL, FailsafeKind.BATTERY_LOW))
            action = s.battery_critical_action if flying else Action.WARN
            if on_ground_disarm and s.battery_critical_action is not Action.WARN:
                action = Action.DISARM
            events.append(
                FailsafeEvent(
                    FailsafeKind.BATTERY_CRITICAL,
                    action,
                    MavSeverity.EMERGENCY,
                    f"Critical battery ({100 * remaining:.0f}%): {_describe(action)}",
                )
            )
        elif (remaining <= s.battery_low_remaining or volt_low) and FailsafeKind.BATTERY_LOW not in self._active:
            self._active.add(FailsafeKind.BATTERY_LOW)
            action = s.battery_low_action if flying else Action.WARN
            if on_ground_disarm and s.battery_low_action is not Action.WARN:
                action = Action.DISARM
            events.append(
                FailsafeEvent(
                    FailsafeKind.BATTERY_LOW,
                    action,
                    MavSeverity.CRITICAL,
                    f"Low battery ({100 * remaining:.0f}%): {_describe(action)}",
                )
            )

    def _geofence(self, x: FailsafeInputs, s: FlightSettings, events: list[FailsafeEvent]) -> None:
        radius, max_alt = s.fence_radius_m, s.fence_max_alt_m
        outside_h = radius > 0.0 and x.distance_from_home_m > radius
        outside_v = max_alt > 0.0 and x.altitude_above_home_m > max_alt
        zone = x.fence_breach if s.fence_uploaded else None
        action = s.fence_action
        if (outside_h or outside_v or zone is not None) and x.armed and x.in_air and action is not None:
            if FailsafeKind.GEOFENCE not in self._active:
                self._active.add(FailsafeKind.GEOFENCE)
                if outside_h:
                    what = f"{x.distance_from_home_m:.0f} m > {radius:.0f} m"
                elif outside_v:
                    what = f"alt {x.altitude_above_home_m:.0f} m > {max_alt:.0f} m"
                else:
                    what = str(zone)
                events.append(
                    FailsafeEvent(
                        FailsafeKind.GEOFENCE,
                        action,
                        MavSeverity.CRITICAL,
                        f"Geofence ({what}): {_describe(action)}",
                    )
                )
        elif not (outside_h or outside_v or zone is not None):
            self._active.discard(FailsafeKind.GEOFENCE)


def _describe(action: Action) -> str:
    return {
        Action.WARN: "warning only",
        Action.HOLD: "holding position",
        Action.RETURN: "returning home",
        Action.LAND: "landing",
        Action.POSITION: "position mode",
        Action.DISARM: "disarming",
    }[action]


#: Modes flown on the sticks (manual-control loss matters there).
_STICK_MODES = frozenset({FlightMode.MANUAL, FlightMode.POSCTL, FlightMode.STABILIZED, FlightMode.ALTCTL})
