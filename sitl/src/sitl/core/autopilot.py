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
"""

from __future__ import annotations

import math

from sitl.core.control import (
    ControlGains,
    Mixer,
    PositionController,
    RateController,
    Setpoint,
    attitude_rate_setpoint,
    quat_from_yaw,
)
from sitl.core.failsafe import Action, FailsafeEvent, FailsafeInputs, FailsafeMonitor
from sitl.core.landing import LandDetector
from sitl.core.mission import MissionStore
from sitl.core.mission_transfer import MissionServer
from sitl.core.modes import FlightMode, ModeContext, check_arm, check_mode_switch
from sitl.core.navigator import (
    GotoTask,
    LandTask,
    MissionProgress,
    MissionTask,
    NavContext,
    NavOutput,
    NavPhase,
    RtlTask,
    TakeoffTask,
    default_limits,
)
from sitl.core.params import ParamTable
from sitl.core.protocol import LandedState, MavResult, MavSeverity, MavState, MissionState
from sitl.core.state import LocalState
from uav_common.geo import GeoPoint, LocalProjection

__all__ = ["Autopilot", "ManualInput"]

NAN = math.nan
Task = GotoTask | TakeoffTask | LandTask | RtlTask | MissionTask
Vec3 = tuple[float, float, float]


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


class Autopilot:
    """One vehicle's autopilot. See the module docstring for the calling protocol."""

    def __init__(
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
    ) -> None:
        self.params = params
        self.gains = ControlGains.from_params(params)
        self._gains_version = params.version
        self.home = home
        self.projection = LocalProjection(home)
        self.outer_dt_s = outer_dt_s
        self.mode = FlightMode.AUTO_LOITER
        self.armed = False
        self.crashed = False
        self.land_detector = LandDetector()
        # a client acting in wall time (MAVSDK: arm, then takeoff) may need this long at any speed factor
        self._client_wall_floor_s = datalink_floor_s
        self.failsafe = FailsafeMonitor(
            datalink_floor_s=datalink_floor_s, offboard_floor_s=offboard_floor_s, manual_floor_s=manual_floor_s
        )
        self.mission_store = MissionStore()
        self.mission_server = MissionServer(self.mission_store)
        self.mission_progress = MissionProgress()
        self.wall_scale = 1.0
        self.statustexts: list[tuple[MavSeverity, str]] = []
        self.heartbeat_due = False
        self.status_version = 0
        self.mission_current_changed = False
        self.t_s = 0.0
        self.wall_s = 0.0
        self.battery_remaining = 1.0
        self.est: LocalState | None = None
        self.last_nav: NavOutput | None = None
        self._task: Task | None = None
        self._offboard_sp: Setpoint | None = None
        self._manual: ManualInput | None = None
        self._speed_override = NAN
        self._takeoff_request: tuple[tuple[float, float] | None, float, float] | None = None
        self._reposition: tuple[Vec3, float, float] | None = None
        self._land_xy: tuple[float, float] | None = None
        self._armed_at_s = 0.0
        self._armed_at_wall_s = 0.0
        self._landed_since_s = 0.0
        self._flew_since_arming = False
        self._pos_ctrl = PositionController()
        self._rate_ctrl = RateController()
        self._mixer = mixer
        self._q_sp: tuple[float, float, float, float] = quat_from_yaw(home_yaw_rad)
        self._thrust = 0.0
        self._yaw_hold = home_yaw_rad
        self._yaw_rate_ff = NAN
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
    def attitude_setpoint(self) -> tuple[float, float, float, float]:
        return self._q_sp

    @property
    def velocity_setpoint(self) -> Vec3:
        return self._pos_ctrl.velocity_setpoint

    @property
    def position_valid(self) -> bool:
        return self.est is not None

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
        return self.mission_store.state(started=prog.started, finished=prog.finished, paused=paused)

    @property
    def mission_current_seq(self) -> int:
        return self.mission_progress.current

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

    def mode_context(self) -> ModeContext:
        return ModeContext(
            armed=self.armed,
            landed=self.landed,
            crashed=self.crashed,
            position_valid=self.position_valid,
            home_valid=True,
            mission_valid=len(self.mission_store) > 0,
            offboard_stream_ok=self.failsafe.offboard_stream_ok(self.t_s, self.wall_s, self.params, self.wall_scale),
            manual_control_ok=self._manual is not None
            and not self.failsafe.manual.silent_for(
                self.params["COM_RC_LOSS_T"], self.t_s, self.wall_s, wall_scale=self.wall_scale, wall_floor_s=0.5
            ),
        )

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
        self._status_changed()
        self.say(MavSeverity.INFO, "Armed by external command" + (" (forced)" if force else ""))
        return MavResult.ACCEPTED

    def prearm_failure(self) -> str | None:
        if self.est is None or not self.est.gps_ok:
            return "no GPS position"
        if not self.landed:
            return "not landed"
        if self.battery_remaining <= self.params["BAT_CRIT_THR"]:
            return f"battery critical ({100 * self.battery_remaining:.0f}%)"
        reason = check_arm(self.mode, self.mode_context())
        if reason is not None:
            return reason
        radius = self.params["GF_MAX_HOR_DIST"]
        if radius > 0 and math.hypot(self.est.pos_ned_m[0], self.est.pos_ned_m[1]) > radius:
            return "outside the geofence"
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
                self.say(MavSeverity.CRITICAL, f"Mode change to {mode.px4_name} denied: {reason}")
            return MavResult.DENIED
        self._enter_mode(mode)
        return MavResult.ACCEPTED

    def _enter_mode(self, mode: FlightMode) -> None:
        self.mode = mode
        self._task = None
        self._status_changed()
        if mode is FlightMode.AUTO_MISSION:
            self._restart_mission_if_new()
            self.mission_current_changed = True

    def _restart_mission_if_new(self) -> None:
        prog = self.mission_progress
        if prog.mission_id != self.mission_store.mission_id or (prog.finished and self.landed):
            self.mission_progress = MissionProgress(mission_id=self.mission_store.mission_id)
            self.mission_current_changed = True

    def takeoff(self, *, alt_amsl_m: float, lat_deg: float, lon_deg: float, yaw_deg: float) -> MavResult:  # noqa: PLR0911
        """NAV_TAKEOFF: NaN altitude means ``MIS_TAKEOFF_ALT`` above home."""
        if self.crashed:
            return MavResult.DENIED
        if math.isnan(alt_amsl_m):
            rel_alt = self.params["MIS_TAKEOFF_ALT"]
        elif math.isfinite(alt_amsl_m):
            rel_alt = alt_amsl_m - self.home.alt_amsl_m
        else:
            return MavResult.DENIED
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

    def reposition(
        self, *, lat_deg: float, lon_deg: float, alt_amsl_m: float, yaw_rad: float, speed_mps: float, change_mode: bool
    ) -> MavResult:
        """DO_REPOSITION: go to a point (NaN parts: keep the present ones) and hold there."""
        if any(math.isinf(v) for v in (lat_deg, lon_deg, alt_amsl_m, yaw_rad, speed_mps)):
            return MavResult.DENIED
        if not self.armed or self.landed or self.est is None:
            self.say(MavSeverity.CRITICAL, "Reposition denied: not flying")
            return MavResult.DENIED
        if not change_mode and self.mode is not FlightMode.AUTO_LOITER:
            return MavResult.DENIED
        n, e, d = self.est.pos_ned_m
        if math.isfinite(lat_deg) and math.isfinite(lon_deg):
            if not (-90.0 <= lat_deg <= 90.0 and -180.0 <= lon_deg <= 180.0):
                return MavResult.DENIED
            n, e, _ = self.projection.to_ned(GeoPoint(lat_deg, lon_deg, self.home.alt_amsl_m))
        if math.isfinite(alt_amsl_m):
            d = self.home.alt_amsl_m - alt_amsl_m
        speed = speed_mps if math.isfinite(speed_mps) and speed_mps > 0.0 else NAN
        self._reposition = ((n, e, d), yaw_rad if math.isfinite(yaw_rad) else NAN, speed)
        if self.mode is FlightMode.AUTO_LOITER:
            self._task = None
            return MavResult.ACCEPTED
        result = self.set_mode(FlightMode.AUTO_LOITER)
        if result is not MavResult.ACCEPTED:
            self._reposition = None
        return result

    def change_speed(self, speed_mps: float) -> MavResult:
        """DO_CHANGE_SPEED: > 0 sets the auto-mode speed, -2 restores the default, -1 keeps it."""
        if speed_mps == -1.0:
            return MavResult.ACCEPTED
        if speed_mps == -2.0:
            self._speed_override = NAN
            self.mission_progress.speed_mps = NAN
            return MavResult.ACCEPTED
        if not (math.isfinite(speed_mps) and 0.0 < speed_mps <= self.params["MPC_XY_VEL_MAX"]):
            return MavResult.DENIED
        self._speed_override = speed_mps
        self.mission_progress.speed_mps = NAN
        return MavResult.ACCEPTED

    def set_mission_current(self, seq: int) -> MavResult:
        if not 0 <= seq < len(self.mission_store):
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
        if len(self.mission_store) == 0:
            self.say(MavSeverity.CRITICAL, "Mission start denied: no mission")
            return MavResult.DENIED
        if first_seq > 0 and self.set_mission_current(first_seq) is not MavResult.ACCEPTED:
            return MavResult.DENIED
        return self.set_mode(FlightMode.AUTO_MISSION)

    def offboard_setpoint(self, sp: Setpoint, t_s: float, wall_s: float) -> None:
        self._offboard_sp = sp
        self.failsafe.offboard.heard(t_s, wall_s)

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
        self.mission_progress = MissionProgress(mission_id=self.mission_store.mission_id)
        self.mission_current_changed = True
        if self.mode is FlightMode.AUTO_MISSION:
            self._task = None
            if len(self.mission_store) == 0:
                self._enter_mode(FlightMode.AUTO_LOITER)

    # ================================================================== loops
    def _refresh_gains(self) -> None:
        if self.params.version != self._gains_version:
            self.gains = ControlGains.from_params(self.params)
            self._gains_version = self.params.version

    def outer_update(self, t_s: float, wall_s: float, est: LocalState, battery_remaining: float) -> None:
        """Land detection, auto-disarm, failsafes, navigation and the position/velocity loops."""
        self.t_s = t_s
        self.wall_s = wall_s
        self.est = est
        self.battery_remaining = battery_remaining
        self._refresh_gains()
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
        if self.mode is FlightMode.MANUAL:
            self._manual_outer(est)
            return
        nav = self._navigate(est)
        self.last_nav = nav
        self._control_outer(est, nav)

    def _auto_disarm(self, t_s: float, wall_s: float) -> None:
        if not (self.armed and self.landed):
            return
        p = self.params
        if self._flew_since_arming:
            delay = p["COM_DISARM_LAND"]
            if delay > 0.0 and t_s - self._landed_since_s >= delay:
                self._disarm("Disarmed by auto disarm on land")
        else:
            delay = p["COM_DISARM_PRFLT"]
            wall_needed = max(delay * self.wall_scale, self._client_wall_floor_s)
            if delay > 0.0 and t_s - self._armed_at_s >= delay and wall_s - self._armed_at_wall_s >= wall_needed:
                self._disarm("Disarmed by auto preflight disarming")

    def _run_failsafes(self, est: LocalState) -> None:
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
        )
        for event in self.failsafe.update(inputs, self.params):
            self._apply_failsafe(event)

    def _apply_failsafe(self, event: FailsafeEvent) -> None:
        self.say(event.severity, event.text)
        target = {
            Action.HOLD: FlightMode.AUTO_LOITER,
            Action.RETURN: FlightMode.AUTO_RTL,
            Action.LAND: FlightMode.AUTO_LAND,
            Action.POSITION: FlightMode.POSCTL,
        }.get(event.action)
        if target is None or self.mode is target:
            return
        if target is FlightMode.AUTO_LOITER:
            self._reposition = None
        if target is FlightMode.AUTO_LAND:
            self._land_xy = None
        if self.set_mode(target, quiet=True) is not MavResult.ACCEPTED and target is FlightMode.AUTO_RTL:
            self.set_mode(FlightMode.AUTO_LAND, quiet=True)

    def _nav_context(self, est: LocalState) -> NavContext:
        speed = self._speed_override if math.isfinite(self._speed_override) else self.params["MPC_XY_CRUISE"]
        return NavContext(
            self.t_s,
            est.pos_ned_m,
            est.vel_ned_mps,
            est.yaw_rad,
            self.landed,
            est.full.height_above_ground_m,
            self.params,
            speed,
        )

    def _navigate(self, est: LocalState) -> NavOutput:
        ctx = self._nav_context(est)
        mode = self.mode
        if mode is FlightMode.OFFBOARD:
            sp = self._offboard_sp if self._offboard_sp is not None else Setpoint(pos=est.pos_ned_m)
            return NavOutput(sp, default_limits(self.params), NavPhase.CRUISE)
        if mode is FlightMode.POSCTL:
            return self._posctl(est, ctx)
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

    def _make_task(self, ctx: NavContext) -> Task:
        mode = self.mode
        here = ctx.pos
        if mode is FlightMode.AUTO_TAKEOFF:
            xy, rel_alt, yaw = self._takeoff_request or (None, self.params["MIS_TAKEOFF_ALT"], NAN)
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
            return MissionTask(self.mission_store, self.mission_progress, self.projection)
        if self._reposition is not None:
            target, yaw, speed = self._reposition
            self._reposition = None
            return GotoTask(target, yaw_rad=yaw, speed_mps=speed, initial_yaw_rad=ctx.yaw_rad)
        return GotoTask(here, yaw_rad=ctx.yaw_rad)

    def _posctl(self, est: LocalState, ctx: NavContext) -> NavOutput:
        p = self.params
        sticks = self._manual if self.mode_context().manual_control_ok else None
        limits = default_limits(p)
        fwd = _deadband(sticks.pitch) if sticks else 0.0
        right = _deadband(sticks.roll) if sticks else 0.0
        climb = _deadband(2.0 * sticks.throttle - 1.0) if sticks else 0.0
        yaw_rate = _deadband(sticks.yaw) * math.radians(p["MPC_MAN_Y_MAX"]) if sticks else 0.0
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
        speed = p["MPC_XY_VEL_MAX"]
        vn = (fwd * math.cos(yaw) - right * math.sin(yaw)) * speed
        ve = (fwd * math.sin(yaw) + right * math.cos(yaw)) * speed
        vd = -climb * (p["MPC_Z_VEL_MAX_UP"] if climb > 0 else p["MPC_Z_VEL_MAX_DN"])
        sp = Setpoint(vel=(vn, ve, vd), yaw_rate_radps=yaw_rate)
        return NavOutput(sp, limits, NavPhase.CRUISE)

    def _wants_climb(self, sp: Setpoint, est: LocalState) -> bool:
        z, vz, az = sp.pos[2], sp.vel[2], sp.acc[2]
        # NaN compares False: an uncontrolled axis never asks for a climb
        return z < est.pos_ned_m[2] - 0.3 or vz < -0.1 or az < -0.5

    def _control_outer(self, est: LocalState, nav: NavOutput) -> None:
        sp = nav.setpoint
        if not self.armed or self.crashed or (self.landed and not self._wants_climb(sp, est)):
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

    def _go_idle(self, est: LocalState) -> None:
        self._idle = True
        self._thrust = 0.0
        self._yaw_hold = est.yaw_rad
        self._q_sp = est.full.q_wxyz
        self._pos_ctrl.reset(est.vel_ned_mps)

    def _manual_outer(self, est: LocalState) -> None:
        p = self.params
        sticks = self._manual if self.mode_context().manual_control_ok else None
        self.last_nav = None
        if sticks is None or not self.armed or self.crashed:
            self._go_idle(est)
            return
        tilt = math.radians(p["MPC_MAN_TILT_MAX"])
        roll = _deadband(sticks.roll) * tilt
        pitch = -_deadband(sticks.pitch) * tilt
        yaw_rate = _deadband(sticks.yaw) * math.radians(p["MPC_MAN_Y_MAX"])
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
        cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
        cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
        cy, sy = math.cos(0.5 * self._yaw_hold), math.sin(0.5 * self._yaw_hold)
        self._q_sp = (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        )
        self._thrust = thrust

    def inner_update(
        self,
        q: tuple[float, float, float, float],
        rates: Vec3,
        dt_s: float,
        voltage_scale: float,
    ) -> tuple[float, float, float, float]:
        """Attitude and rate control and mixing; the four motor duty cycles (0..1)."""
        if not self.armed:
            return 0.0, 0.0, 0.0, 0.0
        if self._idle:
            return self._mixer.idle(voltage_scale)
        rate_sp = attitude_rate_setpoint(q, self._q_sp, self._yaw_rate_ff, self.gains)
        torque = self._rate_ctrl.update(rate_sp, rates, dt_s, self.gains, integrate=not self.landed)
        return self._mixer.mix(self._thrust, torque, voltage_scale)
