"""Child processes of the range's shells and tests: start with a log, wait for a port, stop without leaks.

``uav-run`` starts ``roslaunch``, the tests start roscore, the SITL, the router and nodes;
all of them use this module, so every child runs in its own process group with its output
in a log file, and :func:`stop_process_group` ends the whole group: SIGINT (the clean
shutdown ROS tools expect), then SIGTERM, then SIGKILL, then SIGKILL again for anything
in the group that outlived its leader (``rosbag play --wait-for-subscribers`` ignores SIGINT
while it waits).
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from uav_common.errors import ResourceError

__all__ = ["LoggedProcess", "free_port", "free_udp_port", "stop_process_group", "wait_for_port"]


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A currently free localhost port (TCP by default, UDP with ``socket.SOCK_DGRAM``)."""
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def free_udp_port() -> int:
    return free_port(socket.SOCK_DGRAM)


def stop_process_group(
    proc: subprocess.Popen[bytes] | subprocess.Popen[str],
    *,
    int_timeout_s: float = 5.0,
    term_timeout_s: float = 10.0,
    kill_timeout_s: float = 5.0,
) -> int | None:
    """Stop ``proc`` and its process group (it must have been started with ``start_new_session=True``).

    Returns:
        the leader's exit status (``None`` only if even SIGKILL did not reap it in time).
    """
    stages = ((signal.SIGINT, int_timeout_s), (signal.SIGTERM, term_timeout_s), (signal.SIGKILL, kill_timeout_s))
    for sig, wait_s in stages:
        if proc.poll() is not None:
            break
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=wait_s)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)  # stragglers only: the leader has exited or been killed
    return proc.returncode


def wait_for_port(
    port: int,
    *,
    timeout_s: float = 10.0,
    proc: LoggedProcess | None = None,
    host: str = "127.0.0.1",
) -> None:
    """Block until something accepts TCP connections on ``host:port``.

    Raises:
        ResourceError: ``proc`` exited first (its log's tail is in the message), or the timeout passed.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and not proc.alive():
            msg = f"{proc.name} exited with {proc.popen.returncode} before opening port {port}:\n{proc.tail()}"
            raise ResourceError(msg)
        with socket.socket() as sock:
            sock.settimeout(0.2)
            if sock.connect_ex((host, port)) == 0:
                return
        time.sleep(0.05)
    msg = f"nothing listened on TCP {host}:{port} within {timeout_s} s"
    raise ResourceError(msg)


class LoggedProcess:
    """One child process in its own process group, its stdout and stderr in ``log_path``.

    Use as a context manager or call :meth:`stop`; ``env`` is merged over the current environment.
    """

    def __init__(
        self,
        name: str,
        argv: Sequence[str],
        *,
        log_path: Path,
        env: Mapping[str, str] | None = None,
        cwd: Path | None = None,
    ) -> None:
        self.name = name
        self.argv = list(argv)
        self.log_path = log_path
        log_path.parent.mkdir(parents=True, exist_ok=True)
        self._log = log_path.open("wb")
        full_env = dict(os.environ)
        if env:
            full_env.update(env)
        try:
            self.popen = subprocess.Popen(
                self.argv,
                stdout=self._log,
                stderr=subprocess.STDOUT,
                stdin=subprocess.DEVNULL,
                env=full_env,
                cwd=str(cwd) if cwd is not None else None,
                start_new_session=True,
            )
        except OSError as err:
            self._log.close()
            msg = f"cannot start {name} ({self.argv[0]}): {err.strerror}; is it installed and on PATH?"
            raise ResourceError(msg) from err

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
        """Send ``sig`` to the whole process group."""
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.popen.pid, sig)

    def stop(self, timeout_s: float = 5.0, *, int_timeout_s: float | None = None) -> int | None:
        """:func:`stop_process_group` (``timeout_s`` per stage, ``int_timeout_s`` for SIGINT's); closes the log."""
        code = stop_process_group(
            self.popen,
            int_timeout_s=timeout_s if int_timeout_s is None else int_timeout_s,
            term_timeout_s=timeout_s,
            kill_timeout_s=timeout_s,
        )
        self._log.close()
        return code

    def __enter__(self) -> LoggedProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
