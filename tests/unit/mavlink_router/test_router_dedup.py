"""De-duplication window (mavlink-router's DeduplicationPeriod)."""

from __future__ import annotations

import pytest

from mavlink_router.core.dedup import Deduplicator


def test_window_from_first_sighting() -> None:
    dedup = Deduplicator(1.0)
    assert dedup.is_new(b"a", 10.0)
    assert not dedup.is_new(b"a", 10.5)
    assert not dedup.is_new(b"a", 11.0)  # a repeat does not extend the window
    assert dedup.is_new(b"a", 11.01)
    assert dedup.is_new(b"b", 11.02)
    assert len(dedup) == 2


def test_memory_is_bounded_by_the_window() -> None:
    dedup = Deduplicator(0.1)
    for i in range(10_000):
        dedup.is_new(i.to_bytes(4, "little"), i * 0.001)
    assert len(dedup) <= 102


def test_period_must_be_positive() -> None:
    with pytest.raises(ValueError, match="> 0"):
        Deduplicator(0)
