"""Process harness for ros and e2e tests: free ports, logged child processes, roscore.

Every child gets an explicit environment and its own log file under
``artifacts/logs/`` (named after the test), output is drained by the OS into that
file, and ``stop()`` escalates SIGINT -> SIGTERM -> SIGKILL so a test never leaks
a process, even when it fails.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import subprocess
import time
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def artifacts_dir() -> Path:
    """Where tests write logs and images for a person to look at."""
    path = Path(os.environ.get("UAV_ARTIFACTS", REPO / "artifacts"))
    path.mkdir(parents=True, exist_ok=True)
    return path


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A currently free localhost port (TCP by default, UDP with ``SOCK_DGRAM``)."""
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text)[:120]


class Proc:
    """One child process with a log file; use as a context manager or call stop()."""

    def __init__(
        self,
        name: str,
        argv: Sequence[str],
        *,
        env: Mapping[str, str] | None = None,
        cwd: Path | None = None,
        log_dir: Path | None = None,
    ) -> None:
        self.name = name
        self.argv = list(argv)
        log_dir = log_dir or artifacts_dir() / "logs"
        log_dir.mkdir(parents=True, exist_ok=True)
        self.log_path = log_dir / f"{slug(name)}.log"
        self._log = self.log_path.open("wb")
        full_env = dict(os.environ)
        if env:
            full_env.update(env)
        self.popen = subprocess.Popen(
            self.argv,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=full_env,
            cwd=str(cwd or REPO),
            start_new_session=True,
        )

    @property
    def pid(self) -> int:
        return self.popen.pid

    def alive(self) -> bool:
        return self.popen.poll() is None

    def log_text(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")

    def tail(self, lines: int = 40) -> str:
        return "\n".join(self.log_text().splitlines()[-lines:])

    def wait(self, timeout_s: float) -> int:
        return self.popen.wait(timeout=timeout_s)

    def signal(self, sig: int) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.popen.pid, sig)

    def stop(self, timeout_s: float = 5.0) -> int | None:
        """SIGINT, then SIGTERM, then SIGKILL the whole process group; then SIGKILL what outlived its leader."""
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
            if not self.alive():
                break
            self.signal(sig)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.popen.wait(timeout=timeout_s)
        self.signal(signal.SIGKILL)  # e.g. a `rosbag play --wait-for-subscribers` deaf to SIGINT
        self._log.close()
        return self.popen.returncode

    def __enter__(self) -> Proc:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def wait_for_port(port: int, *, timeout_s: float = 10.0, proc: Proc | None = None) -> None:
    """Block until something accepts TCP connections on localhost:``port``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and not proc.alive():
            msg = f"{proc.name} exited with {proc.popen.returncode} before opening port {port}:\n{proc.tail()}"
            raise RuntimeError(msg)
        with socket.socket() as sock:
            sock.settimeout(0.2)
            if sock.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.05)
    msg = f"nothing listened on TCP {port} within {timeout_s} s"
    raise TimeoutError(msg)


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
