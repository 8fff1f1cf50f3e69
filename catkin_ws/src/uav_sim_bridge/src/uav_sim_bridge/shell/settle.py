"""Quiescence of a process tree: "has everything the last state caused finished?" (lockstep determinism).

For deterministic scenario runs; used only when the
bridge's ``~settle`` parameter is true (see ``nodes/sim_bridge.py``).

A lockstep step master that grants the next step while other processes are still working on
the last one makes the run depend on scheduling. :class:`Settle` waits until every process of
the run (the descendants of ``root_pid``, normally roslaunch, plus the caller's own other
threads) is idle: in ``samples`` consecutive snapshots ``gap_s`` apart (a window longer than
the poll period of any work queue, e.g. the map server's 1-10 ms insertion loop), no thread
is runnable (``R``) or in uninterruptible sleep (``D``), and the kernel's softirq threads are
not runnable (loopback UDP may be delivered from ``ksoftirqd``). A message sent to a process
wakes its reader at once, and a causal chain of messages always has a runnable link until it
ends, so an idle window means everything the last state caused has been handled, by every
node, whatever its code. No component has to report anything. Processes that cannot affect
the simulation (roslaunch's monitor, rosout, rosbag record) are not watched: their periodic
wake-ups would only cost retries.

Linux only (``/proc``). A wait costs a few tens of milliseconds.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

__all__ = ["Settle", "SettleStats"]


def _state(stat_path: str) -> bytes:
    """The one-letter state (``R``, ``S``, ``D``...) from a ``/proc/.../stat`` file; b"" if it is gone."""
    try:
        with open(stat_path, "rb") as fh:
            raw = fh.read()
    except OSError:
        return b""
    end = raw.rfind(b")")  # the command name may contain spaces and parentheses
    return raw[end + 2 : end + 3]


def _program(argv: list[str]) -> str:
    """The program a command line runs: argv[0]'s basename, or the script's for an interpreter."""
    if not argv or not argv[0]:
        return ""
    name = os.path.basename(argv[0])
    if name.startswith("python") and len(argv) > 1:
        return os.path.basename(argv[1])
    return name


@dataclass
class SettleStats:
    waits: int = 0
    timeouts: int = 0
    total_wait_s: float = 0.0
    max_wait_s: float = 0.0


@dataclass
class Settle:
    """Wait until the processes under ``root_pid`` (and our other threads) are idle.

    Args:
        root_pid: the run's root process (its descendants are watched); usually roslaunch.
        timeout_s: give up after this much wall time (the caller logs it; determinism is lost).
        gap_s: time between snapshots (releases the GIL so our own writer threads can run).
        samples: consecutive identical idle snapshots required.
        refresh_s: how often the process list is re-read.
    """

    root_pid: int
    timeout_s: float = 10.0
    gap_s: float = 0.004
    samples: int = 8
    refresh_s: float = 2.0
    #: Programs (basename of argv[0], or of argv[1] for interpreters) that are not watched.
    ignore: tuple[str, ...] = ("roslaunch", "rosout", "record", "rosbag")
    stats: SettleStats = field(default_factory=SettleStats)
    _pids: list[int] = field(default_factory=list)
    _softirq: list[int] = field(default_factory=list)
    _refreshed: float = -1e9

    def _refresh(self, now: float) -> None:
        if now - self._refreshed < self.refresh_s:
            return
        self._refreshed = now
        parent: dict[int, int] = {}
        cmdlines: dict[int, str] = {}
        softirq = []
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            try:
                with open(f"/proc/{entry}/stat", "rb") as fh:
                    raw = fh.read()
            except OSError:
                continue
            name_end = raw.rfind(b")")
            comm = raw[raw.find(b"(") + 1 : name_end]
            fields = raw[name_end + 2 :].split()
            parent[int(entry)] = int(fields[1])
            if comm.startswith(b"ksoftirqd/"):
                softirq.append(int(entry))
            try:
                with open(f"/proc/{entry}/cmdline", "rb") as fh:
                    argv = fh.read().decode(errors="replace").split("\0")
            except OSError:
                argv = []
            cmdlines[int(entry)] = _program(argv)
        tree = {self.root_pid}
        grew = True
        while grew:
            grew = False
            for pid, ppid in parent.items():
                if ppid in tree and pid not in tree:
                    tree.add(pid)
                    grew = True
        tree.add(os.getpid())
        self._pids = sorted(
            p for p in tree if p == os.getpid() or not any(i in cmdlines.get(p, "") for i in self.ignore)
        )
        self._softirq = softirq

    def _busy(self, own_tid: int) -> bool:
        """Is any watched thread (or a softirq thread) runnable or in uninterruptible sleep now?"""
        me = os.getpid()
        for pid in self._pids:
            try:
                tids = os.listdir(f"/proc/{pid}/task")
            except OSError:
                continue
            for tid in tids:
                if pid == me and int(tid) == own_tid:
                    continue  # the waiting thread itself
                if _state(f"/proc/{pid}/task/{tid}/stat") in (b"R", b"D"):
                    return True
        return any(_state(f"/proc/{pid}/stat") == b"R" for pid in self._softirq)

    def wait(self, abort: Callable[[], bool] | None = None) -> bool:
        """Block until idle; ``False`` when ``timeout_s`` passed first or ``abort()`` says so (shutdown)."""
        start = time.monotonic()
        own = threading.get_native_id()
        self._refresh(start)
        quiet = 0
        ok = False
        while True:
            time.sleep(self.gap_s)
            if self._busy(own):
                quiet = 0
            else:
                quiet += 1
                if quiet >= self.samples:
                    ok = True
                    break
            now = time.monotonic()
            if now - start > self.timeout_s or (abort is not None and abort()):
                break
            self._refresh(now)
        waited = time.monotonic() - start
        self.stats.waits += 1
        self.stats.total_wait_s += waited
        self.stats.max_wait_s = max(self.stats.max_wait_s, waited)
        if not ok:
            self.stats.timeouts += 1
        return ok
