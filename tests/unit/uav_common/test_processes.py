"""uav_common.shell.processes: stopping a process group leaves nothing behind (uav-run and the tests use it)."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from uav_common.errors import ResourceError
from uav_common.shell.processes import (
    PORT_RANGE,
    LoggedProcess,
    descendants,
    ephemeral_range,
    free_port,
    free_udp_port,
    stop_process_group,
    wait_for_port,
)

# A leader that exits on SIGINT (as roslaunch does) and a child in its group that ignores SIGINT (as
# `rosbag play --wait-for-subscribers` does while it waits).
LEADER = """
import signal, subprocess, sys, time
child = subprocess.Popen(["bash", "-c", "trap '' INT; exec sleep 300"])
print(child.pid, flush=True)
signal.signal(signal.SIGINT, lambda *_: sys.exit(0))
time.sleep(300)
"""


def _gone(pid: int, timeout_s: float = 5.0) -> bool:
    """The process has exited (a zombie waiting for its new parent to reap it counts as exited)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return True
        if state == "Z":
            return True
        time.sleep(0.05)
    return False


def test_stop_kills_what_ignores_sigint_after_its_leader_exits() -> None:
    leader = subprocess.Popen([sys.executable, "-c", LEADER], stdout=subprocess.PIPE, start_new_session=True, text=True)
    assert leader.stdout is not None
    child = int(leader.stdout.readline())
    time.sleep(0.2)  # the child's bash has set its trap and exec'd sleep
    t0 = time.monotonic()
    stop_process_group(leader, int_timeout_s=10.0)
    assert leader.returncode == 0  # the leader stopped on SIGINT, not escalated to SIGKILL
    assert _gone(child), "the SIGINT-deaf child outlived the group's stop"
    assert time.monotonic() - t0 < 8.0


def test_a_process_that_ignores_sigint_and_sigterm_is_killed(tmp_path: Path) -> None:
    script = (
        "import signal, time\n"
        "signal.signal(signal.SIGINT, signal.SIG_IGN)\n"
        "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "time.sleep(60)"
    )
    proc = LoggedProcess("stubborn", [sys.executable, "-c", script], log_path=tmp_path / "stubborn.log")
    time.sleep(0.3)
    t0 = time.monotonic()
    code = proc.stop(0.5)
    assert code == -9  # SIGKILL, after SIGINT and SIGTERM each waited 0.5 s
    assert time.monotonic() - t0 < 5.0


def test_logged_process_output_goes_to_its_log(tmp_path: Path) -> None:
    with LoggedProcess(
        "echo", ["bash", "-c", "echo hello; echo oops >&2"], log_path=tmp_path / "logs" / "echo.log"
    ) as p:
        assert p.wait(5.0) == 0
        assert p.tail().splitlines() == ["hello", "oops"]


def test_a_missing_program_is_a_resource_error(tmp_path: Path) -> None:
    with pytest.raises(ResourceError, match="no-such-program-xyz"):
        LoggedProcess("ghost", ["no-such-program-xyz"], log_path=tmp_path / "ghost.log")


def test_wait_for_port_sees_a_listener_and_reports_a_dead_process(tmp_path: Path) -> None:
    port = free_port()
    assert free_udp_port() > 0
    server = LoggedProcess(
        "listener", [sys.executable, "-m", "http.server", str(port), "--bind", "127.0.0.1"], log_path=tmp_path / "l.log"
    )
    try:
        wait_for_port(port, timeout_s=10.0, proc=server)
    finally:
        server.stop()
    dead = LoggedProcess("dead", [sys.executable, "-c", "print('bye')"], log_path=tmp_path / "d.log")
    dead.wait(5.0)
    with pytest.raises(ResourceError, match=r"dead exited with 0 before opening port \d+:\nbye"):
        wait_for_port(free_port(), timeout_s=5.0, proc=dead)


# roslaunch starts the master and every node with setsid: out of reach of a signal to roslaunch's group.
ROSLAUNCH_LIKE = """
import signal, subprocess, sys, time
child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(300)"], start_new_session=True)
print(child.pid, flush=True)
signal.signal(signal.SIGINT, signal.SIG_IGN)   # a leader that never shuts its nodes down
signal.signal(signal.SIGTERM, signal.SIG_IGN)
time.sleep(300)
"""


def test_what_the_leader_started_in_its_own_session_is_stopped_too(tmp_path: Path) -> None:
    leader = LoggedProcess("launch", [sys.executable, "-c", ROSLAUNCH_LIKE], log_path=tmp_path / "launch.log")
    deadline = time.monotonic() + 10.0
    while not leader.log_text().strip() and time.monotonic() < deadline:
        time.sleep(0.05)
    node = int(leader.log_text().split()[0])
    assert node in descendants(leader.pid)
    assert leader.stop(0.5) == -9
    assert _gone(node), "a node in its own session outlived its killed launcher"


PARENT = """
import signal, sys, time
sys.path[:0] = {paths!r}
from pathlib import Path
from uav_common.shell.processes import LoggedProcess
child = LoggedProcess("child", [sys.executable, "-c", "import time; print('up', flush=True); time.sleep(300)"],
                      log_path=Path({log!r}), parent_death_signal=signal.SIGINT)
print(child.pid, flush=True)
time.sleep(300)
"""


def test_a_child_told_so_stops_when_its_parent_is_killed(tmp_path: Path) -> None:
    """uav-run starts roslaunch this way: a killed uav-run (or campaign worker) never leaves its run behind."""
    code = PARENT.format(paths=sys.path, log=str(tmp_path / "child.log"))
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, start_new_session=True)
    assert parent.stdout is not None
    child = int(parent.stdout.readline())
    deadline = time.monotonic() + 10.0
    while "up" not in (tmp_path / "child.log").read_text() and time.monotonic() < deadline:
        time.sleep(0.05)
    parent.kill()
    parent.wait(5.0)
    assert _gone(child), "the child outlived its SIGKILLed parent"
    assert "KeyboardInterrupt" in (tmp_path / "child.log").read_text()  # it got SIGINT, a clean stop


def test_free_ports_lie_below_the_ephemeral_range_so_no_client_can_take_one_as_its_source(tmp_path: Path) -> None:
    low, high = ephemeral_range()
    assert 1024 <= low <= high
    ports = {free_port() for _ in range(20)} | {free_udp_port() for _ in range(20)}
    assert all(PORT_RANGE[0] <= p < min(PORT_RANGE[1], low) for p in ports), sorted(ports)
    assert len(ports) > 30  # drawn at random, not handed out in sequence
    with socket.socket() as taken:  # a port in use is never returned
        taken.bind(("127.0.0.1", free_port()))
        assert taken.getsockname()[1] not in {free_port() for _ in range(50)}
    text = tmp_path / "range"
    text.write_text("40000\t50000\n")
    assert ephemeral_range(text) == (40000, 50000)
    assert ephemeral_range(tmp_path / "missing") == (32768, 60999)


# A parent that starts a child which asks to die with it, prints the child's pid and sleeps.
PARENT_OF_A_DEPENDENT = """
import os, subprocess, sys, time
code = (
    "import sys, time\\n"
    "from uav_common.shell.processes import die_with_parent\\n"
    "die_with_parent(int(sys.argv[1]))\\n"
    "print('ready', flush=True)\\n"
    "time.sleep(300)\\n"
)
child = subprocess.Popen([sys.executable, "-c", code, str(os.getpid())], stdout=subprocess.PIPE, text=True)
assert child.stdout.readline().strip() == "ready"
print(child.pid, flush=True)
time.sleep(300)
"""


def test_a_child_that_asked_to_die_with_its_parent_does() -> None:
    parent = subprocess.Popen([sys.executable, "-c", PARENT_OF_A_DEPENDENT], stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        child = int(parent.stdout.readline())
        assert not _gone(child, 0.3)  # alive while its parent is
        parent.kill()  # SIGKILL: the parent gets no chance to clean up
        parent.wait(5)
        assert _gone(child), "the child outlived its parent"
    finally:
        if parent.poll() is None:
            parent.kill()


def test_die_with_parent_of_a_parent_already_gone_dies_at_once() -> None:
    """The parent named is not this process's parent any more (it died and the child was re-parented): the
    signal comes at once instead of never."""
    code = "import os\nfrom uav_common.shell.processes import die_with_parent\ndie_with_parent(os.getppid() + 1)\n"
    proc = subprocess.run([sys.executable, "-c", code], check=False, timeout=30)
    assert proc.returncode == -9  # killed by SIGKILL
