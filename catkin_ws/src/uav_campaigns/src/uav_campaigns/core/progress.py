"""The campaign's progress line: runs done, failed, running, queued, and an ETA (pure; times passed in)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

__all__ = ["Counts", "eta_s", "format_duration", "progress_line"]


@dataclass(frozen=True)
class Counts:
    #: Runs this campaign plans (unique keys).
    total: int
    #: Finished, including those finished by an earlier invocation.
    done: int
    #: Given up (failed ``max_attempts`` times).
    failed: int
    running: int
    queued: int
    #: Failed tries that will be tried again, and orphaned tries (the worker died).
    retrying: int = 0
    #: Workers connected (the embedded cluster's or the remote scheduler's).
    workers: int = 0


def eta_s(
    durations_s: Sequence[float],
    running_elapsed_s: Sequence[float],
    queued: int,
    slots: int,
) -> float | None:
    """Seconds until every run is finished, from the wall time of the runs finished so far.

    Args:
        durations_s: wall seconds of finished runs (this invocation's, or earlier ones').
        running_elapsed_s: how long each running run has been running.
        queued: runs not started yet.
        slots: runs the cluster runs at once (>= 1).

    Returns:
        None before the first run has finished (nothing to extrapolate from).
    """
    finite = [d for d in durations_s if math.isfinite(d) and d > 0]
    if not finite:
        return None
    mean = sum(finite) / len(finite)
    work = queued * mean + sum(max(0.0, mean - e) for e in running_elapsed_s)
    return work / max(1, slots)


def format_duration(seconds: float | None) -> str:
    if seconds is None or not math.isfinite(seconds):
        return "–"
    s = round(seconds)
    if s >= 3600:
        return f"{s // 3600}h{(s % 3600) // 60:02d}m"
    if s >= 60:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s}s"


def progress_line(counts: Counts, eta: float | None, elapsed_s: float, width: int = 24) -> str:
    """``[#####.....] 5/12 done, 1 failed, 2 running, 4 queued | 3 workers | 12m05s elapsed, ETA 6m30s``."""
    total = max(1, counts.total)
    filled = int(width * (counts.done + counts.failed) / total)
    bar = "#" * filled + "." * (width - filled)
    parts = [f"{counts.done}/{counts.total} done", f"{counts.failed} failed", f"{counts.running} running"]
    parts.append(f"{counts.queued} queued")
    if counts.retrying:
        parts.append(f"{counts.retrying} retrying")
    workers = f"{counts.workers} worker{'s' if counts.workers != 1 else ''}"
    if counts.workers == 0:
        workers = "no workers yet (waiting for `dask worker`)"
    return f"[{bar}] {', '.join(parts)} | {workers} | {format_duration(elapsed_s)} elapsed, ETA {format_duration(eta)}"
