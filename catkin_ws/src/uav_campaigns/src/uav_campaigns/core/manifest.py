"""The manifest's meaning: what its events say about each run, and what an invocation does next.

The manifest (``DIR/manifest.jsonl``) is an append-only list of events, one JSON object a line,
written by :mod:`uav_campaigns.shell.store`. This module is pure: :func:`fold` turns the events into
the state of every run key, :func:`decide` says which runs to skip, run or give up on.

Events (every one has ``event``, ``key`` and ``try``; ``try`` counts the times the run was started):

* ``submitted``: the run was handed to Dask (``arm``, ``seed``, ``repeat``).
* ``started``: a worker started it (``worker``, ``host``, ``run_dir``).
* ``finished``: the worker's result: ``status`` ``done`` (the run ended on a stop criterion and was
  scored), ``failed`` (``reason``: ``crashed``, ``hung``, ``bad_config``, ``unavailable``, ``lost``, ...;
  ``exit_code``, ``log_tail``) or ``interrupted`` (the campaign was stopped; not a failure).
* ``orphaned``: the worker running it left the cluster (died, killed, lost its network); Dask gives
  the run to another worker. Not a failure of the run, so it does not count against ``max_attempts``.
* ``retry``: ``uav-campaign run --retry-failed`` forgave the run's failures (it may run ``max_attempts``
  more times).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = ["Decision", "Outcome", "RunState", "decide", "fold"]


class Outcome(enum.Enum):
    DONE = "done"
    FAILED = "failed"
    INTERRUPTED = "interrupted"


#: Failure reasons that trying again cannot fix: the run is given up at once.
PERMANENT_REASONS = frozenset({"bad_config"})


@dataclass
class RunState:
    """Everything the manifest says about one run key."""

    key: str
    #: Highest ``try`` seen (0: never started).
    tries: int = 0
    failures: int = 0
    orphans: int = 0
    interruptions: int = 0
    #: The ``finished`` event of the successful try, if any.
    done: Mapping[str, Any] | None = None
    #: The last ``finished`` failure or ``orphaned`` event.
    last_problem: Mapping[str, Any] | None = None
    permanent_failure: bool = False
    #: Every ``finished`` and ``orphaned`` event, in order.
    history: list[Mapping[str, Any]] = field(default_factory=list)


def fold(events: Iterable[Mapping[str, Any]]) -> dict[str, RunState]:
    """The state of every key the events mention (events without a key are ignored)."""
    states: dict[str, RunState] = {}
    for ev in events:
        key = ev.get("key")
        if not isinstance(key, str):
            continue
        st = states.setdefault(key, RunState(key))
        st.tries = max(st.tries, int(ev.get("try", 0) or 0))
        kind = ev.get("event")
        if kind == "retry":
            st.failures = 0
            st.permanent_failure = False
        elif kind == "orphaned":
            st.orphans += 1
            st.last_problem = ev
            st.history.append(ev)
        elif kind == "finished":
            st.history.append(ev)
            status = ev.get("status")
            if status == Outcome.DONE.value:
                st.done = ev
            elif status == Outcome.INTERRUPTED.value:
                st.interruptions += 1
            else:
                st.failures += 1
                st.last_problem = ev
                if ev.get("reason") in PERMANENT_REASONS:
                    st.permanent_failure = True
    return states


@dataclass(frozen=True)
class Decision:
    #: Keys already finished (skipped).
    done: tuple[str, ...]
    #: (key, try number) of each run to start now.
    run: tuple[tuple[str, int], ...]
    #: Keys that failed ``max_attempts`` times (or for a reason retrying cannot fix): not started again.
    gave_up: tuple[str, ...]


def decide(keys: Sequence[str], states: Mapping[str, RunState], max_attempts: int) -> Decision:
    """What to do with each planned key (each once, in order) given the manifest's states."""
    done: list[str] = []
    run: list[tuple[str, int]] = []
    gave_up: list[str] = []
    seen: set[str] = set()
    for key in keys:
        if key in seen:
            continue
        seen.add(key)
        st = states.get(key)
        if st is None:
            run.append((key, 1))
        elif st.done is not None:
            done.append(key)
        elif st.permanent_failure or st.failures >= max_attempts:
            gave_up.append(key)
        else:
            run.append((key, st.tries + 1))
    return Decision(tuple(done), tuple(run), tuple(gave_up))


def may_retry(state: RunState, max_attempts: int) -> bool:
    """A run that just failed is tried again in the same invocation while this holds."""
    return state.done is None and not state.permanent_failure and state.failures < max_attempts
