"""MAVLink 1/2 framing: find frames in bytes, check them, keep the raw bytes.

Pure code: no sockets, no clocks, no pymavlink. The message table
(:class:`MessageSpec` per message ID) is data passed in by the caller; see
:mod:`mavlink_router.shell.dialect` for how it is built from a pymavlink dialect.

Wire formats (https://mavlink.io/en/guide/serialization.html)::

    MAVLink 2: FD len incompat compat seq sysid compid msgid(3, LE) payload crc(2) [signature(13)]
    MAVLink 1: FE len seq sysid compid msgid payload crc(2)

Rules, as in mavlink-router (``Endpoint::read_msg``):

* A frame whose message ID is in the table must pass the X.25 CRC (with the
  message's ``crc_extra``); a failure is counted and the parser resynchronises
  one byte after the bad start marker.
* A frame with an unknown message ID is forwarded untouched without a CRC check
  (it may be a dialect message we do not know). To keep random garbage from
  being forwarded as "unknown messages", such a frame is accepted only when it is
  followed by another start marker, or by the end of a datagram, and only when no
  CRC-valid known frame starts inside it (then it is a false start swallowing real
  frames). On a byte stream, a frame that ends exactly at the end of the data read
  so far is held until the next byte arrives or the input has been idle
  (:meth:`FrameParser.flush`).
* MAVLink 2 frames with incompatibility flags other than ``SIGNED`` (0x01) are
  rejected, as the MAVLink specification requires.
* Target fields come from the table; in MAVLink 2 a trailing zero field may be
  truncated from the payload, in which case the target is 0.

Frames are returned as plain tuples (the hot path avoids object churn), see
:data:`Frame`.
"""

from __future__ import annotations

import binascii
import re
from collections.abc import Callable, Mapping
from typing import NamedTuple

__all__ = [
    "MAVLINK1_HEADER_LEN",
    "MAVLINK2_HEADER_LEN",
    "NO_TARGET",
    "SIGNATURE_LEN",
    "STX_V1",
    "STX_V2",
    "Frame",
    "FrameParser",
    "MessageSpec",
    "frame_header",
    "x25_crc",
]

STX_V2 = 0xFD
STX_V1 = 0xFE
MAVLINK2_HEADER_LEN = 10
MAVLINK1_HEADER_LEN = 6
SIGNATURE_LEN = 13
IFLAG_SIGNED = 0x01
NO_TARGET = -1
"""Target value for a message without a target field (mavlink-router's ``-1``)."""

MAX_FRAME_LEN = MAVLINK2_HEADER_LEN + 255 + 2 + SIGNATURE_LEN

Frame = tuple[bytes, int, int, int, int, int, int]
"""One frame: ``(raw, msgid, sysid, compid, seq, target_system, target_component)``.

``raw`` is the complete frame exactly as received (header, payload, CRC and, if
present, the signature block). ``target_*`` is :data:`NO_TARGET` when the
message has no such field or its ID is unknown.
"""


class MessageSpec(NamedTuple):
    """What the router needs to know about one message ID."""

    name: str
    crc_extra: int
    target_system_ofs: int = NO_TARGET
    """Byte offset of ``target_system`` in the (wire-ordered) payload, or -1."""
    target_component_ofs: int = NO_TARGET
    """Byte offset of ``target_component`` in the payload, or -1."""


_REV8 = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))


def _rev16(value: int) -> int:
    return (_REV8[value & 0xFF] << 8) | _REV8[value >> 8]


def _x25_crc_binascii(data: bytes, initial: int = 0xFFFF) -> int:
    # CRC-16/MCRF4XX is the bit-reflected form of CRC-CCITT (poly 0x1021), which
    # binascii.crc_hqx computes MSB-first: reflect the input bytes and the
    # register on the way in and out.
    return _rev16(binascii.crc_hqx(data.translate(_REV8), _rev16(initial)))


def _select_crc() -> Callable[..., int]:
    try:
        from fastcrc import crc16  # noqa: PLC0415  (optional accelerator)
    except ImportError:  # pragma: no cover - depends on the environment
        return _x25_crc_binascii
    crc: Callable[..., int] = crc16.mcrf4xx
    return crc


_crc: Callable[..., int] = _select_crc()


def x25_crc(data: bytes, initial: int = 0xFFFF) -> int:
    """MAVLink's checksum (CRC-16/MCRF4XX, "X.25") of ``data``, continuing from ``initial``."""
    return _crc(data, initial)


def frame_header(raw: bytes) -> tuple[int, int, int, int, int]:
    """``(msgid, sysid, compid, seq, payload_offset)`` of a complete raw frame."""
    if raw[0] == STX_V2:
        return raw[7] | (raw[8] << 8) | (raw[9] << 16), raw[5], raw[6], raw[4], MAVLINK2_HEADER_LEN
    return raw[5], raw[3], raw[4], raw[2], MAVLINK1_HEADER_LEN


_MARKER = re.compile(b"[\xfd\xfe]")


class FrameParser:
    """Incremental frame finder for one input (one endpoint, or one datagram).

    Args:
        table: message ID -> :class:`MessageSpec` (known messages are CRC-checked).
        stream: ``True`` for byte streams (TCP, serial): an incomplete frame at the
            end is kept for the next :meth:`feed`. ``False`` for datagrams (UDP):
            every call is self-contained and leftovers are garbage.

    Counters (cumulative): :attr:`crc_errors` (known-ID frames with a bad CRC),
    :attr:`garbage_bytes` (bytes skipped while resynchronising), :attr:`frames`.
    """

    __slots__ = ("_pending", "_specs", "_stream", "bytes_in", "crc_errors", "frames", "garbage_bytes")

    def __init__(self, table: Mapping[int, MessageSpec], *, stream: bool) -> None:
        self._specs: dict[int, tuple[bytes, int, int]] = {
            msgid: (bytes((spec.crc_extra,)), spec.target_system_ofs, spec.target_component_ofs)
            for msgid, spec in table.items()
        }
        self._stream = stream
        self._pending = b""
        self.crc_errors = 0
        self.garbage_bytes = 0
        self.frames = 0
        self.bytes_in = 0

    @property
    def pending_bytes(self) -> int:
        """Bytes held back waiting for the rest of a frame (streams only)."""
        return len(self._pending)

    def reset(self) -> None:
        """Forget a partial frame (after a reconnect)."""
        self._pending = b""

    def feed(self, data: bytes) -> list[Frame]:
        """Return every complete, valid frame in ``data`` (plus what was pending)."""
        self.bytes_in += len(data)
        if self._stream:
            return self._parse(self._pending + data if self._pending else data, stream=True)
        return self._parse(data, stream=False)

    def flush(self) -> list[Frame]:
        """The input is at rest: parse what is pending as if no more bytes were coming.

        A stream holds back an unknown-ID frame that ends exactly at the end of the
        data (the next byte must confirm it is followed by a start marker) and any
        incomplete frame. When nothing more arrives, the caller flushes: the held
        frame is accepted, and an incomplete "frame" that never completed is
        treated as garbage, so a false start marker cannot stall the stream.
        """
        pending, self._pending = self._pending, b""
        return self._parse(pending, stream=False) if pending else []

    def _parse(self, buf: bytes, *, stream: bool) -> list[Frame]:  # noqa: PLR0912, PLR0915 - one hot loop on purpose
        specs = self._specs
        crc = _crc
        out: list[Frame] = []
        n = len(buf)
        pos = 0
        while pos < n:
            stx = buf[pos]
            if stx == STX_V2:
                if n - pos < 12:
                    if stream:
                        break
                    pos = self._resync(buf, pos + 1, pos)
                    continue
                plen = buf[pos + 1]
                incompat = buf[pos + 2]
                if incompat & ~IFLAG_SIGNED:
                    pos = self._resync(buf, pos + 1, pos)
                    continue
                flen = plen + (25 if incompat else 12)
                if n - pos < flen:
                    if stream:
                        break
                    pos = self._resync(buf, pos + 1, pos)
                    continue
                msgid = buf[pos + 7] | (buf[pos + 8] << 8) | (buf[pos + 9] << 16)
                payload = pos + 10
                seq = buf[pos + 4]
                sysid = buf[pos + 5]
                compid = buf[pos + 6]
            elif stx == STX_V1:
                if n - pos < 8:
                    if stream:
                        break
                    pos = self._resync(buf, pos + 1, pos)
                    continue
                plen = buf[pos + 1]
                flen = plen + 8
                if n - pos < flen:
                    if stream:
                        break
                    pos = self._resync(buf, pos + 1, pos)
                    continue
                msgid = buf[pos + 5]
                payload = pos + 6
                seq = buf[pos + 2]
                sysid = buf[pos + 3]
                compid = buf[pos + 4]
            else:
                pos = self._resync(buf, pos, pos)
                continue
            end = payload + plen
            spec = specs.get(msgid)
            if spec is not None:
                if crc(spec[0], crc(buf[pos + 1 : end])) != buf[end] | (buf[end + 1] << 8):
                    self.crc_errors += 1
                    pos = self._resync(buf, pos + 1, pos)
                    continue
                ofs = spec[1]
                tsys = NO_TARGET if ofs < 0 else buf[payload + ofs] if ofs < plen else 0
                ofs = spec[2]
                tcomp = NO_TARGET if ofs < 0 else buf[payload + ofs] if ofs < plen else 0
            else:
                after = pos + flen
                if after < n:
                    if buf[after] != STX_V2 and buf[after] != STX_V1:
                        pos = self._resync(buf, pos + 1, pos)
                        continue
                elif stream:
                    break  # wait for the next byte (or flush()) to confirm the frame boundary
                if self._hides_known_frame(buf, pos + 1, after):
                    pos = self._resync(buf, pos + 1, pos)
                    continue
                tsys = tcomp = NO_TARGET
            out.append((buf[pos : pos + flen], msgid, sysid, compid, seq, tsys, tcomp))
            pos += flen
        if stream:
            self._pending = buf[pos:] if pos < n else b""
        self.frames += len(out)
        return out

    def _hides_known_frame(self, buf: bytes, start: int, end: int) -> bool:
        """Does a complete, CRC-valid frame of a known ID start inside ``buf[start:end]``?

        Then the unknown-ID "frame" around it is misframed garbage (a real payload
        holds a valid MAVLink frame with a matching CRC by chance once in 65536).
        """
        specs = self._specs
        n = len(buf)
        match = _MARKER.search(buf, start, end)
        while match is not None:
            pos = match.start()
            if buf[pos] == STX_V2 and n - pos >= 12:
                plen = buf[pos + 1]
                flen = plen + (25 if buf[pos + 2] & IFLAG_SIGNED else 12)
                msgid = buf[pos + 7] | (buf[pos + 8] << 8) | (buf[pos + 9] << 16)
                crc_end = pos + 10 + plen
            elif buf[pos] == STX_V1 and n - pos >= 8:
                plen = buf[pos + 1]
                flen = plen + 8
                msgid = buf[pos + 5]
                crc_end = pos + 6 + plen
            else:
                flen = n + 1
                msgid = -1
                crc_end = 0
            spec = specs.get(msgid)
            if spec is not None and n - pos >= flen:
                crc = _crc(spec[0], _crc(buf[pos + 1 : crc_end]))
                if crc == buf[crc_end] | (buf[crc_end + 1] << 8):
                    return True
            match = _MARKER.search(buf, pos + 1, end)
        return False

    def _resync(self, buf: bytes, search_from: int, skip_from: int) -> int:
        """Skip to the next start marker at or after ``search_from``; count the skipped bytes."""
        match = _MARKER.search(buf, search_from)
        nxt = match.start() if match is not None else len(buf)
        self.garbage_bytes += nxt - skip_from
        return nxt
