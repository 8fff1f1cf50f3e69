"""Autopilot flight modes and their MAVLink encodings (PX4 and ArduPilot Copter).

The controller reasons in :class:`FlightMode`; only this module knows how each
autopilot encodes a mode in ``HEARTBEAT.custom_mode`` and in ``MAV_CMD_DO_SET_MODE``.

PX4 packs ``custom_mode = main_mode << 16 | sub_mode << 24`` (``px4_custom_mode.hpp``);
``MAV_CMD_DO_SET_MODE`` takes ``param2 = main_mode`` and ``param3 = sub_mode``.
ArduPilot Copter uses plain mode numbers in ``custom_mode`` and ``param2``.
"""

from __future__ import annotations

import enum

__all__ = ["AutopilotFlavor", "FlightMode", "decode_mode", "mode_name", "px4_custom_mode", "set_mode_params"]

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128


class AutopilotFlavor(enum.Enum):
    """Which mode table the autopilot speaks (from ``HEARTBEAT.autopilot``)."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"

    @classmethod
    def from_heartbeat(cls, autopilot: int) -> AutopilotFlavor:
        """ArduPilot for ``MAV_AUTOPILOT_ARDUPILOTMEGA``; PX4 encoding for everything else (as MAVSDK does)."""
        return cls.ARDUPILOT if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else cls.PX4


class FlightMode(enum.Enum):
    """Autopilot modes the controller distinguishes."""

    OFFBOARD = "OFFBOARD"  # PX4 OFFBOARD / ArduPilot GUIDED: follows our setpoints
    RTL = "RTL"
    LAND = "LAND"
    LOITER = "LOITER"  # PX4 AUTO.LOITER (hold) / ArduPilot LOITER
    TAKEOFF = "TAKEOFF"
    MISSION = "MISSION"
    POSCTL = "POSCTL"
    ALTCTL = "ALTCTL"
    MANUAL = "MANUAL"
    STABILIZED = "STABILIZED"
    ACRO = "ACRO"
    READY = "READY"
    UNKNOWN = "UNKNOWN"


_PX4: dict[FlightMode, tuple[int, int, str]] = {
    FlightMode.MANUAL: (1, 0, "MANUAL"),
    FlightMode.ALTCTL: (2, 0, "ALTCTL"),
    FlightMode.POSCTL: (3, 0, "POSCTL"),
    FlightMode.READY: (4, 1, "AUTO.READY"),
    FlightMode.TAKEOFF: (4, 2, "AUTO.TAKEOFF"),
    FlightMode.LOITER: (4, 3, "AUTO.LOITER"),
    FlightMode.MISSION: (4, 4, "AUTO.MISSION"),
    FlightMode.RTL: (4, 5, "AUTO.RTL"),
    FlightMode.LAND: (4, 6, "AUTO.LAND"),
    FlightMode.ACRO: (5, 0, "ACRO"),
    FlightMode.OFFBOARD: (6, 0, "OFFBOARD"),
    FlightMode.STABILIZED: (7, 0, "STABILIZED"),
}
_PX4_BY_MAIN_SUB = {(main, sub): mode for mode, (main, sub, _) in _PX4.items()}

_ARDUCOPTER: dict[FlightMode, tuple[int, str]] = {
    FlightMode.STABILIZED: (0, "STABILIZE"),
    FlightMode.ACRO: (1, "ACRO"),
    FlightMode.ALTCTL: (2, "ALT_HOLD"),
    FlightMode.MISSION: (3, "AUTO"),
    FlightMode.OFFBOARD: (4, "GUIDED"),
    FlightMode.LOITER: (5, "LOITER"),
    FlightMode.RTL: (6, "RTL"),
    FlightMode.LAND: (9, "LAND"),
    FlightMode.POSCTL: (16, "POSHOLD"),
}
_ARDU_BY_NUMBER = {number: mode for mode, (number, _) in _ARDUCOPTER.items()}


def decode_mode(flavor: AutopilotFlavor, custom_mode: int) -> FlightMode:
    """The :class:`FlightMode` in a heartbeat's ``custom_mode``."""
    if flavor is AutopilotFlavor.ARDUPILOT:
        return _ARDU_BY_NUMBER.get(custom_mode, FlightMode.UNKNOWN)
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    mode = _PX4_BY_MAIN_SUB.get((main, sub))
    if mode is None and sub == 0:
        # PX4 reports some main modes with a zero sub mode (e.g. AUTO with sub 0).
        mode = _PX4_BY_MAIN_SUB.get((main, 0))
    return mode or FlightMode.UNKNOWN


def mode_name(flavor: AutopilotFlavor, custom_mode: int) -> str:
    """Human-readable mode name as the autopilot's own tools show it (``AUTO.RTL``, ``GUIDED``)."""
    if flavor is AutopilotFlavor.ARDUPILOT:
        for number, name in _ARDUCOPTER.values():
            if number == custom_mode:
                return name
        return f"MODE_{custom_mode}"
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    for m, s, name in _PX4.values():
        if (m, s) == (main, sub):
            return name
    return f"PX4_{main}.{sub}"


def set_mode_params(flavor: AutopilotFlavor, mode: FlightMode, *, armed: bool) -> tuple[float, float, float]:
    """``(param1, param2, param3)`` of ``MAV_CMD_DO_SET_MODE`` for ``mode``.

    Raises:
        ValueError: the autopilot has no such mode.
    """
    base = float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if armed else 0))
    if flavor is AutopilotFlavor.ARDUPILOT:
        if mode not in _ARDUCOPTER:
            msg = f"ArduPilot Copter has no {mode.value} mode"
            raise ValueError(msg)
        return (base, float(_ARDUCOPTER[mode][0]), 0.0)
    if mode not in _PX4:
        msg = f"PX4 has no {mode.value} mode"
        raise ValueError(msg)
    main, sub, _ = _PX4[mode]
    return (base, float(main), float(sub))


def px4_custom_mode(mode: FlightMode) -> int:
    """PX4 ``custom_mode`` value for ``mode`` (for heartbeats in tests and emulators)."""
    main, sub, _ = _PX4[mode]
    return (main << 16) | (sub << 24)
