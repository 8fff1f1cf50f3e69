"""The MAVLink mission protocol (upload, download, clear), as a pure state machine.

Inbound events return the replies to send, as small value objects the shell
encodes. Items are requested with ``MISSION_REQUEST_INT`` (a PX4 autopilot
must; MAVSDK NACKs a plain ``MISSION_REQUEST``). Timing is injected (``now_s``,
wall-clock seconds: this protocol is paced by the client's timeouts).
"""

from __future__ import annotations

from collections.abc import Hashable
from dataclasses import dataclass

from sitl.core.mission import MAX_ITEMS, MissionItem, MissionStore, validate_item
from sitl.core.protocol import MavMissionResult

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


class MissionServer:
    """Mission protocol endpoint for one vehicle."""

    RETRY_AFTER_S = 0.5
    MAX_RETRIES = 5

    def __init__(self, store: MissionStore) -> None:
        self.store = store
        self._upload: _Upload | None = None
        self._last_upload_peer: Peer | None = None
        self._current_seq = 0

    def set_current_seq(self, seq: int) -> None:
        """The executor's current item (flagged ``current`` in downloads)."""
        self._current_seq = seq

    @property
    def upload_in_progress(self) -> bool:
        return self._upload is not None

    # ------------------------------------------------------------------ upload
    def on_count(self, peer: Peer, count: int, mission_type: int, now_s: float) -> list[MissionOut]:
        if mission_type != MISSION_TYPE_MISSION:
            result = MavMissionResult.ACCEPTED if count == 0 else MavMissionResult.UNSUPPORTED
            return [MissionAckOut(peer, result, mission_type)]
        if self._upload is not None and self._upload.peer != peer:
            return [MissionAckOut(peer, MavMissionResult.DENIED, mission_type)]
        if count > MAX_ITEMS:
            self._upload = None
            return [MissionAckOut(peer, MavMissionResult.NO_SPACE, mission_type)]
        if count <= 0:
            self._upload = None
            self.store.clear()
            return [MissionAckOut(peer, MavMissionResult.ACCEPTED, mission_type)]
        self._upload = _Upload(peer, count, [], now_s)
        return [MissionRequestOut(peer, 0, mission_type)]

    def on_item(self, peer: Peer, item: MissionItem, now_s: float) -> list[MissionOut]:  # noqa: PLR0911
        up = self._upload
        if up is None or up.peer != peer:
            resent_last = (
                item.mission_type == MISSION_TYPE_MISSION
                and peer == self._last_upload_peer
                and len(self.store) > 0
                and item.seq == len(self.store) - 1
            )
            if resent_last:  # our final ACK was lost and the client resent the last item
                return [MissionAckOut(peer, MavMissionResult.ACCEPTED, item.mission_type)]
            return []
        if item.mission_type != MISSION_TYPE_MISSION:
            return []
        expected = len(up.items)
        if item.seq != expected:
            up.last_activity_s = now_s
            return [MissionRequestOut(peer, expected, MISSION_TYPE_MISSION)]
        result = validate_item(item)
        if result is not MavMissionResult.ACCEPTED:
            self._upload = None
            return [MissionAckOut(peer, result, MISSION_TYPE_MISSION)]
        up.items.append(item)
        up.last_activity_s = now_s
        up.retries = 0
        if len(up.items) < up.count:
            return [MissionRequestOut(peer, len(up.items), MISSION_TYPE_MISSION)]
        self.store.replace(tuple(up.items))
        self._upload = None
        self._last_upload_peer = peer
        return [MissionAckOut(peer, MavMissionResult.ACCEPTED, MISSION_TYPE_MISSION)]

    def tick(self, now_s: float) -> list[MissionOut]:
        """Re-request a missing item after a timeout; give up after a few retries."""
        up = self._upload
        if up is None or now_s - up.last_activity_s < self.RETRY_AFTER_S:
            return []
        if up.retries >= self.MAX_RETRIES:
            self._upload = None
            return [MissionAckOut(up.peer, MavMissionResult.OPERATION_CANCELLED, MISSION_TYPE_MISSION)]
        up.retries += 1
        up.last_activity_s = now_s
        return [MissionRequestOut(up.peer, len(up.items), MISSION_TYPE_MISSION)]

    # ------------------------------------------------------------------ download
    def on_request_list(self, peer: Peer, mission_type: int) -> list[MissionOut]:
        count = len(self.store) if mission_type == MISSION_TYPE_MISSION else 0
        return [MissionCountOut(peer, count, mission_type)]

    def on_request(self, peer: Peer, seq: int, mission_type: int, *, as_int: bool) -> list[MissionOut]:
        if mission_type != MISSION_TYPE_MISSION or not 0 <= seq < len(self.store):
            return [MissionAckOut(peer, MavMissionResult.INVALID_SEQUENCE, mission_type)]
        item = self.store.items[seq]
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
        return [MissionAckOut(peer, MavMissionResult.ACCEPTED, mission_type)]
