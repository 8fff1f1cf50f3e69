"""``connected_to_itself``: the TCP self-connection a retrying local client can fall into (real sockets)."""

from __future__ import annotations

import socket

from uav_common.shell.sockets import connected_to_itself


def test_a_socket_connected_to_its_own_port_is_detected() -> None:
    # what the kernel does when a retried connect to a port nobody listens on gets that port as its source
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.connect(sock.getsockname())  # TCP simultaneous open with itself
        assert connected_to_itself(sock)


def test_a_real_connection_and_an_unconnected_socket_are_not() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server, socket.create_connection(server.getsockname()) as client:
        peer, _ = server.accept()
        with peer:
            assert not connected_to_itself(client)
            assert not connected_to_itself(peer)
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as idle:
        assert not connected_to_itself(idle)
