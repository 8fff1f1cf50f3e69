"""Autopilot flight modes and their MAVLink encodings, PX4 and ArduPilot Copter, in one table.

Everything that speaks modes uses this module: the SITL (which flies a subset of these
modes and says so in its heartbeat), the waypoint controller (which requests and decodes
them), the tests and the tools.

* PX4 packs ``HEARTBEAT.custom_mode = main_mode << 16 | sub_mode << 24``
  (``px4_custom_mode.hpp``); ``MAV_CMD_DO_SET_MODE`` takes ``param2 = main_mode`` and
  ``param3 = sub_mode`` (MAVSDK, MAVProxy), or the whole ``custom_mode`` in ``param2`` (QGC).
* ArduPilot Copter uses plain mode numbers in ``custom_mode`` and ``param2``.

:class:`FlightMode` is named and valued after PX4's modes ``(main_mode, sub_mode)``; the
ArduCopter mode that does the same job is attached to each (``GUIDED`` for ``OFFBOARD``...).
"""

from __future__ import annotations

import enum

__all__ = [
    "BASE_MODE_AUTO_ENABLED",
    "BASE_MODE_CUSTOM_MODE_ENABLED",
    "BASE_MODE_GUIDED_ENABLED",
    "BASE_MODE_MANUAL_INPUT_ENABLED",
    "BASE_MODE_SAFETY_ARMED",
    "BASE_MODE_STABILIZE_ENABLED",
    "MAV_AUTOPILOT_ARDUPILOTMEGA",
    "MAV_AUTOPILOT_PX4",
    "Autopilot",
    "FlightMode",
    "decode_custom_mode",
    "mode_from_custom_mode",
    "mode_from_main_sub",
    "mode_from_set_mode_params",
    "mode_name",
    "set_mode_params",
]

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12

BASE_MODE_CUSTOM_MODE_ENABLED = 1
BASE_MODE_AUTO_ENABLED = 4
BASE_MODE_GUIDED_ENABLED = 8
BASE_MODE_STABILIZE_ENABLED = 16
BASE_MODE_MANUAL_INPUT_ENABLED = 64
BASE_MODE_SAFETY_ARMED = 128


class Autopilot(enum.Enum):
    """Which mode table an autopilot speaks (``HEARTBEAT.autopilot``)."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"

    @classmethod
    def from_heartbeat(cls, autopilot: int) -> Autopilot:
        """ArduPilot for ``MAV_AUTOPILOT_ARDUPILOTMEGA``; PX4's encoding for everything else (as MAVSDK does)."""
        return cls.ARDUPILOT if autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else cls.PX4

    @property
    def mav_autopilot(self) -> int:
        """The ``MAV_AUTOPILOT`` value this autopilot puts in its heartbeat."""
        return MAV_AUTOPILOT_ARDUPILOTMEGA if self is Autopilot.ARDUPILOT else MAV_AUTOPILOT_PX4


class FlightMode(enum.Enum):
    """Flight modes, valued by PX4 ``(main_mode, sub_mode)``."""

    MANUAL = (1, 0)
    ALTCTL = (2, 0)
    POSCTL = (3, 0)
    ORBIT = (3, 1)
    AUTO_READY = (4, 1)
    AUTO_TAKEOFF = (4, 2)
    AUTO_LOITER = (4, 3)
    AUTO_MISSION = (4, 4)
    AUTO_RTL = (4, 5)
    AUTO_LAND = (4, 6)
    AUTO_FOLLOW_TARGET = (4, 8)
    ACRO = (5, 0)
    OFFBOARD = (6, 0)
    STABILIZED = (7, 0)

    @property
    def main_mode(self) -> int:
        return self.value[0]

    @property
    def sub_mode(self) -> int:
        return self.value[1]

    @property
    def custom_mode(self) -> int:
        """PX4's ``HEARTBEAT.custom_mode``: ``main << 16 | sub << 24``."""
        return (self.main_mode << 16) | (self.sub_mode << 24)

    @property
    def px4_name(self) -> str:
        """The name QGC, MAVROS and the PX4 console use (``AUTO.LOITER``, ``POSCTL.ORBIT``...)."""
        if self is FlightMode.ORBIT:
            return "POSCTL.ORBIT"
        return self.name.replace("AUTO_", "AUTO.")

    @property
    def ardupilot_number(self) -> int | None:
        """ArduCopter's mode number for the mode that does this job, or ``None`` (no such mode)."""
        entry = _ARDUCOPTER.get(self)
        return None if entry is None else entry[0]

    @property
    def ardupilot_name(self) -> str | None:
        """ArduCopter's name for the mode that does this job (``GUIDED``...), or ``None``."""
        entry = _ARDUCOPTER.get(self)
        return None if entry is None else entry[1]

    @property
    def is_auto(self) -> bool:
        return self.main_mode == 4

    def base_mode(self, *, armed: bool) -> int:
        """``HEARTBEAT.base_mode`` as PX4 fills it in this mode."""
        flags = BASE_MODE_CUSTOM_MODE_ENABLED | BASE_MODE_STABILIZE_ENABLED
        if self in (FlightMode.MANUAL, FlightMode.POSCTL, FlightMode.ORBIT):
            flags |= BASE_MODE_MANUAL_INPUT_ENABLED
        if self.is_auto or self is FlightMode.OFFBOARD:
            flags |= BASE_MODE_AUTO_ENABLED | BASE_MODE_GUIDED_ENABLED
        if self in (FlightMode.POSCTL, FlightMode.ORBIT):
            flags |= BASE_MODE_GUIDED_ENABLED
        if armed:
            flags |= BASE_MODE_SAFETY_ARMED
        return flags

    def name_for(self, autopilot: Autopilot) -> str:
        """The name the autopilot's own tools show (``AUTO.RTL`` on PX4, ``RTL`` on ArduPilot)."""
        if autopilot is Autopilot.ARDUPILOT:
            return self.ardupilot_name or self.px4_name
        return self.px4_name


#: ArduCopter (``mode number``, ``name``) of the mode doing each job (ArduCopter's ``mode.h``).
_ARDUCOPTER: dict[FlightMode, tuple[int, str]] = {
    FlightMode.STABILIZED: (0, "STABILIZE"),
    FlightMode.ACRO: (1, "ACRO"),
    FlightMode.ALTCTL: (2, "ALT_HOLD"),
    FlightMode.AUTO_MISSION: (3, "AUTO"),
    FlightMode.OFFBOARD: (4, "GUIDED"),
    FlightMode.AUTO_LOITER: (5, "LOITER"),
    FlightMode.AUTO_RTL: (6, "RTL"),
    FlightMode.ORBIT: (7, "CIRCLE"),
    FlightMode.AUTO_LAND: (9, "LAND"),
    FlightMode.POSCTL: (16, "POSHOLD"),
    FlightMode.AUTO_FOLLOW_TARGET: (23, "FOLLOW"),
}
_ARDU_BY_NUMBER = {number: mode for mode, (number, _) in _ARDUCOPTER.items()}
_PX4_BY_MAIN_SUB = {mode.value: mode for mode in FlightMode}


def mode_from_main_sub(main_mode: int, sub_mode: int) -> FlightMode | None:
    """The mode for PX4 ``(main, sub)``; ``None`` for a pair PX4 does not define."""
    return _PX4_BY_MAIN_SUB.get((main_mode, sub_mode))


def mode_from_custom_mode(custom_mode: int) -> FlightMode | None:
    """The mode in a full 32-bit PX4 ``custom_mode``; ``None`` when the low 16 bits are set or it is unknown."""
    if custom_mode < 0 or custom_mode > 0xFFFFFFFF or custom_mode & 0xFFFF:
        return None
    return mode_from_main_sub((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


def decode_custom_mode(autopilot: Autopilot, custom_mode: int) -> FlightMode | None:
    """The mode in a heartbeat's ``custom_mode`` from ``autopilot``; ``None`` for one not in the table."""
    if autopilot is Autopilot.ARDUPILOT:
        return _ARDU_BY_NUMBER.get(custom_mode)
    return _PX4_BY_MAIN_SUB.get(((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF))


def mode_name(autopilot: Autopilot, custom_mode: int) -> str:
    """Human-readable name of a heartbeat's mode as the autopilot's tools show it (``AUTO.RTL``, ``GUIDED``)."""
    if autopilot is Autopilot.ARDUPILOT:
        mode = _ARDU_BY_NUMBER.get(custom_mode)
        return mode.name_for(autopilot) if mode is not None else f"MODE_{custom_mode}"
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    px4 = _PX4_BY_MAIN_SUB.get((main, sub))
    return px4.px4_name if px4 is not None else f"PX4_{main}.{sub}"


def set_mode_params(autopilot: Autopilot, mode: FlightMode, *, armed: bool) -> tuple[float, float, float]:
    """``(param1, param2, param3)`` of ``MAV_CMD_DO_SET_MODE`` asking ``autopilot`` for ``mode``.

    Raises:
        ValueError: the autopilot has no such mode.
    """
    base = float(BASE_MODE_CUSTOM_MODE_ENABLED | (BASE_MODE_SAFETY_ARMED if armed else 0))
    if autopilot is Autopilot.ARDUPILOT:
        number = mode.ardupilot_number
        if number is None:
            msg = f"ArduPilot Copter has no mode for PX4's {mode.px4_name}"
            raise ValueError(msg)
        return (base, float(number), 0.0)
    return (base, float(mode.main_mode), float(mode.sub_mode))


def mode_from_set_mode_params(base_mode: float, main_or_custom: float, sub_mode: float) -> FlightMode | None:
    """Decode PX4 ``MAV_CMD_DO_SET_MODE`` params as MAVSDK, MAVProxy and QGC send them; ``None`` if invalid.

    MAVSDK and MAVProxy put PX4's main mode in param2 and the sub mode in param3; QGC's PX4
    plugin may put the whole ``custom_mode`` in param2.
    """
    if not (int(base_mode) & BASE_MODE_CUSTOM_MODE_ENABLED):
        return None
    main = int(main_or_custom)
    if main != main_or_custom or sub_mode != int(sub_mode):
        return None
    if main > 0xFF:
        return mode_from_custom_mode(main)
    return mode_from_main_sub(main, int(sub_mode))
