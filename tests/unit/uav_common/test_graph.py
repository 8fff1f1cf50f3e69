"""unconnected_subscriptions: which subscriptions have not yet connected to their publishers."""

from __future__ import annotations

from typing import Any

from uav_common.graph import bus_info_over_xmlrpc, unconnected_subscriptions

PUBS = [("/cam/depth", ["/sim_bridge"]), ("/cam/color", ["/sim_bridge"]), ("/odom", ["/sim_bridge", "/replayer"])]
SUBS = [("/cam/depth", ["/record", "/map_server"]), ("/cam/color", ["/record"]), ("/odom", ["/record"])]
URIS = {"/sim_bridge": "http://host:4001", "/replayer": "http://host:4002"}


def info(*conns: tuple[str, str, bool]) -> list[list[Any]]:
    """getBusInfo rows: (id, other end, direction, transport, topic, connected, info)."""
    return [[i, end, "i", "TCPROS", topic, ok, ""] for i, (topic, end, ok) in enumerate(conns)]


def check(bus: dict[str, list[list[Any]] | None], **kw: Any) -> list[str]:
    return unconnected_subscriptions(
        PUBS, SUBS, subscriber_nodes={"/record"}, bus_info=bus.get, node_uri=lambda n: URIS.get(n, n), **kw
    )


def test_registered_but_not_connected_is_missing() -> None:
    assert check({"/record": info()}) == [
        "/record /cam/color <- /sim_bridge",
        "/record /cam/depth <- /sim_bridge",
        "/record /odom <- /replayer",
        "/record /odom <- /sim_bridge",
    ]


def test_connections_named_by_node_or_by_uri_count() -> None:
    # roscpp names the other end by node name, rospy by its XML-RPC URI (trailing slash or not)
    bus = {
        "/record": info(
            ("/cam/depth", "/sim_bridge", True),
            ("/cam/color", "http://host:4001/", True),
            ("/odom", "http://host:4001", True),
            ("/odom", "/replayer", False),  # opened, not yet connected
        )
    }
    assert check(bus) == ["/record /odom <- /replayer"]
    assert check(bus, publisher_nodes={"/sim_bridge"}) == []
    assert check(bus, topics={"/cam/depth", "/cam/color"}) == []


def test_an_unreachable_subscriber_counts_as_unconnected() -> None:
    assert check({"/record": None}, topics={"/cam/depth"}) == ["/record /cam/depth <- ?"]
    assert check({}, topics={"/nothing"}) == []  # nobody publishes it: nothing to wait for


def test_bus_info_over_xmlrpc_gives_none_for_a_dead_node() -> None:
    ask = bus_info_over_xmlrpc("/me", lambda _n: "http://127.0.0.1:9", timeout_s=0.5)
    assert ask("/gone") is None

    def no_such_node(_n: str) -> str:
        raise OSError("unknown node")

    assert bus_info_over_xmlrpc("/me", no_such_node)("/x") is None
