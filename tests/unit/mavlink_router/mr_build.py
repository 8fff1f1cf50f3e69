"""Build real MAVLink frames with pymavlink (an independent encoder) for the router's unit tests."""

from __future__ import annotations

from typing import Any

from pymavlink.dialects.v10 import ardupilotmega as v1
from pymavlink.dialects.v20 import ardupilotmega as v2

from mavlink_router.shell.dialect import load_message_table

TABLE = load_message_table("ardupilotmega")
KEY = bytes(range(32))


def encoder(sysid: int = 1, compid: int = 1, *, seq: int = 0, key: bytes | None = None, timestamp: int = 0) -> Any:
    mav = v2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.seq = seq
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.link_id = 3
        mav.signing.timestamp = timestamp
        mav.signing.sign_outgoing = True
    return mav


def pack(msg: Any, sysid: int = 1, compid: int = 1, *, seq: int = 0, **signing: Any) -> bytes:
    """One MAVLink 2 frame of ``msg`` from ``sysid/compid``."""
    return bytes(msg.pack(encoder(sysid, compid, seq=seq, **signing)))


def pack_v1(msg: Any, sysid: int = 1, compid: int = 1, *, seq: int = 0) -> bytes:
    mav = v1.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    mav.seq = seq
    return bytes(msg.pack(mav))


def heartbeat(*, autopilot: int = 12, base_mode: int = 1) -> Any:
    return v2.MAVLink_heartbeat_message(2, autopilot, base_mode, 0, 4, 3)


def command_long(target_system: int, target_component: int, command: int = 400) -> Any:
    return v2.MAVLink_command_long_message(target_system, target_component, command, 0, 1, 0, 0, 0, 0, 0, 0)


def command_ack(target_system: int, target_component: int, command: int = 400) -> Any:
    return v2.MAVLink_command_ack_message(command, 0, 0, 0, target_system, target_component)


def ping(target_system: int, target_component: int, seq: int = 0) -> Any:
    return v2.MAVLink_ping_message(1000, seq, target_system, target_component)


def system_time(usec: int = 1) -> Any:
    return v2.MAVLink_system_time_message(usec, 0)


def unknown_frame(msgid: int = 0xABCDE, payload: bytes = b"\x01\x02\x03", sysid: int = 9, compid: int = 9) -> bytes:
    """A well-formed MAVLink 2 frame with an ID that no dialect knows (CRC is arbitrary)."""
    header = bytes((0xFD, len(payload), 0, 0, 0, sysid, compid, msgid & 0xFF, (msgid >> 8) & 0xFF, msgid >> 16))
    return header + payload + b"\x55\xaa"
