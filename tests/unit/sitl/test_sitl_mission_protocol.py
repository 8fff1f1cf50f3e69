"""Mission items and the upload/download/clear protocol state machine."""

from __future__ import annotations

import math

from sitl.core.mission import MissionItem, MissionStore, item_target_ned, validate_item
from sitl.core.mission_transfer import (
    MissionAckOut,
    MissionCountOut,
    MissionItemOut,
    MissionRequestOut,
    MissionServer,
    Peer,
)
from sitl.core.protocol import MavCmd, MavFrame, MavMissionResult, MissionState
from uav_common.geo import GeoPoint, LocalProjection

A = Peer(("gcs", ("127.0.0.1", 1)), 255, 190)
B = Peer(("api", ("127.0.0.1", 2)), 245, 190)
HOME = GeoPoint(47.397742, 8.545594, 488.0)


def item(  # noqa: PLR0917
    seq: int,
    cmd: int = MavCmd.NAV_WAYPOINT,
    frame: int = MavFrame.GLOBAL_RELATIVE_ALT_INT,
    x: int = 473980000,
    y: int = 85460000,
    z: float = 10.0,
    p2: float = 0.0,
) -> MissionItem:
    return MissionItem(seq, frame, cmd, 0, 1, 0.0, p2, 0.0, math.nan, x, y, z)


def test_validation() -> None:
    assert validate_item(item(0)) is MavMissionResult.ACCEPTED
    assert validate_item(item(0, cmd=MavCmd.NAV_TAKEOFF, x=0, y=0)) is MavMissionResult.ACCEPTED
    assert validate_item(item(0, cmd=MavCmd.NAV_LAND, x=0, y=0, z=math.nan)) is MavMissionResult.ACCEPTED
    assert validate_item(item(0, cmd=MavCmd.NAV_WAYPOINT, x=0, y=0)) is MavMissionResult.INVALID_PARAM5_X
    assert validate_item(item(0, cmd=183)) is MavMissionResult.UNSUPPORTED  # DO_SET_SERVO
    assert validate_item(item(0, frame=MavFrame.LOCAL_NED)) is MavMissionResult.UNSUPPORTED_FRAME
    assert validate_item(item(0, z=math.nan)) is MavMissionResult.INVALID_PARAM7
    assert validate_item(item(0, x=910_000_000)) is MavMissionResult.INVALID_PARAM5_X
    speed = MissionItem(0, MavFrame.MISSION, MavCmd.DO_CHANGE_SPEED, 0, 1, 1, 8.0, -1, 0, 0, 0, 0)
    assert validate_item(speed) is MavMissionResult.ACCEPTED
    bad_speed = MissionItem(0, MavFrame.MISSION, MavCmd.DO_CHANGE_SPEED, 0, 1, 1, -7.0, -1, 0, 0, 0, 0)
    assert validate_item(bad_speed) is MavMissionResult.INVALID_PARAM2
    inf = MissionItem(0, MavFrame.GLOBAL_RELATIVE_ALT_INT, MavCmd.NAV_WAYPOINT, 0, 1, math.inf, 0, 0, 0, 1, 1, 5)
    assert validate_item(inf) is MavMissionResult.INVALID_PARAM1


def test_item_targets_in_local_ned() -> None:
    proj = LocalProjection(HOME)
    geo = proj.to_geo(30.0, -20.0, 0.0)
    rel = item(0, x=round(geo.lat_deg * 1e7), y=round(geo.lon_deg * 1e7), z=15.0)
    n, e, d = item_target_ned(rel, proj, (0.0, 0.0, -5.0))
    assert (round(n, 1), round(e, 1), d) == (30.0, -20.0, -15.0)
    amsl = item(0, frame=MavFrame.GLOBAL_INT, x=rel.x, y=rel.y, z=500.0)
    assert item_target_ned(amsl, proj, (0, 0, 0))[2] == -12.0
    here = item(0, cmd=MavCmd.NAV_LAND, x=0, y=0, z=math.nan)
    assert item_target_ned(here, proj, (1.0, 2.0, -3.0)) == (1.0, 2.0, -3.0)


def test_upload_download_and_clear() -> None:
    store = MissionStore()
    server = MissionServer(store)
    out = server.on_count(A, 3, 0, 0.0)
    assert out == [MissionRequestOut(A, 0, 0)]
    assert server.on_item(A, item(0), 0.1) == [MissionRequestOut(A, 1, 0)]
    assert server.on_item(B, item(1), 0.1) == [], "items from another client are not ours"
    assert server.on_count(B, 2, 0, 0.1) == [MissionAckOut(B, MavMissionResult.DENIED, 0)]
    assert server.on_item(A, item(2), 0.2) == [MissionRequestOut(A, 1, 0)], "out of order: ask again"
    assert server.on_item(A, item(1), 0.2) == [MissionRequestOut(A, 2, 0)]
    assert server.on_item(A, item(2), 0.3) == [MissionAckOut(A, MavMissionResult.ACCEPTED, 0)]
    assert len(store) == 3
    assert store.mission_id == 1
    # the final ACK was lost: the client resends the last item and gets the ACK again
    assert server.on_item(A, item(2), 0.4) == [MissionAckOut(A, MavMissionResult.ACCEPTED, 0)]
    assert server.on_request_list(B, 0) == [MissionCountOut(B, 3, 0)]
    server.set_current_seq(1)
    got = server.on_request(B, 1, 0, as_int=True)
    assert isinstance(got[0], MissionItemOut)
    assert got[0].item.current == 1
    assert got[0].as_int
    assert server.on_request(B, 3, 0, as_int=True) == [MissionAckOut(B, MavMissionResult.INVALID_SEQUENCE, 0)]
    assert server.on_request_list(B, 1) == [MissionCountOut(B, 0, 1)], "no fence"
    assert server.on_clear_all(B, 0) == [MissionAckOut(B, MavMissionResult.ACCEPTED, 0)]
    assert len(store) == 0
    assert store.mission_id == 2


def test_upload_rejects_bad_items_and_times_out() -> None:
    server = MissionServer(MissionStore())
    server.on_count(A, 2, 0, 0.0)
    assert server.on_item(A, item(0, cmd=183), 0.1) == [MissionAckOut(A, MavMissionResult.UNSUPPORTED, 0)]
    assert not server.upload_in_progress
    server.on_count(A, 2, 0, 1.0)
    assert server.tick(1.2) == []
    retries = [server.tick(1.0 + 0.6 * k) for k in range(1, 7)]
    assert retries[0] == [MissionRequestOut(A, 0, 0)]
    assert retries[-1] == [MissionAckOut(A, MavMissionResult.OPERATION_CANCELLED, 0)]
    assert not server.upload_in_progress
    assert server.on_count(A, 5000, 0, 9.0) == [MissionAckOut(A, MavMissionResult.NO_SPACE, 0)]
    assert server.on_count(A, 3, 1, 9.0) == [MissionAckOut(A, MavMissionResult.UNSUPPORTED, 1)], "fence"


def test_mission_state() -> None:
    store = MissionStore()
    assert store.state(started=False, finished=False, paused=False) is MissionState.NO_MISSION
    store.replace((item(0),))
    assert store.state(started=False, finished=False, paused=False) is MissionState.NOT_STARTED
    assert store.state(started=True, finished=False, paused=False) is MissionState.ACTIVE
    assert store.state(started=True, finished=False, paused=True) is MissionState.PAUSED
    assert store.state(started=True, finished=True, paused=True) is MissionState.COMPLETE
