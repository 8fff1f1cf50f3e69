"""Flight tasks: what each mode asks of the position controller.

A task turns the vehicle's situation (:class:`NavContext`) into a
:class:`NavOutput` (setpoint, limits, phase) at the outer-loop rate. Tasks are
small explicit state machines: takeoff, hold/go-to, land, return-to-launch and
the mission executor.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import ClassVar, Protocol

from sitl.core.control import MotionLimits, Setpoint
from sitl.core.mission import MissionItem, MissionStore, item_target_ned
from sitl.core.protocol import MavCmd
from sitl.core.settings import FlightSettings, RtlOrder
from uav_common.geo import GeoPoint, LocalProjection

__all__ = [
    "FollowTarget",
    "FollowTask",
    "GotoTask",
    "LandTask",
    "MissionTask",
    "NavContext",
    "NavOutput",
    "NavPhase",
    "OrbitTask",
    "RtlPhase",
    "RtlTask",
    "TakeoffTask",
    "default_limits",
]

NAN = math.nan
Vec3 = tuple[float, float, float]


class NavPhase(enum.Enum):
    HOLD = "hold"
    TAKEOFF = "takeoff"
    CRUISE = "cruise"
    LANDING = "landing"


@dataclass(frozen=True, slots=True)
class NavContext:
    """What a task sees at each outer-loop update."""

    t_s: float
    pos: Vec3
    vel: Vec3
    yaw_rad: float
    landed: bool
    height_above_ground_m: float
    settings: FlightSettings
    cruise_speed_mps: float


@dataclass(frozen=True, slots=True)
class NavOutput:
    setpoint: Setpoint
    limits: MotionLimits
    phase: NavPhase


def default_limits(s: FlightSettings, speed_xy_mps: float | None = None) -> MotionLimits:
    speed = s.max_speed_xy_mps if speed_xy_mps is None else min(speed_xy_mps, s.max_speed_xy_mps)
    return MotionLimits(
        speed_xy_mps=speed,
        speed_up_mps=s.climb_speed_mps,
        speed_down_mps=s.descent_speed_mps,
        acc_xy_mps2=s.acc_xy_mps2,
        acc_up_mps2=s.acc_up_mps2,
        acc_down_mps2=s.acc_down_mps2,
    )


def _heading_to(frm: Vec3, to: Vec3) -> float:
    return math.atan2(to[1] - frm[1], to[0] - frm[0])


class TakeoffTask:
    """Climb vertically at the takeoff speed to ``target_down`` over ``xy``."""

    def __init__(self, xy: tuple[float, float], target_down_m: float, yaw_rad: float) -> None:
        self.xy = xy
        self.target_down_m = target_down_m
        self.yaw_rad = yaw_rad
        self.done = False

    def update(self, ctx: NavContext) -> NavOutput:
        s = ctx.settings
        if ctx.pos[2] <= self.target_down_m + s.acceptance_z_m and not ctx.landed:
            self.done = True
        limits = default_limits(s, ctx.cruise_speed_mps)
        limits = MotionLimits(
            limits.speed_xy_mps,
            min(s.takeoff_speed_mps, limits.speed_up_mps),
            limits.speed_down_mps,
            limits.acc_xy_mps2,
            limits.acc_up_mps2,
            limits.acc_down_mps2,
        )
        sp = Setpoint(pos=(self.xy[0], self.xy[1], self.target_down_m), yaw_rad=self.yaw_rad)
        return NavOutput(sp, limits, NavPhase.HOLD if self.done else NavPhase.TAKEOFF)


class GotoTask:
    """Fly to ``target`` and hold there (AUTO.LOITER, reposition, waypoints).

    The heading points along the track while more than 2 m away (PX4's
    ``MPC_YAW_MODE`` 0) unless a fixed ``yaw_rad`` is given.
    """

    def __init__(
        self,
        target: Vec3,
        *,
        yaw_rad: float = NAN,
        speed_mps: float = NAN,
        acceptance_xy_m: float = NAN,
        initial_yaw_rad: float = 0.0,
    ) -> None:
        self.target = target
        self.fixed_yaw = yaw_rad
        self.speed_mps = speed_mps
        self.acceptance_xy_m = acceptance_xy_m
        self._yaw = yaw_rad if math.isfinite(yaw_rad) else initial_yaw_rad
        self.reached = False
        self.roi: Vec3 | None = None

    def update(self, ctx: NavContext) -> NavOutput:
        s = ctx.settings
        dist_xy = math.hypot(self.target[0] - ctx.pos[0], self.target[1] - ctx.pos[1])
        if math.isfinite(self.fixed_yaw):
            self._yaw = self.fixed_yaw
        elif self.roi is not None:
            if math.hypot(self.roi[0] - ctx.pos[0], self.roi[1] - ctx.pos[1]) > 0.5:
                self._yaw = _heading_to(ctx.pos, self.roi)
        elif dist_xy > 2.0:
            self._yaw = _heading_to(ctx.pos, self.target)
        acc = self.acceptance_xy_m if math.isfinite(self.acceptance_xy_m) else s.acceptance_xy_m
        if dist_xy <= acc and abs(self.target[2] - ctx.pos[2]) <= s.acceptance_z_m:
            self.reached = True
        speed = self.speed_mps if math.isfinite(self.speed_mps) else ctx.cruise_speed_mps
        sp = Setpoint(pos=self.target, yaw_rad=self._yaw)
        return NavOutput(sp, default_limits(s, speed), NavPhase.HOLD if self.reached else NavPhase.CRUISE)


class LandTask:
    """Descend over ``xy`` until landed: fast high up, the landing speed near the ground, linear in between.

    PX4: ``MPC_Z_VEL_MAX_DN`` above 10 m, ``MPC_LAND_SPEED`` below 5 m; ArduCopter: ``LAND_SPEED_HIGH`` above
    ``LAND_ALT_LOW``, ``LAND_SPEED`` below it.
    """

    def __init__(self, xy: tuple[float, float], yaw_rad: float) -> None:
        self.xy = xy
        self.yaw_rad = yaw_rad
        self.done = False

    def update(self, ctx: NavContext) -> NavOutput:
        s = ctx.settings
        slow, fast = s.land_speed_mps, s.land_fast_speed_mps
        h = ctx.height_above_ground_m
        if h >= s.land_fast_above_m:
            speed = fast
        elif h <= s.land_slow_below_m:
            speed = slow
        else:
            speed = slow + (fast - slow) * (h - s.land_slow_below_m) / (s.land_fast_above_m - s.land_slow_below_m)
        if ctx.landed:
            self.done = True
        sp = Setpoint(pos=(self.xy[0], self.xy[1], NAN), vel=(NAN, NAN, speed), yaw_rad=self.yaw_rad)
        return NavOutput(sp, default_limits(s, ctx.cruise_speed_mps), NavPhase.LANDING)


class RtlPhase(enum.Enum):
    CLIMB = "climb"
    RETURN = "return"
    DESCEND = "descend"
    LOITER = "loiter"
    LAND = "land"
    LANDED = "landed"
    FINAL = "final"


class RtlTask:
    """Return to launch, in the personality's order (:class:`~sitl.core.settings.RtlOrder`).

    PX4 (AUTO.RTL): climb to ``RTL_RETURN_ALT``, return, descend to ``RTL_DESCEND_ALT``, wait
    ``RTL_LAND_DELAY``, land (already over home: no climb). ArduCopter (RTL): climb to ``RTL_ALT`` (at least
    ``RTL_CLIMB_MIN``), return at ``RTL_SPEED``, wait ``RTL_LOIT_TIME`` over home, then land, or hover at
    ``RTL_ALT_FINAL`` when it is set.
    """

    def __init__(self, ctx: NavContext) -> None:
        s = ctx.settings
        self._order = s.rtl_order
        self._return_down = min(ctx.pos[2] - s.rtl_climb_min_m, -s.rtl_return_alt_m)
        self._yaw = ctx.yaw_rad
        self._loiter_since: float | None = None
        self.phase = RtlPhase.CLIMB
        self._start_xy = (ctx.pos[0], ctx.pos[1])
        self._sub: GotoTask | LandTask | None = None
        if ctx.landed:
            self.phase = RtlPhase.LANDED
        elif self._order is RtlOrder.DESCEND_THEN_WAIT and math.hypot(ctx.pos[0], ctx.pos[1]) <= s.acceptance_xy_m:
            self.phase = RtlPhase.DESCEND

    @property
    def done(self) -> bool:
        return self.phase is RtlPhase.LANDED

    def update(self, ctx: NavContext) -> NavOutput:  # noqa: PLR0911, PLR0912 - one branch per phase
        s = ctx.settings
        if self.phase is RtlPhase.CLIMB:
            if ctx.pos[2] <= self._return_down + s.acceptance_z_m:
                self.phase = RtlPhase.RETURN
            else:
                sp = Setpoint(pos=(self._start_xy[0], self._start_xy[1], self._return_down), yaw_rad=self._yaw)
                return NavOutput(sp, default_limits(s, ctx.cruise_speed_mps), NavPhase.CRUISE)
        if self.phase is RtlPhase.RETURN:
            if not isinstance(self._sub, GotoTask):
                self._sub = GotoTask(
                    (0.0, 0.0, self._return_down), speed_mps=s.rtl_speed_mps, initial_yaw_rad=ctx.yaw_rad
                )
            out = self._sub.update(ctx)
            if not self._sub.reached:
                return out
            self._yaw = ctx.yaw_rad
            if self._order is RtlOrder.WAIT_THEN_DESCEND:
                self.phase = RtlPhase.LOITER
                self._loiter_since = ctx.t_s
                self._sub = GotoTask((0.0, 0.0, self._return_down), yaw_rad=self._yaw)
            else:
                self.phase = RtlPhase.DESCEND
                self._sub = None
        if self.phase is RtlPhase.DESCEND:
            if isinstance(self._sub, GotoTask):
                descend_down = self._sub.target[2]
            else:
                descend_down = max(ctx.pos[2], -s.rtl_descend_alt_m)
            if not isinstance(self._sub, GotoTask):
                self._sub = GotoTask((0.0, 0.0, descend_down), yaw_rad=self._yaw)
            out = self._sub.update(ctx)
            if not self._sub.reached:
                return out
            self.phase = RtlPhase.LOITER
            self._loiter_since = ctx.t_s
        if self.phase is RtlPhase.LOITER:
            delay = s.rtl_loiter_s
            since = self._loiter_since if self._loiter_since is not None else ctx.t_s
            if delay < 0.0 or ctx.t_s - since < delay:
                assert isinstance(self._sub, GotoTask)
                return self._sub.update(ctx)
            if self._order is RtlOrder.WAIT_THEN_DESCEND and s.rtl_final_alt_m > 0.0:
                self.phase = RtlPhase.FINAL
                self._sub = GotoTask((0.0, 0.0, -s.rtl_final_alt_m), yaw_rad=self._yaw)
            else:
                self.phase = RtlPhase.LAND
                self._sub = LandTask((0.0, 0.0), self._yaw)
        if self.phase is RtlPhase.FINAL:
            assert isinstance(self._sub, GotoTask)
            return self._sub.update(ctx)
        if self.phase is RtlPhase.LAND:
            assert isinstance(self._sub, LandTask)
            out = self._sub.update(ctx)
            if self._sub.done:
                self.phase = RtlPhase.LANDED
            return out
        sp = Setpoint(pos=(ctx.pos[0], ctx.pos[1], NAN), vel=(NAN, NAN, s.land_speed_mps), yaw_rad=self._yaw)
        return NavOutput(sp, default_limits(s), NavPhase.LANDING)


@dataclass
class MissionProgress:
    """Executor state that survives leaving and re-entering AUTO.MISSION (pause/resume)."""

    current: int = 0
    started: bool = False
    finished: bool = False
    mission_id: int = -1
    reached: list[int] = field(default_factory=list)
    speed_mps: float = NAN
    jumps: dict[int, int] = field(default_factory=dict)
    """DO_JUMP items taken so far: seq -> times."""
    roi: Vec3 | None = None
    """DO_SET_ROI_LOCATION: the point the vehicle faces (LOCAL_NED)."""


class MissionTask:
    """AUTO.MISSION: fly the store's items from ``progress.current``.

    Reached nav items are appended to ``progress.reached`` (the shell sends
    MISSION_ITEM_REACHED); DO_CHANGE_SPEED sets the speed for later legs, DO_JUMP
    repeats a stretch, DO_SET_ROI_LOCATION points the nose at a place, and
    camera/gimbal items are skipped (no payload). With ``takeoff_on_ground``
    (PX4) a mission started on the ground first takes off to the first leg's
    altitude (at least ``MIS_TAKEOFF_ALT``); without it (ArduCopter) only a
    NAV_TAKEOFF item leaves the ground.
    """

    MAX_DO_ITEMS_PER_UPDATE = 32

    def __init__(
        self,
        store: MissionStore,
        progress: MissionProgress,
        projection: LocalProjection,
        *,
        takeoff_on_ground: bool = True,
    ) -> None:
        self.store = store
        self.progress = progress
        self.projection = projection
        self.takeoff_on_ground = takeoff_on_ground
        self._sub: GotoTask | TakeoffTask | LandTask | RtlTask | None = None
        self._sub_seq = -1
        self._hold_since: float | None = None
        self._end_hold: GotoTask | None = None
        self._pre_takeoff: TakeoffTask | None = None

    def restart_item(self) -> None:
        self._sub = None
        self._sub_seq = -1
        self._hold_since = None

    def _advance(self, reached_seq: int | None) -> None:
        if reached_seq is not None:
            self.progress.reached.append(reached_seq)
        self.progress.current += 1
        self.restart_item()
        if self.progress.current >= len(self.store):
            self.progress.finished = True

    def _do_item(self, item: MissionItem) -> None:
        """Execute a DO item and move past it (DO_JUMP may move back)."""
        prog = self.progress
        cmd = item.command
        if cmd == MavCmd.DO_CHANGE_SPEED:
            if item.param2 > 0.0:
                prog.speed_mps = item.param2
            elif item.param2 == -2.0:
                prog.speed_mps = NAN
        elif cmd == MavCmd.DO_JUMP:
            target, repeat = int(item.param1), int(item.param2)
            done = prog.jumps.get(item.seq, 0)
            if 0 <= target < len(self.store) and target != item.seq and (repeat < 0 or done < repeat):
                prog.jumps[item.seq] = done + 1
                prog.current = target
                self.restart_item()
                return
        elif cmd == MavCmd.DO_SET_ROI_LOCATION:
            prog.roi = item_target_ned(item, self.projection, (0.0, 0.0, 0.0))
        elif cmd == MavCmd.DO_SET_ROI_NONE:
            prog.roi = None
        self._advance(None)

    def update(self, ctx: NavContext) -> NavOutput:  # noqa: PLR0911, PLR0912
        prog = self.progress
        prog.started = True
        items = self.store.items
        for _ in range(self.MAX_DO_ITEMS_PER_UPDATE):
            if prog.finished or prog.current >= len(items):
                break
            item = items[prog.current]
            if item.is_nav:
                break
            self._do_item(item)
        speed = prog.speed_mps if math.isfinite(prog.speed_mps) else ctx.cruise_speed_mps
        nav_ctx = NavContext(
            ctx.t_s, ctx.pos, ctx.vel, ctx.yaw_rad, ctx.landed, ctx.height_above_ground_m, ctx.settings, speed
        )
        if prog.finished or prog.current >= len(items):
            prog.finished = True
            if self._end_hold is None:
                self._end_hold = GotoTask(ctx.pos, yaw_rad=ctx.yaw_rad)
            if ctx.landed:
                sp = Setpoint(pos=(ctx.pos[0], ctx.pos[1], NAN), vel=(NAN, NAN, ctx.settings.land_speed_mps))
                return NavOutput(sp, default_limits(ctx.settings), NavPhase.LANDING)
            return self._end_hold.update(nav_ctx)
        item = items[prog.current]
        if not item.is_nav:  # a long run of DO items: the next update carries on with them
            return GotoTask(ctx.pos, yaw_rad=ctx.yaw_rad).update(nav_ctx)
        target = item_target_ned(item, self.projection, ctx.pos)
        if ctx.landed and item.command not in (MavCmd.NAV_TAKEOFF, MavCmd.NAV_LAND, MavCmd.NAV_RETURN_TO_LAUNCH):
            if not self.takeoff_on_ground:
                # ArduCopter: a mission that does not start with NAV_TAKEOFF does not leave the ground
                sp = Setpoint(pos=(ctx.pos[0], ctx.pos[1], NAN), vel=(NAN, NAN, ctx.settings.land_speed_mps))
                return NavOutput(sp, default_limits(ctx.settings), NavPhase.HOLD)
            if self._pre_takeoff is None:
                alt_down = min(target[2], -ctx.settings.takeoff_alt_m)
                self._pre_takeoff = TakeoffTask((ctx.pos[0], ctx.pos[1]), alt_down, ctx.yaw_rad)
            return self._pre_takeoff.update(nav_ctx)
        if self._pre_takeoff is not None and not self._pre_takeoff.done:
            return self._pre_takeoff.update(nav_ctx)
        self._pre_takeoff = None
        if self._sub is None or self._sub_seq != prog.current:
            self._sub = self._make_sub(item, target, nav_ctx)
            self._sub_seq = prog.current
            self._hold_since = None
        if isinstance(self._sub, GotoTask):
            self._sub.roi = prog.roi
        out = self._sub.update(nav_ctx)
        if self._item_complete(item, nav_ctx):
            self._advance(prog.current)
        return out

    def _make_sub(
        self, item: MissionItem, target: Vec3, ctx: NavContext
    ) -> GotoTask | TakeoffTask | LandTask | RtlTask:
        cmd = item.command
        if cmd == MavCmd.NAV_TAKEOFF:
            down = target[2] if math.isfinite(item.z) else -ctx.settings.takeoff_alt_m
            return TakeoffTask((ctx.pos[0], ctx.pos[1]), down, ctx.yaw_rad)
        if cmd == MavCmd.NAV_LAND:
            return LandTask((target[0], target[1]), ctx.yaw_rad)
        if cmd == MavCmd.NAV_RETURN_TO_LAUNCH:
            return RtlTask(ctx)
        if cmd == MavCmd.NAV_DELAY:
            return GotoTask(ctx.pos, yaw_rad=ctx.yaw_rad)  # wait where the vehicle is
        acceptance = item.param2 if cmd == MavCmd.NAV_WAYPOINT and item.param2 > 0.0 else NAN
        yaw = math.radians(item.param4) if cmd == MavCmd.NAV_WAYPOINT and math.isfinite(item.param4) else NAN
        return GotoTask(target, yaw_rad=yaw, acceptance_xy_m=acceptance, initial_yaw_rad=ctx.yaw_rad)

    def _item_complete(self, item: MissionItem, ctx: NavContext) -> bool:
        sub = self._sub
        if isinstance(sub, TakeoffTask):
            return sub.done
        if isinstance(sub, LandTask | RtlTask):
            return sub.done
        assert isinstance(sub, GotoTask)
        if not sub.reached:
            return False
        if item.command == MavCmd.NAV_LOITER_UNLIM:
            return False
        hold_cmds = (MavCmd.NAV_WAYPOINT, MavCmd.NAV_LOITER_TIME, MavCmd.NAV_DELAY)
        hold_s = item.param1 if item.command in hold_cmds else 0.0
        if self._hold_since is None:
            self._hold_since = ctx.t_s
        return ctx.t_s - self._hold_since >= hold_s


class OrbitTask:
    """PX4's ORBIT (POSCTL.ORBIT, MAV_CMD_DO_ORBIT): circle ``centre`` at ``radius_m`` and ``velocity_mps``.

    A positive velocity circles clockwise seen from above. The vehicle first flies straight to the
    nearest point of the circle (at the cruise speed), then follows the circle with a velocity
    setpoint: tangential speed plus a radial correction, as PX4's FlightTaskOrbit does. Yaw
    behaviours (``ORBIT_YAW_BEHAVIOUR``): 0 nose to the centre, 1 initial heading, 2 uncontrolled,
    3 nose along the tangent, 4 as 1 (no sticks here).
    """

    RADIUS_MIN_M: ClassVar[float] = 1.0
    APPROACH_TOLERANCE_M = 1.0

    def __init__(
        self,
        centre: tuple[float, float],
        radius_m: float,
        velocity_mps: float,
        yaw_behaviour: int,
        down_m: float,
        *,
        initial_yaw_rad: float,
    ) -> None:
        self.centre = centre
        self.radius_m = radius_m
        self.velocity_mps = velocity_mps
        self.yaw_behaviour = yaw_behaviour
        self.down_m = down_m
        self.initial_yaw_rad = initial_yaw_rad
        self.approaching = True
        self._approach: GotoTask | None = None

    def update(self, ctx: NavContext) -> NavOutput:
        s = ctx.settings
        cn, ce = ctx.pos[0] - self.centre[0], ctx.pos[1] - self.centre[1]
        dist = math.hypot(cn, ce)
        un, ue = (cn / dist, ce / dist) if dist > 1e-6 else (1.0, 0.0)
        r, v = self.radius_m, self.velocity_mps
        if self.approaching:
            if abs(dist - r) <= self.APPROACH_TOLERANCE_M and abs(ctx.pos[2] - self.down_m) <= 2.0:
                self.approaching = False
            else:
                if self._approach is None:
                    point = (self.centre[0] + un * r, self.centre[1] + ue * r, self.down_m)
                    self._approach = GotoTask(point, yaw_rad=math.atan2(-ue, -un) if dist > r else math.atan2(ue, un))
                out = self._approach.update(ctx)
                if self._approach.reached:
                    self.approaching = False
                return out
        # tangential velocity (clockwise for v > 0 in NED seen from above) plus the radial correction
        vn = -ue * v + (r - dist) * un
        ve = un * v + (r - dist) * ue
        yaw, yaw_rate = NAN, NAN
        if self.yaw_behaviour in (1, 4):
            yaw = self.initial_yaw_rad
        elif self.yaw_behaviour == 3:
            sign = 1.0 if v >= 0 else -1.0
            yaw, yaw_rate = math.atan2(sign * un, -sign * ue), v / r
        elif self.yaw_behaviour == 0:
            yaw, yaw_rate = math.atan2(-ue, -un), v / r
        del yaw_rate  # the heading setpoint moves with the vehicle; the cascade needs no feed-forward here
        sp = Setpoint(pos=(NAN, NAN, self.down_m), vel=(vn, ve, NAN), yaw_rad=yaw)
        speed = min(s.max_speed_xy_mps, abs(v) + abs(r - dist) + 1.0)
        return NavOutput(sp, default_limits(s, speed), NavPhase.CRUISE)


@dataclass(frozen=True)
class FollowTarget:
    """The target of follow-me (FOLLOW_TARGET): where it is and how it moves, LOCAL_NED, at ``t_s``."""

    t_s: float
    pos_ned_m: Vec3
    vel_ned_mps: Vec3


class _FollowSource(Protocol):
    follow_target: FollowTarget | None
    home: GeoPoint


class FollowTask:
    """PX4's follow-me (AUTO.FOLLOW_TARGET): keep ``FLW_TGT_DST`` from the target at ``FLW_TGT_FA``
    from its course, ``FLW_TGT_HT`` above home (``FLW_TGT_ALT_M`` 0, 1) or above the target (2),
    facing it. The target position is filtered (``FLW_TGT_RS``: 0 follows at once, 1 barely moves);
    a target not heard for ``TARGET_TIMEOUT_S`` is held where it was last seen.
    """

    TARGET_TIMEOUT_S = 5.0

    def __init__(self, source: _FollowSource, *, initial_yaw_rad: float) -> None:
        self._source = source
        self._yaw = initial_yaw_rad
        self._filtered: Vec3 | None = None
        self._last_t = -math.inf
        self._course = NAN
        self._hold: GotoTask | None = None

    def update(self, ctx: NavContext) -> NavOutput:
        s = ctx.settings
        target = self._source.follow_target
        if target is None or ctx.t_s - target.t_s > self.TARGET_TIMEOUT_S:
            if self._hold is None:
                self._hold = GotoTask(ctx.pos, yaw_rad=ctx.yaw_rad)
            return self._hold.update(ctx)
        self._hold = None
        if target.t_s != self._last_t:
            self._last_t = target.t_s
            raw = target.pos_ned_m
            f = self._filtered
            rs = s.follow_responsiveness
            self._filtered = raw if f is None else tuple(r + rs * (a - r) for a, r in zip(f, raw, strict=True))  # type: ignore[assignment]
            vn, ve, _ = target.vel_ned_mps
            if math.hypot(vn, ve) > 0.5:
                self._course = math.atan2(ve, vn)
        tn, te, td = self._filtered if self._filtered is not None else target.pos_ned_m
        course = self._course if math.isfinite(self._course) else math.atan2(ctx.pos[1] - te, ctx.pos[0] - tn) + math.pi
        angle = course + s.follow_angle_rad
        n = tn + s.follow_distance_m * math.cos(angle)
        e = te + s.follow_distance_m * math.sin(angle)
        down = td - s.follow_height_m if s.follow_altitude_mode == 2 else -s.follow_height_m
        if math.hypot(tn - ctx.pos[0], te - ctx.pos[1]) > 0.5:
            self._yaw = math.atan2(te - ctx.pos[1], tn - ctx.pos[0])
        vn, ve, _ = target.vel_ned_mps
        sp = Setpoint(pos=(n, e, down), vel=(vn, ve, NAN), yaw_rad=self._yaw)
        limits = default_limits(s, max(s.cruise_speed_mps, math.hypot(vn, ve) + s.follow_max_speed_mps))
        return NavOutput(sp, limits, NavPhase.CRUISE)
