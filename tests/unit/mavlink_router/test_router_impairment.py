"""The lossy link: loss (independent and in bursts), delay, jitter, reordering, seeding; its configuration keys;
and the router core losing an endpoint's inbound frames before it learns or routes them."""

from __future__ import annotations

import itertools
import random

import pytest
from mr_build import TABLE, heartbeat, pack, ping

from mavlink_router.core.config import parse_config_text
from mavlink_router.core.engine import RouterCore
from mavlink_router.core.impairment import ImpairmentConfig, LinkDirection, LinkImpairment
from mavlink_router.errors import ConfigError

NOW = 1_800_000_000.0


def link(seed: int = 1, **kw: float) -> LinkImpairment[int]:
    return LinkImpairment(ImpairmentConfig(**kw), random.Random(seed).random)  # type: ignore[arg-type]


def run(imp: LinkImpairment[int], n: int, period_s: float = 0.01) -> list[tuple[float, int]]:
    """Offer 0..n-1 every ``period_s``; returns (delivery time, item), each released exactly when due."""
    out: list[tuple[float, int]] = []
    t = 0.0
    for i in range(n):
        t = i * period_s
        while imp.next_due_s <= t:
            due = imp.next_due_s
            out += [(due, x) for x in imp.due(due)]
        out += [(t, x) for x in imp.offer(i, t)]
    end = t + 120.0
    while imp.held:
        t = min(imp.next_due_s, end)
        out += [(t, x) for x in imp.due(t)]
    return out


def test_a_perfect_link_delivers_everything_at_once_in_order() -> None:
    imp = link()
    assert not imp.config.active
    got = run(imp, 100)
    assert [x for _, x in got] == list(range(100))
    assert all(t == pytest.approx(x * 0.01) for t, x in got)
    assert imp.counters.as_dict() == {"offered": 100, "dropped": 0, "delayed": 0, "reordered": 0, "delivered": 100}


@pytest.mark.parametrize("loss", [5.0, 20.0, 50.0])
def test_independent_loss_rate(loss: float) -> None:
    imp = link(seed=7, loss_pct=loss)
    got = run(imp, 20000)
    lost = 20000 - len(got)
    assert lost == imp.counters.dropped
    assert abs(lost / 20000 - loss / 100.0) < 0.015
    assert [x for _, x in got] == sorted(x for _, x in got)  # loss alone never reorders


def bursts(delivered: list[int], n: int) -> list[int]:
    """Lengths of the runs of consecutive lost items."""
    kept = set(delivered)
    out, run_len = [], 0
    for i in range(n):
        if i in kept:
            if run_len:
                out.append(run_len)
            run_len = 0
        else:
            run_len += 1
    return out + ([run_len] if run_len else [])


def test_bursty_loss_keeps_the_rate_and_makes_long_fades() -> None:
    n = 50000
    indep = [x for _, x in run(link(seed=3, loss_pct=20.0), n)]
    bursty = [x for _, x in run(link(seed=3, loss_pct=20.0, loss_burst=10.0), n)]
    assert abs(1 - len(bursty) / n - 0.20) < 0.03
    b_indep, b_bursty = bursts(indep, n), bursts(bursty, n)
    assert 1.15 < sum(b_indep) / len(b_indep) < 1.35  # geometric: 1 / (1 - 0.2) = 1.25
    assert 8.0 < sum(b_bursty) / len(b_bursty) < 12.0
    assert max(b_bursty) > 30  # fades long enough to lose a 1 Hz heartbeat for seconds


def test_total_loss_and_no_loss() -> None:
    assert run(link(loss_pct=100.0), 50) == []
    assert len(run(link(loss_pct=0.0, delay_ms=1.0), 50)) == 50


def test_delay_holds_every_frame_and_keeps_order() -> None:
    imp = link(delay_ms=150.0)
    assert imp.offer(0, 0.0) == []
    assert imp.next_due_s == pytest.approx(0.15)
    assert imp.due(0.149) == []
    assert imp.due(0.15) == [0]
    got = run(link(delay_ms=150.0), 50)
    assert [x for _, x in got] == list(range(50))
    assert all(t == pytest.approx(x * 0.01 + 0.15) for t, x in got)


def test_jitter_and_reordering_reorder_and_are_counted() -> None:
    imp = link(seed=5, jitter_ms=40.0)
    got = [x for _, x in run(imp, 2000)]
    assert sorted(got) == list(range(2000))  # nothing lost
    out_of_order = sum(1 for a, b in itertools.pairwise(got) if b < a)
    assert out_of_order > 100
    assert imp.counters.reordered > 100
    imp = link(seed=5, reorder_pct=10.0, reorder_delay_ms=50.0)
    got = [x for _, x in run(imp, 5000)]
    assert sorted(got) == list(range(5000))
    assert abs(imp.counters.delayed / 5000 - 0.10) < 0.02
    # a frame held 50 ms is overtaken by the ~5 sent after it: it arrives after them
    assert imp.counters.reordered == pytest.approx(imp.counters.delayed, rel=0.05)


def test_the_same_seed_gives_the_same_link_and_another_seed_another() -> None:
    a = run(link(seed=11, loss_pct=30.0, jitter_ms=20.0, reorder_pct=5.0), 3000)
    b = run(link(seed=11, loss_pct=30.0, jitter_ms=20.0, reorder_pct=5.0), 3000)
    c = run(link(seed=12, loss_pct=30.0, jitter_ms=20.0, reorder_pct=5.0), 3000)
    assert a == b
    assert a != c


@pytest.mark.parametrize(
    ("kw", "text"),
    [
        ({"loss_pct": 101.0}, r"loss_pct must be in \[0, 100\]"),
        ({"loss_pct": -1.0}, r"loss_pct must be in \[0, 100\]"),
        ({"delay_ms": float("nan")}, "delay_ms"),
        ({"loss_pct": 80.0, "loss_burst": 2.0}, "at least 4 frames"),
        ({"loss_pct": 20.0, "loss_burst": 0.5}, "at least 1 frames"),
    ],
)
def test_bad_settings_say_which(kw: dict[str, float], text: str) -> None:
    with pytest.raises(ValueError, match=text):
        ImpairmentConfig(**kw)  # type: ignore[arg-type]


# ---- configuration file ---------------------------------------------------------------------------------------


def test_link_keys_parse_into_the_endpoint_options() -> None:
    cfg = parse_config_text(
        "[UdpEndpoint controller]\nMode = Normal\nAddress = 127.0.0.1\nPort = 14540\n"
        "LossPercent = 20\nLossBurst = 3\nDelayMs = 40\nJitterMs = 10\nReorderPercent = 2\nLinkDirection = out\n"
        "LinkSeed = 9\n"
        "[UdpEndpoint gcs]\nMode = Normal\nAddress = 127.0.0.1\nPort = 14550\n"
    )
    controller, gcs = cfg.udp
    assert controller.options.link == ImpairmentConfig(
        loss_pct=20.0, loss_burst=3.0, delay_ms=40.0, jitter_ms=10.0, reorder_pct=2.0,
        direction=LinkDirection.OUT, seed=9,
    )  # fmt: skip
    assert gcs.options.link is None


@pytest.mark.parametrize(
    ("line", "text"),
    [
        ("LossPercent = 120", r"<t>:6: \[UdpEndpoint radio\] LossPercent = '120': must be from 0 to 100"),
        ("LossPercent = lots", r"LossPercent = 'lots': expected a number from 0 to 100"),
        ("DelayMs = -5", r"DelayMs = '-5': must be from 0 to 60000"),
        ("LinkDirection = sideways", r"LinkDirection = 'sideways': expected one of both, in, out"),
        ("LossPercnt = 10", r"unknown key 'LossPercnt' \(did you mean 'LossPercent'\?\)"),
        ("LossPercent = 90\nLossBurst = 2", r"\[UdpEndpoint radio\] LossBurst: loss_burst 2 is too short"),
    ],
)
def test_bad_link_keys_name_the_key(line: str, text: str) -> None:
    conf = f"[UdpEndpoint radio]\nMode = Normal\nAddress = 127.0.0.1\nPort = 14550\n\n{line}\n"
    with pytest.raises(ConfigError, match=text):
        parse_config_text(conf, source="<t>")


# ---- the core -------------------------------------------------------------------------------------------------


def test_inbound_loss_happens_before_learning_and_routing() -> None:
    core = RouterCore(TABLE)
    lossy = LinkImpairment(ImpairmentConfig(loss_pct=100.0), random.Random(0).random)
    core.add_endpoint("radio", stream=False, link_in=lossy)
    core.add_endpoint("other", stream=False)
    assert core.ingest(0, pack(heartbeat(), 7, 1), NOW) == []
    assert core.learned(0).sorted_pairs() == []  # a frame lost on the radio taught the router nothing
    assert core.stats(0).rx_msgs == 0
    assert lossy.counters.dropped == 1
    # the other way nothing is lost: the endpoint learns and routes
    [(frame, dests)] = core.ingest(1, pack(heartbeat(), 9, 1), NOW)
    assert dests == (0,)
    assert frame


def test_inbound_delay_releases_frames_when_due_and_counts_sequence_gaps() -> None:
    core = RouterCore(TABLE)
    held = LinkImpairment(ImpairmentConfig(delay_ms=100.0), random.Random(0).random)
    core.add_endpoint("radio", stream=False, link_in=held)
    core.add_endpoint("other", stream=False)
    assert core.ingest(0, pack(ping(0, 0, 1), 7, 1, seq=1), NOW) == []
    assert core.release_inbound(0, NOW + 0.05) == []
    [(_, dests)] = core.release_inbound(0, NOW + 0.1)
    assert dests == (1,)
    assert core.stats(0).rx_msgs == 1
    assert core.release_inbound(1, NOW + 1.0) == []  # no link on that endpoint
    lossy = LinkImpairment(ImpairmentConfig(loss_pct=50.0), random.Random(4).random)
    core2 = RouterCore(TABLE)
    core2.add_endpoint("radio", stream=False, link_in=lossy)
    through = [seq for seq in range(200) if core2.ingest(0, pack(ping(0, 0, seq), 7, 1, seq=seq), NOW)]
    stats = core2.stats(0)
    assert stats.rx_msgs == len(through) == 200 - lossy.counters.dropped
    # the router sees the gaps the radio made (those between the first and the last frame that got through)
    assert stats.seq_lost == through[-1] - through[0] + 1 - len(through) > 50
