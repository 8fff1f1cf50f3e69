"""The manifest's decisions: finished runs are skipped, failed ones retried up to the limit, orphans not blamed."""

from __future__ import annotations

from typing import Any

from uav_campaigns.core.manifest import decide, fold, may_retry


def ev(kind: str, key: str, try_no: int, **extra: Any) -> dict[str, Any]:
    return {"event": kind, "key": key, "try": try_no, **extra}


def test_a_new_campaign_runs_everything_once_in_order() -> None:
    d = decide(["k1", "k2", "k1"], {}, max_attempts=3)
    assert d.run == (("k1", 1), ("k2", 1))
    assert d.done == d.gave_up == ()


def test_done_runs_are_skipped_and_failed_runs_retried_until_the_limit() -> None:
    events = [
        ev("started", "a", 1),
        ev("finished", "a", 1, status="done"),
        ev("finished", "b", 1, status="failed", reason="crashed"),
        ev("finished", "b", 2, status="failed", reason="hung"),
        ev("finished", "c", 1, status="failed", reason="crashed"),
        ev("finished", "c", 2, status="failed", reason="crashed"),
        ev("finished", "c", 3, status="failed", reason="crashed"),
    ]
    states = fold(events)
    d = decide(["a", "b", "c", "d"], states, max_attempts=3)
    assert d.done == ("a",)
    assert d.run == (("b", 3), ("d", 1))
    assert d.gave_up == ("c",)
    assert states["c"].last_problem is not None
    assert states["c"].last_problem["reason"] == "crashed"
    assert may_retry(states["b"], 3)
    assert not may_retry(states["c"], 3)


def test_orphans_and_interruptions_are_not_failures_but_a_bad_config_is_final() -> None:
    events = [
        ev("started", "a", 1, worker="w1"),
        ev("orphaned", "a", 1, worker="w1", reason="worker left"),
        ev("orphaned", "a", 1, worker="w2", reason="worker left"),
        ev("finished", "a", 1, status="interrupted"),
        ev("finished", "b", 1, status="failed", reason="bad_config"),
    ]
    states = fold(events)
    assert (states["a"].failures, states["a"].orphans, states["a"].interruptions) == (0, 2, 1)
    d = decide(["a", "b"], states, max_attempts=3)
    assert d.run == (("a", 2),)
    assert d.gave_up == ("b",)


def test_retry_forgives_failures() -> None:
    events = [ev("finished", "a", n, status="failed", reason="crashed") for n in (1, 2)]
    assert decide(["a"], fold(events), max_attempts=2).gave_up == ("a",)
    events.append(ev("retry", "a", 2))
    assert decide(["a"], fold(events), max_attempts=2).run == (("a", 3),)
    # events without a key (the invocation's) are ignored
    assert fold([{"event": "invocation", "mode": "embedded"}]) == {}
