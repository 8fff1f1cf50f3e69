"""The map server's C++ lockstep bookkeeping (catkin_ws/src/uav_mapping/core/include/uav_mapping/lockstep.h).

``lockstep_tests`` is built by ``make build`` next to the node. Its own cases (dispatch order whatever the
arrival order, foreign publishers, missing counts, duplicates, boundaries, the timer rule) run as one pytest case
each; then random traces of ledger, boundary-queue and timer operations are replayed through the C++ twin
(``lockstep_tests --replay``) and through the Python reference (``uav_common.lockstep``), and every decision must
be the same: the same batch in the same order, the same missing counts, the same errors, the same timer firings
and due times to the last bit.
"""

from __future__ import annotations

import random
import subprocess

import pytest
from helpers.procs import REPO

from uav_common.lockstep.protocol import BoundaryQueue, InputLedger, LockstepError, Tick
from uav_common.lockstep.timers import SimTimer

BINARY = REPO / "catkin_ws" / "devel" / "lib" / "uav_mapping" / "lockstep_tests"


def _names() -> list[str]:
    if not BINARY.exists():
        return ["<lockstep_tests not built: run make build>"]
    out = subprocess.run([str(BINARY), "--list"], capture_output=True, text=True, check=True, timeout=30)
    return out.stdout.split()


@pytest.fixture(scope="module")
def results() -> dict[str, str]:
    assert BINARY.exists(), f"{BINARY} is missing: run `make build`"
    proc = subprocess.run([str(BINARY), "--all"], capture_output=True, text=True, timeout=60, check=False)
    lines: dict[str, str] = {}
    for line in proc.stdout.splitlines():
        verdict, _, rest = line.partition(" ")
        if verdict in ("PASS", "FAIL"):
            name, _, detail = rest.partition(": ")
            lines[name] = f"{verdict} {detail}".strip()
    lines["__returncode__"] = str(proc.returncode)
    lines["__stderr__"] = proc.stderr[-2000:]
    return lines


@pytest.mark.parametrize("name", _names())
def test_cpp(name: str, results: dict[str, str]) -> None:
    verdict = results.get(name)
    assert verdict is not None, f"{name} did not run (exit {results['__returncode__']}): {results['__stderr__']}"
    assert verdict == "PASS", f"{name}: {verdict}"


def test_all_tests_ran_and_the_binary_exited_cleanly(results: dict[str, str]) -> None:
    ran = {k for k in results if not k.startswith("__")}
    assert ran == set(_names())
    failed = sorted(k for k in ran if results[k] != "PASS")
    assert results["__returncode__"] == ("1" if failed else "0"), results["__stderr__"]


# ---------------------------------------------------------------------------------------------- the twin's replay


class _Reference:
    """Runs a replay trace (the commands of ``lockstep_tests --replay``) through the Python reference."""

    def __init__(self) -> None:
        self.ledger: InputLedger[str] = InputLedger(())
        self.queue: BoundaryQueue[str] = BoundaryQueue()
        self.timer = SimTimer(1.0)

    def run(self, trace: list[str]) -> list[str]:
        out: list[str] = []
        for line in trace:
            cmd, *args = line.split()
            if cmd == "ledger":
                self.ledger = InputLedger(())
            elif cmd == "topic":
                self.ledger.add_topic(args[0], first=args[1] == "first")
            elif cmd == "recv":
                self.ledger.received(args[0], args[1], args[2])
            elif cmd == "tick":
                out.append(self._tick(args))
            elif cmd == "queue":
                self.queue = BoundaryQueue()
            elif cmd == "put":
                self.queue.put(int(args[0]), args[1])
            elif cmd == "due":
                out.append(" ".join(["due", *self.queue.due(int(args[0]))]))
            elif cmd == "timer":
                first = None if args[1] == "-" else float(args[1])
                self.timer = SimTimer(float(args[0]), first_due_s=first)
            elif cmd == "at":
                fired = self.timer.due(float(args[0]))
                out.append(f"{int(fired)} {self.timer.next_due_s!r}")
            else:
                raise AssertionError(f"unknown command {cmd}")
        return out

    def _tick(self, args: list[str]) -> str:
        step, t_s, n_parts = int(args[0]), float(args[1]), int(args[2])
        parts = frozenset(args[3 : 3 + n_parts])
        rest = args[3 + n_parts :]
        n_counts = int(rest[0])
        counts = {(rest[1 + 3 * i], rest[2 + 3 * i]): int(rest[3 + 3 * i]) for i in range(n_counts)}
        tick = Tick(step, t_s, counts, parts)
        try:
            missing = self.ledger.missing(tick)
            if missing:
                return " ".join(["missing", *(f"{m.topic} {m.publisher} {m.expected} {m.received}" for m in missing)])
            return " ".join(["take", *(f"{topic}:{msg}" for topic, msg in self.ledger.take(tick))])
        except LockstepError:
            return "error"


def _cpp(trace: list[str]) -> list[str]:
    proc = subprocess.run(
        [str(BINARY), "--replay"],
        input="\n".join(trace) + "\n",
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.splitlines()


def _ledger_trace(rng: random.Random) -> list[str]:
    """A subscriber's life: publishers ahead of and behind the ticks, foreign publishers, messages before the first
    tick, counts of topics it does not take, and now and then a count that goes back (an error)."""
    pool = ["/cloud", "/tf", "/tf_static", "/depth", "/info"]
    inputs = rng.sample(pool, rng.randint(1, 4))
    counted = ["/bridge", "/a", "/odom"]
    foreign = ["/operator", "/replay"]
    trace = ["ledger"]
    for topic in inputs:
        trace.append(f"topic {topic} {'first' if rng.random() < 0.3 else 'last'}")
    sent: dict[tuple[str, str], int] = {}
    counts: dict[tuple[str, str], int] = {}
    undelivered: dict[tuple[str, str], list[str]] = {}
    serial = 0

    def deliver(fraction: float) -> None:
        keys = [k for k, v in undelivered.items() if v]
        rng.shuffle(keys)
        for key in keys:  # one connection per (topic, publisher): in order within it, any order across
            n = len(undelivered[key]) if fraction >= 1.0 else rng.randint(0, len(undelivered[key]))
            for msg in undelivered[key][:n]:
                trace.append(f"recv {key[0]} {key[1]} {msg}")
            undelivered[key] = undelivered[key][n:]

    for step in range(1, rng.randint(4, 14)):
        for _ in range(rng.randint(0, 6)):
            serial += 1
            pub = rng.choice(counted + foreign)
            topic = rng.choice([*inputs, "/elsewhere"]) if rng.random() < 0.9 else "/elsewhere"
            sent[(topic, pub)] = sent.get((topic, pub), 0) + 1
            undelivered.setdefault((topic, pub), []).append(f"m{serial}")
        if step > 1 or rng.random() < 0.5:
            deliver(rng.random())
        for key, n in sent.items():
            if key[1] in counted:
                counts[key] = rng.randint(counts.get(key, 0), n)
        if rng.random() < 0.05 and counts:
            key = rng.choice(sorted(counts))
            counts[key] = max(0, counts[key] - 1)  # a count that goes back: an error in both
        items = sorted((k, n) for k, n in counts.items() if n > 0)
        parts = sorted(counted)
        line = f"tick {step} {0.1 * step!r} {len(parts)} {' '.join(parts)} {len(items)} " + " ".join(
            f"{t} {p} {n}" for (t, p), n in items
        )
        trace.append(line)
        deliver(1.0)
        trace.append(line)  # the same tick again, now complete (the shell re-checks as messages come)
    return trace


def _timer_trace(rng: random.Random) -> list[str]:
    period = rng.choice([0.05, 0.1, 0.2, 0.5, 1.0, 1.0 / 3.0, 0.3, rng.uniform(0.01, 2.0)])
    first = rng.choice(["-", "-", repr(rng.uniform(0.0, 3.0))])
    trace = [f"timer {period!r} {first}"]
    t = rng.choice([0.0, 1000.0, 1.7e9, rng.uniform(0.0, 5000.0)])
    step = rng.choice([0.1, 0.02, 0.004, 0.125, 1.0 / 3.0, rng.uniform(0.001, 0.7)])
    for _ in range(rng.randint(20, 200)):
        t += step if rng.random() < 0.95 else rng.uniform(0.0, 10.0)  # now and then a jump
        trace.append(f"at {t!r}")
    return trace


def _queue_trace(rng: random.Random) -> list[str]:
    trace = ["queue"]
    finished = 0
    for i in range(rng.randint(5, 60)):
        if rng.random() < 0.6:
            trace.append(f"put {finished + rng.randint(-2, 6)} r{i}")
        else:
            finished += rng.randint(0, 3)
            trace.append(f"due {finished}")
    trace.append(f"due {finished + 100}")
    return trace


@pytest.mark.parametrize("kind", ["ledger", "timer", "queue"])
def test_the_cpp_twin_decides_exactly_as_the_python_reference(kind: str) -> None:
    assert BINARY.exists(), f"{BINARY} is missing: run `make build`"
    make = {"ledger": _ledger_trace, "timer": _timer_trace, "queue": _queue_trace}[kind]
    rng = random.Random(f"lockstep-{kind}")
    trace: list[str] = []
    for _ in range(300):
        trace += make(rng)
    expected = _Reference().run(trace)
    got = _cpp(trace)
    assert len(got) == len(expected)
    if kind == "timer":  # due times printed as %.17g by C++, repr by Python: compare the floats
        got = [f"{line.split()[0]} {float(line.split()[1])!r}" for line in got]
    mismatches = [(i, e, g) for i, (e, g) in enumerate(zip(expected, got, strict=True)) if e != g]
    assert not mismatches, f"{len(mismatches)} of {len(expected)} decisions differ, first: {mismatches[0]}"
    decisions = {line.split()[0] for line in expected}
    wanted = {"ledger": {"take", "missing", "error"}, "timer": {"0", "1"}, "queue": {"due"}}[kind]
    assert decisions == wanted, f"the traces never exercised {wanted - decisions}"


def test_unknown_test_name_is_an_error() -> None:
    proc = subprocess.run([str(BINARY), "no_such_test"], capture_output=True, text=True, timeout=30, check=False)
    assert proc.returncode == 2
    assert "unknown test no_such_test" in proc.stderr
