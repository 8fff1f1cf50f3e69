"""A MAVLink client's side of the causal lockstep: step markers on an open pymavlink connection (shell).

docs/lockstep.md, "MAVLink step markers": a client (the waypoint controller, the autopilot odometry node,
the mission manager's fault link; a test) that talks to the router, or straight to the SITL, says HELLO with
its lookahead once, then in every step ``k``:

1. :meth:`LockstepClient.read_step` reads its link up to the peer's STEP(``k``) marker and checks that the
   marker's count is the number of messages that came before it (since the peer's previous marker);
2. it handles those messages, sends what it has to send (every message sent through the connection is
   counted, whoever sends it);
3. :meth:`LockstepClient.end_step` sends STEP(``k``, ``t_k``, count).

Nothing here is timed by the wall clock except the watchdog: a wait logs what it waits for every
:data:`LOG_EVERY_S` wall seconds and gives up with :class:`~uav_common.errors.WaitTimeoutError` after
``watchdog_s``; it never returns without the marker. Protocol violations (a count that does not balance, a
marker for an unexpected step, a gap) raise :class:`~uav_common.lockstep.markers.MarkerError` naming the
link, the step and the counts.
"""

from __future__ import annotations

import contextlib
import logging
import select
import socket
import time
from collections.abc import Callable
from typing import Any

from uav_common.errors import StopRequestedError, WaitTimeoutError
from uav_common.lockstep.markers import (
    MESSAGE_TYPE,
    Marker,
    MarkerError,
    decode_payload,
    encode_payload,
)

__all__ = ["LOG_EVERY_S", "MAX_MESSAGES_PER_STEP", "RCVBUF_BYTES", "LockstepClient"]

log = logging.getLogger(__name__)

#: A wait logs what it waits for this often (wall seconds).
LOG_EVERY_S = 10.0
#: More messages than this before a marker: the peer is not in lockstep (or has lost its markers); an error,
#: instead of a read buffer that grows without bound.
MAX_MESSAGES_PER_STEP = 200_000
#: Receive buffer asked for on UDP sockets (the kernel caps it at net.core.rmem_max): a step's burst of
#: telemetry must never overflow it, since a lost datagram is a count that does not balance.
RCVBUF_BYTES = 4 << 20
_SELECT_S = 1.0
#: A marker addressed to another system/component (skipped: neither a message nor our marker).
_FOREIGN = Marker.end_of_step(0, 0, 0)


class LockstepClient:
    """Step markers on an open ``mavutil.mavlink_connection`` (UDP, TCP).

    Args:
        conn: the open connection (it keeps its own parser and sequence numbers).
        name: the link's name in logs and errors (default: the connection's address).
        target_system, target_component: who the markers are addressed to (the autopilot's ids, 1/1, whether
            the peer is the router or the SITL).
        clock: the wall clock of the watchdog.
        should_stop: asked while waiting (about once a second): True ends the wait with
            :class:`~uav_common.errors.StopRequestedError` (the program is shutting down).

    Every message sent through ``conn.mav`` from now on is counted (markers excluded): the connection's
    ``mav.send`` is wrapped.
    """

    def __init__(
        self,
        conn: Any,
        *,
        name: str | None = None,
        target_system: int = 1,
        target_component: int = 1,
        clock: Callable[[], float] = time.monotonic,
        should_stop: Callable[[], bool] | None = None,
    ) -> None:
        self.conn = conn
        self._should_stop = should_stop
        self.name = name or str(getattr(conn, "address", "MAVLink link"))
        self.target_system = target_system
        self.target_component = target_component
        self._clock = clock
        self._own = (int(conn.mav.srcSystem), int(conn.mav.srcComponent))
        self._send_uncounted: Callable[..., None] = conn.mav.send
        conn.mav.send = self._send_counted
        #: Messages sent through the connection since this client's previous marker.
        self.sent_since_marker = 0
        #: The step the peer registered this client at (None before :meth:`hello`).
        self.registered_step: int | None = None
        #: The last step read with :meth:`read_step` and the last one ended with :meth:`end_step`.
        self.last_read_step: int | None = None
        self.last_ended_step: int | None = None
        self.bad_frames = 0  # BAD_DATA seen (garbage or a CRC error: never counted as a message)
        self.markers_read = 0
        self.markers_sent = 0
        self._tune_socket()

    # ------------------------------------------------------------------ sending
    def _send_counted(self, mavmsg: Any, *args: Any, **kwargs: Any) -> None:
        self._send_uncounted(mavmsg, *args, **kwargs)
        self.sent_since_marker += 1

    def _send_marker(self, marker: Marker) -> None:
        msg = self.conn.mav.v2_extension_encode(
            0, self.target_system, self.target_component, MESSAGE_TYPE, encode_payload(marker)
        )
        self._send_uncounted(msg)
        self.markers_sent += 1

    def hello(self, lookahead_steps: int, *, watchdog_s: float = 120.0) -> int:
        """Say HELLO(``lookahead_steps``), discard everything until the peer's first STEP marker; return its step.

        A UDP server connection (``udpin:``) learns where to send only when something arrives: it first waits
        for any message (the router invites the endpoints it declares ``Lockstep = client`` with its own HELLO).

        Raises:
            MarkerError: a malformed marker, or HELLO called twice.
            WaitTimeoutError: no STEP within ``watchdog_s`` wall seconds.
        """
        if self.registered_step is not None:
            msg = f"{self.name}: lockstep HELLO already said (registered at step {self.registered_step})"
            raise MarkerError(msg)
        hello = Marker.hello(lookahead_steps)
        if not self._can_send():
            self._wait(
                lambda: True if self._read_one() is not None else None,
                f"a first message from the peer on {self.name} (to learn where to say HELLO)",
                watchdog_s,
            )
        self._send_marker(hello)
        self.sent_since_marker = 0
        log.info("%s: said %s; waiting for the peer's first STEP", self.name, hello.describe())
        discarded = 0
        first: list[Marker] = []

        def got_step() -> bool | None:
            nonlocal discarded
            msg = self._read_one()
            if msg is None:
                return None
            marker = self._marker(msg)
            if marker is not None and marker is not _FOREIGN and marker.is_step:
                first.append(marker)
                return True
            discarded += 1
            return False

        self._wait(got_step, f"the peer's first STEP marker on {self.name} after HELLO", watchdog_s)
        step = first[0].step
        self.registered_step = self.last_read_step = self.last_ended_step = step
        log.info("%s: registered at step %d (%d earlier messages discarded)", self.name, step, discarded)
        return step

    def end_step(self, step: int, t_sim_s: float) -> Marker:
        """Send STEP(``step``, ``t_sim_s``, messages sent since the previous marker); returns the marker sent.

        Raises:
            MarkerError: not registered, ``step`` is not the step after the last one ended, or it has not
                been read yet.
        """
        self._require_registered("end_step")
        expected = (self.last_ended_step or 0) + 1
        if step != expected:
            msg = f"{self.name}: end_step({step}) out of order: the next step to end is {expected}"
            raise MarkerError(msg)
        if self.last_read_step is None or step > self.last_read_step:
            msg = f"{self.name}: end_step({step}) before read_step({step}) (last step read: {self.last_read_step})"
            raise MarkerError(msg)
        marker = Marker.end_of_step(step, round(t_sim_s * 1e6), self.sent_since_marker)
        self._send_marker(marker)
        self.sent_since_marker = 0
        self.last_ended_step = step
        return marker

    # ------------------------------------------------------------------ reading
    def read_step(self, step: int, *, watchdog_s: float = 120.0) -> list[Any]:
        """Every non-marker message the peer sent before its STEP(``step``) marker (since its previous one).

        Raises:
            MarkerError: not registered, ``step`` is not the next step, the peer's marker is for another step
                (a gap, or a repeat), or its count is not the number of messages read.
            WaitTimeoutError: no marker within ``watchdog_s`` wall seconds.
        """
        self._require_registered("read_step")
        expected = (self.last_read_step or 0) + 1
        if step != expected:
            msg = f"{self.name}: read_step({step}) out of order: the next step to read is {expected}"
            raise MarkerError(msg)
        messages: list[Any] = []
        found: list[Marker] = []

        def got_marker() -> bool | None:
            msg = self._read_one()
            if msg is None:
                return None
            marker = self._marker(msg)
            if marker is None:
                messages.append(msg)
                if len(messages) > MAX_MESSAGES_PER_STEP:
                    text = (
                        f"{self.name}: more than {MAX_MESSAGES_PER_STEP} messages without the peer's STEP({step}) "
                        "marker: is the peer in lockstep (router Lockstep = true, SITL time.mode lockstep)?"
                    )
                    raise MarkerError(text)
                return False
            if marker is _FOREIGN:
                return False
            if marker.is_hello:
                log.debug("%s: ignored the peer's %s during step %d", self.name, marker.describe(), step)
                return False
            found.append(marker)
            return True

        self._wait(got_marker, f"the peer's STEP({step}) marker on {self.name}", watchdog_s, progress=messages)
        marker = found[0]
        if marker.step != step:
            what = "a gap" if marker.step > step else "a repeated or old step"
            msg = (
                f"{self.name}: expected the peer's STEP({step}) marker, got {marker.describe()} ({what}; "
                f"{len(messages)} messages before it)"
            )
            raise MarkerError(msg)
        if marker.count != len(messages):
            msg = (
                f"{self.name}: step {step}: the peer says it sent {marker.count} messages, {len(messages)} were "
                f"received ({self.bad_frames} bad frames seen so far): a message was lost or duplicated"
            )
            raise MarkerError(msg)
        self.last_read_step = step
        self.markers_read += 1
        return messages

    def _marker(self, msg: Any) -> Marker | None:
        """The marker in ``msg`` (None for any other message); a marker addressed to someone else on the same
        port is :data:`_FOREIGN` (not ours, and not counted by its sender either)."""
        if msg.get_type() != "V2_EXTENSION" or msg.message_type != MESSAGE_TYPE:
            return None
        marker = decode_payload(bytes(msg.payload), message_type=msg.message_type)
        if marker is None:
            return None
        target = (int(msg.target_system), int(msg.target_component))
        if target[0] not in (0, self._own[0]) or target[1] not in (0, self._own[1]):
            log.debug("%s: ignored %s addressed to %d/%d", self.name, marker.describe(), *target)
            return _FOREIGN
        return marker

    def _read_one(self) -> Any | None:
        """The next message (BAD_DATA is counted and skipped), or None when nothing complete is waiting."""
        while True:
            msg = self.conn.recv_msg()
            if msg is None:
                return None
            if msg.get_type() == "BAD_DATA":
                self.bad_frames += 1
                continue
            return msg

    def _wait(
        self, step: Callable[[], bool | None], what: str, watchdog_s: float, *, progress: list[Any] | None = None
    ) -> None:
        """Call ``step()`` until it returns True (done); False: it read something, call it again at once;
        None: nothing was waiting, sleep in ``select`` until the socket is readable (see the module doc)."""
        start = self._clock()
        next_log = start + LOG_EVERY_S
        while True:
            outcome = step()
            if outcome:
                return
            now = self._clock()
            if now >= next_log:
                got = "" if progress is None else f" ({len(progress)} messages so far)"
                log.warning("%s: still waiting for %s after %.0f s%s", self.name, what, now - start, got)
                next_log = now + LOG_EVERY_S
            if now - start >= watchdog_s:
                raise WaitTimeoutError(what, watchdog_s, None if progress is None else len(progress))
            if self._should_stop is not None and self._should_stop():
                msg = f"{self.name}: stopped while waiting for {what}"
                raise StopRequestedError(msg)
            if outcome is not None:
                continue
            fd = self._fileno()
            if fd is None:
                time.sleep(0.01)
                continue
            try:
                select.select([fd], [], [], min(_SELECT_S, max(0.0, watchdog_s - (now - start))))
            except (OSError, ValueError):  # closed and reopened meanwhile
                time.sleep(0.01)

    # ------------------------------------------------------------------ helpers
    def _require_registered(self, what: str) -> None:
        if self.registered_step is None:
            msg = f"{self.name}: {what} before hello(): say HELLO first"
            raise MarkerError(msg)

    def _socket(self) -> socket.socket | None:
        port = getattr(self.conn, "port", None)
        return port if isinstance(port, socket.socket) else None

    def _fileno(self) -> int | None:
        sock = self._socket()
        if sock is not None:
            return sock.fileno()
        fd = getattr(self.conn, "fd", None)
        return fd if isinstance(fd, int) else None

    def _can_send(self) -> bool:
        """A ``udpin:`` connection sends only to the addresses it has heard from."""
        if getattr(self.conn, "udp_server", False):
            return bool(getattr(self.conn, "clients", ()) or getattr(self.conn, "last_address", None))
        return True

    def _tune_socket(self) -> None:
        sock = self._socket()
        if sock is not None and sock.type == socket.SOCK_DGRAM:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
