"""The campaign's progress line and its ETA."""

from __future__ import annotations

import pytest

from uav_campaigns.core.progress import Counts, eta_s, format_duration, progress_line


def test_eta_extrapolates_from_finished_runs_over_the_slots() -> None:
    assert eta_s([], [10.0], queued=3, slots=2) is None  # nothing finished yet: no guess
    # 60 s a run; 4 queued and one running for 20 s, two at a time: (4 x 60 + 40) / 2
    assert eta_s([50.0, 70.0], [20.0], queued=4, slots=2) == pytest.approx(140.0)
    assert eta_s([60.0], [90.0], queued=0, slots=1) == 0.0  # overdue runs count as about to finish
    assert eta_s([60.0], [], queued=2, slots=0) == 120.0  # no workers yet: as if one


def test_the_line_says_done_failed_running_queued_workers_and_eta() -> None:
    line = progress_line(Counts(12, 5, 1, 2, 4, retrying=1, workers=2), 390.0, 725.0)
    assert line.startswith("[" + "#" * 12 + "." * 12 + "]")
    for part in (
        "5/12 done",
        "1 failed",
        "2 running",
        "4 queued",
        "1 retrying",
        "2 workers",
        "12m05s elapsed",
        "ETA 6m30s",
    ):
        assert part in line
    waiting = progress_line(Counts(4, 0, 0, 0, 4), None, 3.0)
    assert "no workers yet" in waiting
    assert "ETA –" in waiting
    assert format_duration(3725) == "1h02m"
    assert format_duration(42.4) == "42s"
