"""The causal lockstep's bookkeeping (uav_common.lockstep): the master's barrier, the subscribers' counting, the
service boundaries and the simulated-time timers. Each rule of docs/lockstep.md has a case that breaks it."""

from __future__ import annotations

import random

import pytest

from uav_common.lockstep.protocol import BoundaryQueue, InputLedger, LockstepError, Manifest, StepBarrier, Tick
from uav_common.lockstep.timers import SimTimer

MASTER = "/sim_bridge"


def barrier(**lookahead: int) -> StepBarrier:
    b = StepBarrier(MASTER)
    for name, steps in lookahead.items():
        b.join(Manifest(f"/{name}", steps), {})
    b.start()
    return b


def test_a_step_is_granted_only_when_every_participant_is_done_with_step_minus_its_lookahead() -> None:
    b = barrier(controller=1, map_server=3)
    assert b.can_grant(), "step 1 needs nobody's done (1 - L <= 0)"
    b.tick(0.1, {})
    assert [w.node for w in b.waiting()] == ["/controller"], "step 2 needs the controller's step 1"
    b.done("/controller", 1, {})
    assert b.can_grant(), "the map server (L = 3) may lag: step 2 needs its step -1"
    for k in (2, 3):
        b.tick(0.1 * k, {})
        b.done("/controller", k, {})
    assert [(w.node, w.needs_step, w.done_step) for w in b.waiting()] == [("/map_server", 1, 0)]
    b.done("/map_server", 1, {})
    assert b.can_grant()


def test_tick_counts_are_each_publishers_counts_its_lookahead_steps_back() -> None:
    b = StepBarrier(MASTER)
    b.join(Manifest("/goal_selector", 2), {"/autonomy/weights": 1})
    b.start()
    t1 = b.tick(0.1, {"/cameras/nadir/points": 1})
    assert t1.counts[("/cameras/nadir/points", MASTER)] == 1, "the master's own step is consumed at once"
    assert t1.counts[("/autonomy/weights", "/goal_selector")] == 1, "start-up (latched) counts from the join"
    assert ("/autonomy/goal", "/goal_selector") not in t1.counts
    b.done("/goal_selector", 1, {"/autonomy/weights": 1, "/autonomy/goal": 1})
    t2 = b.tick(0.2, {"/cameras/nadir/points": 2})
    assert ("/autonomy/goal", "/goal_selector") not in t2.counts, "step 1's goal is an input at step 1 + 2"
    b.done("/goal_selector", 2, {"/autonomy/weights": 1, "/autonomy/goal": 3})
    t3 = b.tick(0.3, {"/cameras/nadir/points": 3})
    assert t3.counts[("/autonomy/goal", "/goal_selector")] == 1
    assert b.can_grant(), "step 4 needs the goal selector's step 2"
    assert b.tick(0.4, {"/cameras/nadir/points": 4}).counts[("/autonomy/goal", "/goal_selector")] == 3
    assert not b.can_grant(), "step 5 needs its step 3"


def test_dones_must_come_in_order_and_counts_never_go_back() -> None:
    b = barrier(tracker=1)
    b.tick(0.1, {})
    with pytest.raises(LockstepError, match="in order"):
        b.done("/tracker", 2, {})
    b.done("/tracker", 1, {"/scenario/tracks": 5})
    b.tick(0.2, {})
    with pytest.raises(LockstepError, match="went backwards"):
        b.done("/tracker", 2, {"/scenario/tracks": 4})
    with pytest.raises(LockstepError, match="has not joined"):
        b.done("/stranger", 1, {})


def test_no_join_after_the_start_and_no_tick_that_is_not_grantable() -> None:
    b = barrier(controller=1)
    with pytest.raises(LockstepError, match="after the run started"):
        b.join(Manifest("/late", 1), {})
    b.tick(0.1, {})
    with pytest.raises(LockstepError, match="waiting for /controller"):
        b.tick(0.2, {})
    with pytest.raises(LockstepError, match="lookahead_steps must be >= 1"):
        Manifest("/x", -1)


def test_a_static_participant_is_never_waited_for_and_its_start_up_counts_stay() -> None:
    b = StepBarrier(MASTER)
    b.join(Manifest("/robot_description", 0), {"/tf_static": 1})
    b.join(Manifest("/controller", 1), {})
    b.start()
    assert b.tick(0.1, {}).counts[("/tf_static", "/robot_description")] == 1
    b.done("/controller", 1, {})
    assert [w.node for w in b.waiting()] == []
    assert b.tick(0.2, {}).counts[("/tf_static", "/robot_description")] == 1
    with pytest.raises(LockstepError, match="in order"):
        b.done("/robot_description", 1, {"/tf_static": 1})


def _tick(step: int, counts: dict[tuple[str, str], int], *participants: str) -> Tick:
    return Tick(step, 0.1 * step, counts, frozenset({MASTER, *participants}))


def test_a_subscriber_takes_exactly_the_counted_messages_in_a_fixed_order_whatever_the_arrival_order() -> None:
    topics = ("/tf", "/autonomy/goal", "/uav/ground_truth/odom")
    sent = [
        ("/uav/ground_truth/odom", MASTER, "odom1"),
        ("/autonomy/goal", "/goal_selector", "goal1"),
        ("/tf", MASTER, "tf1"),
        ("/uav/ground_truth/odom", MASTER, "odom2"),
        ("/tf", "/autopilot_odometry", "tfA"),
        ("/autonomy/goal", "/goal_selector", "goal2"),  # the publisher is ahead: next step's
    ]
    tick = _tick(
        1,
        {
            ("/uav/ground_truth/odom", MASTER): 2,
            ("/autonomy/goal", "/goal_selector"): 1,
            ("/tf", MASTER): 1,
            ("/tf", "/autopilot_odometry"): 1,
        },
        "/goal_selector",
        "/autopilot_odometry",
    )
    orders = []
    for seed in range(20):
        arrival = list(sent)
        random.Random(seed).shuffle(arrival)
        # one publisher's messages on one topic keep their order (one TCP connection)
        arrival.sort(key=lambda m: [x for x in sent if x[:2] == m[:2]].index(m))
        ledger: InputLedger[str] = InputLedger(topics)
        for topic, pub, msg in arrival:
            ledger.received(topic, pub, msg)
        assert ledger.missing(tick) == []
        orders.append([m for _, m in ledger.take(tick)])
        assert ledger.held() == 1, "goal2 waits for a later tick"
    assert all(o == orders[0] for o in orders)
    # topics in declaration order, publishers by name ("/autopilot_odometry" < "/sim_bridge"), arrival order
    assert orders[0] == ["tfA", "tf1", "goal1", "odom1", "odom2"]


def test_a_missing_message_is_reported_and_a_duplicate_is_an_error() -> None:
    ledger: InputLedger[str] = InputLedger(["/scan"])
    ledger.received("/scan", "/lidar", "a")
    tick = _tick(1, {("/scan", "/lidar"): 2}, "/lidar")
    (m,) = ledger.missing(tick)
    assert (m.topic, m.publisher, m.expected, m.received) == ("/scan", "/lidar", 2, 1)
    with pytest.raises(LockstepError, match="1 of 2"):
        ledger.take(tick)
    ledger.received("/scan", "/lidar", "b")
    assert [x for _, x in ledger.take(tick)] == ["a", "b"]
    with pytest.raises(LockstepError, match="already taken"):
        ledger.missing(_tick(2, {("/scan", "/lidar"): 1}, "/lidar"))


def test_foreign_publishers_are_dispatched_after_the_counted_ones_and_topics_not_subscribed_are_ignored() -> None:
    ledger: InputLedger[str] = InputLedger(["/cmd"])
    ledger.received("/cmd", "/rostopic_123", "operator")  # before any tick: classified at the first
    ledger.received("/cmd", "/planner", "planned")
    tick = _tick(1, {("/cmd", "/planner"): 1, ("/other", MASTER): 7}, "/planner")
    assert [x for _, x in ledger.take(tick)] == ["planned", "operator"]


def test_boundary_queue_applies_requests_at_their_boundary_in_arrival_order() -> None:
    q: BoundaryQueue[str] = BoundaryQueue()
    q.put(5, "late")
    q.put(3, "first")
    q.put(3, "second")
    assert q.due(2) == []
    assert q.due(3) == ["first", "second"]
    assert q.due(10) == ["late"]
    assert len(q) == 0


def test_sim_timers_fire_once_per_step_and_never_catch_up_in_bursts() -> None:
    fast = SimTimer(0.05, name="setpoints")  # 20 Hz in 10 Hz steps
    fired = [k for k in range(1, 21) if fast.due(0.1 * k)]
    assert fired == list(range(1, 21))
    slow = SimTimer(0.5)
    fired = [k for k in range(1, 31) if slow.due(0.1 * k)]
    assert fired == [5, 10, 15, 20, 25, 30]
    gap = SimTimer(1.0)
    assert gap.due(5.0), "after a long gap: once"
    assert not gap.due(5.5)
    assert gap.due(6.0)
    with pytest.raises(ValueError, match="period_s"):
        SimTimer(0.0, name="bad")
