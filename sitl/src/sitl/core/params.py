"""The parameter table: names, types, defaults and ranges that drive the autopilot; PX4's table.

A :class:`ParamTable` holds one personality's parameters (PX4's :data:`PARAM_SPECS` by default,
ArduCopter's in :mod:`sitl.core.params_ardupilot`) and turns them into the
:class:`~sitl.core.settings.FlightSettings` the core reads (:attr:`ParamTable.settings`, rebuilt
only after a change). Integers travel *bytewise* over MAVLink for PX4 (the int32 bit pattern
reinterpreted as a float32), as MAVSDK and QGC expect from a PX4 autopilot; ArduPilot casts them.
Values are validated on every write; a rejected write leaves the old value.
"""

from __future__ import annotations

import enum
import math
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from sitl.core.control import ControlGains
from sitl.core.settings import Action, FlightSettings, RtlOrder

__all__ = [
    "PARAM_SPECS",
    "ParamSpec",
    "ParamTable",
    "ParamType",
    "SetOutcome",
    "decode_wire_value",
    "encode_wire_value",
    "px4_settings",
]


class ParamType(enum.IntEnum):
    """``MAV_PARAM_TYPE`` values we use."""

    INT8 = 2
    INT16 = 4
    INT32 = 6
    REAL32 = 9

    @property
    def is_integer(self) -> bool:
        return self is not ParamType.REAL32


@dataclass(frozen=True)
class ParamSpec:
    name: str
    type: ParamType
    default: float
    min: float
    max: float
    unit: str
    description: str
    choices: tuple[int, ...] | None = None
    read_only: bool = False

    def check(self, value: float) -> str | None:
        """``None`` if ``value`` is acceptable, else why not."""
        if not math.isfinite(value):
            return f"{self.name}: value must be finite, got {value}"
        if self.type.is_integer and value != int(value):
            return f"{self.name}: integer parameter, got {value}"
        if not self.min <= value <= self.max:
            return f"{self.name}: {value:g} out of range [{self.min:g}, {self.max:g}]"
        if self.choices is not None and int(value) not in self.choices:
            return f"{self.name}: {value:g} not one of {', '.join(str(c) for c in self.choices)}"
        return None


def _f(name: str, default: float, lo: float, hi: float, unit: str, desc: str) -> ParamSpec:  # noqa: PLR0917
    return ParamSpec(name, ParamType.REAL32, default, lo, hi, unit, desc)


def _i(  # noqa: PLR0917 - table rows read best positionally
    name: str, default: int, lo: int, hi: int, desc: str, choices: tuple[int, ...] | None = None, *, ro: bool = False
) -> ParamSpec:
    return ParamSpec(name, ParamType.INT32, float(default), float(lo), float(hi), "", desc, choices, ro)


PARAM_SPECS: tuple[ParamSpec, ...] = (
    # Commander: arming, failsafes
    _f("BAT_CRIT_THR", 0.07, 0.0, 0.5, "norm", "Critical battery remaining: failsafe lands (COM_LOW_BAT_ACT 3)"),
    _f("BAT_LOW_THR", 0.15, 0.0, 0.5, "norm", "Low battery remaining: failsafe returns (COM_LOW_BAT_ACT 3)"),
    _i("BAT1_N_CELLS", 4, 1, 14, "Cells of the simulated pack (read-only: set battery.cells in config)", ro=True),
    ParamSpec(
        "BAT1_CAPACITY",
        ParamType.REAL32,
        3500.0,
        100.0,
        100000.0,
        "mAh",
        "Capacity of the pack (read-only)",
        None,
        True,
    ),
    _f("COM_DISARM_LAND", 2.0, -1.0, 20.0, "s", "Auto-disarm this long after landing (<= 0: never)"),
    _f("COM_DISARM_PRFLT", 10.0, -1.0, 60.0, "s", "Auto-disarm if armed on the ground without takeoff (<= 0: never)"),
    _f("COM_DL_LOSS_T", 10.0, 0.5, 300.0, "s", "Data link loss timeout (no GCS/SDK heartbeat)"),
    _i("COM_LOW_BAT_ACT", 3, 0, 3, "Battery failsafe: 0 warn only, 3 return at low then land at critical", (0, 3)),
    _i("COM_OBL_RC_ACT", 5, 0, 5, "Offboard loss action: 0 position, 3 return, 4 land, 5 hold", (0, 3, 4, 5)),
    _f("COM_OF_LOSS_T", 1.0, 0.1, 60.0, "s", "Offboard setpoint stream loss timeout"),
    _f("COM_RC_LOSS_T", 0.5, 0.1, 35.0, "s", "Manual control (MANUAL_CONTROL) loss timeout"),
    _i("GF_ACTION", 3, 0, 5, "Geofence breach: 0 none, 1 warn, 2 hold, 3 return, 5 land", (0, 1, 2, 3, 5)),
    _f("GF_MAX_HOR_DIST", 1000.0, 0.0, 100000.0, "m", "Geofence radius around home (0: off)"),
    _f("GF_MAX_VER_DIST", 120.0, 0.0, 10000.0, "m", "Geofence maximum altitude above home (0: off)"),
    _i("MAV_SYS_ID", 1, 1, 254, "MAVLink system id (read-only: set mavlink.system_id in config)", ro=True),
    _i("NAV_DLL_ACT", 0, 0, 3, "Data link loss action: 0 off, 1 hold, 2 return, 3 land", (0, 1, 2, 3)),
    _i("NAV_RCL_ACT", 2, 0, 3, "Manual control loss action: 0 off (hold), 1 hold, 2 return, 3 land", (0, 1, 2, 3)),
    _i("SYS_AUTOSTART", 4001, 0, 9999999, "Airframe (4001: generic quadcopter; read-only)", ro=True),
    _i("SYS_FAILURE_EN", 0, 0, 1, "Failure injection (MAV_CMD_INJECT_FAILURE): 0 refused, 1 allowed", (0, 1)),
    # Navigator: mission, takeoff, RTL
    _f("MIS_TAKEOFF_ALT", 2.5, 0.5, 200.0, "m", "Takeoff altitude above home (NaN takeoff altitude)"),
    _f("NAV_ACC_RAD", 2.0, 0.05, 200.0, "m", "Default horizontal waypoint acceptance radius"),
    _f("NAV_MC_ALT_RAD", 0.8, 0.05, 200.0, "m", "Vertical waypoint acceptance radius"),
    _f("RTL_DESCEND_ALT", 30.0, 2.0, 500.0, "m", "RTL: descend to this altitude above home before landing"),
    _f("RTL_LAND_DELAY", 0.0, -1.0, 300.0, "s", "RTL: hover this long before landing (-1: hover forever)"),
    _f("RTL_RETURN_ALT", 60.0, 0.0, 1000.0, "m", "RTL: climb to at least this altitude above home"),
    # Follow-me (AUTO.FOLLOW_TARGET) and orbit
    _f("FLW_TGT_HT", 8.0, 8.0, 1000.0, "m", "Follow-me: height above home (FLW_TGT_ALT_M 0) or above the target (2)"),
    _f("FLW_TGT_DST", 8.0, 1.0, 1000.0, "m", "Follow-me: horizontal distance to the target"),
    _f("FLW_TGT_FA", 180.0, -180.0, 180.0, "deg", "Follow-me: angle from the target's heading (0 front, 180 behind)"),
    _f("FLW_TGT_RS", 0.1, 0.0, 1.0, "norm", "Follow-me: target filter (0 follows at once, 1 smooths most)"),
    _i(
        "FLW_TGT_ALT_M",
        0,
        0,
        2,
        "Follow-me altitude: 0 height above home, 1 (terrain: as 0), 2 target's + height",
        (0, 1, 2),
    ),
    _f("FLW_TGT_MAX_VEL", 5.0, 0.0, 20.0, "m/s", "Follow-me: maximum speed around the target"),
    _f("MC_ORBIT_RAD_MAX", 1000.0, 1.0, 10000.0, "m", "Orbit: largest radius DO_ORBIT accepts"),
    # Multicopter position control
    _f("MPC_ACC_DOWN_MAX", 3.0, 1.0, 15.0, "m/s^2", "Maximum downward acceleration"),
    _f("MPC_ACC_HOR", 3.0, 1.0, 15.0, "m/s^2", "Maximum horizontal acceleration in auto modes"),
    _f("MPC_ACC_UP_MAX", 4.0, 1.0, 15.0, "m/s^2", "Maximum upward acceleration"),
    _f("MPC_LAND_SPEED", 0.7, 0.2, 3.0, "m/s", "Landing descent speed"),
    _f("MPC_MAN_TILT_MAX", 35.0, 1.0, 85.0, "deg", "Maximum tilt in MANUAL"),
    _f("MPC_MAN_Y_MAX", 150.0, 0.0, 400.0, "deg/s", "Maximum yaw rate from the sticks"),
    _f("MPC_THR_HOVER", 0.225, 0.05, 0.9, "norm", "Collective thrust (fraction of maximum) that hovers"),
    _f("MPC_TILTMAX_AIR", 45.0, 10.0, 89.0, "deg", "Maximum tilt in position-controlled flight"),
    _f("MPC_TKO_SPEED", 1.5, 0.5, 5.0, "m/s", "Takeoff climb speed"),
    _f("MPC_XY_CRUISE", 5.0, 0.5, 20.0, "m/s", "Horizontal speed in auto modes (mission, RTL)"),
    _f("MPC_XY_P", 0.95, 0.0, 3.0, "1/s", "Horizontal position gain"),
    _f("MPC_XY_VEL_I_ACC", 0.4, 0.0, 60.0, "1/s^2", "Horizontal velocity integral gain"),
    _f("MPC_XY_VEL_MAX", 12.0, 0.5, 20.0, "m/s", "Maximum horizontal speed"),
    _f("MPC_XY_VEL_P_ACC", 1.8, 0.5, 15.0, "1/s", "Horizontal velocity proportional gain"),
    _f("MPC_Z_P", 1.0, 0.0, 3.0, "1/s", "Vertical position gain"),
    _f("MPC_Z_VEL_I_ACC", 2.0, 0.0, 60.0, "1/s^2", "Vertical velocity integral gain"),
    _f("MPC_Z_VEL_MAX_DN", 1.5, 0.5, 4.0, "m/s", "Maximum descent speed"),
    _f("MPC_Z_VEL_MAX_UP", 3.0, 0.5, 8.0, "m/s", "Maximum climb speed"),
    _f("MPC_Z_VEL_P_ACC", 4.0, 0.5, 15.0, "1/s", "Vertical velocity proportional gain"),
    # Multicopter attitude and rate control
    _f("MC_PITCH_P", 6.5, 0.0, 12.0, "1/s", "Pitch angle gain"),
    _f("MC_PITCHRATE_D", 0.003, 0.0, 0.1, "", "Pitch rate derivative gain"),
    _f("MC_PITCHRATE_I", 0.2, 0.0, 2.0, "", "Pitch rate integral gain"),
    _f("MC_PITCHRATE_MAX", 220.0, 0.0, 1800.0, "deg/s", "Maximum pitch rate"),
    _f("MC_PITCHRATE_P", 0.15, 0.01, 0.6, "", "Pitch rate proportional gain"),
    _f("MC_ROLL_P", 6.5, 0.0, 12.0, "1/s", "Roll angle gain"),
    _f("MC_ROLLRATE_D", 0.003, 0.0, 0.1, "", "Roll rate derivative gain"),
    _f("MC_ROLLRATE_I", 0.2, 0.0, 2.0, "", "Roll rate integral gain"),
    _f("MC_ROLLRATE_MAX", 220.0, 0.0, 1800.0, "deg/s", "Maximum roll rate"),
    _f("MC_ROLLRATE_P", 0.15, 0.01, 0.6, "", "Roll rate proportional gain"),
    _f("MC_YAW_P", 2.8, 0.0, 5.0, "1/s", "Yaw angle gain"),
    _f("MC_YAWRATE_I", 0.1, 0.0, 2.0, "", "Yaw rate integral gain"),
    _f("MC_YAWRATE_MAX", 200.0, 0.0, 1800.0, "deg/s", "Maximum yaw rate"),
    _f("MC_YAWRATE_P", 0.2, 0.0, 0.6, "", "Yaw rate proportional gain"),
)


def encode_wire_value(value: float, ptype: ParamType, *, bytewise: bool = True) -> float:
    """Value as it travels in ``PARAM_VALUE.param_value``: integers bytewise (PX4) or cast to float (ArduPilot)."""
    if bytewise and ptype.is_integer:
        return float(struct.unpack("<f", struct.pack("<i", int(value)))[0])
    return float(value)


def decode_wire_value(wire: float, wire_type: int, spec: ParamSpec, *, bytewise: bool = True) -> float | None:  # noqa: PLR0911
    """Value a client meant by ``PARAM_SET(param_value=wire, param_type=wire_type)``.

    With ``bytewise`` (PX4), integer types are decoded bytewise; a REAL32 sent for an
    integer parameter is accepted when it is integral (some tools do that). Without
    (ArduPilot), every type carries the value as a float.
    Returns ``None`` when the bits cannot be a value of this parameter.
    """
    if not isinstance(wire, float):
        return None
    if not bytewise:
        return wire if 1 <= wire_type <= 10 else None
    if wire_type in (1, 2, 3, 4, 5, 6):  # UINT8..INT32: the low bytes carry the integer
        raw = struct.unpack("<i", struct.pack("<f", wire))[0]
        if wire_type == 1:
            return float(raw & 0xFF)
        if wire_type == 2:
            return float(struct.unpack("<b", struct.pack("<B", raw & 0xFF))[0])
        if wire_type == 3:
            return float(raw & 0xFFFF)
        if wire_type == 4:
            return float(struct.unpack("<h", struct.pack("<H", raw & 0xFFFF))[0])
        if wire_type == 5:
            return float(raw & 0xFFFFFFFF)
        return float(raw)
    if wire_type == ParamType.REAL32:
        return wire
    return None


@dataclass(frozen=True)
class SetOutcome:
    accepted: bool
    value: float
    reason: str = ""


class ParamTable:
    """Values of every parameter, in a stable (sorted) index order.

    Args:
        specs: the personality's parameters (PX4's by default).
        defaults: values replacing the built-in defaults (from the configuration).
        settings_of: builds the :class:`FlightSettings` from this table (PX4's mapping by default).
        unknown_hint: what to add to "unknown parameter X" (e.g. which personality has X).
        cross_check: extra validation of a write ``(table, name, value) -> problem or None``.

    Raises:
        ValueError: a default names an unknown parameter or is out of range.
    """

    def __init__(
        self,
        specs: tuple[ParamSpec, ...] = PARAM_SPECS,
        defaults: Mapping[str, float] | None = None,
        *,
        settings_of: Callable[[ParamTable], FlightSettings] | None = None,
        unknown_hint: Callable[[str], str] | None = None,
        cross_check: Callable[[ParamTable, str, float], str | None] | None = None,
    ) -> None:
        self._specs = {s.name: s for s in sorted(specs, key=lambda s: s.name)}
        self._names = tuple(self._specs)
        self._index = {name: i for i, name in enumerate(self._names)}
        self._defaults = {name: spec.default for name, spec in self._specs.items()}
        self._settings_of = settings_of if settings_of is not None else px4_settings
        self._unknown_hint = unknown_hint
        self._extra_check = cross_check if cross_check is not None else _px4_cross_check
        self._settings: FlightSettings | None = None
        self._settings_version = -1
        for name, value in (defaults or {}).items():
            spec = self._specs.get(name)
            if spec is None:
                msg = self.unknown_message(name)
                raise ValueError(msg)
            problem = spec.check(float(value))
            if problem:
                raise ValueError(problem)
            self._defaults[name] = float(value)
        self._values = dict(self._defaults)
        self.version = 0

    @property
    def names(self) -> tuple[str, ...]:
        return self._names

    @property
    def settings(self) -> FlightSettings:
        """The values as the core reads them (rebuilt after a change only)."""
        if self._settings is None or self._settings_version != self.version:
            self._settings = self._settings_of(self)
            self._settings_version = self.version
        return self._settings

    def unknown_message(self, name: str) -> str:
        """``unknown parameter 'X'``, plus which personality has it when that is known."""
        hint = self._unknown_hint(name) if self._unknown_hint is not None else ""
        return f"unknown parameter {name!r}" + (f": {hint}" if hint else "")

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name: object) -> bool:
        return name in self._specs

    def index_of(self, name: str) -> int:
        return self._index[name]

    def spec(self, name: str) -> ParamSpec:
        return self._specs[name]

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def default(self, name: str) -> float:
        return self._defaults[name]

    def set(self, name: str, value: float, *, force: bool = False) -> SetOutcome:
        """Validate and store; ``force`` also writes read-only parameters (start-up only)."""
        spec = self._specs.get(name)
        if spec is None:
            return SetOutcome(False, math.nan, self.unknown_message(name))
        current = self._values[name]
        if spec.read_only and not force:
            if value == current:
                return SetOutcome(True, current)
            return SetOutcome(False, current, f"{name} is read-only")
        problem = spec.check(value)
        if problem is None:
            problem = self._extra_check(self, name, value)
        if problem is not None:
            return SetOutcome(False, current, problem)
        if value != current:
            self._values[name] = float(value)
            self.version += 1
        return SetOutcome(True, float(value))

    def changed_from_default(self) -> dict[str, float]:
        """Values differing from the defaults: what the parameter file persists."""
        return {n: v for n, v in self._values.items() if v != self._defaults[n] and not self._specs[n].read_only}

    def apply_persisted(self, values: Mapping[str, object]) -> list[str]:
        """Load persisted values; returns one message per entry that was skipped."""
        problems = []
        for name, raw in values.items():
            if name not in self._specs:
                problems.append(f"{self.unknown_message(name)}; ignored")
                continue
            if not isinstance(raw, int | float) or isinstance(raw, bool):
                problems.append(f"{name}: not a number ({raw!r}), ignored")
                continue
            outcome = self.set(name, float(raw))
            if not outcome.accepted:
                problems.append(f"{outcome.reason}; kept {outcome.value:g}")
        return problems


def _px4_cross_check(table: ParamTable, name: str, value: float) -> str | None:
    if name not in ("BAT_LOW_THR", "BAT_CRIT_THR"):
        return None
    low = value if name == "BAT_LOW_THR" else table["BAT_LOW_THR"]
    crit = value if name == "BAT_CRIT_THR" else table["BAT_CRIT_THR"]
    if crit >= low:
        return f"{name}: need BAT_CRIT_THR ({crit:g}) < BAT_LOW_THR ({low:g})"
    return None


_PX4_DLL = {1: Action.HOLD, 2: Action.RETURN, 3: Action.LAND}
_PX4_OBL = {0: Action.POSITION, 3: Action.RETURN, 4: Action.LAND, 5: Action.HOLD}
_PX4_RCL = {0: Action.HOLD, 1: Action.HOLD, 2: Action.RETURN, 3: Action.LAND}
_PX4_GF = {1: Action.WARN, 2: Action.HOLD, 3: Action.RETURN, 5: Action.LAND}


def px4_settings(p: ParamTable) -> FlightSettings:
    """PX4's parameters as the core reads them (the same numbers, in the same units)."""
    low_bat_act = int(p["COM_LOW_BAT_ACT"]) == 3
    disarm_land = p["COM_DISARM_LAND"]
    disarm_preflight = p["COM_DISARM_PRFLT"]
    return FlightSettings(
        gains=ControlGains.from_params(p),
        cruise_speed_mps=p["MPC_XY_CRUISE"],
        max_speed_xy_mps=p["MPC_XY_VEL_MAX"],
        offboard_speed_xy_mps=p["MPC_XY_VEL_MAX"],
        climb_speed_mps=p["MPC_Z_VEL_MAX_UP"],
        descent_speed_mps=p["MPC_Z_VEL_MAX_DN"],
        acc_xy_mps2=p["MPC_ACC_HOR"],
        acc_up_mps2=p["MPC_ACC_UP_MAX"],
        acc_down_mps2=p["MPC_ACC_DOWN_MAX"],
        takeoff_speed_mps=p["MPC_TKO_SPEED"],
        takeoff_alt_m=p["MIS_TAKEOFF_ALT"],
        acceptance_xy_m=p["NAV_ACC_RAD"],
        acceptance_z_m=p["NAV_MC_ALT_RAD"],
        land_speed_mps=p["MPC_LAND_SPEED"],
        land_fast_speed_mps=max(p["MPC_LAND_SPEED"], p["MPC_Z_VEL_MAX_DN"]),
        land_slow_below_m=5.0,
        land_fast_above_m=10.0,
        rtl_return_alt_m=p["RTL_RETURN_ALT"],
        rtl_climb_min_m=0.0,
        rtl_descend_alt_m=p["RTL_DESCEND_ALT"],
        rtl_loiter_s=p["RTL_LAND_DELAY"],
        rtl_final_alt_m=0.0,
        rtl_speed_mps=math.nan,
        rtl_order=RtlOrder.DESCEND_THEN_WAIT,
        manual_tilt_max_rad=math.radians(p["MPC_MAN_TILT_MAX"]),
        manual_yaw_rate_max_radps=math.radians(p["MPC_MAN_Y_MAX"]),
        disarm_after_landing_s=disarm_land if disarm_land > 0.0 else math.nan,
        disarm_preflight_s=disarm_preflight if disarm_preflight > 0.0 else math.nan,
        battery_low_remaining=p["BAT_LOW_THR"],
        battery_critical_remaining=p["BAT_CRIT_THR"],
        battery_low_voltage_v=0.0,
        battery_critical_voltage_v=0.0,
        battery_voltage_timer_s=0.0,
        battery_low_action=Action.RETURN if low_bat_act else Action.WARN,
        battery_critical_action=Action.LAND if low_bat_act else Action.WARN,
        datalink_timeout_s=p["COM_DL_LOSS_T"],
        datalink_action=_PX4_DLL.get(int(p["NAV_DLL_ACT"])),
        datalink_sysid=0,
        offboard_timeout_s=p["COM_OF_LOSS_T"],
        offboard_loss_action=_PX4_OBL.get(int(p["COM_OBL_RC_ACT"]), Action.HOLD),
        manual_timeout_s=p["COM_RC_LOSS_T"],
        manual_loss_action=_PX4_RCL.get(int(p["NAV_RCL_ACT"]), Action.HOLD),
        fence_radius_m=p["GF_MAX_HOR_DIST"],
        fence_max_alt_m=p["GF_MAX_VER_DIST"],
        fence_action=_PX4_GF.get(int(p["GF_ACTION"])),
        fence_uploaded=True,
        disarm_on_ground_failsafe=False,
        guided_takeoff_required=False,
        guided_timeout_s=math.nan,
        orbit_radius_max_m=p["MC_ORBIT_RAD_MAX"],
        failure_injection_enabled=int(p["SYS_FAILURE_EN"]) == 1,
        follow_height_m=p["FLW_TGT_HT"],
        follow_distance_m=p["FLW_TGT_DST"],
        follow_angle_rad=math.radians(p["FLW_TGT_FA"]),
        follow_responsiveness=p["FLW_TGT_RS"],
        follow_altitude_mode=int(p["FLW_TGT_ALT_M"]),
        follow_max_speed_mps=p["FLW_TGT_MAX_VEL"],
    )
