"""Flight modes: which of the shared mode table this autopilot flies, and the rules for switching.

The table and its PX4/ArduPilot encodings are :mod:`uav_common.autopilot_modes`, shared with the
waypoint controller. The autopilot holds exactly one :class:`FlightMode`; whether a switch is allowed
is decided here, by a pure function of the request and a :class:`ModeContext`
snapshot, so each rule is one line and each has a unit test. Which modes a personality flies and
how it names them on the wire is :mod:`sitl.core.personality`; the module-level helpers here are
PX4's (the default personality).
"""

from __future__ import annotations

from dataclasses import dataclass

from sitl.core.personality import PX4, Personality
from uav_common.autopilot_modes import BASE_MODE_CUSTOM_MODE_ENABLED, BASE_MODE_SAFETY_ARMED, FlightMode

__all__ = [
    "BASE_MODE_CUSTOM_MODE_ENABLED",
    "BASE_MODE_SAFETY_ARMED",
    "FLOWN_MODES",
    "FlightMode",
    "ModeContext",
    "check_arm",
    "check_mode_switch",
    "mode_from_custom_mode",
    "mode_from_main_sub",
    "mode_from_set_mode_params",
    "needs_position",
]

#: The modes the PX4 personality flies. The others of the shared table (ALTCTL, ACRO, STABILIZED,
#: AUTO.READY) are refused as unknown, as PX4 refuses a mode its airframe does not support.
FLOWN_MODES = PX4.flown_modes


def mode_from_main_sub(main_mode: int, sub_mode: int) -> FlightMode | None:
    """The mode for PX4 ``(main, sub)``; ``None`` for modes we do not fly."""
    return PX4.mode_from_custom_mode((main_mode << 16) | (sub_mode << 24)) if 0 <= main_mode <= 0xFF else None


def mode_from_custom_mode(custom_mode: int) -> FlightMode | None:
    """The flown mode encoded in a full 32-bit PX4 ``custom_mode``."""
    return PX4.mode_from_custom_mode(custom_mode)


def mode_from_set_mode_params(base_mode: float, main_or_custom: float, sub_mode: float) -> FlightMode | None:
    """Decode ``MAV_CMD_DO_SET_MODE`` params as MAVSDK, MAVProxy and QGC send them; ``None`` if not flown."""
    return PX4.mode_from_set_mode_params(base_mode, main_or_custom, sub_mode)


def needs_position(mode: FlightMode) -> bool:
    """Every flown mode but the attitude modes (MANUAL, STABILIZE, ALT_HOLD) needs a position estimate."""
    return PX4.needs_position(mode)


#: Modes whose throttle is the pilot's: a vehicle armed in them without sticks would fall.
MANUAL_THROTTLE_MODES = frozenset({FlightMode.MANUAL, FlightMode.STABILIZED})


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
    personality: Personality = PX4


def check_mode_switch(target: FlightMode, ctx: ModeContext) -> str | None:  # noqa: PLR0911 - one return per rule
    """``None`` if switching to ``target`` is allowed, else the reason (for STATUSTEXT)."""
    p = ctx.personality
    name = p.mode_name(target)
    if ctx.crashed:
        return "vehicle crashed: flight terminated"
    if p.needs_position(target) and not ctx.position_valid:
        return f"{name} needs a position estimate"
    if target is FlightMode.AUTO_RTL and not ctx.home_valid:
        return f"{name} needs a home position"
    if target is FlightMode.AUTO_MISSION and not ctx.mission_valid:
        return f"{name} needs an uploaded mission"
    if target is FlightMode.OFFBOARD and p.offboard_needs_stream and not ctx.offboard_stream_ok:
        return "Switching to Offboard is currently not possible: no setpoint stream"
    if target in MANUAL_THROTTLE_MODES and ctx.armed and not ctx.manual_control_ok:
        return f"{name} needs manual control input"
    if target in (FlightMode.ORBIT, FlightMode.AUTO_FOLLOW_TARGET) and (not ctx.armed or ctx.landed):
        return f"{name} needs the vehicle in the air"
    return None


def check_arm(mode: FlightMode, ctx: ModeContext) -> str | None:
    """``None`` if arming in ``mode`` passes the mode part of the pre-arm checks."""
    if not ctx.personality.armable(mode):
        return f"arming denied: not in an armable mode ({ctx.personality.mode_name(mode)})"
    return check_mode_switch(mode, ctx)
