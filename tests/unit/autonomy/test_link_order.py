"""A lossy, reordering link must not make the controller give up a flying vehicle; and the link's bounded reads.

The failure this guards against (tests/e2e/scenarios/test_scenario_autopilot_pose_e2e.py on a slow machine):
the controller went IDLE at 4.3 s, "vehicle disarmed while under control", while the autopilot stayed armed
for the rest of the run: an old HEARTBEAT (from before the arming) arrived after the new ones over the
``lossy_link`` preset, which delays, jitters and reorders. Now the link orders the autopilot's frames and
ignores the older ones, and a disarm must be confirmed before the controller lets go.
"""

from __future__ import annotations

import os
import socket
import threading
from collections.abc import Iterator
from typing import Any

import pytest

os.environ["MAVLINK20"] = "1"

from pymavlink.dialects.v20 import common as mavlink2

from uav_autonomy.core.controller import (
    ControllerConfig,
    ControllerState,
    RequestArm,
    RequestMode,
    SendSetpoint,
    Telemetry,
    TelemetryOrder,
    WaypointController,
)
from uav_autonomy.errors import MavlinkLinkError
from uav_autonomy.mavlink.link import MavlinkLink
from uav_common.autopilot_modes import FlightMode
from uav_common.lockstep.markers import MESSAGE_TYPE, Marker, MarkerError, decode_payload, encode_payload

M = mavlink2
ARMED = 128 | 1  # MAV_MODE_FLAG_SAFETY_ARMED | CUSTOM_MODE_ENABLED
DISARMED = 1
OFFBOARD = FlightMode.OFFBOARD.custom_mode


def frame(seq: int, name: str, *fields: Any) -> Any:
    """A message from the autopilot (1/1) with this MAVLink sequence number, as pymavlink parses it."""
    mav = M.MAVLink(None, srcSystem=1, srcComponent=1)
    mav.seq = seq & 0xFF
    packed = getattr(mav, f"{name}_encode")(*fields).pack(mav)
    return M.MAVLink(None).parse_buffer(packed)[0]


def heartbeat(seq: int, base_mode: int, custom_mode: int = OFFBOARD) -> Any:
    return frame(seq, "heartbeat", 2, 12, base_mode, custom_mode, 4, 3)


def link() -> MavlinkLink:
    return MavlinkLink(
        "udpin:127.0.0.1:0",
        source_system=1,
        source_component=191,
        target_system=1,
        target_component=1,
        reconnect_after_s=5.0,
    )


# ---------------------------------------------------------------------------------------------- ordering


def test_sequence_numbers_order_the_frames_across_the_wrap() -> None:
    order = TelemetryOrder()
    assert order.newer("HEARTBEAT", 250, 0.0)
    for seq in range(251, 300):  # other messages move the stream on, across 255 -> 0
        assert order.newer("ATTITUDE", seq, 0.1, time_boot_ms=seq)
    assert order.newer("HEARTBEAT", 300, 0.2)  # seq 44 after the wrap: newer than 250
    assert not order.newer("HEARTBEAT", 290, 0.2)  # seq 34: an old one, arriving late
    assert not order.newer("HEARTBEAT", 300, 0.2)  # the same frame twice
    assert order.newer("HEARTBEAT", 301, 0.3)
    assert order.stale == 2


def test_a_late_heartbeat_behind_other_messages_is_still_the_newest_heartbeat() -> None:
    """Jitter reorders a heartbeat behind the next few messages: it is still newer than the last heartbeat."""
    order = TelemetryOrder()
    assert order.newer("HEARTBEAT", 10, 0.0)
    for seq in range(11, 200):
        order.newer("LOCAL_POSITION_NED", seq, 0.5, time_boot_ms=seq)
    assert order.newer("HEARTBEAT", 198, 1.0)  # 1 s later, overtaken by one position message


def test_time_boot_ms_orders_what_has_it_and_a_reboot_starts_afresh() -> None:
    order = TelemetryOrder()
    assert order.newer("LOCAL_POSITION_NED", 1, 0.0, time_boot_ms=5000)
    assert not order.newer("LOCAL_POSITION_NED", 2, 0.0, time_boot_ms=4980)  # reordered
    assert not order.newer("LOCAL_POSITION_NED", 3, 0.0, time_boot_ms=5000)  # duplicated
    assert order.newer("LOCAL_POSITION_NED", 4, 0.0, time_boot_ms=5020)
    assert order.newer("LOCAL_POSITION_NED", 5, 0.0, time_boot_ms=100)  # 4.9 s back: the autopilot rebooted


def test_the_stream_is_taken_afresh_after_silence_or_a_restarted_counter() -> None:
    order = TelemetryOrder()
    assert order.newer("HEARTBEAT", 200, 0.0)
    # after a long fade the counter has moved on by more than half its range: the next frame is still the newest
    assert order.newer("HEARTBEAT", 100, 5.0)
    # a link that restarts its counter: after a run of frames that look old, they are taken as new
    order = TelemetryOrder(resync_after_behind=4)
    assert order.newer("HEARTBEAT", 200, 0.0)
    for seq in range(150, 154):
        order.newer("SYS_STATUS", seq, 0.1)
    assert order.newer("HEARTBEAT", 154, 0.1)


def test_a_reordered_or_duplicated_disarmed_heartbeat_changes_nothing() -> None:
    lnk = link()
    lnk._handle(heartbeat(10, DISARMED), 1.0)
    lnk._handle(heartbeat(20, ARMED), 1.5)
    lnk._handle(heartbeat(10, DISARMED), 1.6)
    lnk._handle(heartbeat(15, DISARMED), 1.7)
    t = lnk.telemetry()
    assert t.armed
    assert t.heartbeat_s == 1.5
    assert t.disarmed_heartbeats == 0
    lnk._handle(heartbeat(40, DISARMED), 2.5)
    lnk._handle(heartbeat(40, DISARMED), 2.6)
    assert lnk.telemetry().disarmed_heartbeats == 1
    assert not lnk.telemetry().landed_since_disarmed
    lnk._handle(frame(41, "extended_sys_state", 0, 1), 2.6)
    assert lnk.telemetry().landed_since_disarmed
    lnk._handle(heartbeat(60, DISARMED), 3.5)
    assert lnk.telemetry().disarmed_heartbeats == 2


def test_a_reordered_position_does_not_move_the_vehicle_back() -> None:
    lnk = link()
    lnk._handle(frame(1, "local_position_ned", 2000, 10.0, 0.0, -20.0, 0.0, 0.0, 0.0), 2.0)
    lnk._handle(frame(2, "local_position_ned", 1980, 9.0, 0.0, -20.0, 0.0, 0.0, 0.0), 2.1)
    t = lnk.telemetry()
    assert t.position_enu_m == (0.0, 10.0, 20.0)
    assert t.position_s == 2.0


# ---------------------------------------------------------------------------------------------- the controller


def flying(ctl: WaypointController) -> Telemetry:
    """The controller in HOLD, armed, in OFFBOARD, 10 m up (its telemetry)."""
    t = Telemetry(
        heartbeat_s=0.0,
        custom_mode=OFFBOARD,
        armed=True,
        in_air=True,
        position_enu_m=(0.0, 0.0, 10.0),
        position_s=0.0,
        yaw_enu_rad=0.0,
        disarmed_heartbeats=0,
    )
    ctl.step(0.0, t)
    ctl.request(ControllerState.HOLD, 0.0)
    for k in range(1, 4):
        ctl.step(k * 0.05, Telemetry(**{**t.__dict__, "heartbeat_s": k * 0.05, "position_s": k * 0.05}))
    assert ctl.state is ControllerState.HOLD
    return t


def at(t: Telemetry, now: float, **changes: Any) -> Telemetry:
    return Telemetry(**{**t.__dict__, "heartbeat_s": now, "position_s": now, **changes})


def test_one_disarmed_heartbeat_does_not_end_a_flight() -> None:
    ctl = WaypointController(ControllerConfig())
    t = flying(ctl)
    out = ctl.step(0.2, at(t, 0.2, armed=False, disarmed_heartbeats=1))
    assert ctl.state is ControllerState.HOLD
    assert [type(a) for a in out] == [SendSetpoint]  # it carries on, and asks for nothing new
    assert "a heartbeat says disarmed" in ctl.status().last_event
    out = ctl.step(0.25, at(t, 0.25))  # the next heartbeat says armed: it was a stray frame
    assert ctl.state is ControllerState.HOLD
    assert not any(isinstance(a, RequestArm | RequestMode) for a in out)


@pytest.mark.parametrize(
    "confirmation", [{"disarmed_heartbeats": 2}, {"disarmed_heartbeats": 1, "landed_since_disarmed": True}]
)
def test_a_confirmed_disarm_ends_the_flight(confirmation: dict[str, Any]) -> None:
    ctl = WaypointController(ControllerConfig())
    t = flying(ctl)
    ctl.step(0.2, at(t, 0.2, armed=False, disarmed_heartbeats=1))
    assert ctl.step(1.2, at(t, 1.2, armed=False, **confirmation)) == []
    assert ctl.state is ControllerState.IDLE
    assert ctl.status().last_event == "vehicle disarmed while under control"


def test_a_shell_that_does_not_count_heartbeats_is_taken_at_its_word() -> None:
    ctl = WaypointController(ControllerConfig())
    t = flying(ctl)
    ctl.step(0.2, at(t, 0.2, armed=False, disarmed_heartbeats=None))
    assert ctl.state is ControllerState.IDLE


def test_the_link_and_the_controller_survive_the_lossy_link_failure() -> None:
    """The e2e failure, replayed: heartbeats sent before the arming arrive after it; the controller stays."""
    lnk = link()
    ctl = WaypointController(ControllerConfig())
    flying(ctl)
    now = 0.2
    seq = 100
    armed_at = seq
    for _ in range(3):  # armed heartbeats, with position messages in between (the stream moves on)
        armed_at = seq
        lnk._handle(heartbeat(seq, ARMED), now)
        for _ in range(60):
            seq += 1
            lnk._handle(frame(seq, "local_position_ned", round(now * 1000), 0.0, 0.0, -10.0, 0, 0, 0), now)
            now = round(now + 0.005, 3)
        seq += 1
        ctl.step(now, lnk.telemetry())
    for late in (armed_at - 20, armed_at - 5):  # sent before the last armed one, late and out of order: ignored
        lnk._handle(heartbeat(late, DISARMED), now)
        assert lnk.telemetry().armed
        ctl.step(now, lnk.telemetry())
    assert ctl.state is ControllerState.HOLD, ctl.pop_events()
    assert "disarmed" not in ctl.status().last_event
    # more than 127 frames late, a sequence number cannot tell: the confirmation rule keeps the vehicle
    lnk._handle(heartbeat(seq - 150, DISARMED), now)
    assert not lnk.telemetry().armed
    ctl.step(now, lnk.telemetry())
    lnk._handle(heartbeat(seq + 1, ARMED), now + 0.05)
    ctl.step(now + 0.05, lnk.telemetry())
    assert ctl.state is ControllerState.HOLD, ctl.pop_events()


# ---------------------------------------------------------------------------------------------- bounded reads


class FloodingConnection:
    """A connection with an endless supply of heartbeats (recv_match never runs dry)."""

    def __init__(self) -> None:
        self.read = 0

    def recv_match(self, blocking: bool = False) -> Any:
        self.read += 1
        return heartbeat(self.read, ARMED)

    def close(self) -> None:
        pass


def test_a_poll_reads_a_bounded_number_of_messages() -> None:
    lnk = MavlinkLink("udpin:127.0.0.1:0", source_system=1, source_component=191, target_system=1,
                      target_component=1, reconnect_after_s=5.0, poll_max_messages=50)  # fmt: skip
    conn = FloodingConnection()
    lnk._conn = conn
    assert lnk.poll(100.0) == 50  # and returns, although more are waiting
    assert conn.read == 50
    assert lnk.reconnects == 0  # not silent: messages are waiting
    assert lnk.poll(100.0) == 50
    assert lnk.telemetry().heartbeat_s == 100.0


def test_a_poll_reads_for_a_bounded_wall_time() -> None:
    wall = iter(x * 0.01 for x in range(1000))
    lnk = MavlinkLink("udpin:127.0.0.1:0", source_system=1, source_component=191, target_system=1,
                      target_component=1, reconnect_after_s=5.0, poll_max_wall_s=0.05,
                      wall_clock=lambda: next(wall))  # fmt: skip
    lnk._conn = FloodingConnection()
    assert lnk.poll(1.0) == 4  # 10 ms of wall time per message read, 50 ms at most


# ---------------------------------------------------------------------------------------------- lockstep


@pytest.fixture
def router() -> Iterator[socket.socket]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(2.0)
    yield sock
    sock.close()


def test_a_lockstep_link_handles_a_step_at_its_simulated_time(router: socket.socket) -> None:
    lnk = link()
    lnk.open(0.0, 0.0)
    try:
        port = lnk._require().port.getsockname()[1]  # type: ignore[attr-defined]
        mav = M.MAVLink(None, srcSystem=1, srcComponent=1)

        def send(*msgs: Any) -> None:
            router.sendto(b"".join(m.pack(mav) for m in msgs), ("127.0.0.1", port))

        def marker(m: Marker) -> Any:
            return M.MAVLink_v2_extension_message(0, 1, 191, MESSAGE_TYPE, encode_payload(m))

        send(marker(Marker.hello(1)))  # the router's invitation: now the link knows where to say HELLO
        threading.Timer(0.2, lambda: send(marker(Marker.end_of_step(30, 3_000_000, 0)))).start()
        assert lnk.start_lockstep(2, watchdog_s=5.0) == 30
        assert lnk.lockstep
        with pytest.raises(MavlinkLinkError, match="in lockstep: read it with read_step"):
            lnk.poll(3.0)
        send(
            M.MAVLink_heartbeat_message(2, 12, ARMED, OFFBOARD, 4, 3),
            marker(Marker.end_of_step(31, 3_100_000, 1)),
            M.MAVLink_heartbeat_message(2, 12, DISARMED, OFFBOARD, 4, 3),  # step 32's
        )
        lnk.read_step(31, 3.1)
        assert lnk.step_messages == 1
        t = lnk.telemetry()
        assert t.armed
        assert (t.heartbeat_s, t.heartbeat_wall_s) == (3.1, 3.1)
        lnk.send_setpoint((0.0, 0.0, 10.0), 0.0, 3.1)
        lnk.end_step(31, 3.1)
        data, _ = router.recvfrom(65535)
        hello, setpoint, end = M.MAVLink(None).parse_buffer(
            data + router.recvfrom(65535)[0] + router.recvfrom(65535)[0]
        )
        assert decode_payload(bytes(hello.payload)) == Marker.hello(2)
        assert setpoint.get_type() == "SET_POSITION_TARGET_LOCAL_NED"
        assert decode_payload(bytes(end.payload)) == Marker.end_of_step(31, 3_100_000, 1)
        send(marker(Marker.end_of_step(32, 3_200_000, 2)))  # says 2: one was lost
        with pytest.raises(MarkerError, match="step 32: the peer says it sent 2 messages, 1 were received"):
            lnk.read_step(32, 3.2)
    finally:
        lnk.close()
