"""Mission items, their validation and the mission store.

Items are kept in the ``MISSION_ITEM_INT`` representation: for global frames
``x``/``y`` are latitude/longitude in 1e-7 degrees. The executor that flies
them lives in :mod:`sitl.core.navigator`; the upload/download protocol in
:mod:`sitl.core.mission_transfer`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from sitl.core.protocol import MavCmd, MavFrame, MavMissionResult, MissionState
from uav_common.geo import GeoPoint, LocalProjection

__all__ = [
    "DO_COMMANDS",
    "GLOBAL_FRAMES",
    "NAV_COMMANDS",
    "PAYLOAD_COMMANDS",
    "RELATIVE_FRAMES",
    "MissionItem",
    "MissionStore",
    "item_target_ned",
    "validate_item",
]

NAV_COMMANDS = frozenset(
    {
        MavCmd.NAV_WAYPOINT,
        MavCmd.NAV_LOITER_UNLIM,
        MavCmd.NAV_LOITER_TIME,
        MavCmd.NAV_RETURN_TO_LAUNCH,
        MavCmd.NAV_LAND,
        MavCmd.NAV_TAKEOFF,
        MavCmd.NAV_LOITER_TO_ALT,
        MavCmd.NAV_DELAY,
    }
)
#: Camera, gimbal and video commands: accepted and skipped (the simulated vehicle carries no camera or
#: gimbal that MAVLink controls; PX4 forwards them to a payload that is not there, ArduPilot likewise).
PAYLOAD_COMMANDS = frozenset(
    {
        MavCmd.DO_DIGICAM_CONTROL,
        MavCmd.DO_MOUNT_CONFIGURE,
        MavCmd.DO_MOUNT_CONTROL,
        MavCmd.DO_SET_CAM_TRIGG_DIST,
        MavCmd.DO_SET_CAM_TRIGG_INTERVAL,
        MavCmd.SET_CAMERA_MODE,
        MavCmd.SET_CAMERA_ZOOM,
        MavCmd.SET_CAMERA_FOCUS,
        MavCmd.DO_GIMBAL_MANAGER_PITCHYAW,
        MavCmd.DO_GIMBAL_MANAGER_CONFIGURE,
        MavCmd.IMAGE_START_CAPTURE,
        MavCmd.IMAGE_STOP_CAPTURE,
        MavCmd.VIDEO_START_CAPTURE,
        MavCmd.VIDEO_STOP_CAPTURE,
    }
)
DO_COMMANDS = frozenset(
    {
        MavCmd.DO_CHANGE_SPEED,
        MavCmd.DO_JUMP,
        MavCmd.DO_SET_ROI_LOCATION,
        MavCmd.DO_SET_ROI_NONE,
        MavCmd.DO_LAND_START,
        *PAYLOAD_COMMANDS,
    }
)
GLOBAL_FRAMES = frozenset({MavFrame.GLOBAL, MavFrame.GLOBAL_INT})
RELATIVE_FRAMES = frozenset({MavFrame.GLOBAL_RELATIVE_ALT, MavFrame.GLOBAL_RELATIVE_ALT_INT})
MAX_ITEMS = 1000


@dataclass(frozen=True)
class MissionItem:
    """One item, as in ``MISSION_ITEM_INT`` (``x``, ``y`` in 1e-7 deg for global frames)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    mission_type: int = 0

    @property
    def is_nav(self) -> bool:
        return self.command in NAV_COMMANDS

    @property
    def has_position(self) -> bool:
        """Whether ``x``/``y`` name a place (0/0 means "here" for takeoff and land)."""
        return not (self.x == 0 and self.y == 0)


def validate_item(item: MissionItem) -> MavMissionResult:  # noqa: PLR0911, PLR0912 - one return per check
    """``ACCEPTED`` or the ``MAV_MISSION_RESULT`` that rejects the upload (PX4's checks)."""
    if item.command not in NAV_COMMANDS and item.command not in DO_COMMANDS:
        return MavMissionResult.UNSUPPORTED
    params = (item.param1, item.param2, item.param3, item.param4)
    if any(math.isinf(p) for p in params):
        return MavMissionResult(
            MavMissionResult.INVALID_PARAM1 + next(i for i, p in enumerate(params) if math.isinf(p))
        )
    if item.command in DO_COMMANDS:
        if item.frame not in (MavFrame.MISSION, *GLOBAL_FRAMES, *RELATIVE_FRAMES):
            return MavMissionResult.UNSUPPORTED_FRAME
        if item.command == MavCmd.DO_CHANGE_SPEED and not (item.param2 in (-1.0, -2.0) or 0.0 < item.param2 <= 30.0):
            return MavMissionResult.INVALID_PARAM2
        if item.command == MavCmd.DO_JUMP:
            if not (math.isfinite(item.param1) and item.param1 >= 0 and item.param1 == int(item.param1)):
                return MavMissionResult.INVALID_PARAM1
            if not (math.isfinite(item.param2) and item.param2 >= -1 and item.param2 == int(item.param2)):
                return MavMissionResult.INVALID_PARAM2
        if item.command == MavCmd.DO_SET_ROI_LOCATION:
            if not (-900_000_000 <= item.x <= 900_000_000 and item.has_position):
                return MavMissionResult.INVALID_PARAM5_X
            if not -1_800_000_000 <= item.y <= 1_800_000_000:
                return MavMissionResult.INVALID_PARAM6_Y
        return MavMissionResult.ACCEPTED
    if item.command == MavCmd.NAV_DELAY:
        if not (math.isfinite(item.param1) and item.param1 >= 0.0):
            return MavMissionResult.INVALID_PARAM1  # -1 (wait for a time of day) is not supported
        return MavMissionResult.ACCEPTED
    if item.frame not in GLOBAL_FRAMES and item.frame not in RELATIVE_FRAMES:
        return MavMissionResult.UNSUPPORTED_FRAME
    if not -900_000_000 <= item.x <= 900_000_000:
        return MavMissionResult.INVALID_PARAM5_X
    if not -1_800_000_000 <= item.y <= 1_800_000_000:
        return MavMissionResult.INVALID_PARAM6_Y
    if not math.isfinite(item.z) and item.command not in (MavCmd.NAV_LAND, MavCmd.NAV_RETURN_TO_LAUNCH):
        return MavMissionResult.INVALID_PARAM7
    needs_place = item.command in (
        MavCmd.NAV_WAYPOINT,
        MavCmd.NAV_LOITER_TIME,
        MavCmd.NAV_LOITER_UNLIM,
        MavCmd.NAV_LOITER_TO_ALT,
    )
    if needs_place and not item.has_position:
        return MavMissionResult.INVALID_PARAM5_X
    if item.command in (MavCmd.NAV_WAYPOINT, MavCmd.NAV_LOITER_TIME) and item.param1 < 0.0:
        return MavMissionResult.INVALID_PARAM1
    if item.command == MavCmd.NAV_WAYPOINT and item.param2 < 0.0:
        return MavMissionResult.INVALID_PARAM2
    return MavMissionResult.ACCEPTED


def item_target_ned(
    item: MissionItem, projection: LocalProjection, here_ned: tuple[float, float, float]
) -> tuple[float, float, float]:
    """Where a nav item goes, in LOCAL_NED metres; missing parts default to ``here_ned``.

    ``x``/``y`` of 0/0 mean the present horizontal position, a NaN altitude the
    present altitude (takeoff and land items may leave them out).
    """
    north, east, down = here_ned
    if item.has_position:
        point = GeoPoint(item.x * 1e-7, item.y * 1e-7, projection.origin.alt_amsl_m)
        north, east, _ = projection.to_ned(point)
    if math.isfinite(item.z):
        down = -item.z if item.frame in RELATIVE_FRAMES else projection.origin.alt_amsl_m - item.z
    return north, east, down


class MissionStore:
    """The uploaded mission (type 0 only) and its identity for MISSION_CURRENT/ACK."""

    def __init__(self) -> None:
        self._items: tuple[MissionItem, ...] = ()
        self.mission_id = 0

    @property
    def items(self) -> tuple[MissionItem, ...]:
        return self._items

    def __len__(self) -> int:
        return len(self._items)

    def replace(self, items: tuple[MissionItem, ...]) -> None:
        self._items = tuple(replace(it, seq=i, current=0) for i, it in enumerate(items))
        self.mission_id = (self.mission_id + 1) & 0xFFFFFFFF

    def clear(self) -> None:
        self.replace(())

    def state(self, *, started: bool, finished: bool, paused: bool) -> MissionState:
        if not self._items:
            return MissionState.NO_MISSION
        if finished:
            return MissionState.COMPLETE
        if not started:
            return MissionState.NOT_STARTED
        return MissionState.PAUSED if paused else MissionState.ACTIVE
