"""Routing rules (mavlink-router's Endpoint::accept_msg), as pure tests of RoutingTable."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from mavlink_router.core.frames import NO_TARGET
from mavlink_router.core.routing import AcceptState, Filters, Learned, RoutingTable, accept_msg

PING = 4
HEARTBEAT = 0


def table(n: int, **kwargs: object) -> RoutingTable:
    rt = RoutingTable(**kwargs)  # type: ignore[arg-type]
    for _ in range(n):
        rt.add_endpoint()
    return rt


def test_broadcast_goes_to_every_other_endpoint_even_unknown_ones() -> None:
    rt = table(4)
    rt.learn(0, 1, 1)
    dests, filtered = rt.route(0, HEARTBEAT, 1, 1, NO_TARGET, NO_TARGET)
    assert dests == (1, 2, 3)
    assert filtered == ()
    assert rt.route(0, PING, 1, 1, 0, 0)[0] == (1, 2, 3)  # target_system 0 = broadcast


def test_targeted_message_goes_only_where_the_target_lives() -> None:
    rt = table(3)
    rt.learn(0, 255, 190)  # GCS behind 0
    rt.learn(1, 1, 1)  # autopilot behind 1
    rt.learn(2, 245, 190)  # MAVSDK behind 2
    assert rt.route(0, 76, 255, 190, 1, 1)[0] == (1,)
    assert rt.route(1, 77, 1, 1, 255, 190)[0] == (0,)  # COMMAND_ACK back to the GCS only
    assert rt.route(1, 77, 1, 1, 245, 190)[0] == (2,)


def test_message_to_an_unseen_system_reaches_nobody_and_is_counted() -> None:
    rt = table(3)
    rt.learn(0, 2, 1)
    assert rt.route(0, PING, 2, 1, 100, 1) == ((), ())
    assert rt.msg_to_unknown == 1
    rt.learn(1, 100, 1)  # the target speaks: now it is known
    assert rt.route(0, PING, 2, 1, 100, 1)[0] == (1,)
    assert rt.msg_to_unknown == 1


def test_component_broadcast_goes_to_endpoints_that_saw_the_system() -> None:
    rt = table(3)
    rt.learn(1, 1, 1)
    rt.learn(2, 1, 191)
    assert rt.route(0, 76, 255, 190, 1, 0)[0] == (1, 2)


def test_exact_component_is_required_unless_ignore_comp_id() -> None:
    rt = RoutingTable()
    a = rt.add_endpoint()
    b = rt.add_endpoint()
    c = rt.add_endpoint()
    d = rt.add_endpoint(ignore_comp_id=True)
    rt.learn(b, 1, 1)
    rt.learn(c, 1, 191)
    rt.learn(d, 1, 200)
    assert rt.route(a, 76, 255, 190, 1, 1)[0] == (b, d)
    assert rt.route(a, 76, 255, 190, 1, 191)[0] == (c, d)
    assert rt.route(a, 76, 255, 190, 1, 2)[0] == (d,)


def test_nothing_is_echoed_to_its_source() -> None:
    rt = table(2)
    rt.learn(0, 1, 1)
    rt.learn(0, 255, 190)
    assert rt.route(0, 76, 255, 190, 1, 1) == ((), ())  # target lives behind the source itself
    assert rt.route(0, HEARTBEAT, 1, 1, NO_TARGET, NO_TARGET)[0] == (1,)


def test_loop_prevention_endpoint_that_saw_the_source_is_skipped() -> None:
    # Two links to the same vehicle (e.g. telemetry radio + Wi-Fi): traffic from the
    # vehicle on one link must not be sent back to it over the other.
    rt = table(3)
    rt.learn(0, 1, 1)
    rt.learn(1, 1, 1)
    assert rt.route(0, HEARTBEAT, 1, 1, NO_TARGET, NO_TARGET)[0] == (2,)


def test_out_filters_drop_and_are_reported() -> None:
    rt = RoutingTable()
    src = rt.add_endpoint()
    only_hb = rt.add_endpoint(out_filter=Filters(allow_msg_ids=frozenset({HEARTBEAT})))
    no_sys7 = rt.add_endpoint(out_filter=Filters(block_src_systems=frozenset({7})))
    only_comp1 = rt.add_endpoint(out_filter=Filters(allow_src_comps=frozenset({1})))
    assert rt.route(src, HEARTBEAT, 7, 1, NO_TARGET, NO_TARGET) == ((only_hb, only_comp1), (no_sys7,))
    assert rt.route(src, PING, 8, 2, 0, 0) == ((no_sys7,), (only_hb, only_comp1))
    assert rt.msg_to_unknown == 0


def test_filters_each_list() -> None:
    f = Filters(
        allow_msg_ids=frozenset({1, 2}),
        block_msg_ids=frozenset({2}),
        allow_src_systems=frozenset({10}),
        block_src_comps=frozenset({5}),
    )
    assert f.allows(1, 10, 1)
    assert not f.allows(2, 10, 1)  # blocked beats allowed
    assert not f.allows(3, 10, 1)
    assert not f.allows(1, 11, 1)
    assert not f.allows(1, 10, 5)
    assert Filters().empty
    assert not f.empty


def test_group_members_share_what_they_learned() -> None:
    rt = RoutingTable()
    gcs = rt.add_endpoint()
    radio = rt.add_endpoint(group="vehicle")
    wifi = rt.add_endpoint(group="vehicle")
    rt.learn(radio, 1, 1)
    assert rt.learned(wifi).has_pair(1, 1)
    # The GCS's command reaches the vehicle over both links; the vehicle's own traffic
    # on one link is not reflected into the other.
    assert rt.route(gcs, 76, 255, 190, 1, 1)[0] == (radio, wifi)
    assert rt.route(radio, HEARTBEAT, 1, 1, NO_TARGET, NO_TARGET)[0] == (gcs,)


def test_sniffer_endpoint_gets_everything() -> None:
    rt = RoutingTable(sniffer_sysid=99)
    a, b, sniffer = rt.add_endpoint(), rt.add_endpoint(), rt.add_endpoint()
    rt.learn(b, 1, 1)
    assert rt.route(a, 76, 255, 190, 1, 1)[0] == (b,)
    rt.learn(sniffer, 99, 1)
    assert rt.route(a, 76, 255, 190, 1, 1)[0] == (b, sniffer)


def test_removed_endpoint_is_forgotten_and_slot_reused() -> None:
    rt = table(3)
    rt.learn(2, 1, 1)
    assert rt.route(0, 76, 255, 190, 1, 1)[0] == (2,)
    rt.remove_endpoint(2)
    assert rt.route(0, 76, 255, 190, 1, 1)[0] == ()
    assert rt.add_endpoint() == 2
    assert not rt.learned(2).pairs


def test_learn_reports_new_pairs_only() -> None:
    rt = table(1)
    assert rt.learn(0, 1, 1)
    assert not rt.learn(0, 1, 1)
    assert rt.learned(0).sorted_pairs() == [(1, 1)]


def reference_route(learned: list[set[tuple[int, int]]], src: int, msg: tuple[int, int, int, int]) -> tuple[int, ...]:
    """Straight transcription of Endpoint::accept_msg, no caching, no bit tricks."""
    src_sys, src_comp, tsys, tcomp = msg
    out = []
    for index, pairs in enumerate(learned):
        systems = {s for s, _ in pairs}
        if index == src or (src_sys, src_comp) in pairs:
            continue
        if tsys in (0, -1) or (tcomp > 0 and (tsys, tcomp) in pairs) or (tcomp in (0, -1) and tsys in systems):
            out.append(index)
    return tuple(out)


ids = st.integers(0, 3)
targets = st.sampled_from([-1, 0, 1, 2, 3])


@settings(max_examples=300, deadline=None)
@given(
    events=st.lists(
        st.tuples(st.integers(0, 3), st.booleans(), ids, ids, targets, targets),
        min_size=1,
        max_size=60,
    )
)
def test_cached_table_matches_the_reference_rules(events: list[tuple[int, bool, int, int, int, int]]) -> None:
    """Interleave learning and routing: the cached decisions always equal the rules."""
    rt = table(4)
    learned: list[set[tuple[int, int]]] = [set() for _ in range(4)]
    for src, learn_first, sysid, compid, tsys, tcomp in events:
        if learn_first:
            rt.learn(src, sysid, compid)
            learned[src].add((sysid, compid))
        assert rt.route(src, PING, sysid, compid, tsys, tcomp)[0] == reference_route(
            learned, src, (sysid, compid, tsys, tcomp)
        )


def test_accept_msg_states() -> None:
    seen = Learned({1 << 8 | 1}, {1})
    kwargs = {"msgid": PING, "src_sys": 255, "src_comp": 190}
    assert accept_msg(seen, None, target_sys=1, target_comp=1, **kwargs) is AcceptState.ACCEPTED
    assert accept_msg(seen, None, target_sys=2, target_comp=1, **kwargs) is AcceptState.REJECTED
    blocked = Filters(block_msg_ids=frozenset({PING}))
    assert accept_msg(seen, blocked, target_sys=1, target_comp=1, **kwargs) is AcceptState.FILTERED
    assert accept_msg(seen, None, msgid=PING, src_sys=1, src_comp=1, target_sys=0, target_comp=0) is (
        AcceptState.REJECTED
    )
