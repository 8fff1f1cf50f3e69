"""uav_common.waiting: the one polling loop, against a fake clock (no sleeping in these tests)."""

from __future__ import annotations

import asyncio

import pytest

from uav_common.errors import WaitTimeoutError
from uav_common.waiting import hold_for, wait_until, wait_until_async


class FakeClock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, s: float) -> None:
        self.now += s


def test_wait_until_returns_the_first_value_that_holds() -> None:
    clock = FakeClock()
    values = iter(range(100))
    got = wait_until(lambda: next(values), lambda v: v >= 3, timeout_s=10, describe="3", clock=clock, sleep=clock.sleep)
    assert got == 3
    assert clock.now == pytest.approx(0.15)


def test_wait_until_times_out_with_what_and_the_last_value() -> None:
    clock = FakeClock()
    with pytest.raises(WaitTimeoutError, match=r"timed out after 1.0 s waiting for the goal; last value: 'no'"):
        wait_until(
            lambda: "no", lambda v: v == "yes", timeout_s=1.0, describe="the goal", clock=clock, sleep=clock.sleep
        )
    assert clock.now == pytest.approx(1.0, abs=0.06)


def test_check_ends_a_wait_early() -> None:
    """A wait on a process's output stops as soon as the process is gone, not at the timeout."""
    clock = FakeClock()

    def dead() -> None:
        if clock.now > 0.2:
            raise RuntimeError("the SITL exited")

    with pytest.raises(RuntimeError, match="SITL exited"):
        wait_until(lambda: 0, bool, timeout_s=60, describe="x", clock=clock, sleep=clock.sleep, check=dead)
    assert clock.now < 1.0


def test_hold_for_requires_the_condition_throughout() -> None:
    clock = FakeClock()
    assert hold_for(lambda: 1, lambda v: v == 1, duration_s=2, describe="x", clock=clock, sleep=clock.sleep) == 1
    flips = iter([1, 1, 0, 1])
    with pytest.raises(WaitTimeoutError, match="stopped holding"):
        hold_for(lambda: next(flips), lambda v: v == 1, duration_s=2, describe="x", clock=clock, sleep=clock.sleep)


def test_wait_until_async_polls_an_awaitable_probe() -> None:
    calls = []

    async def probe() -> int:
        calls.append(1)
        return len(calls)

    assert asyncio.run(wait_until_async(probe, lambda v: v >= 3, timeout_s=5, describe="3", poll_s=0.001)) == 3
    with pytest.raises(WaitTimeoutError, match="never"):
        asyncio.run(wait_until_async(probe, lambda v: v < 0, timeout_s=0.05, describe="never", poll_s=0.001))
