"""The MAVLink step markers of the causal lockstep (docs/lockstep.md, "MAVLink step markers"): a pure codec.

A marker is a ``V2_EXTENSION`` (#248) message whose ``message_type`` is :data:`MESSAGE_TYPE` (a local
extension number, above 32767) and whose 249-byte ``payload`` is, little-endian, the rest zero:

=====  =========  =====================================================================================
bytes  field      meaning
=====  =========  =====================================================================================
0-3    magic      ``b"LKST"``
4      version    1
5      kind       1 = HELLO, 2 = STEP
6-7    lookahead  HELLO: the sender's lookahead in steps (>= 1); STEP: 0
8-15   step       the step this marker ends (HELLO: 0)
16-23  t_sim_us   simulation time of that step, microseconds
24-27  count      MAVLink messages the sender sent on this link since its previous marker (markers excluded)
=====  =========  =====================================================================================

:func:`decode_payload` tells a marker from any other ``V2_EXTENSION`` (``None``: not ours) and refuses a
malformed one of ours (:class:`MarkerError`): a marker that cannot be read is a broken link, never a message
to pass on. :func:`decode_wire_payload` reads a marker straight from a MAVLink 2 frame's payload bytes (the
router works on raw frames, where trailing zero bytes are truncated). Standard library only.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from uav_common.errors import UavCommonError

__all__ = [
    "HELLO",
    "KINDS",
    "MAGIC",
    "MESSAGE_TYPE",
    "PAYLOAD_LEN",
    "STEP",
    "V2_EXTENSION_ID",
    "VERSION",
    "Marker",
    "MarkerError",
    "WireMarker",
    "decode_payload",
    "decode_wire_payload",
    "encode_payload",
]

#: ``V2_EXTENSION``'s message id.
V2_EXTENSION_ID = 248
#: ``V2_EXTENSION.message_type`` of a step marker.
MESSAGE_TYPE = 51000
MAGIC = b"LKST"
VERSION = 1
HELLO = 1
STEP = 2
KINDS = {HELLO: "HELLO", STEP: "STEP"}
#: ``V2_EXTENSION.payload`` is 249 bytes.
PAYLOAD_LEN = 249
_LAYOUT = struct.Struct("<4sBBHQQI")  # magic, version, kind, lookahead, step, t_sim_us, count: 28 bytes
#: ``V2_EXTENSION`` on the wire (MAVLink 2 orders fields by size): message_type (uint16), target_network,
#: target_system, target_component (uint8 each), payload (249 bytes): 254 bytes, trailing zeros truncated.
_WIRE_HEAD = struct.Struct("<HBBB")
_WIRE_LEN = _WIRE_HEAD.size + PAYLOAD_LEN
_U16 = 0xFFFF
_U32 = 0xFFFF_FFFF
_U64 = 0xFFFF_FFFF_FFFF_FFFF


class MarkerError(UavCommonError):
    """A step marker is malformed (ours by its magic, but not readable), or the marker protocol is broken.

    The message names what was wrong (the field, the link, the step, the counts expected and received).
    """


@dataclass(frozen=True)
class Marker:
    """One step marker.

    Attributes:
        kind: :data:`HELLO` or :data:`STEP`.
        step: the step this marker ends (0 for HELLO).
        t_sim_us: simulation time of that step, microseconds.
        count: messages the sender sent on the link since its previous marker (markers excluded).
        lookahead: HELLO: the sender's lookahead in steps (>= 1); STEP: 0.
    """

    kind: int
    step: int = 0
    t_sim_us: int = 0
    count: int = 0
    lookahead: int = 0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            msg = f"step marker kind must be {HELLO} (HELLO) or {STEP} (STEP), got {self.kind}"
            raise MarkerError(msg)
        for name, top in (("step", _U64), ("t_sim_us", _U64), ("count", _U32), ("lookahead", _U16)):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or not 0 <= value <= top:
                msg = f"step marker {name} must be an integer in [0, {top}], got {value!r}"
                raise MarkerError(msg)
        if self.kind == HELLO and self.lookahead < 1:
            msg = f"a HELLO marker carries the sender's lookahead (>= 1 step), got {self.lookahead}"
            raise MarkerError(msg)
        if self.kind == STEP and self.lookahead != 0:
            msg = f"a STEP marker has lookahead 0, got {self.lookahead}"
            raise MarkerError(msg)

    @classmethod
    def hello(cls, lookahead: int) -> Marker:
        """HELLO: "count me in, my outputs of step k are inputs at step k + lookahead"."""
        return cls(HELLO, lookahead=lookahead)

    @classmethod
    def end_of_step(cls, step: int, t_sim_us: int, count: int) -> Marker:
        """STEP: "I am done with ``step`` (at ``t_sim_us``); I sent you ``count`` messages since my last marker"."""
        return cls(STEP, step=step, t_sim_us=t_sim_us, count=count)

    @property
    def is_hello(self) -> bool:
        return self.kind == HELLO

    @property
    def is_step(self) -> bool:
        return self.kind == STEP

    def describe(self) -> str:
        """``HELLO(lookahead 2)`` or ``STEP(12, t 1.200000 s, count 7)``, for logs and errors."""
        if self.kind == HELLO:
            return f"HELLO(lookahead {self.lookahead})"
        return f"STEP({self.step}, t {self.t_sim_us / 1e6:.6f} s, count {self.count})"


@dataclass(frozen=True)
class WireMarker:
    """A marker read from a frame, with the addressee the frame names."""

    target_system: int
    target_component: int
    marker: Marker


def encode_payload(marker: Marker) -> bytes:
    """The 249-byte ``V2_EXTENSION.payload`` of ``marker``."""
    head = _LAYOUT.pack(MAGIC, VERSION, marker.kind, marker.lookahead, marker.step, marker.t_sim_us, marker.count)
    return head + bytes(PAYLOAD_LEN - len(head))


def decode_payload(payload: bytes | bytearray, *, message_type: int = MESSAGE_TYPE) -> Marker | None:
    """The marker in a ``V2_EXTENSION`` payload; ``None`` when the extension is not a step marker.

    Args:
        payload: the 249 payload bytes (``bytes(msg.payload)`` of a pymavlink message).
        message_type: the message's ``message_type`` (anything but :data:`MESSAGE_TYPE` is not ours).

    Raises:
        MarkerError: ours (message type and magic) but malformed: wrong length, version or kind, a HELLO
            without a lookahead, a STEP with one, or non-zero bytes after the fields.
    """
    data = bytes(payload)
    if message_type != MESSAGE_TYPE or data[: len(MAGIC)] != MAGIC:
        return None
    if len(data) != PAYLOAD_LEN:
        msg = f"step marker payload must be {PAYLOAD_LEN} bytes, got {len(data)}"
        raise MarkerError(msg)
    magic, version, kind, lookahead, step, t_sim_us, count = _LAYOUT.unpack_from(data)
    del magic
    if version != VERSION:
        msg = f"step marker version {version} is not supported (this build speaks version {VERSION}); update the sender"
        raise MarkerError(msg)
    if kind not in KINDS:
        msg = f"step marker kind {kind} is unknown (1 = HELLO, 2 = STEP)"
        raise MarkerError(msg)
    if any(data[_LAYOUT.size :]):
        msg = f"step marker payload has non-zero bytes after byte {_LAYOUT.size} (a newer or corrupted marker)"
        raise MarkerError(msg)
    return Marker(kind, step=step, t_sim_us=t_sim_us, count=count, lookahead=lookahead)


def decode_wire_payload(wire: bytes | bytearray | memoryview) -> WireMarker | None:
    """The marker in a ``V2_EXTENSION`` frame's payload as it is on the wire (MAVLink 2 may have truncated its
    trailing zero bytes); ``None`` when the extension is not a step marker.

    Raises:
        MarkerError: as :func:`decode_payload`, or a payload longer than a ``V2_EXTENSION``'s 254 bytes.
    """
    data = bytes(wire)
    if len(data) > _WIRE_LEN:
        msg = f"V2_EXTENSION payload of {len(data)} bytes is longer than {_WIRE_LEN}"
        raise MarkerError(msg)
    data += bytes(_WIRE_LEN - len(data))
    message_type, _network, target_system, target_component = _WIRE_HEAD.unpack_from(data)
    marker = decode_payload(data[_WIRE_HEAD.size :], message_type=message_type)
    if marker is None:
        return None
    return WireMarker(target_system, target_component, marker)
