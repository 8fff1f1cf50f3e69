"""ArduCopter's parameters: the names, units and codes an ArduPilot user expects, for what this autopilot models.

Units are ArduCopter's (cm, cm/s, cm/s/s, centidegrees, ms where ArduCopter uses them), so a
parameter file or a script written for ArduCopter means the same here; :func:`ardupilot_settings`
converts them to the SI :class:`~sitl.core.settings.FlightSettings` the core reads. The control
gains carry ArduCopter's names (``ATC_*``, ``PSC_*``, ``MOT_THST_HOVER``) but this airframe's tune
as defaults (the same cascade flies both personalities; its loops have PX4's structure, see
docs/sitl.md). Integers travel as plain floats (ArduPilot's "C cast" encoding), with ArduPilot's
INT8/INT16/INT32 types.
"""

from __future__ import annotations

import math

from sitl.core.control import ControlGains
from sitl.core.params import ParamSpec, ParamTable, ParamType
from sitl.core.settings import Action, FlightSettings, RtlOrder

__all__ = ["ARDUCOPTER_PARAM_SPECS", "ardupilot_settings"]


def _f(name: str, default: float, lo: float, hi: float, unit: str, desc: str) -> ParamSpec:  # noqa: PLR0917
    return ParamSpec(name, ParamType.REAL32, default, lo, hi, unit, desc)


def _i(  # noqa: PLR0917 - table rows read best positionally
    ptype: ParamType,
    name: str,
    default: int,
    lo: int,
    hi: int,
    unit: str,
    desc: str,
    choices: tuple[int, ...] | None = None,
    *,
    ro: bool = False,
) -> ParamSpec:
    return ParamSpec(name, ptype, float(default), float(lo), float(hi), unit, desc, choices, ro)


I8, I16, I32 = ParamType.INT8, ParamType.INT16, ParamType.INT32

#: Failsafe action codes (ArduCopter ``BATT_FS_*_ACT``, ``FS_GCS_ENABLE``, ``FS_THR_ENABLE``, ``FENCE_ACTION``).
#: SmartRTL is not modelled: its codes take ArduCopter's fallback when SmartRTL is unavailable.
_BATT_ACT = {0: Action.WARN, 1: Action.LAND, 2: Action.RETURN, 3: Action.RETURN, 4: Action.LAND}
_GCS_ACT = {1: Action.RETURN, 3: Action.RETURN, 4: Action.LAND, 5: Action.LAND}
_THR_ACT = {0: Action.WARN, 1: Action.RETURN, 3: Action.LAND, 4: Action.RETURN, 5: Action.LAND}
_FENCE_ACT = {0: Action.WARN, 1: Action.RETURN, 2: Action.LAND, 3: Action.RETURN, 4: Action.HOLD}

FENCE_TYPE_ALT_MAX = 1
FENCE_TYPE_CIRCLE = 2
FENCE_TYPE_POLYGON = 4

ARDUCOPTER_PARAM_SPECS: tuple[ParamSpec, ...] = (
    # Identity (read-only: set in the configuration)
    _i(I16, "SYSID_THISMAV", 1, 1, 255, "", "MAVLink system id (read-only: set mavlink.system_id in config)", ro=True),
    _i(I8, "FRAME_CLASS", 1, 0, 20, "", "Frame class (1: quad; read-only)", ro=True),
    _i(I8, "FRAME_TYPE", 1, 0, 20, "", "Frame type (1: X; read-only)", ro=True),
    # Waypoint navigation (AUTO, GUIDED, RTL)
    _f("WPNAV_SPEED", 1000.0, 20.0, 2000.0, "cm/s", "Horizontal speed in AUTO, GUIDED and RTL"),
    _f("WPNAV_SPEED_UP", 250.0, 10.0, 1000.0, "cm/s", "Climb speed (also the takeoff climb)"),
    _f("WPNAV_SPEED_DN", 150.0, 10.0, 500.0, "cm/s", "Descent speed"),
    _f("WPNAV_ACCEL", 250.0, 50.0, 500.0, "cm/s/s", "Horizontal acceleration"),
    _f("WPNAV_ACCEL_Z", 100.0, 50.0, 500.0, "cm/s/s", "Vertical acceleration"),
    _f("WPNAV_RADIUS", 200.0, 5.0, 1000.0, "cm", "Waypoint acceptance radius"),
    _f("LOIT_SPEED", 1250.0, 20.0, 3500.0, "cm/s", "Horizontal speed at full stick (LOITER, POSHOLD) and the limit"),
    _f("PILOT_Y_RATE", 202.5, 1.0, 500.0, "deg/s", "Yaw rate at full stick"),
    _i(I16, "ANGLE_MAX", 3000, 1000, 8000, "cdeg", "Lean angle limit"),
    _f("GUID_TIMEOUT", 3.0, 0.1, 5.0, "s", "GUIDED: velocity, acceleration and attitude targets expire after this"),
    _i(I8, "DISARM_DELAY", 10, 0, 127, "s", "Auto-disarm when armed on the ground without taking off (0: never)"),
    # Landing and return
    _i(I16, "LAND_SPEED", 50, 30, 200, "cm/s", "Final descent speed (below LAND_ALT_LOW)"),
    _i(I16, "LAND_SPEED_HIGH", 0, 0, 2500, "cm/s", "Descent speed above LAND_ALT_LOW (0: WPNAV_SPEED_DN)"),
    _i(I16, "LAND_ALT_LOW", 1000, 100, 10000, "cm", "Altitude of the switch to LAND_SPEED"),
    _i(I32, "RTL_ALT", 1500, 200, 300000, "cm", "RTL: return at least this high above home"),
    _i(I16, "RTL_ALT_FINAL", 0, 0, 1000, "cm", "RTL: hover this high above home instead of landing (0: land)"),
    _i(I16, "RTL_CLIMB_MIN", 0, 0, 3000, "cm", "RTL: climb at least this much first"),
    _i(I32, "RTL_LOIT_TIME", 5000, 0, 60000, "ms", "RTL: hover over home this long before the final descent"),
    _i(I16, "RTL_SPEED", 0, 0, 2000, "cm/s", "RTL: return speed (0: WPNAV_SPEED)"),
    # Battery failsafe
    _i(I32, "BATT_CAPACITY", 3500, 100, 100000, "mAh", "Pack capacity (read-only: set battery.capacity_mah)", ro=True),
    _f("BATT_LOW_MAH", 525.0, 0.0, 100000.0, "mAh", "Low-battery failsafe below this remaining capacity (0: off)"),
    _f("BATT_CRT_MAH", 245.0, 0.0, 100000.0, "mAh", "Critical-battery failsafe below this remaining capacity (0: off)"),
    _f("BATT_LOW_VOLT", 0.0, 0.0, 100.0, "V", "Low-battery failsafe below this voltage for BATT_LOW_TIMER (0: off)"),
    _f("BATT_CRT_VOLT", 0.0, 0.0, 100.0, "V", "Critical-battery failsafe below this voltage (0: off)"),
    _i(I8, "BATT_LOW_TIMER", 10, 0, 120, "s", "A voltage must stay low this long to trigger"),
    _i(
        I8,
        "BATT_FS_LOW_ACT",
        2,
        0,
        4,
        "",
        "Low battery: 0 warn, 1 land, 2 RTL, 3 SmartRTL->RTL, 4 SmartRTL->land",
        (0, 1, 2, 3, 4),
    ),
    _i(
        I8,
        "BATT_FS_CRT_ACT",
        1,
        0,
        4,
        "",
        "Critical battery: 0 warn, 1 land, 2 RTL, 3 SmartRTL->RTL, 4 ->land",
        (0, 1, 2, 3, 4),
    ),
    # GCS (data link) and RC (MANUAL_CONTROL) failsafes
    _i(
        I8,
        "FS_GCS_ENABLE",
        0,
        0,
        5,
        "",
        "GCS failsafe: 0 off, 1 RTL, 3 SmartRTL->RTL, 4 SmartRTL->land, 5 land",
        (0, 1, 3, 4, 5),
    ),
    _f("FS_GCS_TIMEOUT", 5.0, 2.0, 120.0, "s", "GCS failsafe after this long without the GCS's heartbeat"),
    _i(I16, "SYSID_MYGCS", 255, 1, 255, "", "System id whose heartbeats are the ground station's"),
    _i(
        I8,
        "FS_THR_ENABLE",
        1,
        0,
        5,
        "",
        "RC failsafe: 0 off, 1 RTL, 3 land, 4 SmartRTL->RTL, 5 SmartRTL->land",
        (0, 1, 3, 4, 5),
    ),
    _f("RC_OVERRIDE_TIME", 3.0, 0.1, 120.0, "s", "MANUAL_CONTROL (RC override) is lost after this long"),
    # Geofence
    _i(I8, "FENCE_ENABLE", 1, 0, 1, "", "Geofence: 0 off, 1 on", (0, 1)),
    _i(I8, "FENCE_TYPE", 7, 0, 7, "", "Geofence types (bits): 1 max altitude, 2 circle around home, 4 polygons"),
    _i(
        I8,
        "FENCE_ACTION",
        1,
        0,
        4,
        "",
        "Breach: 0 report, 1 RTL or land, 2 land, 3 SmartRTL->RTL, 4 brake (hold)",
        (0, 1, 2, 3, 4),
    ),
    _f("FENCE_RADIUS", 1000.0, 30.0, 10000.0, "m", "Circular fence radius around home"),
    _f("FENCE_ALT_MAX", 120.0, 10.0, 1000.0, "m", "Fence ceiling above home"),
    # Attitude and rate control (this airframe's tune)
    _f("ATC_ANG_RLL_P", 6.5, 0.0, 12.0, "1/s", "Roll angle gain"),
    _f("ATC_ANG_PIT_P", 6.5, 0.0, 12.0, "1/s", "Pitch angle gain"),
    _f("ATC_ANG_YAW_P", 2.8, 0.0, 5.0, "1/s", "Yaw angle gain"),
    _f("ATC_RAT_RLL_P", 0.15, 0.01, 0.6, "", "Roll rate proportional gain"),
    _f("ATC_RAT_RLL_I", 0.2, 0.0, 2.0, "", "Roll rate integral gain"),
    _f("ATC_RAT_RLL_D", 0.003, 0.0, 0.1, "", "Roll rate derivative gain"),
    _f("ATC_RAT_PIT_P", 0.15, 0.01, 0.6, "", "Pitch rate proportional gain"),
    _f("ATC_RAT_PIT_I", 0.2, 0.0, 2.0, "", "Pitch rate integral gain"),
    _f("ATC_RAT_PIT_D", 0.003, 0.0, 0.1, "", "Pitch rate derivative gain"),
    _f("ATC_RAT_YAW_P", 0.2, 0.0, 0.6, "", "Yaw rate proportional gain"),
    _f("ATC_RAT_YAW_I", 0.1, 0.0, 2.0, "", "Yaw rate integral gain"),
    _f("ATC_RATE_R_MAX", 220.0, 1.0, 1800.0, "deg/s", "Maximum roll rate"),
    _f("ATC_RATE_P_MAX", 220.0, 1.0, 1800.0, "deg/s", "Maximum pitch rate"),
    _f("ATC_RATE_Y_MAX", 200.0, 1.0, 1800.0, "deg/s", "Maximum yaw rate"),
    # Position control (this airframe's tune)
    _f("PSC_POSXY_P", 0.95, 0.0, 3.0, "1/s", "Horizontal position gain"),
    _f("PSC_VELXY_P", 1.8, 0.5, 15.0, "1/s", "Horizontal velocity proportional gain"),
    _f("PSC_VELXY_I", 0.4, 0.0, 60.0, "1/s/s", "Horizontal velocity integral gain"),
    _f("PSC_POSZ_P", 1.0, 0.0, 3.0, "1/s", "Vertical position gain"),
    _f("PSC_VELZ_P", 4.0, 0.5, 15.0, "1/s", "Vertical velocity proportional gain"),
    _f("PSC_VELZ_I", 2.0, 0.0, 60.0, "1/s/s", "Vertical velocity integral gain"),
    _f("MOT_THST_HOVER", 0.225, 0.05, 0.9, "norm", "Collective thrust (fraction of maximum) that hovers"),
)


def ardupilot_settings(p: ParamTable) -> FlightSettings:
    """ArduCopter's parameters (cm, cdeg, ms, action codes) as the core reads them (SI)."""
    gains = ControlGains(
        xy_p=p["PSC_POSXY_P"],
        z_p=p["PSC_POSZ_P"],
        xy_vel_p=p["PSC_VELXY_P"],
        xy_vel_i=p["PSC_VELXY_I"],
        z_vel_p=p["PSC_VELZ_P"],
        z_vel_i=p["PSC_VELZ_I"],
        roll_p=p["ATC_ANG_RLL_P"],
        pitch_p=p["ATC_ANG_PIT_P"],
        yaw_p=p["ATC_ANG_YAW_P"],
        roll_rate_pid=(p["ATC_RAT_RLL_P"], p["ATC_RAT_RLL_I"], p["ATC_RAT_RLL_D"]),
        pitch_rate_pid=(p["ATC_RAT_PIT_P"], p["ATC_RAT_PIT_I"], p["ATC_RAT_PIT_D"]),
        yaw_rate_pid=(p["ATC_RAT_YAW_P"], p["ATC_RAT_YAW_I"], 0.0),
        max_rates_radps=(
            math.radians(p["ATC_RATE_R_MAX"]),
            math.radians(p["ATC_RATE_P_MAX"]),
            math.radians(p["ATC_RATE_Y_MAX"]),
        ),
        hover_thrust=p["MOT_THST_HOVER"],
        tilt_max_rad=math.radians(p["ANGLE_MAX"] / 100.0),
    )
    wp_speed = p["WPNAV_SPEED"] / 100.0
    speed_dn = p["WPNAV_SPEED_DN"] / 100.0
    capacity = p["BATT_CAPACITY"]
    fence_on = int(p["FENCE_ENABLE"]) == 1
    fence_type = int(p["FENCE_TYPE"])
    land_low = p["LAND_ALT_LOW"] / 100.0
    disarm_delay = p["DISARM_DELAY"]
    return FlightSettings(
        gains=gains,
        cruise_speed_mps=wp_speed,
        max_speed_xy_mps=max(wp_speed, p["LOIT_SPEED"] / 100.0),
        offboard_speed_xy_mps=wp_speed,
        climb_speed_mps=p["WPNAV_SPEED_UP"] / 100.0,
        descent_speed_mps=speed_dn,
        acc_xy_mps2=p["WPNAV_ACCEL"] / 100.0,
        acc_up_mps2=p["WPNAV_ACCEL_Z"] / 100.0,
        acc_down_mps2=p["WPNAV_ACCEL_Z"] / 100.0,
        takeoff_speed_mps=p["WPNAV_SPEED_UP"] / 100.0,
        takeoff_alt_m=2.5,
        acceptance_xy_m=p["WPNAV_RADIUS"] / 100.0,
        acceptance_z_m=0.8,
        land_speed_mps=p["LAND_SPEED"] / 100.0,
        land_fast_speed_mps=(p["LAND_SPEED_HIGH"] / 100.0) if p["LAND_SPEED_HIGH"] > 0.0 else speed_dn,
        land_slow_below_m=land_low,
        land_fast_above_m=land_low,
        rtl_return_alt_m=p["RTL_ALT"] / 100.0,
        rtl_climb_min_m=p["RTL_CLIMB_MIN"] / 100.0,
        rtl_descend_alt_m=p["RTL_ALT"] / 100.0,
        rtl_loiter_s=p["RTL_LOIT_TIME"] / 1000.0,
        rtl_final_alt_m=p["RTL_ALT_FINAL"] / 100.0,
        rtl_speed_mps=(p["RTL_SPEED"] / 100.0) if p["RTL_SPEED"] > 0.0 else math.nan,
        rtl_order=RtlOrder.WAIT_THEN_DESCEND,
        manual_tilt_max_rad=math.radians(p["ANGLE_MAX"] / 100.0),
        manual_yaw_rate_max_radps=math.radians(p["PILOT_Y_RATE"]),
        disarm_after_landing_s=0.0,
        disarm_preflight_s=float(disarm_delay) if disarm_delay > 0 else math.nan,
        battery_low_remaining=p["BATT_LOW_MAH"] / capacity if p["BATT_LOW_MAH"] > 0.0 else -1.0,
        battery_critical_remaining=p["BATT_CRT_MAH"] / capacity if p["BATT_CRT_MAH"] > 0.0 else -1.0,
        battery_low_voltage_v=p["BATT_LOW_VOLT"],
        battery_critical_voltage_v=p["BATT_CRT_VOLT"],
        battery_voltage_timer_s=p["BATT_LOW_TIMER"],
        battery_low_action=_BATT_ACT[int(p["BATT_FS_LOW_ACT"])],
        battery_critical_action=_BATT_ACT[int(p["BATT_FS_CRT_ACT"])],
        datalink_timeout_s=p["FS_GCS_TIMEOUT"],
        datalink_action=_GCS_ACT.get(int(p["FS_GCS_ENABLE"])),
        datalink_sysid=int(p["SYSID_MYGCS"]),
        offboard_timeout_s=p["GUID_TIMEOUT"],
        offboard_loss_action=None,
        manual_timeout_s=p["RC_OVERRIDE_TIME"],
        manual_loss_action=_THR_ACT[int(p["FS_THR_ENABLE"])],
        fence_radius_m=p["FENCE_RADIUS"] if fence_on and fence_type & FENCE_TYPE_CIRCLE else 0.0,
        fence_max_alt_m=p["FENCE_ALT_MAX"] if fence_on and fence_type & FENCE_TYPE_ALT_MAX else 0.0,
        fence_action=_FENCE_ACT[int(p["FENCE_ACTION"])] if fence_on and fence_type else None,
        fence_uploaded=fence_on and bool(fence_type & FENCE_TYPE_POLYGON),
        disarm_on_ground_failsafe=True,
        guided_takeoff_required=True,
        guided_timeout_s=p["GUID_TIMEOUT"],
        orbit_radius_max_m=0.0,
        follow_height_m=0.0,
        follow_distance_m=0.0,
        follow_angle_rad=0.0,
        follow_responsiveness=0.0,
        follow_altitude_mode=0,
        follow_max_speed_mps=0.0,
    )
