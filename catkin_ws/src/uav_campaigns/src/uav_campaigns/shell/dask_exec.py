"""The runs go out on Dask: an embedded local cluster, or an existing ``dask scheduler`` / ``dask worker`` cluster.

:func:`connect` reaches the cluster (or starts the embedded one, sized so that workers x cores per
run <= the machine's cores) and checks every worker can run the project before anything starts.
:class:`Executor` submits one Dask task per run (:func:`uav_campaigns.shell.runner.dask_execute_run`),
writes every event to the manifest as it happens, shows the progress line, tries failed runs again up
to the campaign's limit, records a run whose worker left the cluster as orphaned (Dask gives the task
to another worker), and on Ctrl-C stops the runs in progress cleanly (a Dask ``Event`` the tasks poll).
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import queue
import re
import shutil
import sys
import threading
import time
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from uav_campaigns.core.config import Campaign
from uav_campaigns.core.manifest import Decision, fold, may_retry
from uav_campaigns.core.plan import PlannedRun
from uav_campaigns.core.progress import Counts, eta_s, format_duration, progress_line
from uav_campaigns.errors import CampaignConfigError, CampaignResourceError
from uav_campaigns.shell.runner import dask_execute_run, probe_worker, unpack_run_dir
from uav_campaigns.shell.store import CampaignDir
from uav_common.config import to_mapping

__all__ = ["Cluster", "Executor", "InvocationResult", "connect", "local_workers", "throughput"]

_ADDRESS = re.compile(r"^(tcp|tls|inproc|ucx|ws|wss)://[^\s:/]+(:\d+)?/?$")


def local_workers(cores: int, cores_per_run: float) -> int:
    """Workers of the embedded cluster: as many runs at once as fit the cores (at least one)."""
    return max(1, math.floor(cores / cores_per_run + 1e-9))


@dataclass
class Cluster:
    """A connected Dask client and, for the embedded cluster, the cluster it started."""

    client: Any
    local: Any | None
    address: str
    dashboard: str

    @property
    def mode(self) -> str:
        return "embedded" if self.local is not None else "remote"

    def workers(self) -> dict[str, int]:
        """Connected workers -> their threads (each thread runs one run at a time)."""
        try:
            return {str(k): int(v) for k, v in self.client.nthreads().items()}
        except (OSError, TimeoutError):
            return {}

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.client.close(timeout=10)
        if self.local is not None:
            with contextlib.suppress(Exception):
                self.local.close(timeout=30)


def connect(
    scheduler: str | None,
    *,
    workers: int | None,
    cores_per_run: float,
    dashboard_address: str = ":8787",
    timeout_s: float = 10.0,
) -> Cluster:
    """Reach the scheduler (``tcp://HOST:8786``) or start the embedded cluster, then check the workers.

    Raises:
        CampaignConfigError: the scheduler address is not an address.
        CampaignResourceError: the scheduler cannot be reached, or a worker cannot run the project's runs.
    """
    from distributed import Client, LocalCluster  # noqa: PLC0415 - slow import, only when runs go out

    if scheduler is not None:
        if not _ADDRESS.match(scheduler):
            msg = f"--scheduler {scheduler!r} is not a Dask scheduler address; give e.g. tcp://HOST:8786"
            raise CampaignConfigError(msg)
        try:
            client = Client(scheduler, timeout=f"{timeout_s}s", set_as_default=False)
        except (OSError, TimeoutError) as err:
            msg = (
                f"cannot reach the Dask scheduler at {scheduler} within {timeout_s:g} s ({err}). Start one with "
                "`scripts/in_env dask scheduler` and workers with `scripts/in_env dask worker "
                f"{scheduler} --nthreads 1`, or leave out --scheduler to run on an embedded local cluster"
            )
            raise CampaignResourceError(msg) from err
        cluster = Cluster(client, None, scheduler, str(client.dashboard_link or ""))
    else:
        n = workers or local_workers(os.cpu_count() or 1, cores_per_run)
        local = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            dashboard_address=dashboard_address,
            silence_logs=logging.ERROR,
            preload=["uav_campaigns.shell.local_worker"],  # the workers ignore Ctrl-C: uav-campaign handles it
        )
        client = Client(local, set_as_default=False)
        cluster = Cluster(client, local, str(local.scheduler_address), str(client.dashboard_link or ""))
    try:
        check_workers(cluster)
    except BaseException:
        cluster.close()
        raise
    return cluster


def check_workers(cluster: Cluster) -> dict[str, dict[str, Any]]:
    """Every connected worker can import the project and finds ``uav-run`` and ``roslaunch``.

    Raises:
        CampaignResourceError: naming each worker that cannot, and how to start one that can.
    """
    if not cluster.workers():
        return {}
    hint = "start workers from a checkout with `scripts/in_env dask worker ADDRESS --nthreads 1` (docs/campaigns.md)"
    try:
        infos: dict[str, dict[str, Any]] = cluster.client.run(probe_worker)
    except Exception as err:
        msg = f"a Dask worker cannot run the project's code ({type(err).__name__}: {err}); {hint}"
        raise CampaignResourceError(msg) from err
    bad = {w: i["missing"] for w, i in infos.items() if i.get("missing")}
    if bad:
        msg = f"Dask workers without the project's programs: {bad}; {hint}"
        raise CampaignResourceError(msg)
    return infos


@dataclass
class _Running:
    key: str
    try_no: int
    worker: str
    run_dir: str
    t0: float


@dataclass
class InvocationResult:
    """What one ``uav-campaign run`` did."""

    finished: int = 0
    failed_tries: int = 0
    orphaned: int = 0
    interrupted: bool = False
    wall_s: float = 0.0
    #: Wall seconds of each run's ``uav-run`` (inside the task) and the simulated seconds it ran.
    run_wall_s: list[float] = field(default_factory=list)
    run_sim_s: list[float] = field(default_factory=list)
    #: The most runs the cluster ran at once (its threads) during the invocation.
    slots: int = 1


class Executor:
    """Runs a campaign's decision on a cluster (module docstring)."""

    def __init__(
        self,
        cluster: Cluster,
        cdir: CampaignDir,
        campaign: Campaign,
        fingerprint: str,
        runs: Sequence[PlannedRun],
        *,
        out: TextIO = sys.stdout,
        transfer: str = "auto",
        progress_every_s: float = 10.0,
    ) -> None:
        self.cluster = cluster
        self.cdir = cdir
        self.campaign = campaign
        self.fingerprint = fingerprint
        self.runs = {r.key: r for r in reversed(runs)}  # the first planned run of a key names it
        self.out = out
        self.transfer = transfer
        self.progress_every_s = progress_every_s
        self.stop_requested = threading.Event()
        self.invocation = uuid.uuid4().hex[:8]
        self.topic = f"uav-campaign-{fingerprint}-{self.invocation}"
        self.stop_name = f"uav-campaign-stop-{fingerprint}-{self.invocation}"
        self._events: queue.Queue[dict[str, Any]] = queue.Queue()
        self._worlds: dict[Path, str] = {}
        self._futures: dict[Any, tuple[str, int]] = {}
        self._running: dict[str, _Running] = {}
        self._durations: list[float] = []
        self._tty = out.isatty()
        self._last_line = 0.0

    # ------------------------------------------------------------------------------------------- jobs

    def _world_text(self, run: PlannedRun) -> str:
        path = run.scenario.world_config_path
        if path not in self._worlds:
            self._worlds[path] = path.read_text()
        return self._worlds[path]

    def make_job(self, run: PlannedRun, try_no: int) -> dict[str, Any]:
        scenario = to_mapping(run.scenario)
        scenario.pop("source", None)
        scenario["name"] = f"{self.campaign.name}-{run.arm}-s{run.seed}-r{run.repeat}"
        return {
            "campaign": self.campaign.name,
            "campaign_id": self.fingerprint,
            "key": run.key,
            "try": try_no,
            "label": run.label,
            "arm": run.arm,
            "seed": run.seed,
            "repeat": run.repeat,
            "config_hash": run.config_hash,
            "scenario": scenario,
            "world_text": self._world_text(run),
            "run_dir": str(self.cdir.run_dir(run, try_no)),
            "out_dir": str(self.cdir.path),
            "budget_s": self.campaign.budget_s(run.scenario.stop.time_limit_s),
            "topic": self.topic,
            "stop_event": self.stop_name,
            "transfer": self.transfer,
        }

    def _submit(self, key: str, try_no: int) -> None:
        run = self.runs[key]
        job = self.make_job(run, try_no)
        fut = self.cluster.client.submit(
            dask_execute_run, job, key=f"uav-run-{key}-t{try_no}-{self.invocation}", pure=False, retries=0
        )
        self._futures[fut] = (key, try_no)
        self.cdir.append(
            {"event": "submitted", "key": key, "try": try_no, "arm": run.arm, "seed": run.seed, "repeat": run.repeat}
        )

    # ------------------------------------------------------------------------------------------- events

    def _say(self, text: str) -> None:
        if self._tty:
            self.out.write("\r\x1b[K")
        self.out.write(text + "\n")
        self.out.flush()

    def _rel(self, run_dir: str) -> str:
        try:
            return os.path.relpath(run_dir, self.cdir.path) if Path(run_dir).is_relative_to(self.cdir.path) else ""
        except ValueError:
            return ""

    def _on_started(self, ev: dict[str, Any]) -> None:
        key = str(ev.get("key"))
        if key not in self.runs:
            return
        previous = self._running.get(key)
        if previous is not None and previous.run_dir != ev.get("run_dir"):
            self._orphan(previous, f"started again on {ev.get('worker')} before its first try reported")
        ev = {**ev, "run_path": self._rel(str(ev.get("run_dir", "")))}
        self.cdir.append(ev)
        if (key, int(ev["try"])) not in self._futures.values():
            return  # its result came first (events and results travel separately): it is not running any more
        self._running[key] = _Running(key, int(ev["try"]), str(ev.get("worker")), str(ev.get("run_dir")), time.time())
        self._say(f"started  {self.runs[key].label} (try {ev['try']}) on {ev.get('worker')} -> {ev.get('run_dir')}")

    def _orphan(self, r: _Running, reason: str) -> None:
        self.cdir.append(
            {
                "event": "orphaned",
                "key": r.key,
                "try": r.try_no,
                "worker": r.worker,
                "run_dir": r.run_dir,
                "run_path": self._rel(r.run_dir),
                "reason": reason,
            }
        )
        self._running.pop(r.key, None)
        self._say(
            f"orphaned {self.runs[r.key].label}: {reason}; its logs: {r.run_dir}; Dask gives it to another worker"
        )

    def _check_workers(self, live: Mapping[str, int]) -> None:
        for r in list(self._running.values()):
            if r.worker not in live:
                self._orphan(r, f"worker {r.worker} left the cluster (died, was killed or lost its connection)")

    def _on_done(self, fut: Any, result: InvocationResult) -> None:
        key, try_no = self._futures.pop(fut)
        run = self.runs[key]
        running = self._running.pop(key, None)
        if fut.status == "finished":
            res = dict(fut.result())
            archive = res.pop("archive", None)
            if archive is not None:
                dest = self.cdir.run_dir(run, try_no)
                unpack_run_dir(archive, dest)
                res["run_dir"] = str(dest)
                res["worker_run_dir"] = res.get("run_dir")
        else:
            exc = None if fut.status == "cancelled" else fut.exception()
            reason = "lost" if type(exc).__name__ == "KilledWorker" else "cancelled" if exc is None else "task_error"
            res = {
                "event": "finished",
                "key": key,
                "try": try_no,
                "status": "failed",
                "reason": reason,
                "log_tail": f"{type(exc).__name__}: {exc}" if exc is not None else "the scheduler cancelled the task",
                "worker": running.worker if running else "",
                "run_dir": running.run_dir if running else "",
            }
        res["run_path"] = self._rel(str(res.get("run_dir", "")))
        self.cdir.append(res)
        status, reason = res.get("status"), res.get("reason", "")
        wall = float(res.get("wall_s") or 0.0)
        if status == "done":
            result.finished += 1
            self._durations.append(wall)
            result.run_wall_s.append(wall)
            result.run_sim_s.append(float(res.get("sim_s") or 0.0))
            self._say(
                f"done     {run.label} in {format_duration(wall)} ({res.get('stop_reason')}, "
                f"{float(res.get('sim_s') or 0):.0f} s simulated) on {res.get('worker')}"
            )
            return
        if status == "interrupted":
            self._say(f"stopped  {run.label}: {reason}; it runs again next time")
            return
        result.failed_tries += 1
        state = fold(ev for ev in self.cdir.events() if ev.get("key") == key).get(key)
        again = state is not None and may_retry(state, self.campaign.max_attempts) and not self.stop_requested.is_set()
        tail = str(res.get("log_tail", "")).strip().splitlines()[-3:]
        self._say(
            f"FAILED   {run.label} (try {try_no}): {reason}, exit {res.get('exit_code')}; logs {res.get('run_dir')}"
            + ("".join(f"\n           | {line}" for line in tail))
            + (
                "\n           trying it again"
                if again
                else f"\n           given up after {state.failures if state else 1} failures"
            )
        )
        if again and state is not None:
            self._submit(key, state.tries + 1)

    # ------------------------------------------------------------------------------------------- progress

    def _counts(self, total: int, live: Mapping[str, int]) -> Counts:
        states = fold(self.cdir.events())
        done = sum(1 for k in self.runs if (s := states.get(k)) is not None and s.done is not None)
        failed = sum(
            1
            for k in self.runs
            if (s := states.get(k)) is not None
            and s.done is None
            and (s.permanent_failure or s.failures >= self.campaign.max_attempts)
        )
        running = len(self._running)
        queued = max(0, len(self._futures) - running)
        retrying = sum(1 for k, _ in self._futures.values() if (s := states.get(k)) is not None and s.history)
        return Counts(total, done, failed, running, queued, retrying, len(live))

    def _progress(self, total: int, t0: float, live: Mapping[str, int], *, force: bool = False) -> None:
        now = time.monotonic()
        if not self._tty and not force and now - self._last_line < self.progress_every_s:
            return
        counts = self._counts(total, live)
        elapsed = [time.time() - r.t0 for r in self._running.values()]
        slots = max(1, sum(live.values()))
        line = progress_line(counts, eta_s(self._durations, elapsed, counts.queued, slots), now - t0)
        if self._tty:
            width = shutil.get_terminal_size((160, 20)).columns - 1
            self.out.write("\r" + line[:width] + "\x1b[K")
        else:
            self.out.write(line + "\n")
        self.out.flush()
        self._last_line = now

    # ------------------------------------------------------------------------------------------- main loop

    def execute(self, decision: Decision, *, poll_s: float = 0.5, worker_check_s: float = 2.0) -> InvocationResult:
        """Run ``decision.run`` to the end (or to Ctrl-C: :attr:`stop_requested`)."""
        from distributed import Event  # noqa: PLC0415

        result = InvocationResult()
        t0 = time.monotonic()
        client = self.cluster.client
        client.subscribe_topic(self.topic, lambda ev: self._events.put(ev[1] if isinstance(ev, tuple) else ev))
        total = len(self.runs)
        for key, try_no in decision.run:
            self._submit(key, try_no)
        live = self.cluster.workers()
        result.slots = max(1, sum(live.values()))
        last_check = time.monotonic()
        try:
            while self._futures:
                self._drain()
                if time.monotonic() - last_check >= worker_check_s:
                    live = self.cluster.workers()
                    result.slots = max(result.slots, sum(live.values()))
                    self._check_workers(live)
                    last_check = time.monotonic()
                for fut in [f for f in self._futures if f.done()]:
                    self._drain()
                    self._on_done(fut, result)
                self._progress(total, t0, live)
                if self.stop_requested.is_set():
                    result.interrupted = True
                    self._stop(Event(self.stop_name, client=client), result)
                    break
                time.sleep(poll_s)
        finally:
            with contextlib.suppress(Exception):
                client.unsubscribe_topic(self.topic)
        self._drain()
        if self._tty:
            self.out.write("\n")
        self._progress(total, t0, self.cluster.workers(), force=True)
        result.wall_s = time.monotonic() - t0
        return result

    def _drain(self) -> None:
        while True:
            try:
                ev = self._events.get_nowait()
            except queue.Empty:
                return
            if isinstance(ev, dict) and ev.get("event") == "started":
                self._on_started(ev)

    def _stop(self, event: Any, result: InvocationResult, wait_s: float = 150.0) -> None:
        """Ctrl-C: the runs in progress stop cleanly (uav-run builds their reports), queued ones are cancelled."""
        self._say(
            f"stopping: {len(self._running)} run(s) in progress stop cleanly (up to {wait_s:.0f} s; Ctrl-C again "
            "abandons them); the next `uav-campaign run` resumes where this one stopped"
        )
        with contextlib.suppress(Exception):
            event.set()
        self._drain()
        queued = [f for f, (k, _) in self._futures.items() if k not in self._running]
        with contextlib.suppress(Exception):
            self.cluster.client.cancel(queued)
        for f in queued:
            self._futures.pop(f, None)
        deadline = time.monotonic() + wait_s
        try:
            while self._futures and time.monotonic() < deadline:
                self._drain()
                for fut in [f for f in self._futures if f.done()]:
                    self._on_done(fut, result)
                time.sleep(0.5)
        except KeyboardInterrupt:
            self._say("abandoning the runs in progress (their workers stop them when the cluster closes)")
        for fut, (key, try_no) in list(self._futures.items()):
            r = self._running.get(key)
            self.cdir.append(
                {
                    "event": "finished",
                    "key": key,
                    "try": try_no,
                    "status": "interrupted",
                    "reason": "abandoned when the campaign was stopped",
                    "worker": r.worker if r else "",
                    "run_dir": r.run_dir if r else "",
                }
            )
            with contextlib.suppress(Exception):
                fut.cancel()
        self._futures.clear()


def throughput(result: InvocationResult) -> tuple[float, float]:
    """(simulated seconds per wall second of the invocation, run-slot seconds per run not spent in uav-run).

    The second is ``(wall x slots - sum of the runs' wall) / runs``: scheduling, task start-up, result handling,
    and slots left idle (e.g. the last run alone at the end).
    """
    n = len(result.run_wall_s)
    if n == 0 or result.wall_s <= 0:
        return (math.nan, math.nan)
    return (sum(result.run_sim_s) / result.wall_s, (result.wall_s * result.slots - sum(result.run_wall_s)) / n)
