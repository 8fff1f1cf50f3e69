"""Fuzz: random bytes, mutated frames and well-formed messages with random content never crash or wedge.

Everything goes through the real parser (per-peer, robust) and the real gateway
into the real autopilot, which keeps stepping the JSBSim model between inputs.
"""

from __future__ import annotations

import math
import struct
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from unit.sitl.sitl_builders import PEER, Client, Rig

from sitl.core.modes import FlightMode
from sitl.shell.links import Received, mavlink

_RIG: Rig | None = None
FUZZ = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def rig() -> Rig:
    global _RIG  # noqa: PLW0603 - one JSBSim vehicle for the whole module
    if _RIG is None:
        _RIG = Rig()
    return _RIG


def feed_bytes(r: Rig, data: bytes, *, datagram: bool = True) -> int:
    route = (r.gcs.name, PEER)
    n = 0
    for msg in r.gcs.parse(data, route, datagram=datagram):
        r.gw.handle(Received(msg, route), r.v.t_s)
        n += 1
    r.step()
    return n


def heartbeat_frame(client: Client) -> bytes:
    return client.frame(client.mav.heartbeat_encode(6, 8, 0, 0, 4))


@FUZZ
@given(st.binary(min_size=0, max_size=700))
def test_random_bytes(data: bytes) -> None:
    r = rig()
    feed_bytes(r, data)
    feed_bytes(r, data, datagram=False)
    assert math.isfinite(r.v.t_s)


@FUZZ
@given(st.data())
def test_mutated_frames(data: st.DataObject) -> None:
    r = rig()
    c = Client()
    frames = [
        heartbeat_frame(c),
        c.frame(c.mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)),
        c.frame(c.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 3.0, 9)),
        c.frame(c.mav.mission_count_encode(1, 1, 3, 0)),
        c.frame(c.mav.set_position_target_local_ned_encode(0, 1, 1, 1, 2552, 1, 2, -3, 0, 0, 0, 0, 0, 0, 0, 0)),
    ]
    frame = bytearray(data.draw(st.sampled_from(frames)))
    op = data.draw(st.sampled_from(["flip", "truncate", "extend", "length", "id"]))
    if op == "flip":
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, len(frame) - 1))
            frame[i] ^= 1 << data.draw(st.integers(0, 7))
    elif op == "truncate":
        frame = frame[: data.draw(st.integers(0, len(frame) - 1))]
    elif op == "extend":
        frame += data.draw(st.binary(min_size=1, max_size=300))
    elif op == "length":
        frame[1] = data.draw(st.integers(0, 255))
    else:  # an unknown or different message id with the old payload
        frame[7:10] = data.draw(st.integers(0, 2**24 - 1)).to_bytes(3, "little")
    t0 = r.v.t_s
    feed_bytes(r, bytes(frame))
    feed_bytes(r, bytes(frame), datagram=False)
    assert r.v.t_s > t0  # the vehicle kept stepping: nothing wedged the loop
    assert all(math.isfinite(x) for x in r.v.pos_ned_truth_m)


def _random_value(draw: Any, ftype: str) -> Any:
    ints = {
        "uint8_t": (0, 255),
        "int8_t": (-128, 127),
        "uint16_t": (0, 65535),
        "int16_t": (-32768, 32767),
        "uint32_t": (0, 2**32 - 1),
        "int32_t": (-(2**31), 2**31 - 1),
        "uint64_t": (0, 2**64 - 1),
        "int64_t": (-(2**63), 2**63 - 1),
    }
    if ftype in ints:
        lo, hi = ints[ftype]
        return draw(st.one_of(st.integers(lo, hi), st.sampled_from([lo, hi, 0, 1])))
    if ftype in ("float", "double"):
        return draw(st.one_of(st.floats(width=32), st.sampled_from([math.nan, math.inf, -math.inf, 0.0, 1e38])))
    return b"x"


MESSAGE_TYPES = sorted(mavlink.mavlink_map.values(), key=lambda t: t.msgname)
# the ones the gateway actually handles get extra weight
HANDLED = [t for t in MESSAGE_TYPES if t.msgname in {
    "HEARTBEAT", "COMMAND_LONG", "COMMAND_INT", "SET_MODE", "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET",
    "MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_LIST", "MISSION_REQUEST_INT",
    "MISSION_REQUEST", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT", "SET_POSITION_TARGET_LOCAL_NED",
    "SET_POSITION_TARGET_GLOBAL_INT", "MANUAL_CONTROL", "TIMESYNC", "PING", "FILE_TRANSFER_PROTOCOL",
}]  # fmt: skip


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_well_formed_messages_with_random_content(data: st.DataObject) -> None:
    r = rig()
    mtype = data.draw(st.one_of(st.sampled_from(HANDLED), st.sampled_from(MESSAGE_TYPES)))
    values = []
    for name, ftype, length in zip(mtype.fieldnames, mtype.fieldtypes, mtype.array_lengths, strict=True):
        if ftype == "char":
            values.append(data.draw(st.binary(max_size=max(length, 1))))
        elif length:
            values.append([_random_value(data.draw, ftype) for _ in range(length)])
        else:
            values.append(_random_value(data.draw, ftype))
        if name in ("target_system", "target") and data.draw(st.booleans()):
            values[-1] = 1  # often aim at us so the handlers really run
    try:
        msg = mtype(*values)
        frame = Client(system_id=data.draw(st.integers(1, 255))).frame(msg)
    except (struct.error, OverflowError, ValueError, TypeError):
        return  # pymavlink cannot even encode it; nothing to send
    feed_bytes(r, frame)
    assert math.isfinite(r.v.t_s)


def test_still_answers_and_flies_after_the_fuzz() -> None:
    """After every fuzz case above (same vehicle), a ground station still arms it, flies it up and lands it."""
    r = rig()
    for payload in (b"\xfd" * 300, bytes(range(256)) * 3, heartbeat_frame(Client())):
        feed_bytes(r, payload)
    stats = r.gcs.stats
    assert stats.rx_bad_frames > 0  # the fuzz reached the parser...
    assert stats.rx_messages > 0  # ...and well-formed messages got through it
    # Whatever the fuzz left it in, bring it to a known state through the MAVLink interface only.
    r.cmd(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)  # force disarm (lands nothing: it is on the ground)
    for _ in range(250):
        r.step()
    ack = r.cmd(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION)
    assert ack is not None
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED
    r.gcs.clear()
    r.feed(r.client.mav.heartbeat_encode(6, 8, 0, 0, 4))
    for _ in range(round(1.5 / r.v.dt_s)):  # heartbeats go out at 1 Hz
        r.step()
    assert r.gcs.of_type("HEARTBEAT"), "no heartbeat after the fuzz"
    # Fly: AUTO.LOITER, arm, take off to 8 m above home, then land and disarm, all commanded over MAVLink.
    assert r.cmd(mavlink.MAV_CMD_DO_SET_MODE, 1, 4, 3).result == mavlink.MAV_RESULT_ACCEPTED
    ack = r.cmd(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED, r.v.autopilot.statustexts
    home_alt = r.v.home.alt_amsl_m
    ack = r.cmd(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, home_alt + 8.0)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED, r.v.autopilot.statustexts
    climbed = 0.0
    for _ in range(round(30.0 / r.v.dt_s)):
        r.step()
        climbed = -r.v.pos_ned_truth_m[2]
        if r.v.autopilot.mode is FlightMode.AUTO_LOITER and climbed > 7.0:
            break
    assert climbed > 7.0, f"reached only {climbed:.1f} m after the fuzz"
    here = (0, 0, 0, math.nan, math.nan, math.nan)  # land where it is (lat/lon NaN; 0/0 would be off Africa)
    assert r.cmd(mavlink.MAV_CMD_NAV_LAND, *here).result == mavlink.MAV_RESULT_ACCEPTED
    for _ in range(round(30.0 / r.v.dt_s)):  # ~12 s down at the land speed, then the land detector
        r.step()
        if not r.v.autopilot.armed:
            break
    assert not r.v.autopilot.armed, "did not land and disarm after the fuzz"
    assert -r.v.pos_ned_truth_m[2] < 1.0
