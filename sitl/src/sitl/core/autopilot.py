"""The autopilot core: commander (arming, modes, failsafes), navigator and control cascade.

Pure: no sockets, no clock, no JSBSim. The shell calls, in simulation time,

* :meth:`Autopilot.outer_update` every ``outer_loop_divider`` physics steps with
  the estimated state and the battery reading (land detection, failsafes, mode
  logic, position and velocity control), and
* :meth:`Autopilot.inner_update` every physics step with attitude and body rates
  (attitude and rate control, mixing), which returns the four motor duties.

Requests from MAVLink arrive as method calls (:meth:`arm`, :meth:`set_mode`,
:meth:`takeoff`...) returning a :class:`~sitl.core.protocol.MavResult`; what the
autopilot wants to say goes to :attr:`statustexts` and the other outboxes.

What differs between PX4 and ArduCopter is asked of :attr:`Autopilot.personality`
(:mod:`sitl.core.personality`) and read from :attr:`Autopilot.settings` (the
personality's parameters in SI units); the flight logic itself is shared.
"""

from __future__ import annotations

import math

from sitl.core.control import (
    GRAVITY_MPS2,
    ControlGains,
    Mixer,
    PositionController,
    RateController,
    Setpoint,
    attitude_rate_setpoint,
    quat_from_yaw,
)
from sitl.core.failsafe import FailsafeEvent, FailsafeInputs, FailsafeKind, FailsafeMonitor
from sitl.core.faults import FailureType, FaultState, InjectOutcome
from sitl.core.geofence import FenceStore
from sitl.core.landing import LandDetector
from sitl.core.mission import MissionItem, MissionStore
from sitl.core.mission_transfer import MissionServer
from sitl.core.modes import FlightMode, ModeContext, check_arm, check_mode_switch
from sitl.core.navigator import (
    FollowTarget,
    FollowTask,
    GotoTask,
    LandTask,
    MissionProgress,
    MissionTask,
    NavContext,
    NavOutput,
    NavPhase,
    OrbitTask,
    RtlTask,
    TakeoffTask,
    default_limits,
)
from sitl.core.offboard import AttitudeSetpoint
from sitl.core.params import ParamTable
from sitl.core.personality import PX4, Personality
from sitl.core.protocol import LandedState, MavCmd, MavFrame, MavResult, MavSeverity, MavState, MissionState
from sitl.core.settings import Action, FlightSettings
from sitl.core.state import LocalState
from uav_common.geo import GeoPoint, LocalProjection

__all__ = ["Autopilot", "ManualInput"]

NAN = math.nan
Task = GotoTask | TakeoffTask | LandTask | RtlTask | MissionTask | OrbitTask | FollowTask
Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


class ManualInput:
    """MANUAL_CONTROL sticks, normalised: pitch/roll/yaw in [-1, 1], throttle in [0, 1]."""

    __slots__ = ("pitch", "roll", "throttle", "yaw")

    def __init__(self, pitch: float, roll: float, throttle: float, yaw: float) -> None:
        self.pitch = pitch
        self.roll = roll
        self.throttle = throttle
        self.yaw = yaw


def _deadband(v: float, band: float = 0.05) -> float:
    if abs(v) <= band:
        return 0.0
    return math.copysign((abs(v) - band) / (1.0 - band), v)


def _quat_from_euler(roll: float, pitch: float, yaw: float) -> Quat:
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


_FAILSAFE_MODES = {
    Action.HOLD: FlightMode.AUTO_LOITER,
    Action.RETURN: FlightMode.AUTO_RTL,
    Action.LAND: FlightMode.AUTO_LAND,
    Action.POSITION: FlightMode.POSCTL,
}


class Autopilot:
    """One vehicle's autopilot. See the module docstring for the calling protocol."""

    def __init__(  # noqa: PLR0915 - the state of one autopilot
        self,
        *,
        params: ParamTable,
        home: GeoPoint,
        home_yaw_rad: float,
        mixer: Mixer,
        outer_dt_s: float,
        datalink_floor_s: float = 3.0,
        offboard_floor_s: float = 0.5,
        manual_floor_s: float = 0.5,
        personality: Personality = PX4,
    ) -> None:
        self.params = params
        self.personality = personality
        self.settings: FlightSettings = params.settings
        self.gains: ControlGains = self.settings.gains
        self.home = home
        self.projection = LocalProjection(home)
        self.outer_dt_s = outer_dt_s
        self.mode = personality.boot_mode
        self.armed = False
        self.crashed = False
        self.land_detector = LandDetector()
        # a client acting in wall time (MAVSDK: arm, then takeoff) may need this long at any speed factor
        self._client_wall_floor_s = datalink_floor_s
        self.faults = FaultState()
        self.failsafe = FailsafeMonitor(
            datalink_floor_s=datalink_floor_s, offboard_floor_s=offboard_floor_s, manual_floor_s=manual_floor_s
        )
        self._first_item = 1 if personality.mission_home_item else 0
        self.mission_store = MissionStore()
        self.fence_store = FenceStore(self.projection)
        self.mission_server = MissionServer(
            self.mission_store,
            self.fence_store,
            home_item=self._home_item if personality.mission_home_item else None,
        )
        self.mission_progress = MissionProgress(current=self._first_item)
        self.wall_scale = 1.0
        self.statustexts: list[tuple[MavSeverity, str]] = []
        self.heartbeat_due = False
        self.status_version = 0
        self.mission_current_changed = False
        self.t_s = 0.0
        self.wall_s = 0.0
        self.battery_remaining = 1.0
        self.battery_voltage_v = NAN
        self.est: LocalState | None = None
        self.last_nav: NavOutput | None = None
        self._task: Task | None = None
        self._offboard_sp: Setpoint | AttitudeSetpoint | None = None
        self._offboard_sp_t = 0.0
        self._manual: ManualInput | None = None
        self._speed_override = NAN
        self._takeoff_request: tuple[tuple[float, float] | None, float, float] | None = None
        self._reposition: tuple[Vec3, float, float] | None = None
        self._land_xy: tuple[float, float] | None = None
        self._user_takeoff: TakeoffTask | None = None
        self._orbit: OrbitTask | None = None
        self.follow_target: FollowTarget | None = None
        self._armed_at_s = 0.0
        self._armed_at_wall_s = 0.0
        self._landed_since_s = 0.0
        self._flew_since_arming = False
        self._pos_ctrl = PositionController()
        self._rate_ctrl = RateController()
        self._mixer = mixer
        self._q_sp: Quat = quat_from_yaw(home_yaw_rad)
        self._thrust = 0.0
        self._yaw_hold = home_yaw_rad
        self._yaw_rate_ff = NAN
        self._rate_sp: Vec3 | None = None
        self._alt_hold_down: float | None = None
        self._alt_integral = 0.0
        self._idle = True
        self._last_mission_seq = 0

    # ================================================================== status
    @property
    def landed(self) -> bool:
        return self.land_detector.landed

    @property
    def thrust(self) -> float:
        return self._thrust

    @property
    def attitude_setpoint(self) -> Quat:
        return self._q_sp

    @property
    def velocity_setpoint(self) -> Vec3:
        return self._pos_ctrl.velocity_setpoint

    @property
    def position_valid(self) -> bool:
        return self.est is not None and self.est.pos_valid

    @property
    def mode_name(self) -> str:
        return self.personality.mode_name(self.mode)

    @property
    def orbit_task(self) -> OrbitTask | None:
        """The orbit being flown (ORBIT mode)."""
        return self._orbit if self.mode is FlightMode.ORBIT else None

    @property
    def landed_state(self) -> LandedState:
        if self.landed:
            return LandedState.ON_GROUND
        nav = self.last_nav
        if nav is not None and self.armed:
            if nav.phase is NavPhase.TAKEOFF:
                return LandedState.TAKEOFF
            if nav.phase is NavPhase.LANDING:
                return LandedState.LANDING
        return LandedState.IN_AIR

    @property
    def system_status(self) -> MavState:
        if self.crashed:
            return MavState.FLIGHT_TERMINATION
        if self.failsafe.active and self.armed:
            return MavState.CRITICAL
        return MavState.ACTIVE if self.armed else MavState.STANDBY

    @property
    def mission_state(self) -> MissionState:
        prog = self.mission_progress
        paused = self.mode is not FlightMode.AUTO_MISSION
        if self.personality.mission_home_item and len(self.mission_store) <= 1:
            return MissionState.NO_MISSION  # ArduPilot: home alone is no mission
        return self.mission_store.state(started=prog.started, finished=prog.finished, paused=paused)

    @property
    def mission_current_seq(self) -> int:
        return self.mission_progress.current

    @property
    def mission_has_items(self) -> bool:
        """Whether there is a mission to fly (ArduPilot: more than the home item)."""
        return len(self.mission_store) > self._first_item

    def drain_reached(self) -> list[int]:
        out = list(self.mission_progress.reached)
        self.mission_progress.reached.clear()
        return out

    def _status_changed(self) -> None:
        """Mode, arming, landed or crash state changed: announce it (HEARTBEAT now)."""
        self.heartbeat_due = True
        self.status_version += 1

    @property
    def events_pending(self) -> bool:
        """Whether the shell has anything to send besides the periodic streams."""
        return bool(
            self.heartbeat_due or self.statustexts or self.mission_progress.reached or self.mission_current_changed
        )

    def say(self, severity: MavSeverity, text: str) -> None:
        self.statustexts.append((severity, text))

    def _manual_ok(self) -> bool:
        return self._manual is not None and not self.failsafe.manual.silent_for(
            self.settings.manual_timeout_s, self.t_s, self.wall_s, wall_scale=self.wall_scale, wall_floor_s=0.5
        )

    def mode_context(self) -> ModeContext:
        return ModeContext(
            armed=self.armed,
            landed=self.landed,
            crashed=self.crashed,
            position_valid=self.position_valid,
            home_valid=True,
            mission_valid=self.mission_has_items,
            offboard_stream_ok=self.failsafe.offboard_stream_ok(self.t_s, self.wall_s, self.params, self.wall_scale),
            manual_control_ok=self._manual_ok(),
            personality=self.personality,
        )

    def _home_item(self) -> MissionItem:
        """ArduPilot's mission item 0: the home position (AMSL)."""
        h = self.home
        return MissionItem(
            0, MavFrame.GLOBAL, MavCmd.NAV_WAYPOINT, 0, 1, 0.0, 0.0, 0.0, 0.0,
            round(h.lat_deg * 1e7), round(h.lon_deg * 1e7), h.alt_amsl_m,
        )  # fmt: skip

    # ================================================================== requests
    def arm(self, *, force: bool) -> MavResult:
        if self.armed:
            return MavResult.ACCEPTED
        if self.crashed:
            self.say(MavSeverity.CRITICAL, "Arming denied: vehicle crashed, flight terminated")
            return MavResult.DENIED
        if not force:
            reason = self.prearm_failure()
            if reason is not None:
                self.say(MavSeverity.CRITICAL, f"Arming denied: {reason}")
                return MavResult.DENIED
        self.armed = True
        self._armed_at_s = self.t_s
        self._armed_at_wall_s = self.wall_s
        self._landed_since_s = self.t_s
        self._flew_since_arming = not self.landed
        self._pos_ctrl.reset(self.est.vel_ned_mps if self.est else (0.0, 0.0, 0.0))
        self._rate_ctrl.reset()
        self._task = None
        self._user_takeoff = None
        self._status_changed()
        self.say(MavSeverity.INFO, "Armed by external command" + (" (forced)" if force else ""))
        return MavResult.ACCEPTED

    def prearm_failure(self) -> str | None:  # noqa: PLR0911 - one return per check
        s = self.settings
        if self.personality.needs_position(self.mode) and (self.est is None or not self.est.gps_ok):
            return "no GPS position"
        if self.est is None:
            return "no GPS position"
        if not self.landed:
            return "not landed"
        faults = self.faults
        if faults.mag is not FailureType.OK or faults.baro is not FailureType.OK:
            # PX4's preflight sensor checks refuse a compass or baro that is silent, stale or implausible
            return "compass 0 failed" if faults.mag is not FailureType.OK else "barometer 0 failed"
        if self.battery_remaining <= s.battery_critical_remaining:
            return f"battery critical ({100 * self.battery_remaining:.0f}%)"
        reason = check_arm(self.mode, self.mode_context())
        if reason is not None:
            return reason
        radius = s.fence_radius_m
        if radius > 0 and math.hypot(self.est.pos_ned_m[0], self.est.pos_ned_m[1]) > radius:
            return "outside the geofence"
        if s.fence_action is not None and s.fence_uploaded:
            zone = self.fence_store.fence.breach(self.est.pos_ned_m[0], self.est.pos_ned_m[1])
            if zone is not None:
                return f"outside the geofence ({zone})"
        return None

    def disarm(self, *, force: bool, reason: str = "external command") -> MavResult:
        if not self.armed:
            return MavResult.ACCEPTED
        if not force and not self.landed:
            self.say(MavSeverity.CRITICAL, "Disarming denied: not landed")
            return MavResult.DENIED
        self._disarm(f"Disarmed by {reason}" + (" (forced)" if force and not self.landed else ""))
        return MavResult.ACCEPTED

    def _disarm(self, text: str) -> None:
        self.armed = False
        self._thrust = 0.0
        self._idle = True
        self._user_takeoff = None
        self._status_changed()
        self.say(MavSeverity.INFO, text)

    def set_mode(self, mode: FlightMode, *, quiet: bool = False) -> MavResult:
        if mode is self.mode:
            if mode is FlightMode.AUTO_MISSION and self.mission_progress.finished:
                self._restart_mission_if_new()
            return MavResult.ACCEPTED
        reason = check_mode_switch(mode, self.mode_context())
        if reason is not None:
            if not quiet:
                self.say(MavSeverity.CRITICAL, f"Mode change to {self.personality.mode_name(mode)} denied: {reason}")
            return MavResult.DENIED
        self._enter_mode(mode)
        return MavResult.ACCEPTED

    def _enter_mode(self, mode: FlightMode) -> None:
        self.mode = mode
        self._task = None
        self._user_takeoff = None
        self._alt_hold_down = None
        self._status_changed()
        if mode is FlightMode.OFFBOARD and not self.personality.offboard_needs_stream and self.est is not None:
            # ArduCopter: GUIDED starts by holding where the vehicle is; targets sent before GUIDED were ignored
            self._offboard_sp = Setpoint(pos=self.est.pos_ned_m, yaw_rad=self.est.yaw_rad)
            self._offboard_sp_t = self.t_s
        if mode is FlightMode.AUTO_MISSION:
            self._restart_mission_if_new()
            self.mission_current_changed = True

    def _restart_mission_if_new(self) -> None:
        prog = self.mission_progress
        if prog.mission_id != self.mission_store.mission_id or (prog.finished and self.landed):
            self.mission_progress = MissionProgress(mission_id=self.mission_store.mission_id, current=self._first_item)
            self.mission_current_changed = True

    def takeoff(self, *, alt_amsl_m: float, lat_deg: float, lon_deg: float, yaw_deg: float) -> MavResult:  # noqa: PLR0911
        """NAV_TAKEOFF: NaN altitude means the personality's default takeoff altitude above home."""
        if self.crashed:
            return MavResult.DENIED
        if math.isnan(alt_amsl_m):
            rel_alt = self.settings.takeoff_alt_m
        elif math.isfinite(alt_amsl_m):
            rel_alt = alt_amsl_m - self.home.alt_amsl_m
        else:
            return MavResult.DENIED
        if self.personality.takeoff_modes:
            return self._user_takeoff_request(rel_alt, yaw_deg)
        if not 0.5 <= rel_alt <= 10000.0:
            self.say(MavSeverity.CRITICAL, f"Takeoff denied: altitude {rel_alt:.1f} m above home is invalid")
            return MavResult.DENIED
        if math.isinf(lat_deg) or math.isinf(lon_deg) or math.isinf(yaw_deg):
            return MavResult.DENIED
        xy = None
        if math.isfinite(lat_deg) and math.isfinite(lon_deg):
            if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
                return MavResult.DENIED
            n, e, _ = self.projection.to_ned(GeoPoint(lat_deg, lon_deg, self.home.alt_amsl_m))
            xy = (n, e)
        yaw = math.radians(yaw_deg) if math.isfinite(yaw_deg) else NAN
        previous = self._takeoff_request
        self._takeoff_request = (xy, rel_alt, yaw)
        if self.mode is FlightMode.AUTO_TAKEOFF:
            self._task = None
            return MavResult.ACCEPTED
        result = self.set_mode(FlightMode.AUTO_TAKEOFF)
        if result is not MavResult.ACCEPTED:
            self._takeoff_request = previous
        return result

    def _user_takeoff_request(self, rel_alt_m: float, yaw_deg: float) -> MavResult:
        """ArduCopter's user takeoff (GUIDED, LOITER): armed, landed, going up; the mode stays."""
        name = self.personality.mode_name(self.mode)
        problem = None
        if self.mode not in self.personality.takeoff_modes:
            problem = f"{name} does not take off (use GUIDED)"
        elif not self.armed:
            problem = "not armed"
        elif not self.landed:
            problem = "already flying"
        elif self.est is None or not rel_alt_m > -self.est.pos_ned_m[2] or rel_alt_m > 10000.0:
            problem = f"altitude {rel_alt_m:.1f} m above home is not above the vehicle"
        if problem is not None:
            self.say(MavSeverity.CRITICAL, f"Takeoff failed: {problem}")
            return MavResult.FAILED
        assert self.est is not None
        yaw = math.radians(yaw_deg) if math.isfinite(yaw_deg) and yaw_deg != 0.0 else self.est.yaw_rad
        here = self.est.pos_ned_m
        self._user_takeoff = TakeoffTask((here[0], here[1]), -rel_alt_m, yaw)
        return MavResult.ACCEPTED

    def land(self, *, lat_deg: float, lon_deg: float) -> MavResult:
        if math.isinf(lat_deg) or math.isinf(lon_deg):
            return MavResult.DENIED
        if math.isfinite(lat_deg) and math.isfinite(lon_deg):
            if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
                return MavResult.DENIED
            n, e, _ = self.projection.to_ned(GeoPoint(lat_deg, lon_deg, self.home.alt_amsl_m))
            self._land_xy = (n, e)
        else:
            self._land_xy = None
        if self.mode is FlightMode.AUTO_LAND:
            self._task = None
            return MavResult.ACCEPTED
        return self.set_mode(FlightMode.AUTO_LAND)

    def return_to_launch(self) -> MavResult:
        return self.set_mode(FlightMode.AUTO_RTL)

    def reposition(  # noqa: PLR0911
        self, *, lat_deg: float, lon_deg: float, alt_amsl_m: float, yaw_rad: float, speed_mps: float, change_mode: bool
    ) -> MavResult:
        """DO_REPOSITION: go to a point (NaN parts: keep the present ones) and hold there.

        PX4 holds there in AUTO.LOITER; ArduCopter flies there in GUIDED.
        """
        if any(math.isinf(v) for v in (lat_deg, lon_deg, alt_amsl_m, yaw_rad, speed_mps)):
            return MavResult.DENIED
        if not self.armed or self.landed or self.est is None:
            self.say(MavSeverity.CRITICAL, "Reposition denied: not flying")
            return MavResult.DENIED
        hold_mode = FlightMode.OFFBOARD if self.personality.is_ardupilot else FlightMode.AUTO_LOITER
        if not change_mode and self.mode is not hold_mode and not self.personality.is_ardupilot:
            return MavResult.DENIED
        n, e, d = self.est.pos_ned_m
        if math.isfinite(lat_deg) and math.isfinite(lon_deg):
            if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
                return MavResult.DENIED
            n, e, _ = self.projection.to_ned(GeoPoint(lat_deg, lon_deg, self.home.alt_amsl_m))
        if math.isfinite(alt_amsl_m):
            d = self.home.alt_amsl_m - alt_amsl_m
        if hold_mode is FlightMode.OFFBOARD:
            result = self.set_mode(FlightMode.OFFBOARD)
            if result is MavResult.ACCEPTED:
                self._offboard_sp = Setpoint(pos=(n, e, d), yaw_rad=yaw_rad if math.isfinite(yaw_rad) else NAN)
                self._offboard_sp_t = self.t_s
            return result
        speed = speed_mps if math.isfinite(speed_mps) and speed_mps > 0.0 else NAN
        self._reposition = ((n, e, d), yaw_rad if math.isfinite(yaw_rad) else NAN, speed)
        if self.mode is FlightMode.AUTO_LOITER:
            self._task = None
            return MavResult.ACCEPTED
        result = self.set_mode(FlightMode.AUTO_LOITER)
        if result is not MavResult.ACCEPTED:
            self._reposition = None
        return result

    def orbit(  # noqa: PLR0911
        self,
        *,
        radius_m: float,
        velocity_mps: float,
        yaw_behaviour: float,
        lat_deg: float,
        lon_deg: float,
        alt_amsl_m: float,
    ) -> MavResult:
        """DO_ORBIT (PX4): circle a centre (NaN: the present orbit's, else a radius south of the vehicle).

        ``radius_m``'s sign is the direction (positive: clockwise seen from above); NaN keeps the present
        radius; ``velocity_mps`` NaN keeps the present speed (1 m/s at first). Refused with the reason when
        the vehicle is not flying or the speed cannot be flown on that radius.
        """
        if any(math.isinf(v) for v in (radius_m, velocity_mps, yaw_behaviour, lat_deg, lon_deg, alt_amsl_m)):
            return MavResult.DENIED
        if not self.armed or self.landed or self.est is None:
            self.say(MavSeverity.CRITICAL, "Orbit denied: not flying")
            return MavResult.DENIED
        behaviour = self._orbit.yaw_behaviour if self._orbit is not None else 0
        if math.isfinite(yaw_behaviour):
            if yaw_behaviour not in (0, 1, 2, 3, 4):
                self.say(MavSeverity.CRITICAL, f"Orbit denied: unknown yaw behaviour {yaw_behaviour:g}")
                return MavResult.DENIED
            behaviour = int(yaw_behaviour)
        est = self.est
        previous = self._orbit if self.mode is FlightMode.ORBIT else None
        radius = (
            abs(radius_m) if math.isfinite(radius_m) else (previous.radius_m if previous else OrbitTask.RADIUS_MIN_M)
        )
        clockwise = radius_m > 0 if math.isfinite(radius_m) else (previous.velocity_mps >= 0 if previous else True)
        radius = min(max(radius, OrbitTask.RADIUS_MIN_M), self.settings.orbit_radius_max_m)
        speed = abs(velocity_mps) if math.isfinite(velocity_mps) else (abs(previous.velocity_mps) if previous else 1.0)
        acc = self.settings.acc_xy_mps2
        if speed >= self.settings.max_speed_xy_mps or speed * speed >= acc * radius:
            limit = min(self.settings.max_speed_xy_mps, math.sqrt(acc * radius))
            self.say(MavSeverity.CRITICAL, f"Orbit denied: {speed:.1f} m/s on {radius:.0f} m is over {limit:.1f} m/s")
            return MavResult.DENIED
        if math.isfinite(lat_deg) and math.isfinite(lon_deg):
            if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
                return MavResult.DENIED
            cn, ce, _ = self.projection.to_ned(GeoPoint(lat_deg, lon_deg, self.home.alt_amsl_m))
            centre = (cn, ce)
        elif previous is not None:
            centre = previous.centre
        else:
            centre = (est.pos_ned_m[0] - radius, est.pos_ned_m[1])
        down = (
            self.home.alt_amsl_m - alt_amsl_m
            if math.isfinite(alt_amsl_m)
            else (previous.down_m if previous is not None else est.pos_ned_m[2])
        )
        task = OrbitTask(centre, radius, speed if clockwise else -speed, behaviour, down, initial_yaw_rad=est.yaw_rad)
        if self.mode is not FlightMode.ORBIT:
            result = self.set_mode(FlightMode.ORBIT)
            if result is not MavResult.ACCEPTED:
                return result
        self._orbit = task
        self._task = None
        return MavResult.ACCEPTED

    def change_speed(self, speed_mps: float) -> MavResult:
        """DO_CHANGE_SPEED: > 0 sets the auto-mode speed, -2 restores the default, -1 keeps it."""
        if speed_mps == -1.0:
            return MavResult.ACCEPTED
        if speed_mps == -2.0:
            self._speed_override = NAN
            self.mission_progress.speed_mps = NAN
            return MavResult.ACCEPTED
        if not (math.isfinite(speed_mps) and 0.0 < speed_mps <= self.settings.max_speed_xy_mps):
            return MavResult.DENIED
        self._speed_override = speed_mps
        self.mission_progress.speed_mps = NAN
        return MavResult.ACCEPTED

    def set_mission_current(self, seq: int) -> MavResult:
        if self.personality.mission_home_item and seq == 0:
            seq = self._first_item  # ArduPilot: item 0 is home; the mission starts at 1
        if not self._first_item <= seq < len(self.mission_store):
            return MavResult.DENIED
        self._restart_mission_if_new()
        prog = self.mission_progress
        prog.current = seq
        prog.finished = False
        if isinstance(self._task, MissionTask):
            self._task.restart_item()
        self.mission_current_changed = True
        return MavResult.ACCEPTED

    def start_mission(self, first_seq: int) -> MavResult:
        if not self.mission_has_items:
            self.say(MavSeverity.CRITICAL, "Mission start denied: no mission")
            return MavResult.DENIED
        if first_seq > 0 and self.set_mission_current(first_seq) is not MavResult.ACCEPTED:
            return MavResult.DENIED
        return self.set_mode(FlightMode.AUTO_MISSION)

    def offboard_setpoint(self, sp: Setpoint | AttitudeSetpoint, t_s: float, wall_s: float) -> None:
        """A SET_POSITION_TARGET_* or SET_ATTITUDE_TARGET, already decoded."""
        if not self.personality.offboard_needs_stream and self.mode is not FlightMode.OFFBOARD:
            return  # ArduCopter ignores targets outside GUIDED
        if self._user_takeoff is not None and self.mode is FlightMode.OFFBOARD:
            # ArduCopter: a target replaces the takeoff; still on the ground, the vehicle then stays there
            self._user_takeoff = None
        self._offboard_sp = sp
        self._offboard_sp_t = t_s
        self.failsafe.offboard.heard(t_s, wall_s)

    def follow_target_update(self, target: FollowTarget) -> None:
        """A FOLLOW_TARGET report (the target's position and velocity)."""
        self.follow_target = target

    def manual_control(self, sticks: ManualInput, t_s: float, wall_s: float) -> None:
        self._manual = sticks
        self.failsafe.manual.heard(t_s, wall_s)

    def datalink_heard(self, t_s: float, wall_s: float) -> None:
        self.failsafe.gcs.heard(t_s, wall_s)

    def collision(self, world_id: int) -> None:
        """A collision reported on the simulation link: crash, disarm, announce."""
        if self.crashed:
            return
        self.crashed = True
        self.armed = False
        self._thrust = 0.0
        self._idle = True
        self._status_changed()
        self.say(
            MavSeverity.EMERGENCY,
            f"Collision (world object {world_id}): crashed, disarmed",
        )

    def mission_uploaded(self) -> None:
        """The mission store changed: restart progress; leave AUTO.MISSION if it became empty."""
        self.mission_progress = MissionProgress(mission_id=self.mission_store.mission_id, current=self._first_item)
        self.mission_current_changed = True
        if self.mode is FlightMode.AUTO_MISSION:
            self._task = None
            if not self.mission_has_items:
                self._enter_mode(FlightMode.AUTO_LOITER)

    # ================================================================== loops
    def refresh_settings(self) -> None:
        """Read the parameters again now (after a PARAM_SET: a command in the same instant must see it)."""
        s = self.params.settings
        if s is not self.settings:
            self.settings = s
            self.gains = s.gains

    def outer_update(
        self, t_s: float, wall_s: float, est: LocalState, battery_remaining: float, battery_voltage_v: float = NAN
    ) -> None:
        """Land detection, auto-disarm, failsafes, navigation and the position/velocity loops."""
        self.t_s = t_s
        self.wall_s = wall_s
        self.est = est
        self.battery_remaining = battery_remaining
        self.battery_voltage_v = battery_voltage_v
        self.refresh_settings()
        was_landed = self.landed
        landed = self.land_detector.update(
            t_s,
            armed=self.armed,
            thrust=self._thrust,
            hover_thrust=self.gains.hover_thrust,
            vel_ned=est.vel_ned_mps,
            height_above_ground_m=est.full.height_above_ground_m,
        )
        if landed != was_landed:
            self._status_changed()
            if self.armed:
                self.say(MavSeverity.INFO, "Landing detected" if landed else "Takeoff detected")
            self._landed_since_s = t_s
            if not landed:
                self._flew_since_arming = True
        self._auto_disarm(t_s, wall_s)
        self._run_failsafes(est)
        mode = self.mode
        if not est.pos_valid and self.personality.needs_position(mode):
            self._descend_outer(est)
            return
        if mode is FlightMode.MANUAL or mode is FlightMode.STABILIZED:
            self._manual_outer(est)
            return
        if mode is FlightMode.ALTCTL:
            self._altctl_outer(est)
            return
        nav = self._navigate(est)
        self.last_nav = nav
        sp = self._offboard_sp
        if mode is FlightMode.OFFBOARD and isinstance(sp, AttitudeSetpoint) and self._user_takeoff is None:
            self._attitude_outer(est, sp)
            return
        self._rate_sp = None
        self._control_outer(est, nav)

    def _auto_disarm(self, t_s: float, wall_s: float) -> None:
        if not (self.armed and self.landed):
            return
        s = self.settings
        if self._flew_since_arming:
            delay = s.disarm_after_landing_s
            if not math.isnan(delay) and t_s - self._landed_since_s >= delay:
                self._disarm("Disarmed by auto disarm on land")
        else:
            delay = s.disarm_preflight_s
            if math.isnan(delay):
                return
            wall_needed = max(delay * self.wall_scale, self._client_wall_floor_s)
            if t_s - self._armed_at_s >= delay and wall_s - self._armed_at_wall_s >= wall_needed:
                self._disarm("Disarmed by auto preflight disarming")

    def _run_failsafes(self, est: LocalState) -> None:
        s = self.settings
        breach = None
        if s.fence_uploaded and s.fence_action is not None and not self.fence_store.fence.empty:
            breach = self.fence_store.fence.breach(est.pos_ned_m[0], est.pos_ned_m[1])
        inputs = FailsafeInputs(
            t_s=self.t_s,
            wall_s=self.wall_s,
            wall_scale=self.wall_scale,
            armed=self.armed,
            in_air=not self.landed,
            mode=self.mode,
            battery_remaining=self.battery_remaining,
            distance_from_home_m=math.hypot(est.pos_ned_m[0], est.pos_ned_m[1]),
            altitude_above_home_m=-est.pos_ned_m[2],
            battery_voltage_v=self.battery_voltage_v,
            fence_breach=breach,
            position_valid=est.pos_valid,
            needs_position=self.personality.needs_position(self.mode),
        )
        for event in self.failsafe.update(inputs, self.params):
            self._apply_failsafe(event)

    def _apply_failsafe(self, event: FailsafeEvent) -> None:
        self.say(event.severity, event.text)
        if event.action is Action.DISARM:
            if self.armed:
                self._disarm("Disarmed by failsafe on the ground")
            return
        target = _FAILSAFE_MODES.get(event.action)
        if target is None or self.mode is target:
            return
        if event.kind is FailsafeKind.POSITION_LOST:
            # PX4's Descend (reported as AUTO.LAND): entered although the mode needs a position it lacks
            self._land_xy = None
            self._enter_mode(target)
            return
        if target is FlightMode.AUTO_LOITER:
            self._reposition = None
        if target is FlightMode.AUTO_LAND:
            self._land_xy = None
        if self.set_mode(target, quiet=True) is not MavResult.ACCEPTED and target is FlightMode.AUTO_RTL:
            self.set_mode(FlightMode.AUTO_LAND, quiet=True)

    def _nav_context(self, est: LocalState) -> NavContext:
        s = self.settings
        speed = self._speed_override if math.isfinite(self._speed_override) else s.cruise_speed_mps
        return NavContext(
            self.t_s,
            est.pos_ned_m,
            est.vel_ned_mps,
            est.yaw_rad,
            self.landed,
            est.full.height_above_ground_m,
            s,
            speed,
        )

    def _navigate(self, est: LocalState) -> NavOutput:
        ctx = self._nav_context(est)
        mode = self.mode
        if self._user_takeoff is not None:
            return self._user_takeoff_nav(ctx)
        if mode is FlightMode.OFFBOARD:
            return self._offboard_nav(est, ctx)
        if mode is FlightMode.POSCTL:
            return self._posctl(est, ctx)
        if mode is FlightMode.AUTO_LOITER and self.personality.is_ardupilot and self._manual_ok():
            return self._posctl(est, ctx)  # ArduCopter's LOITER: the sticks move the vehicle
        if self._task is None:
            self._task = self._make_task(ctx)
        task = self._task
        out = task.update(ctx)
        if isinstance(task, TakeoffTask) and task.done and self.armed:
            self._reposition = ((task.xy[0], task.xy[1], task.target_down_m), task.yaw_rad, NAN)
            self._enter_mode(FlightMode.AUTO_LOITER)
        if isinstance(task, MissionTask):
            seq = self.mission_progress.current
            if seq != self._last_mission_seq:
                self._last_mission_seq = seq
                self.mission_current_changed = True
            self.mission_server.set_current_seq(seq)
        return out

    def _user_takeoff_nav(self, ctx: NavContext) -> NavOutput:
        """ArduCopter's user takeoff in GUIDED or LOITER; afterwards the mode holds the reached point."""
        task = self._user_takeoff
        assert task is not None
        out = task.update(ctx)
        if task.done:
            self._user_takeoff = None
            target = (task.xy[0], task.xy[1], task.target_down_m)
            if self.mode is FlightMode.OFFBOARD:
                self._offboard_sp = Setpoint(pos=target, yaw_rad=task.yaw_rad)
                self._offboard_sp_t = self.t_s
            else:
                self._reposition = (target, task.yaw_rad, NAN)
                self._task = None
        return out

    def _offboard_nav(self, est: LocalState, ctx: NavContext) -> NavOutput:
        s = self.settings
        sp = self._offboard_sp
        if isinstance(sp, AttitudeSetpoint):
            return NavOutput(Setpoint(), default_limits(s), NavPhase.CRUISE)
        if sp is None:
            sp = Setpoint(pos=est.pos_ned_m)
        elif not math.isnan(s.guided_timeout_s) and self.t_s - self._offboard_sp_t > s.guided_timeout_s:
            px, py, pz = sp.pos
            if math.isnan(px) or math.isnan(py) or math.isnan(pz):
                # ArduCopter: a velocity or acceleration target older than GUID_TIMEOUT stops the vehicle
                sp = Setpoint(vel=(0.0, 0.0, 0.0), yaw_rad=sp.yaw_rad if not math.isnan(sp.yaw_rad) else NAN)
        return NavOutput(sp, default_limits(s, s.offboard_speed_xy_mps), NavPhase.CRUISE)

    def _make_task(self, ctx: NavContext) -> Task:  # noqa: PLR0911
        mode = self.mode
        here = ctx.pos
        if mode is FlightMode.AUTO_TAKEOFF:
            xy, rel_alt, yaw = self._takeoff_request or (None, self.settings.takeoff_alt_m, NAN)
            self._takeoff_request = None
            target_xy = xy if xy is not None else (here[0], here[1])
            return TakeoffTask(target_xy, -rel_alt, yaw if math.isfinite(yaw) else ctx.yaw_rad)
        if mode is FlightMode.AUTO_LAND:
            xy = self._land_xy if self._land_xy is not None else (here[0], here[1])
            self._land_xy = None
            return LandTask(xy, ctx.yaw_rad)
        if mode is FlightMode.AUTO_RTL:
            return RtlTask(ctx)
        if mode is FlightMode.AUTO_MISSION:
            self._restart_mission_if_new()
            return MissionTask(
                self.mission_store,
                self.mission_progress,
                self.projection,
                takeoff_on_ground=not self.personality.is_ardupilot,
            )
        if mode is FlightMode.ORBIT and self._orbit is not None:
            return self._orbit
        if mode is FlightMode.AUTO_FOLLOW_TARGET:
            return FollowTask(self, initial_yaw_rad=ctx.yaw_rad)
        if self._reposition is not None:
            target, yaw, speed = self._reposition
            self._reposition = None
            return GotoTask(target, yaw_rad=yaw, speed_mps=speed, initial_yaw_rad=ctx.yaw_rad)
        return GotoTask(here, yaw_rad=ctx.yaw_rad)

    def _posctl(self, est: LocalState, ctx: NavContext) -> NavOutput:
        s = self.settings
        sticks = self._manual if self._manual_ok() else None
        limits = default_limits(s)
        fwd = _deadband(sticks.pitch) if sticks else 0.0
        right = _deadband(sticks.roll) if sticks else 0.0
        climb = _deadband(2.0 * sticks.throttle - 1.0) if sticks else 0.0
        yaw_rate = _deadband(sticks.yaw) * s.manual_yaw_rate_max_radps if sticks else 0.0
        centred = fwd == 0.0 and right == 0.0 and climb == 0.0 and yaw_rate == 0.0
        if centred:
            if not isinstance(self._task, GotoTask):
                # sticks released: brake to a stop, then hold where the vehicle stopped (PX4 POSCTL)
                vn, ve, vd = est.vel_ned_mps
                if math.hypot(vn, ve) > 0.3 or abs(vd) > 0.3:
                    sp = Setpoint(vel=(0.0, 0.0, 0.0), yaw_rad=self._yaw_hold)
                    return NavOutput(sp, limits, NavPhase.CRUISE)
                self._task = GotoTask(est.pos_ned_m, yaw_rad=est.yaw_rad)
            return self._task.update(ctx)
        self._task = None
        yaw = est.yaw_rad
        speed = s.max_speed_xy_mps
        vn = (fwd * math.cos(yaw) - right * math.sin(yaw)) * speed
        ve = (fwd * math.sin(yaw) + right * math.cos(yaw)) * speed
        vd = -climb * (s.climb_speed_mps if climb > 0 else s.descent_speed_mps)
        sp = Setpoint(vel=(vn, ve, vd), yaw_rate_radps=yaw_rate)
        return NavOutput(sp, limits, NavPhase.CRUISE)

    def _wants_climb(self, sp: Setpoint, est: LocalState) -> bool:
        z, vz, az = sp.pos[2], sp.vel[2], sp.acc[2]
        # NaN compares False: an uncontrolled axis never asks for a climb
        return z < est.pos_ned_m[2] - 0.3 or vz < -0.1 or az < -0.5

    def _stays_on_ground(self) -> bool:
        """ArduCopter's GUIDED (and LOITER): a landed vehicle leaves the ground only by a takeoff command."""
        return (
            self.settings.guided_takeoff_required
            and self.mode in self.personality.takeoff_modes
            and self._user_takeoff is None
        )

    def _control_outer(self, est: LocalState, nav: NavOutput) -> None:
        sp = nav.setpoint
        if (
            not self.armed
            or self.crashed
            or (self.landed and (self._stays_on_ground() or not self._wants_climb(sp, est)))
        ):
            self._go_idle(est)
            return
        if self._idle:
            self._idle = False
            self._pos_ctrl.reset(est.vel_ned_mps)
            self._rate_ctrl.reset()
            self._yaw_hold = est.yaw_rad
        if not math.isnan(sp.yaw_rad):
            self._yaw_hold = sp.yaw_rad
            self._yaw_rate_ff = NAN
        elif not math.isnan(sp.yaw_rate_radps):
            self._yaw_hold = est.yaw_rad + sp.yaw_rate_radps * self.outer_dt_s
            self._yaw_rate_ff = sp.yaw_rate_radps
        else:
            self._yaw_rate_ff = NAN
        self._q_sp, self._thrust = self._pos_ctrl.update(
            sp,
            est.pos_ned_m,
            est.vel_ned_mps,
            self._yaw_hold,
            dt_s=self.outer_dt_s,
            gains=self.gains,
            limits=nav.limits,
        )

    def _attitude_outer(self, est: LocalState, att: AttitudeSetpoint) -> None:
        """OFFBOARD attitude or body-rate setpoints (SET_ATTITUDE_TARGET): the position loops are bypassed."""
        s = self.settings
        stale = not math.isnan(s.guided_timeout_s) and self.t_s - self._offboard_sp_t > s.guided_timeout_s
        if stale:
            # ArduCopter: an attitude target older than GUID_TIMEOUT levels the vehicle and holds the altitude
            self._rate_sp = None
            nav = NavOutput(Setpoint(vel=(0.0, 0.0, 0.0)), default_limits(s), NavPhase.CRUISE)
            self.last_nav = nav
            self._control_outer(est, nav)
            return
        hover = self.gains.hover_thrust
        thrust = att.thrust if not math.isnan(att.thrust) else hover
        if not self.armed or self.crashed or (self.landed and thrust < 0.5 * hover):
            self._go_idle(est)
            self._rate_sp = None
            return
        if self._idle:
            self._idle = False
            self._rate_ctrl.reset()
            self._pos_ctrl.reset(est.vel_ned_mps)
        self._yaw_rate_ff = NAN
        if att.q is not None:
            self._q_sp = att.q
            self._yaw_hold = math.atan2(
                2.0 * (att.q[0] * att.q[3] + att.q[1] * att.q[2]), 1.0 - 2.0 * (att.q[2] ** 2 + att.q[3] ** 2)
            )
        else:
            self._q_sp = est.full.q_wxyz
        rates = att.body_rates_radps
        self._rate_sp = rates if att.q is None else None
        self._thrust = min(1.0, max(0.0, thrust))

    def _go_idle(self, est: LocalState) -> None:
        self._idle = True
        self._thrust = 0.0
        self._yaw_hold = est.yaw_rad
        self._q_sp = est.full.q_wxyz
        self._pos_ctrl.reset(est.vel_ned_mps)

    def _stick_attitude(self, est: LocalState, sticks: ManualInput) -> tuple[float, float, float]:
        """Roll, pitch (rad) and yaw rate (rad/s) from the sticks."""
        s = self.settings
        tilt = s.manual_tilt_max_rad
        return (
            _deadband(sticks.roll) * tilt,
            -_deadband(sticks.pitch) * tilt,
            _deadband(sticks.yaw) * s.manual_yaw_rate_max_radps,
        )

    def _manual_outer(self, est: LocalState) -> None:
        sticks = self._manual if self._manual_ok() else None
        self.last_nav = None
        self._rate_sp = None
        if sticks is None or not self.armed or self.crashed:
            self._go_idle(est)
            return
        roll, pitch, yaw_rate = self._stick_attitude(est, sticks)
        hover = self.gains.hover_thrust
        thr = sticks.throttle
        thrust = 2.0 * hover * thr if thr <= 0.5 else hover + (1.0 - hover) * (thr - 0.5) * 2.0
        if self.landed and thrust < 0.5 * hover:
            self._go_idle(est)
            return
        if self._idle:
            self._idle = False
            self._rate_ctrl.reset()
            self._yaw_hold = est.yaw_rad
        self._yaw_hold += yaw_rate * self.outer_dt_s
        self._yaw_rate_ff = yaw_rate
        self._q_sp = _quat_from_euler(roll, pitch, self._yaw_hold)
        self._thrust = thrust

    def _descend_outer(self, est: LocalState) -> None:
        """PX4's Descend: no horizontal position, so level attitude and a steady descent until landed."""
        self.last_nav = None
        self._rate_sp = None
        if not self.armed or self.crashed or self.landed:
            self._go_idle(est)
            self._alt_integral = 0.0
            return
        if self._idle:
            self._idle = False
            self._rate_ctrl.reset()
            self._yaw_hold = est.yaw_rad
            self._alt_integral = 0.0
        g = self.gains
        ez = self.settings.land_speed_mps - est.vel_ned_mps[2]
        limit = 6.0 / max(g.z_vel_i, 1e-6)
        self._alt_integral = max(-limit, min(limit, self._alt_integral + ez * self.outer_dt_s))
        az = g.z_vel_p * ez + g.z_vel_i * self._alt_integral
        self._thrust = min(1.0, max(0.1 * g.hover_thrust, g.hover_thrust * (1.0 - az / GRAVITY_MPS2)))
        self._yaw_rate_ff = 0.0
        self._q_sp = _quat_from_euler(0.0, 0.0, self._yaw_hold)

    def inject_failure(self, unit: int, failure_type: int, instance: int) -> MavResult:
        """MAV_CMD_INJECT_FAILURE: refused unless SYS_FAILURE_EN is 1 (PX4); see :mod:`sitl.core.faults`."""
        if self.personality.is_ardupilot:
            return MavResult.UNSUPPORTED
        if not self.params.settings.failure_injection_enabled:  # the table, not the per-step copy
            self.say(MavSeverity.WARNING, "Failure injection denied: SYS_FAILURE_EN is 0")
            return MavResult.DENIED
        result = self.faults.inject(unit, failure_type, instance)
        if result.outcome is InjectOutcome.ACCEPTED:
            self.say(MavSeverity.CRITICAL, result.text)
            return MavResult.ACCEPTED
        self.say(MavSeverity.WARNING, result.text)
        return MavResult.UNSUPPORTED if result.outcome is InjectOutcome.UNSUPPORTED else MavResult.DENIED

    def _altctl_outer(self, est: LocalState) -> None:
        """ALT_HOLD (ArduCopter) / ALTCTL: sticks tilt the vehicle; throttle is a climb rate (centred holds)."""
        s = self.settings
        sticks = self._manual if self._manual_ok() else None
        self.last_nav = None
        self._rate_sp = None
        climb = _deadband(2.0 * sticks.throttle - 1.0) if sticks is not None else 0.0
        if not self.armed or self.crashed or (self.landed and climb <= 0.0):
            self._go_idle(est)
            self._alt_hold_down = None
            self._alt_integral = 0.0
            return
        roll, pitch, yaw_rate = self._stick_attitude(est, sticks) if sticks is not None else (0.0, 0.0, 0.0)
        if self._idle:
            self._idle = False
            self._rate_ctrl.reset()
            self._yaw_hold = est.yaw_rad
            self._alt_integral = 0.0
        z = est.pos_ned_m[2]
        if climb == 0.0:
            if self._alt_hold_down is None:
                self._alt_hold_down = z
            err = self._alt_hold_down - z
            vz_sp = max(-s.climb_speed_mps, min(s.descent_speed_mps, self.gains.z_p * err))
        else:
            self._alt_hold_down = None
            vz_sp = -climb * (s.climb_speed_mps if climb > 0 else s.descent_speed_mps)
        g = self.gains
        ez = vz_sp - est.vel_ned_mps[2]
        limit = 6.0 / max(g.z_vel_i, 1e-6)
        self._alt_integral = max(-limit, min(limit, self._alt_integral + ez * self.outer_dt_s))
        az = g.z_vel_p * ez + g.z_vel_i * self._alt_integral
        tilt_cos = max(0.5, math.cos(roll) * math.cos(pitch))
        self._thrust = min(1.0, max(0.1 * g.hover_thrust, g.hover_thrust * (1.0 - az / GRAVITY_MPS2) / tilt_cos))
        self._yaw_hold += yaw_rate * self.outer_dt_s
        self._yaw_rate_ff = yaw_rate
        self._q_sp = _quat_from_euler(roll, pitch, self._yaw_hold)

    def inner_update(
        self,
        q: Quat,
        rates: Vec3,
        dt_s: float,
        voltage_scale: float,
    ) -> tuple[float, float, float, float]:
        """Attitude and rate control and mixing; the four motor duty cycles (0..1)."""
        if not self.armed:
            return 0.0, 0.0, 0.0, 0.0
        if self._idle:
            return self._mixer.idle(voltage_scale)
        rate_sp = self._rate_sp
        if rate_sp is None:
            rate_sp = attitude_rate_setpoint(q, self._q_sp, self._yaw_rate_ff, self.gains)
        torque = self._rate_ctrl.update(rate_sp, rates, dt_s, self.gains, integrate=not self.land_detector.landed)
        return self._mixer.mix(self._thrust, torque, voltage_scale)
