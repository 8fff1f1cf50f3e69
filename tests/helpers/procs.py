"""Process harness for ros and e2e tests: logged child processes, roscore, free ports.

The process plumbing is :mod:`uav_common.shell.processes` (shared with ``uav-run``): every
child gets an explicit environment and its own log file under ``artifacts/logs/`` (named
after the test), and ``stop()`` escalates SIGINT -> SIGTERM -> SIGKILL over the whole process
group, so a test never leaks a process, even when it fails.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import subprocess
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

from helpers.paths import REPO
from uav_common.shell.processes import LoggedProcess, descendants, free_port, free_udp_port, wait_for_port

__all__ = [
    "REPO",
    "Proc",
    "artifacts_dir",
    "crash_launched_node",
    "free_port",
    "free_udp_port",
    "roscore",
    "slug",
    "wait_for_port",
]


def artifacts_dir() -> Path:
    """Where tests write logs and images for a person to look at."""
    path = Path(os.environ.get("UAV_ARTIFACTS", REPO / "artifacts"))
    path.mkdir(parents=True, exist_ok=True)
    return path


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)[:120]


class Proc(LoggedProcess):
    """A :class:`uav_common.shell.processes.LoggedProcess` logging to ``artifacts/logs/<name>.log``, run in the repo."""

    def __init__(
        self,
        name: str,
        argv: Sequence[str],
        *,
        env: Mapping[str, str] | None = None,
        cwd: Path | None = None,
        log_dir: Path | None = None,
    ) -> None:
        log_dir = log_dir or artifacts_dir() / "logs"
        super().__init__(name, argv, log_path=log_dir / f"{slug(name)}.log", env=env, cwd=cwd or REPO)


def crash_launched_node(launch: LoggedProcess, node_name: str, timeout_s: float = 10.0) -> int:
    """SIGKILL the node ``node_name`` (its ``__name:=``) that the ``roslaunch`` process ``launch`` started, and
    wait until it is gone; returns its pid. roslaunch starts each node in a session of its own, so a signal to
    the launch's process group never reaches the node: this is how a test crashes one."""
    pids = [pid for pid in descendants(launch.pid) if f"__name:={node_name}" in _cmdline(pid).split("\0")]
    if len(pids) != 1:
        msg = f"{launch.name}: expected one node named {node_name}, found pids {pids}"
        raise AssertionError(msg)
    os.kill(pids[0], signal.SIGKILL)
    deadline = time.monotonic() + timeout_s
    while _running(pids[0]):
        if time.monotonic() > deadline:
            msg = f"{launch.name}: node {node_name} (pid {pids[0]}) still running {timeout_s} s after SIGKILL"
            raise AssertionError(msg)
        time.sleep(0.05)
    return pids[0]


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
    except OSError:  # gone meanwhile
        return ""


def _running(pid: int) -> bool:
    """Whether ``pid`` exists and is not a zombie (dead, waiting for its parent to reap it)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


@contextlib.contextmanager
def roscore(name: str = "roscore") -> Iterator[dict[str, str]]:
    """Start a real ``roscore`` on a free port; yield the env that points at it."""
    port = free_port()
    env = {"ROS_MASTER_URI": f"http://127.0.0.1:{port}", "ROS_IP": "127.0.0.1", "ROS_HOSTNAME": "127.0.0.1"}
    proc = Proc(name, ["roscore", "-p", str(port)], env=env)
    try:
        wait_for_port(port, timeout_s=20.0, proc=proc)
        # The master accepts connections slightly before /rosout is up; wait for rosout.
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline:
            out = subprocess.run(
                ["rosnode", "list"], env={**os.environ, **env}, capture_output=True, text=True, check=False
            )
            if "/rosout" in out.stdout:
                break
            time.sleep(0.2)
        os.environ.update(env)
        yield env
    finally:
        proc.stop()
