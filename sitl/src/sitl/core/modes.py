"""Flight modes: PX4's custom_mode encoding and the rules for switching between them.

The autopilot holds exactly one :class:`FlightMode`; whether a switch is allowed
is decided here, by a pure function of the request and a :class:`ModeContext`
snapshot, so each rule is one line and each has a unit test.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

__all__ = [
    "BASE_MODE_CUSTOM_MODE_ENABLED",
    "BASE_MODE_SAFETY_ARMED",
    "FlightMode",
    "ModeContext",
    "check_arm",
    "check_mode_switch",
    "mode_from_custom_mode",
    "mode_from_main_sub",
    "mode_from_set_mode_params",
]

BASE_MODE_CUSTOM_MODE_ENABLED = 1
BASE_MODE_STABILIZE_ENABLED = 16
BASE_MODE_GUIDED_ENABLED = 8
BASE_MODE_AUTO_ENABLED = 4
BASE_MODE_MANUAL_INPUT_ENABLED = 64
BASE_MODE_SAFETY_ARMED = 128


class FlightMode(enum.Enum):
    """The modes this autopilot flies, valued by PX4 ``(main_mode, sub_mode)``."""

    MANUAL = (1, 0)
    POSCTL = (3, 0)
    AUTO_TAKEOFF = (4, 2)
    AUTO_LOITER = (4, 3)
    AUTO_MISSION = (4, 4)
    AUTO_RTL = (4, 5)
    AUTO_LAND = (4, 6)
    OFFBOARD = (6, 0)

    @property
    def main_mode(self) -> int:
        return self.value[0]

    @property
    def sub_mode(self) -> int:
        return self.value[1]

    @property
    def custom_mode(self) -> int:
        """``HEARTBEAT.custom_mode``: ``main << 16 | sub << 24`` (PX4 ``px4_custom_mode``)."""
        return (self.main_mode << 16) | (self.sub_mode << 24)

    @property
    def px4_name(self) -> str:
        """The name QGC, MAVROS and the PX4 console use (``AUTO.LOITER``...)."""
        return _PX4_NAMES[self]

    @property
    def is_auto(self) -> bool:
        return self.main_mode == 4

    @property
    def needs_position(self) -> bool:
        return self is not FlightMode.MANUAL

    def base_mode(self, *, armed: bool) -> int:
        """``HEARTBEAT.base_mode`` as PX4 fills it for this mode."""
        flags = BASE_MODE_CUSTOM_MODE_ENABLED | BASE_MODE_STABILIZE_ENABLED
        if self in (FlightMode.MANUAL, FlightMode.POSCTL):
            flags |= BASE_MODE_MANUAL_INPUT_ENABLED
        if self.is_auto or self is FlightMode.OFFBOARD:
            flags |= BASE_MODE_AUTO_ENABLED | BASE_MODE_GUIDED_ENABLED
        if self is FlightMode.POSCTL:
            flags |= BASE_MODE_GUIDED_ENABLED
        if armed:
            flags |= BASE_MODE_SAFETY_ARMED
        return flags


_PX4_NAMES = {
    FlightMode.MANUAL: "MANUAL",
    FlightMode.POSCTL: "POSCTL",
    FlightMode.AUTO_TAKEOFF: "AUTO.TAKEOFF",
    FlightMode.AUTO_LOITER: "AUTO.LOITER",
    FlightMode.AUTO_MISSION: "AUTO.MISSION",
    FlightMode.AUTO_RTL: "AUTO.RTL",
    FlightMode.AUTO_LAND: "AUTO.LAND",
    FlightMode.OFFBOARD: "OFFBOARD",
}

_BY_MAIN_SUB = {mode.value: mode for mode in FlightMode}


def mode_from_main_sub(main_mode: int, sub_mode: int) -> FlightMode | None:
    """The mode for PX4 ``(main, sub)``; ``None`` for modes we do not fly."""
    return _BY_MAIN_SUB.get((main_mode, sub_mode))


def mode_from_custom_mode(custom_mode: int) -> FlightMode | None:
    """The mode encoded in a full 32-bit PX4 ``custom_mode``."""
    if custom_mode < 0 or custom_mode > 0xFFFFFFFF or custom_mode & 0xFFFF:
        return None
    return mode_from_main_sub((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


def mode_from_set_mode_params(base_mode: float, main_or_custom: float, sub_mode: float) -> FlightMode | None:
    """Decode ``MAV_CMD_DO_SET_MODE`` params as MAVSDK, MAVProxy and QGC send them.

    MAVSDK and MAVProxy put PX4's main mode in param2 and the sub mode in param3;
    QGC's PX4 plugin may put the whole ``custom_mode`` in param2.
    """
    if not (int(base_mode) & BASE_MODE_CUSTOM_MODE_ENABLED):
        return None
    main = int(main_or_custom)
    if main != main_or_custom or sub_mode != int(sub_mode):
        return None
    if main > 0xFF:
        return mode_from_custom_mode(main)
    return mode_from_main_sub(main, int(sub_mode))


@dataclass(frozen=True)
class ModeContext:
    """What the mode rules look at, sampled when a switch is requested."""

    armed: bool
    landed: bool
    crashed: bool
    position_valid: bool
    home_valid: bool
    mission_valid: bool
    offboard_stream_ok: bool
    manual_control_ok: bool


def check_mode_switch(target: FlightMode, ctx: ModeContext) -> str | None:  # noqa: PLR0911 - one return per rule
    """``None`` if switching to ``target`` is allowed, else the reason (for STATUSTEXT)."""
    if ctx.crashed:
        return "vehicle crashed: flight terminated"
    if target.needs_position and not ctx.position_valid:
        return f"{target.px4_name} needs a position estimate"
    if target is FlightMode.AUTO_RTL and not ctx.home_valid:
        return "AUTO.RTL needs a home position"
    if target is FlightMode.AUTO_MISSION and not ctx.mission_valid:
        return "AUTO.MISSION needs an uploaded mission"
    if target is FlightMode.OFFBOARD and not ctx.offboard_stream_ok:
        return "Switching to Offboard is currently not possible: no setpoint stream"
    if target is FlightMode.MANUAL and ctx.armed and not ctx.manual_control_ok:
        return "MANUAL needs manual control input"
    return None


def check_arm(mode: FlightMode, ctx: ModeContext) -> str | None:
    """``None`` if arming in ``mode`` passes the mode part of the pre-arm checks."""
    if mode in (FlightMode.AUTO_RTL, FlightMode.AUTO_LAND):
        return f"arming denied: not in an armable mode ({mode.px4_name})"
    return check_mode_switch(mode, ctx)
