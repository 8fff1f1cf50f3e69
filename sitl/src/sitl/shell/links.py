"""MAVLink links on our own sockets: UDP (PX4-style GCS/API ports) and a TCP server.

Each link packs outgoing messages with its own pymavlink ``MAVLink`` instance
(its own sequence numbers and, when configured, MAVLink 2 signing) and parses
incoming bytes with one robust parser per remote peer. Nothing here raises on
bad input: malformed frames, bad CRCs, unknown message ids and unsigned
messages on a signed link are counted in :class:`LinkStats` and dropped.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import socket
import struct
import time
from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fastcrc.crc16 import mcrf4xx
from pymavlink.dialects.v20 import common as mavlink

from sitl.errors import LinkError
from sitl.shell.wire import WireMessage
from uav_common.mavlink_parser import reset_parser

__all__ = [
    "LinkStats",
    "MavLink",
    "Received",
    "TcpServerLink",
    "UdpLink",
    "bind_error",
    "frame_only",
    "frame_v2",
    "load_signing_key",
    "mavlink",
]

# Messages a signed link still accepts unsigned: they only read state (MAVLink signing spec's advice).
UNSIGNED_ALLOWED = frozenset(
    {
        mavlink.MAVLINK_MSG_ID_HEARTBEAT,
        mavlink.MAVLINK_MSG_ID_SYSTEM_TIME,
        mavlink.MAVLINK_MSG_ID_PING,
        mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_READ,
        mavlink.MAVLINK_MSG_ID_PARAM_REQUEST_LIST,
        mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_LIST,
        mavlink.MAVLINK_MSG_ID_MISSION_REQUEST,
        mavlink.MAVLINK_MSG_ID_MISSION_REQUEST_INT,
        mavlink.MAVLINK_MSG_ID_MISSION_ACK,
        mavlink.MAVLINK_MSG_ID_TIMESYNC,
        mavlink.MAVLINK_MSG_ID_REQUEST_DATA_STREAM,
        mavlink.MAVLINK_MSG_ID_RADIO_STATUS,
        mavlink.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL,
    }
)
# MAVLink signing timestamps: units of 10 us since 2015-01-01.
_SIGNING_EPOCH_S = 1420070400
MAX_PEERS = 64


def load_signing_key(path: Path) -> bytes:
    """A 32-byte secret from a file: 64 hex digits, or any passphrase (SHA-256, as MAVProxy does)."""
    try:
        text = path.read_text(encoding="utf-8").strip()
    except OSError as err:
        msg = f"cannot read signing key file {path}: {err.strerror}"
        raise LinkError(msg) from err
    if not text:
        msg = f"signing key file {path} is empty"
        raise LinkError(msg)
    if len(text) == 64:
        with contextlib.suppress(ValueError):
            return bytes.fromhex(text)
    return hashlib.sha256(text.encode("utf-8")).digest()


@dataclass
class LinkStats:
    """Counters per link, reported in the log and checked by the fuzz tests."""

    rx_bytes: int = 0
    rx_messages: int = 0
    rx_bad_frames: int = 0
    rx_unknown_ids: int = 0
    rx_rejected_unsigned: int = 0
    rx_other_target: int = 0
    rx_invalid_values: int = 0
    rx_truncated: int = 0
    tx_messages: int = 0
    tx_bytes: int = 0
    tx_errors: int = 0
    bad_reasons: dict[str, int] = field(default_factory=dict)

    def bad(self, reason: str) -> None:
        self.rx_bad_frames += 1
        key = reason.split(" in msgID", maxsplit=1)[0].split(" Got ", maxsplit=1)[0][:60]
        self.bad_reasons[key] = self.bad_reasons.get(key, 0) + 1

    def summary(self) -> str:
        return (
            f"rx {self.rx_messages} msgs/{self.rx_bytes} B, bad {self.rx_bad_frames}, "
            f"unknown-id {self.rx_unknown_ids}, "
            f"unsigned-rejected {self.rx_rejected_unsigned}, other-target {self.rx_other_target}, "
            f"invalid-values {self.rx_invalid_values}; tx {self.tx_messages} msgs/{self.tx_bytes} B"
        )


@dataclass(frozen=True)
class Received:
    """One good message and where it came from (``route`` leads back to the sender)."""

    msg: Any
    route: Hashable


class _Sink:
    """pymavlink writes packed frames into a 'file'; we take them from here."""

    __slots__ = ("data",)

    def __init__(self) -> None:
        self.data = b""

    def write(self, data: bytes) -> None:
        self.data = data


_HEADER_V2 = struct.Struct("<BBBBBBBHB")


def _return_payload(_mav: Any, _crc_extra: int, payload: bytes, force_mavlink1: bool = False) -> bytes:
    return payload


def frame_v2(msg: Any, seq: int, system_id: int, component_id: int) -> bytes:
    """Unsigned MAVLink 2 frame of ``msg``, byte-identical to pymavlink's ``msg.pack`` but ~3x cheaper.

    The generated ``pack`` computes the payload and hands it to ``_pack``; the
    payload is taken from there, then header, trailing-zero truncation and the
    CRC (with the message's CRC_EXTRA) are done here. Checked against pymavlink
    for every message we send (tests/unit/sitl/test_sitl_links.py). A
    :class:`~sitl.shell.wire.WireMessage` is framed from its payload directly.
    """
    if isinstance(msg, WireMessage):
        return msg.frame(seq, system_id, component_id)
    msg._pack = _return_payload
    try:
        payload: bytes = msg.pack(None)
    finally:
        del msg._pack
    body = payload.rstrip(b"\0") or payload[:1]
    cls = type(msg)  # class attributes: some messages have a field called "id"
    msg_id = cls.id
    header = _HEADER_V2.pack(253, len(body), 0, 0, seq, system_id, component_id, msg_id & 0xFFFF, msg_id >> 16)
    crc = mcrf4xx(header[1:] + body + bytes((cls.crc_extra,)), 0xFFFF)
    return header + body + crc.to_bytes(2, "little")


def _make_parser(key: bytes | None) -> Any:
    parser = mavlink.MAVLink(None)
    parser.robust_parsing = True
    if key is not None:
        parser.signing.secret_key = key
        parser.signing.allow_unsigned_callback = _allow_unsigned
        parser.signing.timestamp = int((time.time() - _SIGNING_EPOCH_S) * 1e5)
    return parser


def _allow_unsigned(_mav: Any, msg_id: int) -> bool:
    return msg_id in UNSIGNED_ALLOWED


class MavLink:
    """Common part of a link: encoder, per-peer parsers, counters."""

    def __init__(
        self, name: str, *, system_id: int, component_id: int, signing_key: bytes | None, link_id: int
    ) -> None:
        self.name = name
        self.stats = LinkStats()
        self.signing_key = signing_key
        self._sink = _Sink()
        self.encoder = mavlink.MAVLink(self._sink, srcSystem=system_id, srcComponent=component_id)
        if signing_key is not None:
            self.encoder.signing.secret_key = signing_key
            self.encoder.signing.sign_outgoing = True
            self.encoder.signing.link_id = link_id & 0xFF
            self.encoder.signing.timestamp = int((time.time() - _SIGNING_EPOCH_S) * 1e5)
        self._parsers: dict[Hashable, Any] = {}
        #: Also yield the frames that arrived whole but are not handled (unknown ids, unsigned frames a signed
        #: link rejects): a lockstep peer counts every frame it sends (sitl.shell.lockstep_links), so these
        #: count as received. The caller drops them (:func:`frame_only`).
        self.keep_unknown = False

    def pack(self, msg: Any) -> bytes:
        """One MAVLink 2 frame with this link's sequence number (signed if the link signs)."""
        enc = self.encoder
        if self.signing_key is not None:
            buf: bytes = msg.pack(enc)
        elif isinstance(msg, WireMessage):
            buf = msg.frame(enc.seq, enc.srcSystem, enc.srcComponent)
        else:
            buf = frame_v2(msg, enc.seq, enc.srcSystem, enc.srcComponent)
        enc.seq = (enc.seq + 1) % 256
        return buf

    def _parser(self, peer: Hashable) -> Any:
        parser = self._parsers.get(peer)
        if parser is None:
            if len(self._parsers) >= MAX_PEERS:
                self._parsers.pop(next(iter(self._parsers)))
            parser = _make_parser(self.signing_key)
            self._parsers[peer] = parser
        return parser

    def send(self, msg: Any, route: Hashable | None = None) -> None:
        """Send to ``route``'s peer, or to every peer of the link (``None``, possibly batched until :meth:`flush`)."""
        raise NotImplementedError

    def flush(self) -> None:
        """Put batched frames on the wire."""

    def close(self) -> None:
        raise NotImplementedError

    def routes(self) -> list[Hashable]:
        """The route of every peer the link sends broadcasts to."""
        return []

    def sent_count(self, route: Hashable) -> int:
        """Messages sent so far to ``route``'s peer (counted for TCP clients and pinned UDP peers)."""
        return 0

    def pin(self, route: Hashable) -> None:
        """Keep ``route``'s peer (a lockstep peer) and count what is sent to it: it is never expired."""

    def unpin(self, route: Hashable) -> None:
        """Forget :meth:`pin`."""

    def forget_peer(self, peer: Hashable) -> None:
        self._parsers.pop(peer, None)

    def parse(self, data: bytes, peer: Hashable, *, datagram: bool) -> Iterator[Any]:
        """Good messages in ``data``; everything else is counted and dropped."""
        stats = self.stats
        stats.rx_bytes += len(data)
        parser = self._parser(peer)
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception as err:  # pymavlink can raise on pathological input; never let it out
            stats.bad(f"parser error: {type(err).__name__}")
            msgs = []
            reset_parser(parser)
        if datagram and parser.buf_len() > 0:
            stats.rx_truncated += 1
            reset_parser(parser)
        for msg in msgs:
            msg_type = msg.get_type()
            if msg_type == "BAD_DATA":
                reason = str(getattr(msg, "reason", "bad data"))
                if "signature" in reason:
                    stats.rx_rejected_unsigned += 1
                    if self.keep_unknown:
                        yield msg
                else:
                    stats.bad(reason)
                continue
            if msg_type.startswith("UNKNOWN_"):
                stats.rx_unknown_ids += 1
                if self.keep_unknown:
                    yield msg
                continue
            stats.rx_messages += 1
            yield msg


def frame_only(msg: Any) -> bool:
    """A frame :meth:`MavLink.parse` yields only with ``keep_unknown``: counted, never handled."""
    kind: str = msg.get_type()
    return kind == "BAD_DATA" or kind.startswith("UNKNOWN_")


def bind_error(what: str, host: str, port: int, err: OSError) -> LinkError:
    hint = ""
    if err.errno == errno.EADDRINUSE:
        hint = " (port busy: another uav-sitl or PX4 SITL running? choose another port with the CLI flag)"
    msg = f"{what}: cannot bind {host}:{port}: {err.strerror}{hint}"
    return LinkError(msg)


class UdpLink(MavLink):
    """PX4-style UDP link: bind a local port, send to the remote port and to every peer heard recently."""

    PEER_TIMEOUT_S = 10.0
    BATCH_BYTES = 1200

    def __init__(
        self,
        name: str,
        *,
        local: tuple[str, int],
        remote: tuple[str, int],
        system_id: int,
        component_id: int,
        signing_key: bytes | None = None,
        link_id: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        super().__init__(name, system_id=system_id, component_id=component_id, signing_key=signing_key, link_id=link_id)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(local)
        except OSError as err:
            self.sock.close()
            what = f"{name} link (UDP)"
            raise bind_error(what, local[0], local[1], err) from err
        self.sock.setblocking(False)
        with contextlib.suppress(OSError):
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
        self.local_port = int(self.sock.getsockname()[1])
        self.remote = (socket.gethostbyname(remote[0]), remote[1])
        self._peers: dict[tuple[str, int], float] = {}
        self._clock = clock
        self._batch = bytearray()
        self._batch_count = 0
        #: Pinned peers (lockstep peers): never expired; messages sent to each, counted.
        self._pinned: dict[tuple[str, int], int] = {}

    def fileno(self) -> int:
        return self.sock.fileno()

    def routes(self) -> list[Hashable]:
        return [(self.name, dest) for dest in self.destinations()]

    def pin(self, route: Hashable) -> None:
        if isinstance(route, tuple) and route[0] == self.name:
            self._pinned.setdefault(route[1], 0)

    def unpin(self, route: Hashable) -> None:
        if isinstance(route, tuple) and route[0] == self.name:
            self._pinned.pop(route[1], None)

    def sent_count(self, route: Hashable) -> int:
        if isinstance(route, tuple) and route[0] == self.name:
            return self._pinned.get(route[1], 0)
        return 0

    def read(self) -> list[Received]:
        out: list[Received] = []
        now = self._clock()
        for _ in range(256):
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break  # e.g. ICMP port unreachable reported on a later recv
            peer = (addr[0], int(addr[1]))
            if peer not in self._peers and len(self._peers) >= MAX_PEERS:
                self._expire(now, force=True)
            self._peers[peer] = now
            route = (self.name, peer)
            out.extend(Received(msg, route) for msg in self.parse(data, route, datagram=True))
        return out

    def _expire(self, now: float, *, force: bool = False) -> None:
        for peer, last in list(self._peers.items()):
            if now - last > self.PEER_TIMEOUT_S and peer not in self._pinned:
                del self._peers[peer]
                self.forget_peer((self.name, peer))
        if force and len(self._peers) >= MAX_PEERS:
            unpinned = [p for p in self._peers if p not in self._pinned] or list(self._peers)
            oldest = min(unpinned, key=self._peers.__getitem__)
            del self._peers[oldest]

    def destinations(self) -> list[tuple[str, int]]:
        self._expire(self._clock())
        dests = [self.remote]
        dests.extend(p for p in self._peers if p != self.remote)
        dests.extend(p for p in self._pinned if p != self.remote and p not in self._peers)
        return dests

    def send(self, msg: Any, route: Hashable | None = None) -> None:
        """Pack once; send to ``route``'s peer at once, or batch for the remote and every live peer.

        Like PX4's mavlink module, several frames share one datagram (up to
        :attr:`BATCH_BYTES`); every MAVLink parser reads them one after another.
        """
        enc = self.encoder
        if self.signing_key is None and isinstance(msg, WireMessage):  # the streamed telemetry: framed here
            buf = msg.frame(enc.seq, enc.srcSystem, enc.srcComponent)
            enc.seq = (enc.seq + 1) % 256
        else:
            buf = self.pack(msg)
        if route is None:
            batch = self._batch
            batch += buf
            self._batch_count += 1
            if len(batch) >= self.BATCH_BYTES:
                self.flush()
            return
        if isinstance(route, tuple) and route[0] == self.name:
            self._sendto(buf, route[1], 1)

    def flush(self) -> None:
        if not self._batch:
            return
        data, count = bytes(self._batch), self._batch_count
        self._batch.clear()
        self._batch_count = 0
        for dest in self.destinations():
            self._sendto(data, dest, count)

    def _sendto(self, data: bytes, dest: tuple[str, int], count: int) -> None:
        pinned = self._pinned
        if dest in pinned:  # counted whether or not the kernel takes it: a lost datagram is a lost message
            pinned[dest] += count
        try:
            self.sock.sendto(data, dest)
            self.stats.tx_messages += count
            self.stats.tx_bytes += len(data)
        except OSError:
            self.stats.tx_errors += 1

    def close(self) -> None:
        self.flush()
        self.sock.close()


class _TcpClient:
    __slots__ = ("addr", "out", "sent", "sock")

    def __init__(self, sock: socket.socket, addr: tuple[str, int]) -> None:
        self.sock = sock
        self.addr = addr
        self.out = bytearray()
        self.sent = 0  # messages queued for this client (sent_count)


class TcpServerLink(MavLink):
    """A TCP server; every accepted connection is a peer that gets all broadcast traffic."""

    MAX_OUT_BUFFER = 4 << 20
    BATCH_BYTES = 4096

    def __init__(
        self,
        name: str,
        *,
        local: tuple[str, int],
        system_id: int,
        component_id: int,
        max_clients: int = 8,
        signing_key: bytes | None = None,
        link_id: int = 0,
    ) -> None:
        super().__init__(name, system_id=system_id, component_id=component_id, signing_key=signing_key, link_id=link_id)
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.server.bind(local)
            self.server.listen(max_clients)
        except OSError as err:
            self.server.close()
            what = f"{name} link (TCP server)"
            raise bind_error(what, local[0], local[1], err) from err
        self.server.setblocking(False)
        self.local_port = int(self.server.getsockname()[1])
        self.max_clients = max_clients
        self.clients: dict[int, _TcpClient] = {}
        self._next_id = 0
        self.on_drop: Callable[[socket.socket], None] | None = None
        #: Called with the route of a client that is gone (after ``on_drop``).
        self.on_forget: Callable[[Hashable], None] | None = None

    def fileno(self) -> int:
        return self.server.fileno()

    def routes(self) -> list[Hashable]:
        return [(self.name, cid) for cid in self.clients]

    def sent_count(self, route: Hashable) -> int:
        if isinstance(route, tuple) and route[0] == self.name:
            client = self.clients.get(route[1])
            return 0 if client is None else client.sent
        return 0

    def accept(self) -> _TcpClient | None:
        try:
            sock, addr = self.server.accept()
        except (BlockingIOError, InterruptedError, OSError):
            return None
        if len(self.clients) >= self.max_clients:
            sock.close()
            return None
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._next_id += 1
        client = _TcpClient(sock, (addr[0], int(addr[1])))
        self.clients[self._next_id] = client
        return client

    def client_id(self, client: _TcpClient) -> int:
        return next(cid for cid, c in self.clients.items() if c is client)

    def read_client(self, cid: int) -> list[Received]:
        client = self.clients.get(cid)
        if client is None:
            return []
        out: list[Received] = []
        for _ in range(64):
            try:
                data = client.sock.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                data = b""
            if not data:
                self.drop(cid)
                break
            route = (self.name, cid)
            out.extend(Received(msg, route) for msg in self.parse(data, route, datagram=False))
        return out

    def drop(self, cid: int) -> None:
        """Forget a client; ``on_drop`` hears of it while its socket is still open."""
        client = self.clients.pop(cid, None)
        if client is not None:
            if self.on_drop is not None:
                self.on_drop(client.sock)
            with contextlib.suppress(OSError):
                client.sock.close()
            self.forget_peer((self.name, cid))
            if self.on_forget is not None:
                self.on_forget((self.name, cid))

    def send(self, msg: Any, route: Hashable | None = None) -> None:
        if not self.clients:
            # still advance the sequence like an always-on link would
            self.encoder.seq = (self.encoder.seq + 1) % 256
            return
        buf = self.pack(msg)
        if route is not None:
            targets = [route[1]] if isinstance(route, tuple) and route[0] == self.name else []
        else:
            targets = list(self.clients)
        for cid in targets:
            client = self.clients.get(cid)
            if client is None:
                continue
            client.out += buf
            client.sent += 1
            self.stats.tx_messages += 1
            self.stats.tx_bytes += len(buf)
            if route is not None or len(client.out) >= self.BATCH_BYTES:
                self.flush_client(cid)

    def flush(self) -> None:
        for cid in list(self.clients):
            self.flush_client(cid)

    def flush_client(self, cid: int) -> None:
        client = self.clients.get(cid)
        if client is None or not client.out:
            return
        try:
            sent = client.sock.send(client.out)
            del client.out[:sent]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self.stats.tx_errors += 1
            self.drop(cid)
            return
        if len(client.out) > self.MAX_OUT_BUFFER:
            self.stats.tx_errors += 1
            self.drop(cid)

    def close(self) -> None:
        for cid in list(self.clients):
            self.drop(cid)
        self.server.close()
