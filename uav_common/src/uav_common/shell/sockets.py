"""Socket plumbing shared by every package's shells."""

from __future__ import annotations

import socket

__all__ = ["connected_to_itself"]


def connected_to_itself(sock: socket.socket) -> bool:
    """A TCP socket whose local and peer addresses are the same: a self-connection.

    A client that keeps retrying a local port inside the kernel's ephemeral range while nothing listens on it
    yet (a server still starting) can be given that very port as its source: the TCP simultaneous open then
    connects the socket to itself, and the server cannot bind its port when it comes up. Clients that retry
    local ports check this after each connect, and drop and retry such a connection.
    """
    try:
        return bool(sock.getsockname() == sock.getpeername())
    except OSError:  # not connected (any more)
        return False
