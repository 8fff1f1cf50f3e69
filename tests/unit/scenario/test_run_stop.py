"""uav-run's stop of roslaunch's process group leaves nothing behind."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from uav_autonomy.ros.scenario_run import _stop

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
    _stop(leader, timeout_s=10.0)  # type: ignore[arg-type]
    assert leader.returncode == 0  # the leader stopped on SIGINT, not escalated to SIGKILL
    assert _gone(child), "the SIGINT-deaf child outlived uav-run's stop"
    assert time.monotonic() - t0 < 8.0
