"""Endpoints: the sockets and serial ports the router reads and writes (shell).

Every endpoint has a routing *slot* in :class:`~mavlink_router.core.engine.RouterCore`
and hands the bytes it reads to :meth:`Host.deliver`. Frames routed to an
endpoint are collected by :meth:`Endpoint.send` and written by
:meth:`Endpoint.flush`, which the host calls right after handling each event:
one system call per destination per burst of input. Writing never blocks:

* UDP: ``sendto`` on a non-blocking socket, whole frames packed into datagrams of
  up to 1400 bytes (``Coalesce``, on by default); if the kernel buffer is full
  the frames are dropped and counted (UDP is lossy by nature; there is nothing
  to retransmit).
* Streams (TCP, serial): a frame is written directly when nothing is pending;
  otherwise it waits in a bounded queue *per source endpoint*, and the queues are
  drained round-robin when the socket is writable. A client that stops reading
  therefore fills only its own queues (drops are counted) and a source that
  floods cannot starve another source's commands to the same destination. A
  frame is never split or interleaved: partially written data is finished first.

Reading is budgeted per event (:data:`READ_BUDGET` datagrams, or one read of up
to 64 KiB) so one busy input cannot monopolise the loop.
"""

from __future__ import annotations

import abc
import errno
import logging
import os
import socket
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol

from mavlink_router.core.config import TcpEndpointConfig, UartEndpointConfig, UdpEndpointConfig, UdpMode
from mavlink_router.core.engine import EndpointStats
from mavlink_router.errors import SerialUnavailableError
from uav_common.shell.sockets import connected_to_itself

__all__ = [
    "READ_BUDGET",
    "Endpoint",
    "Host",
    "TcpClientEndpoint",
    "TcpConnection",
    "TcpServer",
    "UartEndpoint",
    "UdpEndpoint",
    "check_serial_available",
    "pack_datagrams",
]

_LOG = logging.getLogger("mavlink_router.shell.endpoints")

EVENT_READ = 1  # selectors.EVENT_READ
EVENT_WRITE = 2  # selectors.EVENT_WRITE
READ_BUDGET = 64
"""Datagrams read from one UDP socket per readiness event."""
STREAM_READ_BYTES = 65536
WRITE_BATCH_BYTES = 65536
UDP_CLIENT_REVERT_S = 5.0
"""A UDP client replies to the last sender; after this much silence it goes back to its Address:Port."""
UDP_RCVBUF_BYTES = 4 << 20
"""Requested UDP receive buffer (the kernel caps it at net.core.rmem_max): absorbs bursts
while the router is not scheduled, instead of dropping them."""
UDP_SNDBUF_BYTES = 1 << 20
TCP_SNDBUF_BYTES = 64 * 1024
FIRST_RETRY_S = 0.25
UART_BAUD_CYCLE_S = 5.0


MAX_DATAGRAM_BYTES = 1400
"""Frames for one UDP destination are packed into datagrams up to this size (no IP fragmentation)."""


def pack_datagrams(frames: list[bytes], limit: int = MAX_DATAGRAM_BYTES) -> list[tuple[bytes, int]]:
    """Group consecutive frames into ``(datagram, frame_count)`` of at most ``limit`` bytes.

    MAVLink parsers (pymavlink, MAVSDK, QGroundControl, MAVProxy, the C library)
    read a UDP datagram as a byte stream, so several whole frames in one datagram
    are parsed exactly like separate datagrams; this saves system calls when a
    burst is routed to the same place. A frame is never split.
    """
    out: list[tuple[bytes, int]] = []
    chunk: list[bytes] = []
    size = 0
    for frame in frames:
        if chunk and size + len(frame) > limit:
            out.append((b"".join(chunk), len(chunk)))
            chunk = []
            size = 0
        chunk.append(frame)
        size += len(frame)
    if chunk:
        out.append((b"".join(chunk) if len(chunk) > 1 else chunk[0], len(chunk)))
    return out


class Timer(Protocol):
    def cancel(self) -> None: ...


class Host(Protocol):
    """What endpoints need from the main loop."""

    def watch(self, fileobj: Any, events: int, handler: Callable[[int], None]) -> None: ...
    def unwatch(self, fileobj: Any) -> None: ...
    def call_later(self, delay_s: float, callback: Callable[[], None]) -> Timer: ...
    def deliver(self, slot: int, data: bytes) -> None: ...
    def monotonic(self) -> float: ...
    def connection_lost(self, endpoint: Endpoint) -> None: ...
    def reset_stream(self, slot: int) -> None: ...
    def mark_dirty(self, endpoint: Endpoint) -> None: ...
    def endpoint_connected(self, endpoint: Endpoint) -> None: ...


def _family(address: str) -> tuple[socket.AddressFamily, str]:
    if address.startswith("["):
        return socket.AF_INET6, address[1:-1]
    return socket.AF_INET, address


def _nonfatal_send_error(err: OSError) -> bool:
    return err.errno in (
        errno.EAGAIN,
        errno.ENOBUFS,
        errno.ECONNREFUSED,
        errno.ENETUNREACH,
        errno.EHOSTUNREACH,
        errno.EPERM,
    )


class Endpoint(abc.ABC):
    """Base class: a name, a routing slot, statistics and lifecycle."""

    kind = "endpoint"
    stream = False
    """Byte-stream endpoints (TCP, serial) reassemble frames across reads."""
    dynamic = False
    """Dynamic endpoints (accepted TCP clients) are removed when they close."""

    def __init__(self, name: str, host: Host) -> None:
        self.name = name
        self.host = host
        self.slot = -1
        self.stats = EndpointStats()  # replaced by the core's record in bind_slot()
        self.connected = False
        self.last_error = ""

    def bind_slot(self, slot: int, stats: EndpointStats) -> None:
        self.slot = slot
        self.stats = stats

    @abc.abstractmethod
    def describe(self) -> str:
        """Human-readable type and address, e.g. ``udp client 127.0.0.1:14550``."""

    @abc.abstractmethod
    def start(self) -> None:
        """Open the endpoint; failures are logged and retried, never raised."""

    @abc.abstractmethod
    def send(self, frame: bytes, source: int) -> None:
        """Collect one frame for :meth:`flush` (never blocks, never raises)."""

    @abc.abstractmethod
    def flush(self) -> None:
        """Write what :meth:`send` collected since the last flush (the host calls it after each event)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the socket or device."""

    def tick(self, now_mono: float) -> None:  # noqa: B027 - optional hook
        """Periodic housekeeping (default: nothing)."""

    def status(self) -> dict[str, object]:
        return {"name": self.name, "type": self.kind, "address": self.describe(), "connected": self.connected}

    def _count_drop(self) -> None:
        self.stats.tx_drops += 1


# --------------------------------------------------------------------------------------
# UDP


class UdpEndpoint(Endpoint):
    """``[UdpEndpoint]`` in Normal (client) or Server mode."""

    kind = "udp"

    def __init__(self, config: UdpEndpointConfig, host: Host) -> None:
        super().__init__(config.name, host)
        self.config = config
        self._family, self._host_ip = _family(config.address)
        self._configured_peer: tuple[Any, ...] | None = (
            (self._host_ip, config.port) if config.mode is UdpMode.NORMAL else None
        )
        self._peer = self._configured_peer
        self._sock: socket.socket | None = None
        self._last_rx_mono = 0.0
        self._outbox: list[bytes] = []
        self._retry: Timer | None = None

    def describe(self) -> str:
        mode = "client" if self.config.mode is UdpMode.NORMAL else "server"
        return f"udp {mode} {self.config.address}:{self.config.port}"

    def start(self) -> None:
        self._retry = None
        try:
            sock = socket.socket(self._family, socket.SOCK_DGRAM)
        except OSError as err:
            self._failed(err)
            return
        try:
            sock.setblocking(False)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, UDP_RCVBUF_BYTES)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, UDP_SNDBUF_BYTES)
            if self.config.mode is UdpMode.SERVER:
                sock.bind((self._host_ip, self.config.port))
            else:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        except OSError as err:
            sock.close()
            self._failed(err)
            return
        self._sock = sock
        self.connected = True
        self.last_error = ""
        self.host.watch(sock, EVENT_READ, self._on_event)
        _LOG.info("opened %s (%s)", self.name, self.describe())
        if self._peer is not None:  # Normal mode: someone to talk to (a Server waits for its first packet)
            self.host.endpoint_connected(self)

    def _failed(self, err: OSError) -> None:
        self.last_error = str(err)
        _LOG.error("%s (%s): cannot open: %s; retrying in 2 s", self.name, self.describe(), err)
        self._retry = self.host.call_later(2.0, self.start)

    def _on_event(self, mask: int) -> None:
        sock = self._sock
        if sock is None:
            return
        deliver = self.host.deliver
        slot = self.slot
        received = False
        for _ in range(READ_BUDGET):
            try:
                data, addr = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as err:  # e.g. ICMP port unreachable reported on a later call
                _LOG.debug("%s: recvfrom: %s", self.name, err)
                continue
            first = self._peer is None
            self._peer = addr
            received = True
            if first:
                self.host.endpoint_connected(self)
            deliver(slot, data)
        if received:
            self._last_rx_mono = self.host.monotonic()

    def send(self, frame: bytes, source: int) -> None:
        box = self._outbox
        if not box:
            self.host.mark_dirty(self)
        box.append(frame)

    def flush(self) -> None:
        frames = self._outbox
        if not frames:
            return
        self._outbox = []
        peer = self._peer
        sock = self._sock
        if peer is None or sock is None:
            return  # a server nobody has talked to yet: nobody to send to (as mavlink-routerd)
        stats = self.stats
        datagrams = pack_datagrams(frames) if self.config.coalesce and len(frames) > 1 else [(f, 1) for f in frames]
        for data, count in datagrams:
            try:
                sock.sendto(data, peer)
            except OSError as err:
                stats.tx_drops += count
                if not _nonfatal_send_error(err):
                    self.last_error = str(err)
                    _LOG.warning("%s: sendto %s: %s", self.name, peer, err)
                continue
            stats.tx_msgs += count
            stats.tx_bytes += len(data)

    def tick(self, now_mono: float) -> None:
        if (
            self.config.mode is UdpMode.NORMAL
            and self._peer != self._configured_peer
            and now_mono - self._last_rx_mono > UDP_CLIENT_REVERT_S
        ):
            _LOG.info(
                "%s: no messages for %.0f s, sending to %s again", self.name, UDP_CLIENT_REVERT_S, self.describe()
            )
            self._peer = self._configured_peer

    def status(self) -> dict[str, object]:
        out = super().status()
        out["peer"] = f"{self._peer[0]}:{self._peer[1]}" if self._peer else None
        if self.last_error:
            out["last_error"] = self.last_error
        return out

    def close(self) -> None:
        if self._retry is not None:
            self._retry.cancel()
            self._retry = None
        self.flush()
        if self._sock is not None:
            self.host.unwatch(self._sock)
            self._sock.close()
            self._sock = None
        self.connected = False


# --------------------------------------------------------------------------------------
# Byte streams (TCP, serial): bounded fair queues


class StreamEndpoint(Endpoint):
    """Shared write path of TCP and serial endpoints (see the module docstring)."""

    stream = True

    def __init__(self, name: str, host: Host, queue_limit: int) -> None:
        super().__init__(name, host)
        self._queue_limit = queue_limit
        self._queues: dict[int, deque[bytes]] = {}
        self._backlog = 0
        self._partial: memoryview | None = None
        self._write_wanted = False
        self._outbox: list[bytes] = []
        self._outbox_sources: list[int] = []

    # -- to be provided by subclasses -----------------------------------------------
    @abc.abstractmethod
    def _fileobj(self) -> Any: ...

    @abc.abstractmethod
    def _write(self, data: bytes | memoryview) -> int: ...

    @abc.abstractmethod
    def _read(self) -> bytes: ...

    @abc.abstractmethod
    def _lost(self, reason: str) -> None: ...

    # -- writing ---------------------------------------------------------------------
    def send(self, frame: bytes, source: int) -> None:
        if not self.connected:
            self._count_drop()
            return
        if not self._outbox:
            self.host.mark_dirty(self)
        self._outbox.append(frame)
        self._outbox_sources.append(source)

    def flush(self) -> None:
        frames = self._outbox
        if not frames:
            return
        sources = self._outbox_sources
        self._outbox = []
        self._outbox_sources = []
        stats = self.stats
        if not self.connected:
            stats.tx_drops += len(frames)
            return
        if self._partial is None and not self._backlog:
            data = frames[0] if len(frames) == 1 else b"".join(frames)
            try:
                written = self._write(data)
            except (BlockingIOError, InterruptedError):
                written = 0
            except OSError as err:
                stats.tx_drops += len(frames)
                self._lost(f"write failed: {err}")
                return
            stats.tx_msgs += len(frames)
            stats.tx_bytes += len(data)
            if written < len(data):
                self._partial = memoryview(data)[written:]
                self._want_write(True)
            return
        self._enqueue(frames, sources)

    def _enqueue(self, frames: list[bytes], sources: list[int]) -> None:
        """Backlogged: bounded per-source queues, drained round-robin when writable."""
        stats = self.stats
        limit = self._queue_limit
        queues = self._queues
        for frame, source in zip(frames, sources, strict=True):
            queue = queues.get(source)
            if queue is None:
                queue = queues[source] = deque()
            if len(queue) >= limit:
                stats.tx_drops += 1
                continue
            queue.append(frame)
            self._backlog += 1

    def _drain(self) -> None:
        """Writable: finish the partial write, then send queued frames round-robin by source."""
        stats = self.stats
        while True:
            partial = self._partial
            if partial is not None:
                try:
                    written = self._write(partial)
                except (BlockingIOError, InterruptedError):
                    return
                except OSError as err:
                    self._lost(f"write failed: {err}")
                    return
                if written < len(partial):
                    self._partial = partial[written:]
                    return
                self._partial = None
            if not self._backlog:
                self._want_write(False)
                return
            batch: list[bytes] = []
            size = 0
            queues = self._queues
            while self._backlog and size < WRITE_BATCH_BYTES:
                for source in list(queues):  # one frame per source per round: fair
                    queue = queues[source]
                    frame = queue.popleft()
                    if not queue:
                        del queues[source]
                    batch.append(frame)
                    size += len(frame)
                    self._backlog -= 1
            stats.tx_msgs += len(batch)
            stats.tx_bytes += size
            self._partial = memoryview(b"".join(batch))

    def _want_write(self, wanted: bool) -> None:
        if wanted != self._write_wanted and self.connected:
            self._write_wanted = wanted
            self.host.watch(self._fileobj(), EVENT_READ | (EVENT_WRITE if wanted else 0), self._on_event)

    def _drop_pending(self) -> None:
        """Count everything still queued as dropped (on disconnect)."""
        self.stats.tx_drops += self._backlog + len(self._outbox)
        self._outbox = []
        self._outbox_sources = []
        self._queues.clear()
        self._backlog = 0
        self._partial = None
        self._write_wanted = False

    @property
    def queued_frames(self) -> int:
        return self._backlog

    # -- reading ---------------------------------------------------------------------
    def _on_event(self, mask: int) -> None:
        if mask & EVENT_WRITE:
            self._drain()
        if mask & EVENT_READ and self.connected:
            try:
                data = self._read()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as err:
                self._lost(f"read failed: {err}")
                return
            if not data:
                self._lost("closed by peer")
                return
            self.host.deliver(self.slot, data)

    def status(self) -> dict[str, object]:
        out = super().status()
        out["queued_frames"] = self._backlog
        if self.last_error:
            out["last_error"] = self.last_error
        return out


class _SocketStream(StreamEndpoint):
    def __init__(self, name: str, host: Host, queue_limit: int) -> None:
        super().__init__(name, host, queue_limit)
        self._sock: socket.socket | None = None

    def _fileobj(self) -> Any:
        return self._sock

    def _write(self, data: bytes | memoryview) -> int:
        assert self._sock is not None
        return self._sock.send(data)

    def _read(self) -> bytes:
        assert self._sock is not None
        return self._sock.recv(STREAM_READ_BYTES)

    def _close_socket(self) -> None:
        sock, self._sock = self._sock, None
        self.connected = False
        if sock is not None:
            self.host.unwatch(sock)
            sock.close()


def _tune_tcp(sock: socket.socket) -> None:
    sock.setblocking(False)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    # A bounded kernel buffer (no autotuning to megabytes) keeps the backlog in our
    # fair, counted queues, where a slow reader's excess is dropped, not in the kernel.
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, TCP_SNDBUF_BYTES)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)


class TcpClientEndpoint(_SocketStream):
    """``[TcpEndpoint]``: connects out; reconnects with exponential backoff up to ``RetryTimeout``."""

    kind = "tcp"

    def __init__(self, config: TcpEndpointConfig, host: Host) -> None:
        super().__init__(config.name, host, config.options.tx_queue_limit)
        self.config = config
        self._family, self._host_ip = _family(config.address)
        self._connecting = False
        self._retry: Timer | None = None
        self._delay_s = FIRST_RETRY_S
        self._closed = False
        self.connects = 0

    def describe(self) -> str:
        return f"tcp client {self.config.address}:{self.config.port}"

    def start(self) -> None:
        self._retry = None
        if self._closed:
            return
        try:
            sock = socket.socket(self._family, socket.SOCK_STREAM)
            _tune_tcp(sock)
        except OSError as err:
            self._schedule_retry(f"socket: {err}")
            return
        code = sock.connect_ex((self._host_ip, self.config.port))
        if code not in (0, errno.EINPROGRESS, errno.EWOULDBLOCK):
            sock.close()
            self._schedule_retry(os.strerror(code))
            return
        self._sock = sock
        self._connecting = True
        self.host.watch(sock, EVENT_WRITE, self._on_connect)

    def _on_connect(self, mask: int) -> None:
        sock = self._sock
        if sock is None:
            return
        code = sock.getsockopt(socket.SOL_SOCKET, socket.SO_ERROR)
        self._connecting = False
        if code != 0:
            self._close_socket()
            self._schedule_retry(os.strerror(code))
            return
        if connected_to_itself(sock):
            # (a SITL still starting would then find its port taken; seen on a loaded machine)
            self._close_socket()
            self._schedule_retry("connected to itself (nothing listening on the port yet)")
            return
        self.connected = True
        self.connects += 1
        self.last_error = ""
        self._delay_s = FIRST_RETRY_S
        self._write_wanted = False
        if self.slot >= 0:
            self.host.reset_stream(self.slot)
        self.host.watch(sock, EVENT_READ, self._on_event)
        _LOG.info("%s: connected to %s:%d", self.name, self.config.address, self.config.port)
        self.host.endpoint_connected(self)

    def _lost(self, reason: str) -> None:
        if not self.connected and not self._connecting:
            return
        _LOG.warning("%s: connection to %s:%d lost (%s)", self.name, self.config.address, self.config.port, reason)
        self._drop_pending()
        self._close_socket()
        self._connecting = False
        self._schedule_retry(reason)

    def _schedule_retry(self, reason: str) -> None:
        self.last_error = reason
        if self._closed:
            return
        if self.config.retry_timeout_s <= 0:
            _LOG.error(
                "%s: %s:%d: %s; RetryTimeout = 0, not reconnecting",
                self.name,
                self.config.address,
                self.config.port,
                reason,
            )
            return
        delay = min(self._delay_s, self.config.retry_timeout_s)
        _LOG.info(
            "%s: %s:%d unavailable (%s); retrying in %.2f s",
            self.name,
            self.config.address,
            self.config.port,
            reason,
            delay,
        )
        self._delay_s = min(self._delay_s * 2, self.config.retry_timeout_s)
        self._retry = self.host.call_later(delay, self.start)

    def close(self) -> None:
        self._closed = True
        if self._retry is not None:
            self._retry.cancel()
            self._retry = None
        self.flush()
        if self.connected and (self._partial is not None or self._backlog):
            self._drain()  # best effort, non-blocking
        self._close_socket()

    def status(self) -> dict[str, object]:
        out = super().status()
        out["connects"] = self.connects
        return out


class TcpConnection(_SocketStream):
    """A client accepted by the TCP server: a dynamic endpoint, removed when it disconnects."""

    kind = "tcp"
    dynamic = True

    def __init__(self, sock: socket.socket, peer: tuple[Any, ...], host: Host, queue_limit: int) -> None:
        super().__init__(f"tcp:{peer[0]}:{peer[1]}", host, queue_limit)
        self.peer = peer
        self._sock = sock

    def describe(self) -> str:
        return f"tcp server client {self.peer[0]}:{self.peer[1]}"

    def start(self) -> None:
        assert self._sock is not None
        _tune_tcp(self._sock)
        self.connected = True
        self.host.watch(self._sock, EVENT_READ, self._on_event)
        _LOG.info("TCP client %s:%d connected", self.peer[0], self.peer[1])

    def _lost(self, reason: str) -> None:
        if not self.connected:
            return
        _LOG.info("TCP client %s:%d gone (%s)", self.peer[0], self.peer[1], reason)
        self._drop_pending()
        self._close_socket()
        self.host.connection_lost(self)

    def close(self) -> None:
        self.flush()
        if self.connected and (self._partial is not None or self._backlog):
            self._drain()
        self._close_socket()


class TcpServer:
    """Listens on ``TcpServerPort``; every accepted client becomes a :class:`TcpConnection`."""

    def __init__(self, port: int, host: Host, on_client: Callable[[socket.socket, tuple[Any, ...]], None]) -> None:
        self.port = port
        self.host = host
        self._on_client = on_client
        self._sock: socket.socket | None = None
        self._retry: Timer | None = None
        self.last_error = ""

    def start(self) -> None:
        self._retry = None
        try:
            sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setblocking(False)
            sock.bind(("0.0.0.0", self.port))
            sock.listen(16)
        except OSError as err:
            sock.close()
            self.last_error = str(err)
            _LOG.error("TCP server: cannot listen on port %d: %s; retrying in 2 s", self.port, err)
            self._retry = self.host.call_later(2.0, self.start)
            return
        self._sock = sock
        self.last_error = ""
        self.host.watch(sock, EVENT_READ, self._on_accept)
        _LOG.info("TCP server listening on port %d", self.port)

    @property
    def listening(self) -> bool:
        return self._sock is not None

    def _on_accept(self, mask: int) -> None:
        if self._sock is None:
            return
        for _ in range(16):
            try:
                client, peer = self._sock.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as err:
                _LOG.warning("TCP server: accept: %s", err)
                return
            self._on_client(client, peer)

    def close(self) -> None:
        if self._retry is not None:
            self._retry.cancel()
        if self._sock is not None:
            self.host.unwatch(self._sock)
            self._sock.close()
            self._sock = None


# --------------------------------------------------------------------------------------
# Serial


def _import_serial() -> Any:
    try:
        import serial  # noqa: PLC0415 - optional dependency, imported only when a UART is configured
    except ImportError as err:
        msg = (
            "a UART endpoint is configured but pyserial is not installed; install it "
            "(pip install 'uav-mavlink-router[serial]' or pip install pyserial) or remove the [UartEndpoint] section"
        )
        raise SerialUnavailableError(msg) from err
    return serial


class UartEndpoint(StreamEndpoint):
    """``[UartEndpoint]``: a serial device (pyserial); bauds are cycled until MAVLink is heard."""

    kind = "uart"

    def __init__(self, config: UartEndpointConfig, host: Host) -> None:
        super().__init__(config.name, host, config.options.tx_queue_limit)
        self.config = config
        self._serial_mod = _import_serial()
        self._port: Any = None
        self._fd = -1
        self._baud_index = 0
        self._retry: Timer | None = None
        self._baud_timer: Timer | None = None
        self._rx_at_baud = 0
        self._closed = False

    @property
    def baud(self) -> int:
        return self.config.bauds[self._baud_index]

    def describe(self) -> str:
        return f"uart {self.config.device} @ {self.baud}"

    def start(self) -> None:
        self._retry = None
        if self._closed:
            return
        try:
            port = self._serial_mod.Serial(
                self.config.device, self.baud, rtscts=self.config.flow_control, timeout=0, write_timeout=0
            )
        except (OSError, ValueError, self._serial_mod.SerialException) as err:
            self.last_error = str(err)
            _LOG.error("%s: cannot open %s: %s; retrying in 5 s", self.name, self.config.device, err)
            self._retry = self.host.call_later(5.0, self.start)
            return
        self._port = port
        self._fd = port.fileno()
        os.set_blocking(self._fd, False)
        self.connected = True
        self.last_error = ""
        if self.slot >= 0:
            self.host.reset_stream(self.slot)
        self.host.watch(self._fd, EVENT_READ, self._on_event)
        _LOG.info("%s: opened %s at %d baud", self.name, self.config.device, self.baud)
        self.host.endpoint_connected(self)
        self._arm_baud_cycle()

    def _arm_baud_cycle(self) -> None:
        if len(self.config.bauds) > 1:
            self._rx_at_baud = self.stats.rx_msgs
            self._baud_timer = self.host.call_later(UART_BAUD_CYCLE_S, self._maybe_next_baud)

    def _maybe_next_baud(self) -> None:
        self._baud_timer = None
        if not self.connected:
            return
        if self.stats.rx_msgs > self._rx_at_baud:
            _LOG.info("%s: MAVLink heard at %d baud, keeping it", self.name, self.baud)
            return
        self._baud_index = (self._baud_index + 1) % len(self.config.bauds)
        _LOG.info("%s: no MAVLink at the previous rate; trying %d baud", self.name, self.baud)
        try:
            self._port.baudrate = self.baud
        except (OSError, ValueError, self._serial_mod.SerialException) as err:
            self._lost(f"cannot set baud rate: {err}")
            return
        self._arm_baud_cycle()

    def _fileobj(self) -> Any:
        return self._fd

    def _write(self, data: bytes | memoryview) -> int:
        return os.write(self._fd, data)

    def _read(self) -> bytes:
        return os.read(self._fd, STREAM_READ_BYTES)

    def _lost(self, reason: str) -> None:
        if not self.connected:
            return
        _LOG.warning("%s: %s: %s; reopening in 5 s", self.name, self.config.device, reason)
        self.last_error = reason
        self._drop_pending()
        self._close_port()
        if not self._closed:
            self._retry = self.host.call_later(5.0, self.start)

    def _close_port(self) -> None:
        if self._baud_timer is not None:
            self._baud_timer.cancel()
            self._baud_timer = None
        if self._fd >= 0:
            self.host.unwatch(self._fd)
        if self._port is not None:
            try:
                self._port.close()
            except (OSError, self._serial_mod.SerialException) as err:
                _LOG.debug("%s: close: %s", self.name, err)
        self._port = None
        self._fd = -1
        self.connected = False

    def close(self) -> None:
        self._closed = True
        if self._retry is not None:
            self._retry.cancel()
            self._retry = None
        self.flush()
        if self.connected and (self._partial is not None or self._backlog):
            self._drain()
        self._close_port()


def check_serial_available() -> None:
    """Raise :class:`SerialUnavailableError` now if pyserial is missing."""
    _import_serial()
