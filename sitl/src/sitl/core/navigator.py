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

from sitl.core.control import MotionLimits, Setpoint
from sitl.core.mission import MissionItem, MissionStore, item_target_ned
from sitl.core.params import ParamTable
from sitl.core.protocol import MavCmd
from uav_common.geo import LocalProjection

__all__ = [
    "GotoTask",
    "LandTask",
    "MissionTask",
    "NavContext",
    "NavOutput",
    "NavPhase",
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
    params: ParamTable
    cruise_speed_mps: float


@dataclass(frozen=True, slots=True)
class NavOutput:
    setpoint: Setpoint
    limits: MotionLimits
    phase: NavPhase


def default_limits(params: ParamTable, speed_xy_mps: float | None = None) -> MotionLimits:
    speed = params["MPC_XY_VEL_MAX"] if speed_xy_mps is None else min(speed_xy_mps, params["MPC_XY_VEL_MAX"])
    return MotionLimits(
        speed_xy_mps=speed,
        speed_up_mps=params["MPC_Z_VEL_MAX_UP"],
        speed_down_mps=params["MPC_Z_VEL_MAX_DN"],
        acc_xy_mps2=params["MPC_ACC_HOR"],
        acc_up_mps2=params["MPC_ACC_UP_MAX"],
        acc_down_mps2=params["MPC_ACC_DOWN_MAX"],
    )


def _heading_to(frm: Vec3, to: Vec3) -> float:
    return math.atan2(to[1] - frm[1], to[0] - frm[0])


class TakeoffTask:
    """Climb vertically at ``MPC_TKO_SPEED`` to ``target_down`` over ``xy``."""

    def __init__(self, xy: tuple[float, float], target_down_m: float, yaw_rad: float) -> None:
        self.xy = xy
        self.target_down_m = target_down_m
        self.yaw_rad = yaw_rad
        self.done = False

    def update(self, ctx: NavContext) -> NavOutput:
        p = ctx.params
        if ctx.pos[2] <= self.target_down_m + p["NAV_MC_ALT_RAD"] and not ctx.landed:
            self.done = True
        limits = default_limits(p, ctx.cruise_speed_mps)
        limits = MotionLimits(
            limits.speed_xy_mps,
            min(p["MPC_TKO_SPEED"], limits.speed_up_mps),
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

    def update(self, ctx: NavContext) -> NavOutput:
        p = ctx.params
        dist_xy = math.hypot(self.target[0] - ctx.pos[0], self.target[1] - ctx.pos[1])
        if math.isfinite(self.fixed_yaw):
            self._yaw = self.fixed_yaw
        elif dist_xy > 2.0:
            self._yaw = _heading_to(ctx.pos, self.target)
        acc = self.acceptance_xy_m if math.isfinite(self.acceptance_xy_m) else p["NAV_ACC_RAD"]
        if dist_xy <= acc and abs(self.target[2] - ctx.pos[2]) <= p["NAV_MC_ALT_RAD"]:
            self.reached = True
        speed = self.speed_mps if math.isfinite(self.speed_mps) else ctx.cruise_speed_mps
        sp = Setpoint(pos=self.target, yaw_rad=self._yaw)
        return NavOutput(sp, default_limits(p, speed), NavPhase.HOLD if self.reached else NavPhase.CRUISE)


class LandTask:
    """Descend over ``xy`` (fast high up, ``MPC_LAND_SPEED`` below 5 m) until landed."""

    ALT_FAST_M = 10.0
    ALT_SLOW_M = 5.0

    def __init__(self, xy: tuple[float, float], yaw_rad: float) -> None:
        self.xy = xy
        self.yaw_rad = yaw_rad
        self.done = False

    def update(self, ctx: NavContext) -> NavOutput:
        p = ctx.params
        slow, fast = p["MPC_LAND_SPEED"], max(p["MPC_LAND_SPEED"], p["MPC_Z_VEL_MAX_DN"])
        h = ctx.height_above_ground_m
        if h >= self.ALT_FAST_M:
            speed = fast
        elif h <= self.ALT_SLOW_M:
            speed = slow
        else:
            speed = slow + (fast - slow) * (h - self.ALT_SLOW_M) / (self.ALT_FAST_M - self.ALT_SLOW_M)
        if ctx.landed:
            self.done = True
        sp = Setpoint(pos=(self.xy[0], self.xy[1], NAN), vel=(NAN, NAN, speed), yaw_rad=self.yaw_rad)
        return NavOutput(sp, default_limits(p, ctx.cruise_speed_mps), NavPhase.LANDING)


class RtlPhase(enum.Enum):
    CLIMB = "climb"
    RETURN = "return"
    DESCEND = "descend"
    LOITER = "loiter"
    LAND = "land"
    LANDED = "landed"


class RtlTask:
    """AUTO.RTL: climb to ``RTL_RETURN_ALT``, return home, descend to ``RTL_DESCEND_ALT``, wait, land."""

    def __init__(self, ctx: NavContext) -> None:
        p = ctx.params
        self._return_down = min(ctx.pos[2], -p["RTL_RETURN_ALT"])
        self._yaw = ctx.yaw_rad
        self._loiter_since: float | None = None
        self.phase = RtlPhase.CLIMB
        self._start_xy = (ctx.pos[0], ctx.pos[1])
        self._sub: GotoTask | LandTask | None = None
        if ctx.landed:
            self.phase = RtlPhase.LANDED
        elif math.hypot(ctx.pos[0], ctx.pos[1]) <= p["NAV_ACC_RAD"]:
            self.phase = RtlPhase.DESCEND

    @property
    def done(self) -> bool:
        return self.phase is RtlPhase.LANDED

    def update(self, ctx: NavContext) -> NavOutput:  # noqa: PLR0912 - one branch per phase
        p = ctx.params
        if self.phase is RtlPhase.CLIMB:
            if ctx.pos[2] <= self._return_down + p["NAV_MC_ALT_RAD"]:
                self.phase = RtlPhase.RETURN
            else:
                sp = Setpoint(pos=(self._start_xy[0], self._start_xy[1], self._return_down), yaw_rad=self._yaw)
                return NavOutput(sp, default_limits(p, ctx.cruise_speed_mps), NavPhase.CRUISE)
        if self.phase is RtlPhase.RETURN:
            if not isinstance(self._sub, GotoTask):
                self._sub = GotoTask((0.0, 0.0, self._return_down), initial_yaw_rad=ctx.yaw_rad)
            out = self._sub.update(ctx)
            if not self._sub.reached:
                return out
            self._yaw = ctx.yaw_rad
            self.phase = RtlPhase.DESCEND
            self._sub = None
        if self.phase is RtlPhase.DESCEND:
            if isinstance(self._sub, GotoTask):
                descend_down = self._sub.target[2]
            else:
                descend_down = max(ctx.pos[2], -p["RTL_DESCEND_ALT"])
            if not isinstance(self._sub, GotoTask):
                self._sub = GotoTask((0.0, 0.0, descend_down), yaw_rad=self._yaw)
            out = self._sub.update(ctx)
            if not self._sub.reached:
                return out
            self.phase = RtlPhase.LOITER
            self._loiter_since = ctx.t_s
        if self.phase is RtlPhase.LOITER:
            delay = p["RTL_LAND_DELAY"]
            since = self._loiter_since if self._loiter_since is not None else ctx.t_s
            if delay < 0.0 or ctx.t_s - since < delay:
                assert isinstance(self._sub, GotoTask)
                return self._sub.update(ctx)
            self.phase = RtlPhase.LAND
            self._sub = LandTask((0.0, 0.0), self._yaw)
        if self.phase is RtlPhase.LAND:
            assert isinstance(self._sub, LandTask)
            out = self._sub.update(ctx)
            if self._sub.done:
                self.phase = RtlPhase.LANDED
            return out
        sp = Setpoint(pos=(ctx.pos[0], ctx.pos[1], NAN), vel=(NAN, NAN, p["MPC_LAND_SPEED"]), yaw_rad=self._yaw)
        return NavOutput(sp, default_limits(p), NavPhase.LANDING)


@dataclass
class MissionProgress:
    """Executor state that survives leaving and re-entering AUTO.MISSION (pause/resume)."""

    current: int = 0
    started: bool = False
    finished: bool = False
    mission_id: int = -1
    reached: list[int] = field(default_factory=list)
    speed_mps: float = NAN


class MissionTask:
    """AUTO.MISSION: fly the store's items from ``progress.current``.

    Reached nav items are appended to ``progress.reached`` (the shell sends
    MISSION_ITEM_REACHED); DO_CHANGE_SPEED sets the speed for later legs.
    On the ground the vehicle first takes off to the first leg's altitude
    (at least ``MIS_TAKEOFF_ALT``), as PX4 does.
    """

    MAX_DO_ITEMS_PER_UPDATE = 32

    def __init__(self, store: MissionStore, progress: MissionProgress, projection: LocalProjection) -> None:
        self.store = store
        self.progress = progress
        self.projection = projection
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

    def update(self, ctx: NavContext) -> NavOutput:  # noqa: PLR0912
        prog = self.progress
        prog.started = True
        items = self.store.items
        for _ in range(self.MAX_DO_ITEMS_PER_UPDATE):
            if prog.finished or prog.current >= len(items):
                break
            item = items[prog.current]
            if item.command == MavCmd.DO_CHANGE_SPEED:
                if item.param2 > 0.0:
                    prog.speed_mps = item.param2
                elif item.param2 == -2.0:
                    prog.speed_mps = NAN
                self._advance(None)
                continue
            break
        speed = prog.speed_mps if math.isfinite(prog.speed_mps) else ctx.cruise_speed_mps
        nav_ctx = NavContext(
            ctx.t_s, ctx.pos, ctx.vel, ctx.yaw_rad, ctx.landed, ctx.height_above_ground_m, ctx.params, speed
        )
        if prog.finished or prog.current >= len(items):
            prog.finished = True
            if self._end_hold is None:
                self._end_hold = GotoTask(ctx.pos, yaw_rad=ctx.yaw_rad)
            if ctx.landed:
                sp = Setpoint(pos=(ctx.pos[0], ctx.pos[1], NAN), vel=(NAN, NAN, ctx.params["MPC_LAND_SPEED"]))
                return NavOutput(sp, default_limits(ctx.params), NavPhase.LANDING)
            return self._end_hold.update(nav_ctx)
        item = items[prog.current]
        target = item_target_ned(item, self.projection, ctx.pos)
        if ctx.landed and item.command not in (MavCmd.NAV_TAKEOFF, MavCmd.NAV_LAND, MavCmd.NAV_RETURN_TO_LAUNCH):
            if self._pre_takeoff is None:
                alt_down = min(target[2], -ctx.params["MIS_TAKEOFF_ALT"])
                self._pre_takeoff = TakeoffTask((ctx.pos[0], ctx.pos[1]), alt_down, ctx.yaw_rad)
            return self._pre_takeoff.update(nav_ctx)
        if self._pre_takeoff is not None and not self._pre_takeoff.done:
            return self._pre_takeoff.update(nav_ctx)
        self._pre_takeoff = None
        if self._sub is None or self._sub_seq != prog.current:
            self._sub = self._make_sub(item, target, nav_ctx)
            self._sub_seq = prog.current
            self._hold_since = None
        out = self._sub.update(nav_ctx)
        if self._item_complete(item, nav_ctx):
            self._advance(prog.current)
        return out

    def _make_sub(
        self, item: MissionItem, target: Vec3, ctx: NavContext
    ) -> GotoTask | TakeoffTask | LandTask | RtlTask:
        cmd = item.command
        if cmd == MavCmd.NAV_TAKEOFF:
            down = target[2] if math.isfinite(item.z) else -ctx.params["MIS_TAKEOFF_ALT"]
            return TakeoffTask((ctx.pos[0], ctx.pos[1]), down, ctx.yaw_rad)
        if cmd == MavCmd.NAV_LAND:
            return LandTask((target[0], target[1]), ctx.yaw_rad)
        if cmd == MavCmd.NAV_RETURN_TO_LAUNCH:
            return RtlTask(ctx)
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
        hold_s = item.param1 if item.command in (MavCmd.NAV_WAYPOINT, MavCmd.NAV_LOITER_TIME) else 0.0
        if self._hold_since is None:
            self._hold_since = ctx.t_s
        return ctx.t_s - self._hold_since >= hold_s
