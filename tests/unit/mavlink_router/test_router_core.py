"""RouterCore: bytes in, routed frames out; dedup, inbound filters, signing, stats, arm state."""

from __future__ import annotations

from mr_build import KEY, TABLE, command_ack, command_long, heartbeat, pack, ping, system_time, unknown_frame
from pymavlink.dialects.v20 import ardupilotmega as v2

from mavlink_router.core.engine import RouterCore, SigningPolicy
from mavlink_router.core.routing import Filters
from mavlink_router.core.signing import SIGNING_EPOCH_UNIX_S, STATE_CHANGING_MESSAGES
from mavlink_router.shell.dialect import message_ids

NOW = 1_800_000_000.0
TS_NOW = int((NOW - SIGNING_EPOCH_UNIX_S) * 100_000)


def core_with(n: int, **kwargs: object) -> RouterCore:
    core = RouterCore(TABLE, **kwargs)  # type: ignore[arg-type]
    for i in range(n):
        core.add_endpoint(f"ep{i}", stream=False)
    return core


def test_frames_are_routed_unchanged() -> None:
    core = core_with(3)
    raw = pack(heartbeat(), 1, 1)
    [(frame, dests)] = core.ingest(0, raw, NOW)
    assert frame == raw
    assert dests == (1, 2)


def test_mavlink_router_routing_scenario() -> None:
    """The scenario of mavlink-router's tests/routing_test.py, deterministic.

    Endpoint 0 carries two senders: 1/1 pings everyone (target 0), 2/1 pings 100/1.
    Endpoints 1 and 2 are receivers 100/1 and 101/1, which answer every ping with a
    ping targeted at its sender. The first targeted ping is lost (100 is unknown).
    """
    core = core_with(3)
    decoder = v2.MAVLink(None)
    got: dict[str, int] = {"s1": 0, "s2": 0, "r100": 0, "r101": 0}
    receivers = {1: (100, "r100"), 2: (101, "r101")}

    def deliver(src: int, raw: bytes) -> None:
        for frame, dests in core.ingest(src, raw, NOW):
            msg = decoder.decode(bytearray(frame))
            for dest in dests:
                if dest in receivers:
                    sysid, name = receivers[dest]
                    got[name] += 1
                    reply = ping(msg.get_srcSystem(), msg.get_srcComponent(), msg.seq)
                    deliver(dest, pack(reply, sysid, 1, seq=msg.get_seq()))
                else:
                    got["s1" if msg.target_system == 1 else "s2"] += 1

    for i in range(10):
        deliver(0, pack(ping(100, 1, i), 2, 1, seq=i))
        deliver(0, pack(ping(0, 0, i), 1, 1, seq=i))
    assert got["r101"] == 10  # broadcasts only
    assert got["r100"] == 19  # 10 broadcasts + 9 targeted (the first was to an unknown system)
    assert got["s1"] == 20  # one reply from each receiver per broadcast
    assert got["s2"] == 9
    assert core.routing.msg_to_unknown == 1


def test_command_ack_goes_back_to_the_commanding_client_only() -> None:
    core = core_with(4)
    vehicle, gcs, mavsdk, controller = 0, 1, 2, 3
    core.ingest(vehicle, pack(heartbeat(), 1, 1), NOW)
    core.ingest(gcs, pack(heartbeat(autopilot=8), 255, 190), NOW)
    core.ingest(mavsdk, pack(heartbeat(autopilot=8), 245, 190), NOW)
    core.ingest(controller, pack(heartbeat(autopilot=8), 1, 191), NOW)
    [(_, dests)] = core.ingest(mavsdk, pack(command_long(1, 1), 245, 190), NOW)
    assert dests == (vehicle,)
    [(_, dests)] = core.ingest(vehicle, pack(command_ack(245, 190), 1, 1), NOW)
    assert dests == (mavsdk,)
    [(_, dests)] = core.ingest(vehicle, pack(command_ack(1, 191), 1, 1), NOW)
    assert dests == (controller,)


def test_unknown_message_is_broadcast_untouched() -> None:
    core = core_with(3)
    raw = unknown_frame()
    assert core.ingest(0, raw, NOW) == [(raw, (1, 2))]


def test_dedup_drops_copies_within_the_window_only() -> None:
    core = core_with(3, dedup_period_s=0.1)
    raw = pack(heartbeat(), 1, 1, seq=5)
    assert len(core.ingest(0, raw, NOW)) == 1
    assert core.ingest(1, raw, NOW + 0.05) == []  # same bytes over a redundant link
    assert core.stats(1).dedup_drops == 1
    assert len(core.ingest(1, raw, NOW + 0.2)) == 1  # window expired


def test_inbound_filters_drop_before_learning() -> None:
    core = RouterCore(TABLE)
    a = core.add_endpoint("a", stream=False, in_filter=Filters(block_msg_ids=frozenset({0})))
    b = core.add_endpoint("b", stream=False)
    assert core.ingest(a, pack(heartbeat(), 7, 1), NOW) == []
    assert core.stats(a).in_filtered == 1
    assert not core.learned(a).pairs
    assert core.ingest(a, pack(system_time(), 7, 1), NOW) == [(pack(system_time(), 7, 1), (b,))]


def test_out_filtered_counted_on_the_destination() -> None:
    core = RouterCore(TABLE)
    a = core.add_endpoint("a", stream=False)
    b = core.add_endpoint("b", stream=False, out_filter=Filters(allow_msg_ids=frozenset({0})))
    [(_, dests)] = core.ingest(a, pack(system_time(), 7, 1), NOW)
    assert dests == ()
    assert core.stats(b).out_filtered == 1


def signed_core() -> tuple[RouterCore, int, int]:
    core = RouterCore(TABLE)
    policy = SigningPolicy(KEY, message_ids(TABLE, STATE_CHANGING_MESSAGES))
    gcs = core.add_endpoint("gcs", stream=False, signing=policy)
    vehicle = core.add_endpoint("vehicle", stream=False)
    core.ingest(vehicle, pack(heartbeat(), 1, 1), NOW)
    return core, gcs, vehicle


def test_signing_required_drops_unsigned_commands_but_not_telemetry() -> None:
    core, gcs, _ = signed_core()
    assert core.ingest(gcs, pack(command_long(1, 1), 255, 190), NOW) == []
    assert core.stats(gcs).unsigned_drops == 1
    assert len(core.ingest(gcs, pack(heartbeat(autopilot=8), 255, 190), NOW)) == 1


def test_signed_command_passes_with_its_signature() -> None:
    core, gcs, vehicle = signed_core()
    raw = pack(command_long(1, 1), 255, 190, key=KEY, timestamp=TS_NOW)
    assert core.ingest(gcs, raw, NOW) == [(raw, (vehicle,))]


def test_wrong_key_and_replay_are_dropped() -> None:
    core, gcs, _ = signed_core()
    assert core.ingest(gcs, pack(command_long(1, 1), 255, 190, key=bytes(32), timestamp=TS_NOW), NOW) == []
    assert core.stats(gcs).bad_signature_drops == 1
    raw = pack(command_long(1, 1), 255, 190, key=KEY, timestamp=TS_NOW + 10)
    assert len(core.ingest(gcs, raw, NOW)) == 1
    assert core.ingest(gcs, raw, NOW) == []  # the very same signed frame again
    assert core.stats(gcs).replay_drops == 1
    old = pack(command_long(1, 1), 255, 191, key=KEY, timestamp=TS_NOW - 120 * 100_000)
    assert core.ingest(gcs, old, NOW) == []  # new stream, two minutes old
    assert core.stats(gcs).replay_drops == 2


def test_stats_count_messages_bytes_sequence_and_errors() -> None:
    core = core_with(2)
    frames = [pack(heartbeat(), 1, 1, seq=s) for s in (0, 1, 2, 5, 6, 255, 0)]
    for raw in frames:
        core.ingest(0, raw, NOW)
    bad = bytearray(pack(heartbeat(), 1, 1, seq=1))
    bad[-1] ^= 1
    core.ingest(0, b"\x00junk" + bytes(bad), NOW + 1)
    stats = core.stats(0)
    assert stats.rx_msgs == 7
    assert stats.rx_bytes == sum(map(len, frames))
    assert stats.seq_lost == 2 + 248  # 2 -> 5, then 6 -> 255
    assert stats.crc_errors == 1
    assert stats.garbage_bytes >= 5
    assert stats.last_rx_s == NOW


def test_arm_state_follows_the_autopilot_heartbeat() -> None:
    core = core_with(2)
    core.ingest(1, pack(heartbeat(autopilot=8, base_mode=128), 255, 190), NOW)  # a GCS: ignored
    assert core.arm_state is None
    core.ingest(0, pack(heartbeat(base_mode=1), 1, 1), NOW)
    assert core.arm_state is not None
    assert not core.arm_state.armed
    core.ingest(0, pack(heartbeat(base_mode=129), 1, 1), NOW)
    assert core.arm_state.armed
    assert core.arm_state.sysid == 1


def test_log_system_id_selects_the_vehicle() -> None:
    core = core_with(2, log_system_id=2)
    core.ingest(0, pack(heartbeat(base_mode=129), 1, 1), NOW)
    assert core.arm_state is None
    core.ingest(1, pack(heartbeat(base_mode=129), 2, 1), NOW)
    assert core.arm_state is not None
    assert core.arm_state.sysid == 2


def test_stream_endpoint_flushes_an_idle_held_frame() -> None:
    core = RouterCore(TABLE)
    tcp = core.add_endpoint("tcp", stream=True)
    core.add_endpoint("udp", stream=False)
    raw = unknown_frame()
    assert core.ingest(tcp, raw, NOW) == []
    assert core.flush_idle(tcp, NOW) == []  # first call only notes the position
    assert core.flush_idle(tcp, NOW + 0.25) == [(raw, (1,))]


def test_removed_endpoint_returns_final_stats() -> None:
    core = core_with(2)
    core.ingest(1, pack(heartbeat(), 1, 1), NOW)
    stats = core.remove_endpoint(1)
    assert stats.rx_msgs == 1
    [(_, dests)] = core.ingest(0, pack(heartbeat(), 2, 1), NOW)
    assert dests == ()
