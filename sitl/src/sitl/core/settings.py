"""What the autopilot's logic reads: its parameters in SI units, whichever autopilot's names they have.

The navigator, the failsafes, the commander and the control cascade never look a parameter up by
name: they read one :class:`FlightSettings`, which the personality builds from its own parameter
table (PX4's ``MPC_XY_CRUISE`` in m/s, ArduCopter's ``WPNAV_SPEED`` in cm/s: both become
``cruise_speed_mps``). A settings object is rebuilt only when a parameter changes
(:attr:`sitl.core.params.ParamTable.settings`), so reading it costs an attribute lookup.

The failsafe actions are :class:`Action` values; ``None`` where the personality has no
such failsafe (ArduCopter has no offboard-stream failsafe: GUIDED keeps its last target).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from sitl.core.control import ControlGains

__all__ = ["Action", "FlightSettings", "RtlOrder"]


class Action(enum.Enum):
    """What a failsafe does when it triggers."""

    WARN = "warn"
    HOLD = "hold"
    RETURN = "return"
    LAND = "land"
    POSITION = "position"
    DISARM = "disarm"


class RtlOrder(enum.Enum):
    """Where a return waits before landing."""

    #: PX4: return at ``RTL_RETURN_ALT``, descend to ``RTL_DESCEND_ALT``, wait ``RTL_LAND_DELAY``, land.
    DESCEND_THEN_WAIT = "descend_then_wait"
    #: ArduCopter: return at ``RTL_ALT``, wait ``RTL_LOIT_TIME`` there, then descend and land (or hold at
    #: ``RTL_ALT_FINAL``).
    WAIT_THEN_DESCEND = "wait_then_descend"


@dataclass(frozen=True, slots=True)
class FlightSettings:
    """Every tunable the core uses, in SI units (m, s, m/s, rad), from one personality's parameters."""

    gains: ControlGains
    # ------------------------------------------------------------ speeds and accelerations
    cruise_speed_mps: float
    """Horizontal speed of the auto modes (mission, return, reposition)."""
    max_speed_xy_mps: float
    """Horizontal speed limit (and the sticks' full deflection in position control)."""
    offboard_speed_xy_mps: float
    """Horizontal speed limit while following an offboard / GUIDED position target."""
    climb_speed_mps: float
    descent_speed_mps: float
    acc_xy_mps2: float
    acc_up_mps2: float
    acc_down_mps2: float
    takeoff_speed_mps: float
    # ------------------------------------------------------------ navigation
    takeoff_alt_m: float
    """Takeoff altitude above home when a takeoff or a mission start gives none."""
    acceptance_xy_m: float
    acceptance_z_m: float
    # ------------------------------------------------------------ landing
    land_speed_mps: float
    """Final descent speed (below ``land_slow_below_m``)."""
    land_fast_speed_mps: float
    """Descent speed above ``land_fast_above_m`` (linear in between)."""
    land_slow_below_m: float
    land_fast_above_m: float
    # ------------------------------------------------------------ return
    rtl_return_alt_m: float
    rtl_climb_min_m: float
    """Climb at least this much above the present altitude before returning (ArduCopter ``RTL_CLIMB_MIN``)."""
    rtl_descend_alt_m: float
    rtl_loiter_s: float
    """Hover at home this long before landing (-1: forever)."""
    rtl_final_alt_m: float
    """ArduCopter ``RTL_ALT_FINAL``: > 0 hovers there instead of landing; 0 lands."""
    rtl_speed_mps: float
    """Return speed; NaN: the cruise speed."""
    rtl_order: RtlOrder
    # ------------------------------------------------------------ sticks
    manual_tilt_max_rad: float
    manual_yaw_rate_max_radps: float
    # ------------------------------------------------------------ arming and disarming
    disarm_after_landing_s: float
    """Auto-disarm this long after landing; NaN: never."""
    disarm_preflight_s: float
    """Auto-disarm when armed on the ground without taking off; NaN: never."""
    # ------------------------------------------------------------ failsafes
    battery_low_remaining: float
    """Remaining fraction at or below which the low-battery failsafe triggers (negative: never)."""
    battery_critical_remaining: float
    battery_low_voltage_v: float
    """Pack voltage that triggers it after ``battery_voltage_timer_s`` (0: off; ArduCopter ``BATT_LOW_VOLT``)."""
    battery_critical_voltage_v: float
    battery_voltage_timer_s: float
    battery_low_action: Action
    battery_critical_action: Action
    datalink_timeout_s: float
    datalink_action: Action | None
    """None: the data-link failsafe is off."""
    datalink_sysid: int
    """Only heartbeats from this system id are the ground station's (ArduCopter ``SYSID_MYGCS``); 0: any GCS or
    onboard controller (PX4)."""
    offboard_timeout_s: float
    offboard_loss_action: Action | None
    """None: no offboard-stream failsafe (ArduCopter: GUIDED holds its last position target)."""
    manual_timeout_s: float
    manual_loss_action: Action
    fence_radius_m: float
    """Circular fence around home (0: off)."""
    fence_max_alt_m: float
    """Fence ceiling above home (0: off)."""
    fence_action: Action | None
    """None: every fence (circle, ceiling, uploaded polygons and circles) is off."""
    fence_uploaded: bool
    """Whether uploaded fence polygons and circles are enforced (ArduCopter ``FENCE_TYPE`` bit 4)."""
    disarm_on_ground_failsafe: bool
    """A battery or data-link failsafe while armed on the ground disarms (ArduCopter)."""
    # ------------------------------------------------------------ GUIDED / offboard specifics
    guided_takeoff_required: bool
    """ArduCopter: a landed vehicle in GUIDED stays on the ground until MAV_CMD_NAV_TAKEOFF."""
    guided_timeout_s: float
    """ArduCopter ``GUID_TIMEOUT``: velocity, acceleration and attitude targets older than this stop the
    vehicle (position targets never expire); NaN: never."""
    # ------------------------------------------------------------ orbit and follow-me (PX4)
    orbit_radius_max_m: float
    follow_height_m: float
    follow_distance_m: float
    follow_angle_rad: float
    follow_responsiveness: float
    follow_altitude_mode: int
    follow_max_speed_mps: float
    # ------------------------------------------------------------ failure injection (PX4)
    failure_injection_enabled: bool = False
    """PX4 ``SYS_FAILURE_EN``: MAV_CMD_INJECT_FAILURE is accepted (ArduCopter has no such command)."""

    @property
    def has_fence(self) -> bool:
        return self.fence_action is not None and (
            self.fence_radius_m > 0.0 or self.fence_max_alt_m > 0.0 or self.fence_uploaded
        )

    @property
    def rtl_hovers_forever(self) -> bool:
        return self.rtl_loiter_s < 0.0
