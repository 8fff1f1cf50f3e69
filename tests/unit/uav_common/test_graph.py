"""unconnected_subscriptions: which subscriptions have not yet connected to their publishers."""

from __future__ import annotations

from typing import Any

from uav_common.ros.graph import bus_info_over_xmlrpc, node_uri_lookup, unconnected_subscriptions

PUBS = [("/cam/depth", ["/sim_bridge"]), ("/cam/color", ["/sim_bridge"]), ("/odom", ["/sim_bridge", "/replayer"])]
SUBS = [("/cam/depth", ["/record", "/map_server"]), ("/cam/color", ["/record"]), ("/odom", ["/record"])]
URIS = {"/sim_bridge": "http://host:4001", "/replayer": "http://host:4002"}


def info(*conns: tuple[str, str, str, bool]) -> list[list[Any]]:
    """getBusInfo rows: (id, other end, direction, transport, topic, connected, info)."""
    return [[i, end, way, "TCPROS", topic, ok, ""] for i, (way, topic, end, ok) in enumerate(conns)]


def check(bus: dict[str, list[list[Any]] | None], **kw: Any) -> list[str]:
    return unconnected_subscriptions(
        PUBS, SUBS, subscriber_nodes={"/record"}, bus_info=bus.get, node_uri=lambda n: URIS.get(n, n), **kw
    )


#: both ends of every link of /record, named the ways roscpp (by node name) and rospy (by XML-RPC URI,
#: trailing slash or not) name them; /replayer's /odom link is dialled but not yet taken
RECORD = info(
    ("i", "/cam/depth", "/sim_bridge", True),
    ("i", "/cam/color", "http://host:4001/", True),
    ("i", "/odom", "http://host:4001", True),
    ("i", "/odom", "/replayer", True),
)
SIM_BRIDGE = info(
    ("o", "/cam/depth", "/record", True), ("o", "/cam/color", "/record", True), ("o", "/odom", "/record", True)
)
REPLAYER = info(("o", "/odom", "/map_server", True))


def test_registered_but_not_connected_is_missing() -> None:
    assert check({"/record": info(), "/sim_bridge": info(), "/replayer": info()}) == [
        "/record /cam/color <- /sim_bridge",
        "/record /cam/depth <- /sim_bridge",
        "/record /odom <- /replayer",
        "/record /odom <- /sim_bridge",
    ]


def test_a_link_counts_once_both_ends_list_it() -> None:
    bus = {"/record": RECORD, "/sim_bridge": SIM_BRIDGE, "/replayer": REPLAYER}
    assert check(bus) == ["/record /odom <- /replayer"]  # the subscriber has dialled, the publisher not taken it
    assert check(bus, publisher_nodes={"/sim_bridge"}) == []
    assert check(bus, topics={"/cam/depth", "/cam/color"}) == []
    assert check({**bus, "/replayer": info(("o", "/odom", "/record", True))}) == []
    # the publisher took it, but the subscriber side is not up (or only opened)
    assert check({**bus, "/record": info(("i", "/cam/depth", "/sim_bridge", False))}, topics={"/cam/depth"}) == [
        "/record /cam/depth <- /sim_bridge"
    ]


def test_an_unreachable_node_counts_as_unconnected() -> None:
    assert check({"/record": None, "/sim_bridge": SIM_BRIDGE}, topics={"/cam/depth"}) == ["/record /cam/depth <- ?"]
    assert check({"/record": RECORD, "/sim_bridge": None}, topics={"/cam/depth"}) == [
        "/record /cam/depth <- /sim_bridge"
    ]
    assert check({}, topics={"/nothing"}) == []  # nobody publishes it: nothing to wait for


def test_bus_info_over_xmlrpc_gives_none_for_a_dead_node() -> None:
    ask = bus_info_over_xmlrpc("/me", lambda _n: "http://127.0.0.1:9", timeout_s=0.5)
    assert ask("/gone") is None

    def no_such_node(_n: str) -> str:
        raise OSError("unknown node")

    assert bus_info_over_xmlrpc("/me", no_such_node)("/x") is None


def test_node_uri_lookup_asks_once_and_falls_back_to_the_name() -> None:
    asked: list[str] = []

    def lookup(node: str) -> str:
        asked.append(node)
        if node == "/gone":
            raise OSError("unknown node")
        return f"http://host:1/{node.strip('/')}/"

    uri = node_uri_lookup(lookup)
    assert uri("/a") == "http://host:1/a"
    assert uri("/a") == "http://host:1/a"
    assert uri("/gone") == "/gone"
    assert asked == ["/a", "/gone"]
    assert bus_info_over_xmlrpc("/me", uri)("/gone") is None  # a name is no URI: not connected
