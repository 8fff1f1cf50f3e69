"""The MAVLink mission protocol (upload, download, clear), as a pure state machine.

Inbound events return the replies to send, as small value objects the shell
encodes. Items are requested with ``MISSION_REQUEST_INT`` (a PX4 autopilot
must; MAVSDK NACKs a plain ``MISSION_REQUEST``). Timing is injected (``now_s``,
wall-clock seconds: this protocol is paced by the client's timeouts).

Two item lists are served: the mission (type 0) and, when a fence store is given, the geofence
(type 1). Rally points (type 2) are refused (UNSUPPORTED; their downloads are empty). With
``home_item`` (ArduPilot), mission item 0 is home: an upload's item 0 is accepted as it comes
and a download's item 0 is the present home position.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass, replace

from sitl.core.geofence import MAX_FENCE_ITEMS, FenceStore, validate_fence_item
from sitl.core.mission import MAX_ITEMS, MissionItem, MissionStore, validate_item
from sitl.core.protocol import MavCmd, MavMissionResult

__all__ = [
    "MissionAckOut",
    "MissionCountOut",
    "MissionItemOut",
    "MissionOut",
    "MissionRequestOut",
    "MissionServer",
    "Peer",
]

MISSION_TYPE_MISSION = 0
MISSION_TYPE_FENCE = 1
MISSION_TYPE_RALLY = 2
MISSION_TYPE_ALL = 255


@dataclass(frozen=True)
class Peer:
    """Who sent a message: its ids and an opaque route back to it (link and address)."""

    route: Hashable
    system_id: int
    component_id: int


@dataclass(frozen=True)
class MissionRequestOut:
    peer: Peer
    seq: int
    mission_type: int


@dataclass(frozen=True)
class MissionAckOut:
    peer: Peer
    result: MavMissionResult
    mission_type: int


@dataclass(frozen=True)
class MissionCountOut:
    peer: Peer
    count: int
    mission_type: int


@dataclass(frozen=True)
class MissionItemOut:
    peer: Peer
    item: MissionItem
    as_int: bool


MissionOut = MissionRequestOut | MissionAckOut | MissionCountOut | MissionItemOut


@dataclass
class _Upload:
    peer: Peer
    count: int
    items: list[MissionItem]
    last_activity_s: float
    retries: int = 0
    mission_type: int = MISSION_TYPE_MISSION


class MissionServer:
    """Mission protocol endpoint for one vehicle.

    Args:
        store: the mission.
        fence: the geofence store (None: fence uploads are refused as UNSUPPORTED).
        home_item: ArduPilot's convention: item 0 is home; this builds it for downloads.
    """

    RETRY_AFTER_S = 0.5
    MAX_RETRIES = 5

    def __init__(
        self,
        store: MissionStore,
        fence: FenceStore | None = None,
        *,
        home_item: Callable[[], MissionItem] | None = None,
    ) -> None:
        self.store = store
        self.fence = fence
        self._home_item = home_item
        self._upload: _Upload | None = None
        self._last_upload: tuple[Peer, int] | None = None
        self._current_seq = 0

    def set_current_seq(self, seq: int) -> None:
        """The executor's current item (flagged ``current`` in downloads)."""
        self._current_seq = seq

    @property
    def upload_in_progress(self) -> bool:
        return self._upload is not None

    def _served(self, mission_type: int) -> MissionStore | FenceStore | None:
        if mission_type == MISSION_TYPE_MISSION:
            return self.store
        if mission_type == MISSION_TYPE_FENCE:
            return self.fence
        return None

    def _validate(self, item: MissionItem) -> MavMissionResult:
        if item.mission_type == MISSION_TYPE_FENCE:
            return validate_fence_item(item)
        if self._home_item is not None and item.seq == 0:
            # ArduPilot: item 0 is home, whatever a client puts there (MAVSDK, MAVProxy and QGC send a waypoint)
            ok = item.command == MavCmd.NAV_WAYPOINT
            return MavMissionResult.ACCEPTED if ok else MavMissionResult.UNSUPPORTED
        return validate_item(item)

    # ------------------------------------------------------------------ upload
    def on_count(self, peer: Peer, count: int, mission_type: int, now_s: float) -> list[MissionOut]:
        target = self._served(mission_type)
        if target is None:
            result = MavMissionResult.ACCEPTED if count == 0 else MavMissionResult.UNSUPPORTED
            return [MissionAckOut(peer, result, mission_type)]
        if self._upload is not None and self._upload.peer != peer:
            return [MissionAckOut(peer, MavMissionResult.DENIED, mission_type)]
        limit = MAX_ITEMS if mission_type == MISSION_TYPE_MISSION else MAX_FENCE_ITEMS
        if count > limit:
            self._upload = None
            return [MissionAckOut(peer, MavMissionResult.NO_SPACE, mission_type)]
        if count <= 0:
            self._upload = None
            target.clear()
            return [MissionAckOut(peer, MavMissionResult.ACCEPTED, mission_type)]
        self._upload = _Upload(peer, count, [], now_s, mission_type=mission_type)
        return [MissionRequestOut(peer, 0, mission_type)]

    def on_item(self, peer: Peer, item: MissionItem, now_s: float) -> list[MissionOut]:  # noqa: PLR0911
        up = self._upload
        if up is None or up.peer != peer:
            target = self._served(item.mission_type)
            resent_last = (
                target is not None
                and self._last_upload == (peer, item.mission_type)
                and len(target) > 0
                and item.seq == len(target) - 1
            )
            if resent_last:  # our final ACK was lost and the client resent the last item
                return [MissionAckOut(peer, MavMissionResult.ACCEPTED, item.mission_type)]
            return []
        if item.mission_type != up.mission_type:
            return []
        expected = len(up.items)
        if item.seq != expected:
            up.last_activity_s = now_s
            return [MissionRequestOut(peer, expected, up.mission_type)]
        result = self._validate(item)
        if result is not MavMissionResult.ACCEPTED:
            self._upload = None
            return [MissionAckOut(peer, result, up.mission_type)]
        up.items.append(item)
        up.last_activity_s = now_s
        up.retries = 0
        if len(up.items) < up.count:
            return [MissionRequestOut(peer, len(up.items), up.mission_type)]
        self._upload = None
        items = tuple(up.items)
        if up.mission_type == MISSION_TYPE_FENCE:
            assert self.fence is not None
            result = self.fence.check(items)
            if result is not MavMissionResult.ACCEPTED:
                return [MissionAckOut(peer, result, up.mission_type)]
            self.fence.replace(items)
        else:
            self.store.replace(items)
        self._last_upload = (peer, up.mission_type)
        return [MissionAckOut(peer, MavMissionResult.ACCEPTED, up.mission_type)]

    def tick(self, now_s: float) -> list[MissionOut]:
        """Re-request a missing item after a timeout; give up after a few retries."""
        up = self._upload
        if up is None or now_s - up.last_activity_s < self.RETRY_AFTER_S:
            return []
        if up.retries >= self.MAX_RETRIES:
            self._upload = None
            return [MissionAckOut(up.peer, MavMissionResult.OPERATION_CANCELLED, up.mission_type)]
        up.retries += 1
        up.last_activity_s = now_s
        return [MissionRequestOut(up.peer, len(up.items), up.mission_type)]

    # ------------------------------------------------------------------ download
    def on_request_list(self, peer: Peer, mission_type: int) -> list[MissionOut]:
        target = self._served(mission_type)
        count = len(target) if target is not None else 0
        return [MissionCountOut(peer, count, mission_type)]

    def on_request(self, peer: Peer, seq: int, mission_type: int, *, as_int: bool) -> list[MissionOut]:
        target = self._served(mission_type)
        if target is None or not 0 <= seq < len(target):
            return [MissionAckOut(peer, MavMissionResult.INVALID_SEQUENCE, mission_type)]
        if mission_type == MISSION_TYPE_FENCE:
            return [MissionItemOut(peer, target.items[seq], as_int)]
        item = self.store.items[seq]
        if seq == 0 and self._home_item is not None:
            item = replace(self._home_item(), seq=0)
        flagged = MissionItem(
            item.seq,
            item.frame,
            item.command,
            1 if seq == self._current_seq else 0,
            item.autocontinue,
            item.param1,
            item.param2,
            item.param3,
            item.param4,
            item.x,
            item.y,
            item.z,
            item.mission_type,
        )
        return [MissionItemOut(peer, flagged, as_int)]

    # ------------------------------------------------------------------ clear
    def on_clear_all(self, peer: Peer, mission_type: int) -> list[MissionOut]:
        if mission_type in (MISSION_TYPE_MISSION, MISSION_TYPE_ALL):
            self._upload = None
            self.store.clear()
        if mission_type in (MISSION_TYPE_FENCE, MISSION_TYPE_ALL) and self.fence is not None:
            self._upload = None
            self.fence.clear()
        return [MissionAckOut(peer, MavMissionResult.ACCEPTED, mission_type)]
