"""One campaign run on a worker: exactly the run ``uav-run`` makes, in its own folder, within a budget.

:func:`execute_run` is what a Dask worker executes (through :func:`dask_execute_run`, which wires
it to the worker's event log and the campaign's stop event); the benchmark and the tests call it
directly. It writes the run's world file and effective scenario into the run folder and starts
``uav-run SCENARIO --run-dir RUN_DIR --quiet`` (its own ROS master, free ports, log, report). The
run is therefore self-contained: ``uav-run RUN_DIR/scenario.yaml`` repeats it anywhere.

What can go wrong, and what is recorded (``status``/``reason`` of the result):

* the run ends on a stop criterion and is scored: ``done``;
* ``uav-run`` exits non-zero or a node dies: ``failed``/``crashed`` (with the log's tail);
* it outlives its wall-clock budget (or the mission manager's wall guard stops it): ``failed``/``hung``;
  it is stopped (SIGINT, then escalation to its whole process group);
* the scenario does not load on this worker: ``failed``/``bad_config``; a tool is missing: ``failed``/
  ``unavailable``;
* the campaign is stopped (Ctrl-C): the run is stopped cleanly and reported ``interrupted``.

If the worker process dies, ``uav-run`` gets SIGTERM from the kernel (``setpriv --pdeathsig``) and
stops its run cleanly; the client records the run as orphaned and Dask gives it to another worker.

Results come back in the returned dict. When the worker sees the campaign directory (a shared
file system, or the same machine) it writes the run folder there; otherwise it runs in a temporary
folder and returns the folder as a ``tar.gz`` archive (without bags and map files), which the client
unpacks into the campaign directory.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import signal
import socket
import tarfile
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import yaml

from uav_common.errors import ResourceError
from uav_common.shell.processes import LoggedProcess, with_parent_death_signal

__all__ = [
    "ARCHIVE_EXCLUDE",
    "classify",
    "dask_execute_run",
    "execute_run",
    "pack_run_dir",
    "probe_worker",
    "uav_run_argv",
    "unpack_run_dir",
    "write_inputs",
]

#: Files left out of a run folder sent back over the network (big, and not needed by the campaign report).
ARCHIVE_EXCLUDE = (".bag", ".bag.active", ".ot", ".bt", ".vdb", ".tlog")
#: Extra wall seconds after the budget: uav-run's start-up (world, nodes) and its report.
BUDGET_GRACE_S = 120.0
#: Stop reasons that mean the run did not finish its job (infrastructure, not a result).
FAILED_STOPS = {"wall_timeout": "hung", "node_died": "crashed"}

EventSink = Callable[[dict[str, Any]], None]


def _tail(path: Path, lines: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None
    return data if isinstance(data, dict) else None


def _shared_dir(job: Mapping[str, Any]) -> bool:
    """Whether this worker sees the campaign directory (so it writes the run folder there)."""
    if job.get("transfer") == "always":
        return False
    ident = _read_json(Path(str(job["out_dir"])) / "campaign.json")
    return ident is not None and ident.get("campaign_id") == job["campaign_id"]


def _fresh_dir(path: Path) -> Path:
    """``path``, or ``path.2``, ``path.3``... if a try that was orphaned already used it."""
    candidate, n = path, 1
    while candidate.exists():
        n += 1
        candidate = path.with_name(f"{path.name}.{n}")
    return candidate


def write_inputs(job: Mapping[str, Any], run_dir: Path) -> Path:
    """The world file and the effective scenario (pointing at that world file) in the run folder."""
    run_dir.mkdir(parents=True, exist_ok=True)
    world = run_dir / "world.yaml"
    world.write_text(str(job["world_text"]))
    scenario = dict(job["scenario"])
    scenario["world"] = {**dict(scenario["world"]), "config": str(world)}
    path = run_dir / "campaign_scenario.yaml"
    header = f"# Campaign {job['campaign']} run {job['label']} (configuration {str(job['config_hash'])[:16]}).\n"
    path.write_text(header + yaml.safe_dump(scenario, sort_keys=False))
    return path


def uav_run_argv(scenario: Path, run_dir: Path) -> list[str]:
    """``uav-run SCENARIO --run-dir RUN_DIR --quiet``, under ``setpriv --pdeathsig TERM``."""
    argv = ["uav-run", str(scenario), "--run-dir", str(run_dir), "--quiet"]
    # the kernel sends uav-run SIGTERM if the worker dies: it then stops its run instead of orphaning it
    return with_parent_death_signal(argv, signal.SIGTERM)


#: uav-run's exit status -> the failure reason (docs/architecture.md exit codes); others: killed by a signal.
_EXIT_REASONS = {0: "no_metrics", 1: "crashed", 2: "bad_config", 3: "unavailable", None: "crashed"}


def classify(rc: int | None, metrics: dict[str, Any] | None, *, hung: bool, stopped: bool) -> tuple[str, str]:
    """(status, reason) of a finished ``uav-run`` (module docstring)."""
    stop = str((metrics or {}).get("stop_reason") or "")
    if stopped:
        out = ("interrupted", "campaign stopped")
    elif hung or stop in FAILED_STOPS:
        out = ("failed", "hung" if hung else FAILED_STOPS[stop])
    elif rc == 0 and metrics is not None and metrics.get("final"):
        out = ("done", "")
    else:
        out = ("failed", _EXIT_REASONS.get(rc, f"killed (exit {rc})"))
    return out


def execute_run(
    job: Mapping[str, Any],
    *,
    on_event: EventSink | None = None,
    should_stop: Callable[[], bool] | None = None,
    worker: str = "",
    poll_s: float = 1.0,
) -> dict[str, Any]:
    """Run one planned run to its end (module docstring) and return its result.

    Args:
        job: what the client sends (:func:`uav_campaigns.shell.dask_exec.make_job`).
        on_event: called with the ``started`` event once the run folder exists.
        should_stop: polled every ``poll_s``; True stops the run cleanly (the campaign was interrupted).
        worker: this worker's address, for the manifest.
    """
    host = socket.gethostname()
    shared = _shared_dir(job)
    planned = Path(str(job["run_dir"]))
    tmp_root = None if shared else Path(tempfile.mkdtemp(prefix="uav-campaign-"))
    run_dir = _fresh_dir(planned) if tmp_root is None else tmp_root / planned.name
    base = {"key": job["key"], "try": job["try"], "worker": worker, "host": host}
    result: dict[str, Any] = {**base, "event": "finished", "run_dir": str(run_dir), "shared": shared}
    if should_stop is not None and should_stop():
        return {**result, "status": "interrupted", "reason": "campaign stopped before the run started"}
    t0 = time.monotonic()
    started_at = time.time()
    log = run_dir / "uav-run.log"
    rc: int | None = None
    hung = stopped = False
    try:
        scenario = write_inputs(job, run_dir)
        if on_event is not None:
            on_event({**base, "event": "started", "run_dir": str(run_dir), "t": started_at})
        proc = LoggedProcess("uav-run", uav_run_argv(scenario, run_dir), log_path=log, env={"PYTHONUNBUFFERED": "1"})
        deadline = t0 + float(job["budget_s"]) + float(job.get("grace_s", BUDGET_GRACE_S))
        try:
            while proc.alive():
                time.sleep(poll_s)
                if should_stop is not None and should_stop():
                    stopped = True
                    break
                if time.monotonic() > deadline:
                    hung = True
                    break
        finally:
            # SIGINT: uav-run stops roslaunch (every node, the bag) and still builds the report; then escalate
            rc = proc.stop(float(job.get("stop_timeout_s", 20.0)), int_timeout_s=float(job.get("int_timeout_s", 90.0)))
    except ResourceError as err:
        result.update(status="failed", reason="unavailable", exit_code=None, log_tail=str(err))
        return _finish(result, job, run_dir, tmp_root, t0)
    except OSError as err:
        result.update(status="failed", reason="runner_error", exit_code=None, log_tail=f"{type(err).__name__}: {err}")
        return _finish(result, job, run_dir, tmp_root, t0)
    metrics = _read_json(run_dir / "metrics.json")
    pace = _read_json(run_dir / "pace.json") or {}
    status, reason = classify(rc, metrics, hung=hung, stopped=stopped)
    tail = (
        "" if status == "done" else _tail(log) + "\n--- roslaunch.log ---\n" + _tail(run_dir / "logs" / "roslaunch.log")
    )
    result.update(
        status=status,
        reason=reason,
        exit_code=rc,
        stop_reason=(metrics or {}).get("stop_reason"),
        sim_s=((metrics or {}).get("time") or {}).get("duration_s"),
        rtf=pace.get("real_time_factor"),
        started_at=started_at,
        log_tail=tail[-6000:],
    )
    return _finish(result, job, run_dir, tmp_root, t0)


def _finish(
    result: dict[str, Any], job: Mapping[str, Any], run_dir: Path, tmp_root: Path | None, t0: float
) -> dict[str, Any]:
    result["wall_s"] = round(time.monotonic() - t0, 3)
    if tmp_root is not None:
        result["archive"] = pack_run_dir(run_dir)
        shutil.rmtree(tmp_root, ignore_errors=True)
    return result


def pack_run_dir(run_dir: Path) -> bytes:
    """The run folder as ``tar.gz`` bytes (without :data:`ARCHIVE_EXCLUDE`), names relative to it."""
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        if run_dir.is_dir():
            for path in sorted(run_dir.rglob("*")):
                if path.is_file() and not path.name.endswith(ARCHIVE_EXCLUDE):
                    tar.add(path, arcname=str(path.relative_to(run_dir)), recursive=False)
    return buf.getvalue()


def unpack_run_dir(archive: bytes, dest: Path) -> None:
    """Unpack :func:`pack_run_dir`'s bytes into ``dest`` (only regular files, only inside ``dest``)."""
    dest.mkdir(parents=True, exist_ok=True)
    root = dest.resolve()
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        for member in tar.getmembers():  # Debian's Python 3.11.2 has no extraction filters: check by hand
            target = (root / member.name).resolve()
            if not member.isfile() or not target.is_relative_to(root):
                continue
            src = tar.extractfile(member)
            if src is None:
                continue
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(src.read())


def probe_worker() -> dict[str, Any]:
    """What a worker can run (called on every worker before the campaign starts)."""
    missing = [tool for tool in ("uav-run", "roslaunch") if shutil.which(tool) is None]
    return {
        "host": socket.gethostname(),
        "pid": os.getpid(),
        "cpus": os.cpu_count() or 1,
        "missing": missing,
        "setpriv": shutil.which("setpriv") is not None,
    }


def dask_execute_run(job: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`execute_run` inside a Dask task: events to the campaign's topic, the campaign's stop event polled."""
    from distributed import Event, get_worker  # noqa: PLC0415 - only on a worker

    w = get_worker()
    topic = str(job["topic"])
    event = Event(str(job["stop_event"]))

    def on_event(ev: dict[str, Any]) -> None:
        w.log_event(topic, ev)

    def should_stop() -> bool:
        try:
            return bool(event.is_set())
        except (OSError, TimeoutError, RuntimeError):
            return False  # the scheduler is briefly unreachable: keep running

    return execute_run(job, on_event=on_event, should_stop=should_stop, worker=str(w.address))
