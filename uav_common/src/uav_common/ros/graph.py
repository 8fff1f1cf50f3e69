"""Which subscriptions of a ROS graph are not connected yet (pure: the master and the nodes are passed in).

Registering with the master is not receiving: a subscriber gets messages only once it has opened a
connection to each publisher of its topic, a moment later (longer on a busy machine). Whoever must not
miss the first messages (a recorder, a deterministic start) waits until :func:`unconnected_subscriptions`
is empty. The answer comes from each subscriber's own ``getBusInfo``, the same record ``rosnode info``
shows.
"""

from __future__ import annotations

import xmlrpc.client
from collections.abc import Callable, Collection, Iterable, Sequence
from typing import Any

__all__ = ["bus_info_over_xmlrpc", "node_uri_lookup", "unconnected_subscriptions"]

#: ``getSystemState``'s publishers or subscribers: ``[(topic, [node, ...]), ...]``.
TopicNodes = Iterable[tuple[str, Iterable[str]]]


def unconnected_subscriptions(
    publishers: TopicNodes,
    subscribers: TopicNodes,
    *,
    subscriber_nodes: Collection[str],
    bus_info: Callable[[str], Sequence[Sequence[Any]] | None],
    node_uri: Callable[[str], str],
    publisher_nodes: Collection[str] | None = None,
    topics: Collection[str] | None = None,
) -> list[str]:
    """``"<subscriber> <topic> <- <publisher>"`` for each missing connection, sorted; empty when all are up.

    A connection counts once both ends list it: the subscriber (an inbound link from the publisher) and
    the publisher (an outbound link to the subscriber). roscpp lists the subscriber's end as soon as it
    has dialled; messages flow only once the publisher has taken the connection, which a busy rospy
    publisher (its threads waiting for the GIL) did seconds later.

    Args:
        publishers, subscribers: the master's ``getSystemState()[0]`` and ``[1]``.
        subscriber_nodes: the subscribers to check.
        bus_info: a node's ``getBusInfo`` connection list, or ``None`` if the node could not be asked
            (then the connections it should hold count as missing).
        node_uri: a node's XML-RPC URI (rospy names the other end of a connection by it, roscpp by name).
        publisher_nodes: only connections to these publishers count (``None``: every publisher).
        topics: only these topics (``None``: every topic).
    """
    by_topic = {topic: set(nodes) for topic, nodes in publishers}
    infos: dict[str, Sequence[Sequence[Any]] | None] = {}

    def ends(node: str, direction: str, topic: str) -> set[str] | None:
        """The other ends of ``node``'s connected links on ``topic`` in ``direction``; None: not asked."""
        if node not in infos:
            infos[node] = bus_info(node)
        info = infos[node]
        if info is None:
            return None
        # (id, other end, direction, transport, topic, connected, ...)
        return {str(c[1]).rstrip("/") for c in info if len(c) > 5 and c[2] == direction and c[4] == topic and c[5]}

    def linked(other_ends: set[str] | None, node: str) -> bool:
        return other_ends is not None and (node in other_ends or node_uri(node) in other_ends)

    missing: list[str] = []
    for topic, nodes in subscribers:
        if topics is not None and topic not in topics:
            continue
        want = by_topic.get(topic, set())
        if publisher_nodes is not None:
            want &= set(publisher_nodes)
        for sub in nodes:
            if sub not in subscriber_nodes:
                continue
            inbound = ends(sub, "i", topic)
            for pub in sorted(want):
                if not (linked(inbound, pub) and linked(ends(pub, "o", topic), sub)):
                    missing.append(f"{sub} {topic} <- {pub if inbound is not None else '?'}")
    return sorted(missing)


def node_uri_lookup(lookup_node: Callable[[str], Any]) -> Callable[[str], str]:
    """The ``node_uri`` of :func:`unconnected_subscriptions` from the master's ``lookupNode``: each node's
    XML-RPC URI without a trailing slash, asked once; the node's name if the master does not know it (then
    its ``getBusInfo`` fails and its connections count as missing)."""
    uris: dict[str, str] = {}

    def uri(node: str) -> str:
        if node not in uris:
            try:
                uris[node] = str(lookup_node(node)).rstrip("/")
            except Exception:  # rosgraph.MasterError (unknown node) or OSError (no master): not up yet
                return node
        return uris[node]

    return uri


def bus_info_over_xmlrpc(
    caller_id: str, node_uri: Callable[[str], str], timeout_s: float = 2.0
) -> Callable[[str], Sequence[Sequence[Any]] | None]:
    """The ``bus_info`` of :func:`unconnected_subscriptions` for a live graph: asks each node over XML-RPC
    (ROS's slave API, no ROS import); ``None`` when the node cannot be reached or answers an error."""

    def ask(node: str) -> Sequence[Sequence[Any]] | None:
        try:
            uri = node_uri(node)
            transport = _TimeoutTransport(timeout_s) if uri.startswith("http://") else None
            reply: Any = xmlrpc.client.ServerProxy(uri, transport=transport).getBusInfo(caller_id)
        except Exception:  # unreachable, unknown to the master, or a fault: not connected yet
            return None
        if not isinstance(reply, list | tuple) or len(reply) < 3 or reply[0] != 1:
            return None
        return list(reply[2])

    return ask


class _TimeoutTransport(xmlrpc.client.Transport):
    """HTTP transport with a socket timeout (a stopped node must not hang the caller)."""

    def __init__(self, timeout_s: float) -> None:
        super().__init__()
        self._timeout_s = timeout_s

    def make_connection(self, host: Any) -> Any:
        conn = super().make_connection(host)
        conn.timeout = self._timeout_s
        return conn
