"""Command protocol semantics: COMMAND_LONG / COMMAND_INT -> autopilot calls and a MAV_RESULT.

Every command gets exactly one result: the supported ones are executed or
refused with the right MAV_RESULT (DENIED for invalid or non-finite values and
for refused state changes), anything else is UNSUPPORTED. Commands whose answer
is a message (REQUEST_MESSAGE, GET_HOME_POSITION...) list the message ids the
shell sends after the ACK, on the link the command came from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from sitl.core.autopilot import Autopilot
from sitl.core.protocol import FORCE_ARM_MAGIC, MavCmd, MavFrame, MavResult, MavSeverity, MsgId
from sitl.core.telemetry import PRODUCIBLE, StreamScheduler

__all__ = ["CommandOutcome", "CommandRequest", "handle_command"]

REPOSITION_FLAG_CHANGE_MODE = 1
_RELATIVE = frozenset({MavFrame.GLOBAL_RELATIVE_ALT, MavFrame.GLOBAL_RELATIVE_ALT_INT})
_GLOBAL = frozenset({MavFrame.GLOBAL, MavFrame.GLOBAL_INT, *_RELATIVE})


@dataclass(frozen=True)
class CommandRequest:
    """A command with params 1..7; for COMMAND_INT, ``param5``/``param6`` are already degrees."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    frame: int | None = None

    @property
    def is_int(self) -> bool:
        return self.frame is not None


@dataclass(frozen=True)
class CommandOutcome:
    result: MavResult
    send: tuple[int, ...] = ()
    interval_of: int | None = None


def _as_int(value: float, low: int, high: int) -> int | None:
    if not math.isfinite(value) or value != int(value) or not low <= value <= high:
        return None
    return int(value)


def _alt_amsl(req: CommandRequest, ap: Autopilot, *, relative_long: bool = False) -> float:
    """param7 as AMSL; COMMAND_INT in a relative frame is relative to home, and so is a COMMAND_LONG's
    when ``relative_long`` (ArduCopter's NAV_TAKEOFF altitude)."""
    alt = req.params[6]
    relative = req.frame in _RELATIVE if req.is_int else relative_long
    if relative and math.isfinite(alt):
        return alt + ap.home.alt_amsl_m
    return alt


def handle_command(req: CommandRequest, ap: Autopilot, streams: StreamScheduler, t_s: float) -> CommandOutcome:  # noqa: PLR0911, PLR0912
    """Execute ``req``; the outcome's ``result`` goes into the COMMAND_ACK."""
    p1, p2, p3, p4, p5, p6, _ = req.params
    cmd = req.command
    ardupilot = ap.personality.is_ardupilot
    positional = (MavCmd.NAV_TAKEOFF, MavCmd.NAV_LAND, MavCmd.DO_REPOSITION, MavCmd.DO_ORBIT)
    if req.is_int and cmd in positional and req.frame not in _GLOBAL:
        return CommandOutcome(MavResult.UNSUPPORTED)
    if cmd == MavCmd.COMPONENT_ARM_DISARM:
        arm = _as_int(p1, 0, 1)
        if arm is None:
            return CommandOutcome(MavResult.DENIED)
        force = p2 == FORCE_ARM_MAGIC
        return CommandOutcome(ap.arm(force=force) if arm else ap.disarm(force=force))
    if cmd == MavCmd.NAV_TAKEOFF:
        alt = _alt_amsl(req, ap, relative_long=ardupilot)
        return CommandOutcome(ap.takeoff(alt_amsl_m=alt, lat_deg=p5, lon_deg=p6, yaw_deg=p4))
    if cmd == MavCmd.NAV_LAND:
        return CommandOutcome(ap.land(lat_deg=p5, lon_deg=p6))
    if cmd == MavCmd.NAV_RETURN_TO_LAUNCH:
        return CommandOutcome(ap.return_to_launch())
    if cmd == MavCmd.DO_REPOSITION:
        flags = _as_int(p2, 0, 0xFFFF) if math.isfinite(p2) else 0
        if flags is None:
            return CommandOutcome(MavResult.DENIED)
        return CommandOutcome(
            ap.reposition(
                lat_deg=p5,
                lon_deg=p6,
                alt_amsl_m=_alt_amsl(req, ap),
                yaw_rad=p4,
                speed_mps=p1,
                change_mode=bool(flags & REPOSITION_FLAG_CHANGE_MODE),
            )
        )
    if cmd == MavCmd.DO_SET_MODE:
        if not all(math.isfinite(v) for v in (p1, p2, p3)):
            return CommandOutcome(MavResult.DENIED)
        mode = ap.personality.mode_from_set_mode_params(p1, p2, p3)
        if mode is None:
            what = f"number {p2:g}" if ardupilot else f"main {p2:g}, sub {p3:g}"
            ap.say(MavSeverity.CRITICAL, f"Mode change denied: unsupported mode (base {p1:g}, {what})")
            return CommandOutcome(MavResult.DENIED)
        return CommandOutcome(ap.set_mode(mode))
    if cmd == MavCmd.DO_ORBIT:
        if ardupilot:
            ap.say(MavSeverity.WARNING, "DO_ORBIT is not supported by ArduCopter (its CIRCLE mode is not emulated)")
            return CommandOutcome(MavResult.UNSUPPORTED)
        return CommandOutcome(
            ap.orbit(
                radius_m=p1,
                velocity_mps=p2,
                yaw_behaviour=p3,
                lat_deg=p5,
                lon_deg=p6,
                alt_amsl_m=req.params[6],  # AMSL in any frame, as PX4 reads it (MAVSDK sends AMSL with frame 3)
            )
        )
    if cmd == MavCmd.DO_CHANGE_SPEED:
        return CommandOutcome(ap.change_speed(p2))
    if cmd == MavCmd.DO_SET_MISSION_CURRENT:
        seq = _as_int(p1, -1, 65535)
        if seq is None:
            return CommandOutcome(MavResult.DENIED)
        if seq == -1:
            return CommandOutcome(MavResult.ACCEPTED)
        return CommandOutcome(ap.set_mission_current(seq))
    if cmd == MavCmd.MISSION_START:
        first = _as_int(p1, 0, 65535) if math.isfinite(p1) else 0
        if first is None:
            return CommandOutcome(MavResult.DENIED)
        return CommandOutcome(ap.start_mission(first))
    if cmd == MavCmd.REQUEST_MESSAGE:
        msg_id = _as_int(p1, 0, 0xFFFFFF)
        if msg_id is None:
            return CommandOutcome(MavResult.DENIED)
        if msg_id not in PRODUCIBLE:
            return CommandOutcome(MavResult.UNSUPPORTED)
        return CommandOutcome(MavResult.ACCEPTED, send=(msg_id,))
    if cmd == MavCmd.REQUEST_AUTOPILOT_CAPABILITIES:
        if p1 != 1.0:
            return CommandOutcome(MavResult.ACCEPTED)
        return CommandOutcome(MavResult.ACCEPTED, send=(MsgId.AUTOPILOT_VERSION,))
    if cmd == MavCmd.INJECT_FAILURE:
        unit, ftype, instance = _as_int(p1, 0, 255), _as_int(p2, 0, 255), _as_int(p3, 0, 255)
        if unit is None or ftype is None or instance is None:
            return CommandOutcome(MavResult.DENIED)
        return CommandOutcome(ap.inject_failure(unit, ftype, instance))
    if cmd == MavCmd.GET_HOME_POSITION:
        return CommandOutcome(MavResult.ACCEPTED, send=(MsgId.HOME_POSITION,))
    if cmd == MavCmd.SET_MESSAGE_INTERVAL:
        msg_id = _as_int(p1, 0, 0xFFFFFF)
        if msg_id is None:
            return CommandOutcome(MavResult.DENIED)
        return CommandOutcome(streams.set_interval(msg_id, p2, t_s))
    if cmd == MavCmd.GET_MESSAGE_INTERVAL:
        msg_id = _as_int(p1, 0, 0xFFFFFF)
        if msg_id is None:
            return CommandOutcome(MavResult.DENIED)
        return CommandOutcome(MavResult.ACCEPTED, send=(MsgId.MESSAGE_INTERVAL,), interval_of=msg_id)
    return CommandOutcome(MavResult.UNSUPPORTED)
