"""Child processes of the range's shells and tests: start with a log, wait for a port, stop without leaks.

``uav-run`` starts ``roslaunch``, the tests start roscore, the SITL, the router and nodes;
all of them use this module, so every child runs in its own process group with its output
in a log file, and :func:`stop_process_group` ends the whole group: SIGINT (the clean
shutdown ROS tools expect), then SIGTERM, then SIGKILL, then SIGKILL again for anything
in the group that outlived its leader (``rosbag play --wait-for-subscribers`` ignores SIGINT
while it waits). ``roslaunch`` starts the master and every node in a session of its own, out of
its group's reach: whatever descended from the leader and is still alive once the leader is
gone (a master and nodes orphaned by a killed roslaunch) is stopped too, SIGTERM then SIGKILL.
A child can also be told to receive a signal when its parent dies (``with_parent_death_signal`` for a
command, :func:`die_with_parent` inside a ``multiprocessing`` child), so a killed ``uav-run``, campaign
worker or dataset worker never leaves its children behind.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import random
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from uav_common.errors import ResourceError

__all__ = [
    "LoggedProcess",
    "descendants",
    "die_with_parent",
    "free_port",
    "free_udp_port",
    "stop_process_group",
    "wait_for_port",
    "with_parent_death_signal",
]


def _start_time(pid: int) -> str | None:
    """The process's start time (clock ticks since boot), to tell it from a later process with the same pid."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return fields[19] if len(fields) > 19 and fields[0] != "Z" else None


def descendants(pid: int) -> dict[int, str]:
    """Every live descendant of ``pid`` (children, their children...), pid -> start time (Linux ``/proc``)."""
    parent: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int(Path(entry, "stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        parent[int(entry.name)] = ppid
    children: dict[int, list[int]] = {}
    for child, ppid in parent.items():
        children.setdefault(ppid, []).append(child)
    out: dict[int, str] = {}
    todo = list(children.get(pid, []))
    while todo:
        child = todo.pop()
        started = _start_time(child)
        if started is not None:
            out[child] = started
        todo.extend(children.get(child, []))
    return out


def _stop_orphans(known: dict[int, str], timeout_s: float) -> None:
    """SIGTERM, then SIGKILL, the processes of ``known`` that are still the same processes and alive."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        alive = [pid for pid, started in known.items() if _start_time(pid) == started]
        if not alive:
            return
        for pid in alive:
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.kill(pid, sig)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and any(_start_time(pid) == known[pid] for pid in alive):
            time.sleep(0.05)


#: Where :func:`free_port` looks first: below the kernel's usual ephemeral range (32768-60999 on Linux).
PORT_RANGE = (20000, 32768)
_PORT_RNG = random.SystemRandom()  # not the global generator: a test that seeds it must not make runs collide


def ephemeral_range(path: Path = Path("/proc/sys/net/ipv4/ip_local_port_range")) -> tuple[int, int]:
    """The kernel's ephemeral port range ``(low, high)``, inclusive (Linux's default if it cannot be read)."""
    try:
        low, high = (int(v) for v in path.read_text().split()[:2])
    except (OSError, ValueError):
        return 32768, 60999
    return low, high


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    """A currently free localhost port (TCP by default, UDP with ``socket.SOCK_DGRAM``), outside the kernel's
    ephemeral range when it can be: a client that retries a port inside that range while its server is still
    starting can be handed that very port as its own source and connect to itself (see
    :func:`uav_common.shell.sockets.connected_to_itself`); a port below the range cannot be a source port.
    Falls back to a port the kernel picks when no port of :data:`PORT_RANGE` below the range is free."""
    low, _ = ephemeral_range()
    top = min(PORT_RANGE[1], low)
    for _ in range(100 if top > PORT_RANGE[0] else 0):
        port = _PORT_RNG.randrange(PORT_RANGE[0], top)
        with socket.socket(socket.AF_INET, kind) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
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
    tree = descendants(proc.pid)  # before the leader can die and its children be re-parented
    stages = ((signal.SIGINT, int_timeout_s), (signal.SIGTERM, term_timeout_s), (signal.SIGKILL, kill_timeout_s))
    for sig, wait_s in stages:
        if proc.poll() is not None:
            break
        tree |= descendants(proc.pid)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=wait_s)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)  # stragglers only: the leader has exited or been killed
    _stop_orphans(tree, kill_timeout_s)  # what the leader started in sessions of their own and left behind
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


def with_parent_death_signal(argv: Sequence[str], sig: int) -> list[str]:
    """``argv`` run under ``setpriv --pdeathsig SIG`` (util-linux): the kernel sends ``sig`` when its parent dies.

    Raises:
        ResourceError: ``setpriv`` is not installed.
    """
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        msg = "setpriv (util-linux) is not on PATH; install util-linux (it is part of every Debian system)"
        raise ResourceError(msg)
    return [setpriv, "--pdeathsig", signal.Signals(sig).name.removeprefix("SIG"), "--", *argv]


_PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent(parent_pid: int, sig: int = signal.SIGKILL) -> None:
    """Have the kernel send ``sig`` to this process when its parent dies (``prctl(PR_SET_PDEATHSIG)``), for a
    ``multiprocessing`` child that must not outlive the process that feeds it. If the parent (``parent_pid``)
    is already gone, the signal is sent now. The kernel watches the parent *thread* that started this process:
    start it from a thread that lives as long as it is needed.

    Raises:
        ResourceError: the kernel refused (not Linux).
    """
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
        err = ctypes.get_errno()
        msg = f"prctl(PR_SET_PDEATHSIG) failed: {os.strerror(err)} (Linux only)"
        raise ResourceError(msg)
    if os.getppid() != parent_pid:  # died before the request: nobody will send the signal
        os.kill(os.getpid(), sig)


class LoggedProcess:
    """One child process in its own process group, its stdout and stderr in ``log_path``.

    Use as a context manager or call :meth:`stop`; ``env`` is merged over the current environment.
    ``parent_death_signal`` (e.g. ``signal.SIGINT``): the signal the child gets if this process dies.
    """

    def __init__(
        self,
        name: str,
        argv: Sequence[str],
        *,
        log_path: Path,
        env: Mapping[str, str] | None = None,
        cwd: Path | None = None,
        parent_death_signal: int | None = None,
    ) -> None:
        self.name = name
        self.argv = list(argv) if parent_death_signal is None else with_parent_death_signal(argv, parent_death_signal)
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
