"""uav_sim_bridge.shell.settle: "is the run idle?" over a real process tree (the determinism mechanism)."""

from __future__ import annotations

import subprocess
import sys
import time

from uav_sim_bridge.shell.settle import Settle


def test_an_idle_tree_settles_and_a_busy_child_does_not() -> None:
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        settle = Settle(sleeper.pid, timeout_s=1.0)
        time.sleep(0.3)  # let the interpreter start and go to sleep
        assert settle.wait()
    finally:
        sleeper.kill()
        sleeper.wait()
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        settle = Settle(spinner.pid, timeout_s=0.5)
        t0 = time.monotonic()
        assert not settle.wait()
        assert time.monotonic() - t0 >= 0.5
        assert settle.stats.timeouts == 1
    finally:
        spinner.kill()
        spinner.wait()
