"""Fast MAVLink 2 encoding of the telemetry the SITL streams, byte-identical to pymavlink's.

pymavlink builds a message object per message and packs it field by field; at 250 physics steps
per simulated second and a few hundred telemetry messages per simulated second that costs more than
the flight dynamics. Here each streamed message type gets a packer generated from pymavlink's own
class metadata (wire field order, array lengths, struct format, CRC_EXTRA): ``packers.attitude(...)``
takes the same arguments in the same order as pymavlink's ``attitude_encode(...)`` and returns a
:class:`WireMessage` holding just the payload. A link frames it (header, payload truncation, CRC)
with its own sequence number. Anything that reads a field (tests, signing links) gets pymavlink's
object, decoded from the payload on first access. ``tests/unit/sitl/test_sitl_links.py`` checks
every packer against pymavlink frame for frame.
"""

from __future__ import annotations

import inspect
import struct
from collections.abc import Callable
from typing import Any

from fastcrc.crc16 import mcrf4xx
from pymavlink.dialects.v20 import common as mavlink

__all__ = ["STREAMED", "WireMessage", "WirePackers"]

_HEADER_V2 = struct.Struct("<BBBBBBBHB")

#: The messages streamed periodically or on every state instant (vehicle links and the simulation link).
STREAMED = (
    "HEARTBEAT",
    "SYS_STATUS",
    "EXTENDED_SYS_STATE",
    "GLOBAL_POSITION_INT",
    "LOCAL_POSITION_NED",
    "ATTITUDE",
    "ATTITUDE_QUATERNION",
    "GPS_RAW_INT",
    "HOME_POSITION",
    "BATTERY_STATUS",
    "VFR_HUD",
    "ALTITUDE",
    "MISSION_CURRENT",
    "POSITION_TARGET_LOCAL_NED",
    "HIGHRES_IMU",
    "ODOMETRY",
    "SYSTEM_TIME",
    "HIL_STATE_QUATERNION",
    "HIL_ACTUATOR_CONTROLS",
)


class WireMessage:
    """A packed payload of one message type; decodes to pymavlink's object only when a field is read."""

    __slots__ = ("_decoded", "body", "cls", "msg_id", "payload", "trailer")

    def __init__(self, cls: type, payload: bytes) -> None:
        self.cls = cls
        self.payload = payload
        self._decoded: Any = None
        c: Any = cls
        self.msg_id: int = c.id
        # what every frame of this message shares: the truncated payload and the CRC's trailing CRC_EXTRA
        self.body = payload.rstrip(b"\0") or payload[:1]
        self.trailer = self.body + bytes((c.crc_extra,))

    def get_type(self) -> str:
        return str(self.cls.msgname)  # type: ignore[attr-defined]

    def get_msgId(self) -> int:  # noqa: N802 - pymavlink's name
        return int(self.cls.id)  # type: ignore[attr-defined]

    def frame(self, seq: int, system_id: int, component_id: int) -> bytes:
        msg_id = self.msg_id
        body = self.body
        header = _HEADER_V2.pack(253, len(body), 0, 0, seq, system_id, component_id, msg_id & 0xFFFF, msg_id >> 16)
        return header + body + mcrf4xx(header[1:] + self.trailer, 0xFFFF).to_bytes(2, "little")

    def decoded(self) -> Any:
        """pymavlink's message object for this payload."""
        if self._decoded is None:
            cls: Any = self.cls
            values = list(cls.unpacker.unpack(self.payload))
            fields: list[Any] = []
            i = 0
            for name, length in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True):
                if length and cls.fieldtypes[cls.fieldnames.index(name)] != "char":
                    fields.append(values[i : i + length])
                    i += length
                else:
                    fields.append(values[i])
                    i += 1
            by_name = dict(zip(cls.ordered_fieldnames, fields, strict=True))
            self._decoded = cls(*(by_name[n] for n in cls.fieldnames))
        return self._decoded

    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
        """As pymavlink's ``msg.pack(mav)`` (signing links use it)."""
        return bytes(self.decoded().pack(mav, force_mavlink1=force_mavlink1))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.decoded(), name)


def _packer(cls: Any) -> Callable[..., WireMessage]:
    """A function ``(*encode_args) -> WireMessage`` with pymavlink's ``<name>_encode`` arguments and defaults."""
    encode = getattr(mavlink.MAVLink, f"{cls.msgname.lower()}_encode")
    defaults = {
        n: p.default
        for n, p in inspect.signature(encode).parameters.items()
        if p.default is not inspect.Parameter.empty
    }
    wire_args: list[str] = []
    for name, length in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True):
        is_char = cls.fieldtypes[cls.fieldnames.index(name)] == "char"
        if length and not is_char:
            wire_args += [f"{name}[{k}]" for k in range(length)]
        else:
            wire_args.append(name)
    params = ", ".join(f"{n}=D[{n!r}]" if n in defaults else n for n in cls.fieldnames)
    source = f"def pack({params}):\n    return W(C, S({', '.join(wire_args)}))\n"
    namespace: dict[str, Any] = {"W": WireMessage, "C": cls, "S": cls.unpacker.pack, "D": defaults}
    exec(source, namespace)
    packer: Callable[..., WireMessage] = namespace["pack"]
    return packer


_ODOMETRY = mavlink.MAVLink_odometry_message
_ODOMETRY_HEAD = struct.Struct("<Qfff4fffffff")
_ODOMETRY_TAIL = struct.Struct("<BBBBb")
#: ODOMETRY's two covariances when unknown (first element NaN, the rest 0), packed once.
_UNKNOWN_COVARIANCES = struct.pack("<21f21f", *([float("nan")] + [0.0] * 20) * 2)


class WirePackers:
    """``packers.<message name lowercase>(...)`` for every :data:`STREAMED` message."""

    def __init__(self) -> None:
        for name in STREAMED:
            cls = mavlink.mavlink_map[getattr(mavlink, f"MAVLINK_MSG_ID_{name}")]
            setattr(self, name.lower(), _packer(cls))

    @staticmethod
    def odometry_unknown_covariance(  # noqa: PLR0917 - ODOMETRY's fields in order
        time_usec: int,
        frame_id: int,
        child_frame_id: int,
        x: float,
        y: float,
        z: float,
        q: list[float],
        vx: float,
        vy: float,
        vz: float,
        rollspeed: float,
        pitchspeed: float,
        yawspeed: float,
        estimator_type: int,
        quality: int,
    ) -> WireMessage:
        """ODOMETRY with both covariances unknown and reset_counter 0 (the SITL's): the constant part pre-packed."""
        head = _ODOMETRY_HEAD.pack(
            time_usec, x, y, z, q[0], q[1], q[2], q[3], vx, vy, vz, rollspeed, pitchspeed, yawspeed
        )
        tail = _ODOMETRY_TAIL.pack(frame_id, child_frame_id, 0, estimator_type, quality)
        return WireMessage(_ODOMETRY, head + _UNKNOWN_COVARIANCES + tail)

    def __getattr__(self, name: str) -> Callable[..., WireMessage]:  # for mypy: the packers are set in __init__
        msg = f"no fast packer for {name}"
        raise AttributeError(msg)
