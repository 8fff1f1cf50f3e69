"""The router's lockstep scheduler (core/lockstep.py): markers in, a deterministic schedule out; and its keys.

The scheduler is pure: these tests play the autopilot's and the clients' markers in different interleavings
and check that what is released, delivered and sent upstream depends on the steps and seeds only.
"""

from __future__ import annotations

import random

import pytest
from mr_build import TABLE, pack
from pymavlink.dialects.v20 import ardupilotmega as v2

from mavlink_router.core.config import LockstepRole, parse_config_text
from mavlink_router.core.frames import FrameParser
from mavlink_router.core.impairment import ImpairmentConfig, LinkImpairment
from mavlink_router.core.lockstep import (
    Deliver,
    LockstepScheduler,
    MarkerToClient,
    MarkerUpstream,
    Release,
    marker_frame,
    marker_in,
)
from mavlink_router.errors import ConfigError, LockstepError
from uav_common.lockstep.markers import MESSAGE_TYPE, Marker, encode_payload

STEP_US = 100_000  # 0.1 s steps


def step(g: int, count: int = 0) -> Marker:
    return Marker.end_of_step(g, g * STEP_US, count)


def upstream_steps(actions: list[object]) -> list[int]:
    return [a.step for a in actions if isinstance(a, MarkerUpstream)]


def released(actions: list[object]) -> list[tuple[str, tuple[object, ...]]]:
    return [(a.client, a.frames) for a in actions if isinstance(a, Release)]


def synced(*clients: tuple[str, int]) -> LockstepScheduler[str, str]:
    """A scheduler synced at step 0 with these (name, lookahead) clients registered."""
    s: LockstepScheduler[str, str] = LockstepScheduler()
    s.autopilot_marker(step(0))
    for name, lookahead in clients:
        (answer,) = s.client_hello(name, Marker.hello(lookahead), (1, 191))
        assert answer == MarkerToClient(name, step(0), (1, 191))
    return s


def test_plain_lockstep_answers_every_autopilot_step_at_once() -> None:
    s = synced()
    for g in range(1, 6):
        for _ in range(g):
            s.autopilot_frame()
        assert s.autopilot_marker(step(g, count=g)) == []
        assert s.upstream() == [MarkerUpstream(g, g * STEP_US)]
    assert s.t_sim_s == pytest.approx(0.5)
    assert s.steps_seen == 5


def test_the_autopilot_count_and_order_are_checked() -> None:
    s = synced()
    s.autopilot_frame()
    with pytest.raises(LockstepError, match="says it sent 2 messages in step 1, 1 were received"):
        s.autopilot_marker(step(1, count=2))
    s = synced()
    with pytest.raises(LockstepError, match=r"expected its STEP\(1\)"):
        s.autopilot_marker(step(2))


def test_gating_by_lookahead() -> None:
    """Upstream STEP(g) waits for each client's STEP(g + 1 - L): L = 1 the tightest loop, L = 2 one step of slack."""
    s = synced(("a_tight", 1), ("b_slack", 2))
    s.autopilot_marker(step(1))
    assert upstream_steps(s.upstream()) == []  # a_tight has not ended step 1
    assert upstream_steps(s.client_marker("b_slack", step(1))) == []
    assert s.waiting_for() == ["a_tight (needs its STEP(1), has ended 0)"]
    assert upstream_steps(s.client_marker("a_tight", step(1))) == [1]
    s.autopilot_marker(step(2))
    # b_slack has ended 1 = 2 + 1 - 2: enough; a_tight must end 2
    assert upstream_steps(s.upstream()) == []
    assert upstream_steps(s.client_marker("a_tight", step(2))) == [2]
    s.autopilot_marker(step(3))
    assert upstream_steps(s.client_marker("a_tight", step(3))) == []  # now b_slack (ended 1) holds step 3 up
    assert upstream_steps(s.client_marker("b_slack", step(2))) == [3]


def offered_frames(schedule: list[tuple[str, int, int]], lookahead: int = 1, **link: float) -> dict[str, int]:
    """Play a client that sends frame ``f<j>`` in its step j = 1..10 over a lossy inbound link, with the
    autopilot's and the client's markers interleaved as ``schedule`` says; returns frame -> the upstream STEP it
    was released before."""
    s = synced()
    imp: LinkImpairment[object] = LinkImpairment(ImpairmentConfig(**link), random.Random(5).random)  # type: ignore[arg-type]
    s.client_hello("c", Marker.hello(lookahead), (1, 191), link_in=imp)
    out: dict[str, int] = {}

    def note(actions: list[object]) -> None:
        pending: list[str] = []
        for action in actions:
            if isinstance(action, Release):
                pending += list(action.frames)
            elif isinstance(action, MarkerUpstream):
                out.update(dict.fromkeys(pending, action.step))
                pending = []

    for who, g, _ in schedule:
        if who == "ap":
            s.autopilot_marker(step(g))
            note(s.upstream())
        else:
            s.client_frame("c", f"f{g}")
            note(s.client_marker("c", step(g, count=1)))
    return out


def interleavings() -> list[list[tuple[str, int, int]]]:
    """The autopilot up to step 20; the client ends step j at once after the autopilot's STEP(j), or late
    (right before the autopilot's next STEP can go on)."""
    eager = [e for g in range(1, 21) for e in (("ap", g, 0), ("c", g, 0))]
    late = [("ap", 1, 0)] + [e for g in range(2, 21) for e in (("c", g - 1, 0), ("ap", g, 0))] + [("c", 20, 0)]
    return [eager, late]


@pytest.mark.parametrize("lookahead", [1, 2])
def test_a_delay_counts_in_simulated_steps_whatever_the_interleaving(lookahead: int) -> None:
    """A 250 ms delay with 0.1 s steps: a client frame of step j reaches the autopilot just before the router's
    STEP(j + 3) (t_j + 0.25 <= t_(j+3)), the third upstream marker after the one that ends its step."""
    results = [offered_frames(schedule, lookahead, delay_ms=250.0) for schedule in interleavings()]
    assert results[0] == results[1]
    assert results[0] == {f"f{j}": j + 3 for j in range(1, 18)}


def test_a_delay_on_a_step_boundary_is_not_one_step_late() -> None:
    # t_1 + 0.2 s = 0.30000000000000004 in floating point: still due at t_3 = 0.3
    assert offered_frames(interleavings()[0], delay_ms=200.0)["f1"] == 3


def test_zero_delay_releases_at_the_lookahead() -> None:
    assert offered_frames(interleavings()[0], lookahead=1)["f4"] == 4  # the autopilot takes it before grant 5
    assert offered_frames(interleavings()[1], lookahead=2)["f4"] == 5  # before grant 6


def test_seeded_losses_and_jitter_are_the_same_in_every_run_and_interleaving() -> None:
    link = {"loss_pct": 30.0, "delay_ms": 30.0, "jitter_ms": 180.0, "reorder_pct": 20.0}
    runs = [offered_frames(schedule, **link) for schedule in interleavings() for _ in range(2)]
    assert all(run == runs[0] for run in runs)
    assert 3 <= len(runs[0]) <= 17  # some lost
    # the same as the link's seeded generator decides, frame by frame in arrival order
    imp: LinkImpairment[object] = LinkImpairment(ImpairmentConfig(**link), random.Random(5).random)  # type: ignore[arg-type]
    fates = {f"f{j}": imp.judge(j * 0.1) for j in range(1, 21)}
    assert {f for f, fate in fates.items() if fate is not None and fate[1] <= 2.0 + 1e-6} == set(runs[0])


def test_clients_are_released_in_name_order_and_each_in_due_order() -> None:
    s = synced(("zulu", 1), ("alpha", 1))
    imp: LinkImpairment[object] = LinkImpairment(
        ImpairmentConfig(reorder_pct=100.0, reorder_delay_ms=100.0), random.Random(1).random
    )  # type: ignore[arg-type]
    s.client_hello("zulu", Marker.hello(1), (1, 191), link_in=imp)  # registered anew, with a link
    s.autopilot_marker(step(1))
    s.client_frame("zulu", "z1")
    s.client_frame("alpha", "a1")
    s.client_frame("alpha", "a2")
    s.client_marker("zulu", step(1, count=1))
    actions = s.client_marker("alpha", step(1, count=2))
    assert released(actions) == [("alpha", ("a1", "a2"))]  # z1 is reordered: 100 ms later
    assert upstream_steps(actions) == [1]
    s.autopilot_marker(step(2))
    s.client_frame("zulu", "z2")
    s.client_marker("zulu", step(2, count=1))
    actions = s.client_marker("alpha", step(2))
    assert released(actions) == [("zulu", ("z1",))]  # z2 is due at 0.3


def test_a_late_registration_starts_at_the_autopilots_step() -> None:
    s = synced(("early", 2))
    for g in range(1, 6):
        s.autopilot_marker(step(g))
        s.client_marker("early", step(g))
        s.upstream()
    (answer,) = s.client_hello("late", Marker.hello(1), (1, 192))
    assert answer == MarkerToClient("late", step(5), (1, 192))
    s.client_frame("late", "x")
    s.autopilot_marker(step(6))
    assert upstream_steps(s.upstream()) == []  # waits for late's STEP(6)
    with pytest.raises(LockstepError, match=r"expected its STEP\(6\)"):
        s.client_marker("late", step(5))


def test_a_client_hello_before_the_first_autopilot_step_waits_for_it() -> None:
    s: LockstepScheduler[str, str] = LockstepScheduler()
    assert s.client_hello("c", Marker.hello(2), (1, 191)) == []
    assert s.said_hello("c")
    assert not s.is_client("c")
    assert s.client_frame("c", "early")  # kept: it counts towards the client's first step
    assert s.autopilot_marker(step(7)) == [MarkerToClient("c", step(7), (1, 191))]
    assert s.is_client("c")
    s.autopilot_marker(step(8))
    assert upstream_steps(s.upstream()) == [8]  # lookahead 2: the client's STEP(7) (its HELLO) is enough
    assert s.client_marker("c", step(8, count=1)) == []
    s.autopilot_marker(step(9))
    actions = s.upstream()
    assert released(actions) == [("c", ("early",))]  # its step 8, an input of the autopilot's step 8 + 2
    assert upstream_steps(actions) == [9]


def test_client_errors_name_the_client_and_the_counts() -> None:
    s = synced(("controller", 1))
    s.autopilot_marker(step(1))
    s.client_frame("controller", "x")
    with pytest.raises(LockstepError, match="lockstep client controller: step 1: it says it sent 3 messages, 1 were"):
        s.client_marker("controller", step(1, count=3))
    s = synced(("controller", 1))
    with pytest.raises(LockstepError, match=r"STEP\(1\) before the router sent it"):
        s.client_marker("controller", step(1))


def test_what_the_autopilot_sends_in_a_step_reaches_the_clients_at_its_marker() -> None:
    s = synced(("b", 1), ("a", 1))
    link: LinkImpairment[str] = LinkImpairment(ImpairmentConfig(delay_ms=150.0), random.Random(1).random)
    s.client_hello("b", Marker.hello(1), (1, 191), link_out=link)
    for g in range(1, 4):
        assert s.to_client("a", f"a{g}")
        assert s.to_client("b", f"b{g}")
        actions = s.autopilot_marker(step(g))
        a_frames = [x.frames for x in actions if isinstance(x, Deliver) and x.client == "a"]
        b_frames = [x.frames for x in actions if isinstance(x, Deliver) and x.client == "b"]
        markers = [(x.client, x.marker.count) for x in actions if isinstance(x, MarkerToClient)]
        assert a_frames == [(f"a{g}",)]
        assert b_frames == ([] if g < 3 else [("b1",)])  # b1 at t_1 + 0.15 s: due at t_3
        assert markers == [("a", 1), ("b", 0 if g < 3 else 1)]  # in name order, after the frames
        s.client_marker("a", step(g))
        s.client_marker("b", step(g))
    assert not s.to_client("nobody", "x")


def test_a_removed_client_is_waited_for_no_more() -> None:
    s = synced(("gone", 1))
    s.autopilot_marker(step(1))
    assert upstream_steps(s.upstream()) == []
    assert upstream_steps(s.remove_client("gone")) == [1]


def test_marker_frames_are_real_mavlink_and_are_recognised() -> None:
    raw = marker_frame(step(3, count=9), seq=17, target=(1, 1))
    (msg,) = v2.MAVLink(None).parse_buffer(raw)
    assert (msg.get_type(), msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq()) == ("V2_EXTENSION", 1, 240, 17)
    assert (msg.message_type, msg.target_system, msg.target_component) == (MESSAGE_TYPE, 1, 1)
    (frame,) = FrameParser(TABLE, stream=False).feed(raw)
    wire = marker_in(frame)
    assert wire is not None
    assert wire.marker == step(3, count=9)
    # another extension, and another message, are not markers
    other = pack(v2.MAVLink_v2_extension_message(0, 1, 1, 12345, encode_payload(step(1))))
    (frame,) = FrameParser(TABLE, stream=False).feed(other)
    assert marker_in(frame) is None
    (frame,) = FrameParser(TABLE, stream=False).feed(pack(v2.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3)))
    assert marker_in(frame) is None
    bad = pack(v2.MAVLink_v2_extension_message(0, 1, 1, MESSAGE_TYPE, b"LKST\x09" + bytes(244)))
    (frame,) = FrameParser(TABLE, stream=False).feed(bad)
    with pytest.raises(LockstepError, match=r"malformed lockstep marker from system 1 component 1: .*version 9"):
        marker_in(frame)


# ---------------------------------------------------------------------------------------------- configuration

BASE = """[General]
Lockstep = true
{general}
[TcpEndpoint sitl]
Address = 127.0.0.1
Port = 5760
{sitl}
[UdpEndpoint controller]
Mode = Normal
Address = 127.0.0.1
Port = 14540
{controller}
"""


def conf(general: str = "", sitl: str = "Lockstep = autopilot", controller: str = "") -> str:
    return BASE.format(general=general, sitl=sitl, controller=controller)


def test_lockstep_keys() -> None:
    cfg = parse_config_text(conf(controller="Lockstep = client\nDelayMs = 30"), source="r.conf")
    assert cfg.general.lockstep
    assert cfg.tcp[0].options.lockstep is LockstepRole.AUTOPILOT
    assert cfg.udp[0].options.lockstep is LockstepRole.CLIENT
    plain = parse_config_text("[UdpEndpoint a]\nMode = Normal\nAddress = 127.0.0.1\n", source="r.conf")
    assert not plain.general.lockstep
    assert plain.udp[0].options.lockstep is None


@pytest.mark.parametrize(
    ("text", "error"),
    [
        (conf(sitl=""), r"r.conf:1: \[General\] Lockstep = true needs one endpoint with 'Lockstep = autopilot'"),
        (conf(controller="Lockstep = autopilot"), "only one endpoint may be 'Lockstep = autopilot', got"),
        (conf(sitl="Lockstep = pilot"), r"\[TcpEndpoint sitl\] Lockstep = 'pilot': expected one of autopilot, client"),
        (conf(general="Lockstep = maybe"), r"\[General\] Lockstep = 'maybe': expected true, false"),
        (conf(general="DeduplicationPeriod = 100"), "DeduplicationPeriod = 100 cannot be used with Lockstep = true"),
        (conf(sitl="Lockstep = autopilot\nLossPercent = 5"), "the autopilot endpoint sitl cannot have a lossy link"),
        (conf().replace("Lockstep = true", "Lockstep = false"), r"Lockstep = autopilot needs '\[General\] Lockstep"),
    ],
)
def test_lockstep_configuration_errors_name_the_key(text: str, error: str) -> None:
    with pytest.raises(ConfigError, match=error):
        parse_config_text(text, source="r.conf")
