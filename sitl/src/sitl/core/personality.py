"""Autopilot personalities: what makes the same vehicle look and behave like PX4 or like ArduCopter.

A :class:`Personality` is everything that differs between the two on the wire and in their rules,
gathered in one place so the rest of the core asks instead of branching on names:

* identity: ``HEARTBEAT.autopilot``, how ``custom_mode`` and ``base_mode`` encode a mode, the
  mode names, the firmware version and the protocol capabilities AUTOPILOT_VERSION advertises;
* modes: which modes it flies, the mode it boots in, how ``MAV_CMD_DO_SET_MODE`` names a mode;
* parameters: its table (PX4's or ArduCopter's names and units), how integers travel (PX4
  bytewise, ArduPilot as a float cast), and which personality has a name this one lacks;
* conventions: mission item 0 is home on ArduPilot; GUIDED needs MAV_CMD_NAV_TAKEOFF to leave the
  ground; the failsafe behaviours (through :class:`~sitl.core.settings.FlightSettings`).

The modes themselves are the shared table :mod:`uav_common.autopilot_modes`; both personalities
fly the same :class:`FlightMode` values (GUIDED is ``OFFBOARD``, LOITER is ``AUTO_LOITER``...).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from sitl.core.params import PARAM_SPECS, ParamSpec, ParamTable, px4_settings
from sitl.core.params_ardupilot import ARDUCOPTER_PARAM_SPECS, ardupilot_settings
from sitl.core.protocol import MavProtocolCapability as Cap
from uav_common import autopilot_modes as modes
from uav_common.autopilot_modes import (
    BASE_MODE_CUSTOM_MODE_ENABLED,
    BASE_MODE_GUIDED_ENABLED,
    BASE_MODE_MANUAL_INPUT_ENABLED,
    BASE_MODE_SAFETY_ARMED,
    BASE_MODE_STABILIZE_ENABLED,
    Autopilot,
    FlightMode,
)

__all__ = [
    "ARDUCOPTER",
    "PERSONALITIES",
    "PX4",
    "ConfigDefaults",
    "Personality",
    "UnknownPersonalityError",
    "personality_named",
]


class UnknownPersonalityError(ValueError):
    """A personality name that is neither ``px4`` nor ``ardupilot``."""


@dataclass(frozen=True)
class ConfigDefaults:
    """The configuration values a personality turns into its own parameter defaults."""

    battery_return_land: bool
    battery_low_remaining: float
    battery_critical_remaining: float
    battery_capacity_mah: float
    battery_cells: int
    datalink_action: str  # disabled, hold, return, land
    datalink_timeout_s: float
    offboard_action: str  # hold, return, land
    offboard_timeout_s: float
    geofence_action: str  # disabled, warn, hold, return, land
    geofence_radius_m: float
    geofence_max_altitude_m: float
    system_id: int


@dataclass(frozen=True)
class Personality:
    """One autopilot's face; the two instances are :data:`PX4` and :data:`ARDUCOPTER`."""

    name: str
    """The ``--autopilot`` value: ``px4`` or ``ardupilot``."""
    label: str
    autopilot: Autopilot
    flown_modes: frozenset[FlightMode]
    boot_mode: FlightMode
    param_specs: tuple[ParamSpec, ...]
    int_params_bytewise: bool
    mission_home_item: bool
    """ArduPilot: mission item 0 is home; the mission proper starts at item 1."""
    capabilities: int
    """``AUTOPILOT_VERSION.capabilities``: exactly what this emulator implements for this personality."""
    flight_sw_version: int
    """``major << 24 | minor << 16 | patch << 8 | type`` (255: official release)."""
    takeoff_modes: frozenset[FlightMode]
    """Modes in which MAV_CMD_NAV_TAKEOFF starts a takeoff (ArduCopter: user takeoff in GUIDED/LOITER; PX4 switches
    to AUTO.TAKEOFF from any mode)."""
    offboard_needs_stream: bool
    """PX4: OFFBOARD needs a setpoint stream before the switch; ArduCopter enters GUIDED holding position."""

    # ------------------------------------------------------------ modes on the wire
    @property
    def mav_autopilot(self) -> int:
        return self.autopilot.mav_autopilot

    @property
    def is_ardupilot(self) -> bool:
        return self.autopilot is Autopilot.ARDUPILOT

    def custom_mode(self, mode: FlightMode) -> int:
        """``HEARTBEAT.custom_mode`` for ``mode``."""
        if self.is_ardupilot:
            number = mode.ardupilot_number
            return 0 if number is None else number
        return mode.custom_mode

    def base_mode(self, mode: FlightMode, *, armed: bool) -> int:
        """``HEARTBEAT.base_mode`` as the real autopilot fills it."""
        if not self.is_ardupilot:
            return mode.base_mode(armed=armed)
        # ArduCopter: STABILIZE | MANUAL_INPUT | CUSTOM always; GUIDED while its position controller runs.
        flags = BASE_MODE_CUSTOM_MODE_ENABLED | BASE_MODE_STABILIZE_ENABLED | BASE_MODE_MANUAL_INPUT_ENABLED
        if mode not in (FlightMode.STABILIZED, FlightMode.ALTCTL):
            flags |= BASE_MODE_GUIDED_ENABLED
        if armed:
            flags |= BASE_MODE_SAFETY_ARMED
        return flags

    def mode_name(self, mode: FlightMode) -> str:
        """The name this autopilot's own tools show (``AUTO.RTL`` / ``RTL``)."""
        return mode.name_for(self.autopilot)

    def _flown(self, mode: FlightMode | None) -> FlightMode | None:
        return mode if mode in self.flown_modes else None

    def mode_from_custom_mode(self, custom_mode: int) -> FlightMode | None:
        """The flown mode a ``SET_MODE.custom_mode`` names; ``None`` if unknown or not flown."""
        if self.is_ardupilot:
            return self._flown(modes.decode_custom_mode(Autopilot.ARDUPILOT, custom_mode))
        return self._flown(modes.mode_from_custom_mode(custom_mode))

    def mode_from_set_mode_params(self, base_mode: float, param2: float, param3: float) -> FlightMode | None:
        """The flown mode ``MAV_CMD_DO_SET_MODE`` asks for; ``None`` if unknown or not flown.

        PX4: param2 main + param3 sub (MAVSDK, MAVProxy) or the whole custom_mode in param2 (QGC).
        ArduPilot: param2 is the mode number (MAVProxy's ``mode GUIDED``, MAVSDK, QGC).
        """
        if not self.is_ardupilot:
            return self._flown(modes.mode_from_set_mode_params(base_mode, param2, param3))
        if not (int(base_mode) & BASE_MODE_CUSTOM_MODE_ENABLED) or param2 != int(param2) or param2 < 0:
            return None
        return self._flown(modes.decode_custom_mode(Autopilot.ARDUPILOT, int(param2)))

    def needs_position(self, mode: FlightMode) -> bool:
        """Every flown mode but the attitude modes needs a position estimate."""
        return mode not in (FlightMode.MANUAL, FlightMode.STABILIZED, FlightMode.ALTCTL)

    def armable(self, mode: FlightMode) -> bool:
        """Whether arming is allowed in ``mode`` (ArduCopter: not in AUTO, RTL, LAND; PX4: not in RTL, LAND)."""
        if mode in (FlightMode.AUTO_RTL, FlightMode.AUTO_LAND):
            return False
        return not (self.is_ardupilot and mode in (FlightMode.AUTO_MISSION, FlightMode.ORBIT))

    # ------------------------------------------------------------ parameters
    def other(self) -> Personality:
        return ARDUCOPTER if self is PX4 else PX4

    def unknown_param_hint(self, name: str) -> str:
        """Which personality has ``name`` when this one does not (empty when neither has it)."""
        other = self.other()
        if any(spec.name == name for spec in other.param_specs):
            return f"{name} is a {other.label} parameter, not {self.label}'s: start uav-sitl --autopilot {other.name}"
        return ""

    def param_table(self, defaults: Mapping[str, float] | None = None) -> ParamTable:
        """An empty (default-valued) table of this personality's parameters.

        Raises:
            ValueError: a default names a parameter this personality does not have (the message says which
                personality has it) or is out of range.
        """
        return ParamTable(
            self.param_specs,
            defaults,
            settings_of=ardupilot_settings if self.is_ardupilot else px4_settings,
            unknown_hint=self.unknown_param_hint,
            cross_check=_no_cross_check if self.is_ardupilot else None,
        )

    def config_defaults(self, c: ConfigDefaults) -> dict[str, float]:
        """The parameter defaults the configuration's ``failsafe``, ``battery`` and ``mavlink`` sections give."""
        if self.is_ardupilot:
            return _ardupilot_config_defaults(c)
        return _px4_config_defaults(c)


def _no_cross_check(_table: ParamTable, _name: str, _value: float) -> str | None:
    return None


def _px4_config_defaults(c: ConfigDefaults) -> dict[str, float]:
    action_codes = {"disabled": 0, "hold": 1, "return": 2, "land": 3}
    obl_codes = {"hold": 5, "return": 3, "land": 4}
    gf_codes = {"disabled": 0, "warn": 1, "hold": 2, "return": 3, "land": 5}
    if c.datalink_action not in action_codes:
        msg = f"failsafe.datalink_loss_action cannot be {c.datalink_action!r}"
        raise ValueError(msg)
    return {
        "BAT_LOW_THR": c.battery_low_remaining,
        "BAT_CRIT_THR": c.battery_critical_remaining,
        "COM_LOW_BAT_ACT": 3 if c.battery_return_land else 0,
        "NAV_DLL_ACT": action_codes[c.datalink_action],
        "COM_DL_LOSS_T": c.datalink_timeout_s,
        "COM_OBL_RC_ACT": obl_codes[c.offboard_action],
        "COM_OF_LOSS_T": c.offboard_timeout_s,
        "GF_ACTION": gf_codes[c.geofence_action],
        "GF_MAX_HOR_DIST": c.geofence_radius_m,
        "GF_MAX_VER_DIST": c.geofence_max_altitude_m,
        "BAT1_N_CELLS": c.battery_cells,
        "BAT1_CAPACITY": c.battery_capacity_mah,
        "MAV_SYS_ID": c.system_id,
    }


def _ardupilot_config_defaults(c: ConfigDefaults) -> dict[str, float]:
    gcs_codes = {"disabled": 0, "return": 1, "land": 5}
    fence_codes = {"warn": 0, "return": 1, "land": 2, "hold": 4}
    if c.datalink_action not in gcs_codes:
        msg = (
            f"failsafe.datalink_loss_action cannot be {c.datalink_action!r} with --autopilot ardupilot "
            "(ArduCopter's FS_GCS_ENABLE returns or lands: use disabled, return or land)"
        )
        raise ValueError(msg)
    out: dict[str, float] = {
        "BATT_CAPACITY": c.battery_capacity_mah,
        "BATT_LOW_MAH": round(c.battery_low_remaining * c.battery_capacity_mah, 3),
        "BATT_CRT_MAH": round(c.battery_critical_remaining * c.battery_capacity_mah, 3),
        "BATT_FS_LOW_ACT": 2 if c.battery_return_land else 0,
        "BATT_FS_CRT_ACT": 1 if c.battery_return_land else 0,
        "FS_GCS_ENABLE": gcs_codes[c.datalink_action],
        "FS_GCS_TIMEOUT": min(max(c.datalink_timeout_s, 2.0), 120.0),
        "FENCE_ENABLE": 0 if c.geofence_action == "disabled" else 1,
        "SYSID_THISMAV": c.system_id,
    }
    if c.geofence_action != "disabled":
        out["FENCE_ACTION"] = fence_codes[c.geofence_action]
    fence_type = 4
    if c.geofence_radius_m > 0.0:
        out["FENCE_RADIUS"] = min(max(c.geofence_radius_m, 30.0), 10000.0)
        fence_type |= 2
    if c.geofence_max_altitude_m > 0.0:
        out["FENCE_ALT_MAX"] = min(max(c.geofence_max_altitude_m, 10.0), 1000.0)
        fence_type |= 1
    out["FENCE_TYPE"] = fence_type
    return out


def _version(major: int, minor: int, patch: int) -> int:
    return (major << 24) | (minor << 16) | (patch << 8) | 255


_COMMON_CAPS = (
    Cap.MISSION_INT
    | Cap.COMMAND_INT
    | Cap.SET_POSITION_TARGET_LOCAL_NED
    | Cap.SET_POSITION_TARGET_GLOBAL_INT
    | Cap.SET_ATTITUDE_TARGET
    | Cap.MAVLINK2
    | Cap.MISSION_FENCE
)

PX4 = Personality(
    name="px4",
    label="PX4",
    autopilot=Autopilot.PX4,
    flown_modes=frozenset(
        {
            FlightMode.MANUAL,
            FlightMode.POSCTL,
            FlightMode.ORBIT,
            FlightMode.AUTO_TAKEOFF,
            FlightMode.AUTO_LOITER,
            FlightMode.AUTO_MISSION,
            FlightMode.AUTO_RTL,
            FlightMode.AUTO_LAND,
            FlightMode.AUTO_FOLLOW_TARGET,
            FlightMode.OFFBOARD,
        }
    ),
    boot_mode=FlightMode.AUTO_LOITER,
    param_specs=PARAM_SPECS,
    int_params_bytewise=True,
    mission_home_item=False,
    capabilities=int(_COMMON_CAPS | Cap.MISSION_FLOAT | Cap.PARAM_ENCODE_BYTEWISE),
    flight_sw_version=_version(1, 14, 0),
    takeoff_modes=frozenset(),
    offboard_needs_stream=True,
)

ARDUCOPTER = Personality(
    name="ardupilot",
    label="ArduPilot",
    autopilot=Autopilot.ARDUPILOT,
    flown_modes=frozenset(
        {
            FlightMode.STABILIZED,
            FlightMode.ALTCTL,
            FlightMode.POSCTL,
            FlightMode.AUTO_LOITER,
            FlightMode.AUTO_MISSION,
            FlightMode.AUTO_RTL,
            FlightMode.AUTO_LAND,
            FlightMode.OFFBOARD,
        }
    ),
    boot_mode=FlightMode.STABILIZED,
    param_specs=ARDUCOPTER_PARAM_SPECS,
    int_params_bytewise=False,
    mission_home_item=True,
    capabilities=int(_COMMON_CAPS | Cap.MISSION_FLOAT | Cap.PARAM_FLOAT | Cap.PARAM_ENCODE_C_CAST),
    flight_sw_version=_version(4, 5, 7),
    takeoff_modes=frozenset({FlightMode.OFFBOARD, FlightMode.AUTO_LOITER}),
    offboard_needs_stream=False,
)

PERSONALITIES: dict[str, Personality] = {p.name: p for p in (PX4, ARDUCOPTER)}


def personality_named(name: str) -> Personality:
    """``px4`` or ``ardupilot`` (case-insensitive).

    Raises:
        UnknownPersonalityError: any other name; the message lists the known ones.
    """
    found = PERSONALITIES.get(name.strip().lower())
    if found is None:
        known = ", ".join(sorted(PERSONALITIES))
        msg = f"unknown autopilot personality {name!r}; choose one of: {known}"
        raise UnknownPersonalityError(msg)
    return found
