"""``uav-dataset generate``'s library: plan the frames, make them (in worker processes), assemble the dataset.

:func:`generate` is the whole job and the CLI is a thin shell over it. The steps:

1. the plan: sampled viewpoints over the split worlds (:func:`~uav_datasets.core.plan.plan_viewpoints`),
   or the frames of a flight (:func:`~uav_datasets.shell.flight.load_flight`);
2. the folder: a new one gets ``dataset.json``; one with the same fingerprint is resumed; anything else
   is refused (:func:`~uav_datasets.shell.folder.prepare_folder`);
3. the frames not made yet, shared among ``workers`` processes (``spawn``: a process never forks after
   a GL context exists). Each worker renders with its own EGL context, writes each frame's files and
   journals the frame. A frame's viewpoint depends only on the seeds and its index, so any sharing
   gives the same dataset;
4. the annotation files, the card and the manifest, once every frame is made.
"""

from __future__ import annotations

import itertools
import json
import multiprocessing
import os
import queue as queue_mod
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from uav_common.errors import ConfigError, ResourceError
from uav_datasets.core.config import DatasetConfig
from uav_datasets.core.plan import FramePlan, plan_viewpoints, shard
from uav_datasets.core.records import FrameRecord
from uav_datasets.errors import DatasetConfigError, DatasetError, FlightError, SamplingError, WorkerError
from uav_datasets.shell.assemble import assemble
from uav_datasets.shell.encoder import InlineWriter, ProcessWriter
from uav_datasets.shell.flight import fly_scenario, load_flight
from uav_datasets.shell.folder import (
    ENGINE_VERSION,
    PROGRESS,
    fingerprint,
    journal_records,
    prepare_folder,
    read_manifest,
    remove_temporaries,
    write_manifest,
)
from uav_datasets.shell.produce import FrameProducer
from uav_datasets.shell.worlds import DEFAULT_CACHE_DIR, load_world, world_configs
from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.world_config import WorldConfig
from uav_sim_bridge.errors import RenderError

__all__ = ["GenerateResult", "ShardJob", "generate", "run_shard"]

Progress = Callable[[int, int], None]


@dataclass(frozen=True)
class GenerateResult:
    """What :func:`generate` did."""

    out_dir: Path
    frames: int
    made: int
    resumed: int
    seconds: float
    already_complete: bool
    manifest: dict[str, Any] = field(default_factory=dict)

    @property
    def frames_per_s(self) -> float:
        return self.made / self.seconds if self.seconds > 0 else 0.0


@dataclass(frozen=True)
class ShardJob:
    """One worker's share: everything it needs, picklable (sent to a spawned process)."""

    out_dir: Path
    cfg: DatasetConfig
    worlds: dict[int, WorldConfig]
    cache_dir: Path
    camera: CameraModel
    frames: tuple[FramePlan, ...]
    journal: Path
    #: A helper process encodes and writes the images (else they are written inline, in this thread).
    encoder_process: bool = True


def run_shard(job: ShardJob, report: Callable[[int], None]) -> None:
    """Make the frames of ``job`` in this process and thread; ``report(index)`` after each is journaled.

    With ``job.encoder_process`` a helper process encodes and writes the images (:class:`ProcessWriter`);
    without, they are written inline.

    Raises:
        DatasetError: a viewpoint cannot be drawn, a world cannot be loaded, the writer died.
        RenderError: no GL context.
    """
    job.journal.parent.mkdir(parents=True, exist_ok=True)
    cam = job.camera
    writer: InlineWriter | ProcessWriter = (
        ProcessWriter(job.out_dir, cam.height, cam.width) if job.encoder_process else InlineWriter(job.out_dir)
    )
    records: dict[int, FrameRecord] = {}
    try:
        with job.journal.open("a", encoding="utf-8") as journal:

            def finish(keys: list[int]) -> None:
                for key in keys:
                    rec = records.pop(key)
                    journal.write(json.dumps(rec.to_json(), sort_keys=True) + "\n")
                    journal.flush()
                    report(rec.index)

            for seed, group in itertools.groupby(job.frames, key=lambda f: f.world_seed):
                world = load_world(job.worlds[seed], job.cache_dir)
                producer = FrameProducer(world, seed, job.cfg, cam, job.out_dir)
                try:
                    for plan in group:
                        rec, payload = producer.make(plan)
                        records[rec.index] = rec
                        writer.submit(payload, producer.class_lut)
                        finish(writer.completed())
                finally:
                    producer.close()
            while writer.pending:
                finish(writer.completed(block=True))
            finish(writer.completed())
    finally:
        writer.close()


_KINDS: dict[str, type[DatasetError]] = {
    "config": DatasetConfigError,
    "sampling": SamplingError,
    "flight": FlightError,
}


class _OrphanedError(Exception):
    """The parent of a worker is gone."""


def _shard_main(job: ShardJob, messages: Any) -> None:
    """A spawned worker: run the shard, send ``("frame", index)`` per frame, ``("error", kind, text)`` on failure.

    It stops after the frame in hand when its parent is gone (killed), rather than finishing its shard alone.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the parent, which stops the workers
    parent = multiprocessing.parent_process()

    def report(index: int) -> None:
        if parent is not None and not parent.is_alive():
            raise _OrphanedError
        messages.put(("frame", index))

    try:
        run_shard(job, report)
    except _OrphanedError:
        return
    except SamplingError as err:
        messages.put(("error", "sampling", str(err)))
    except FlightError as err:
        messages.put(("error", "flight", str(err)))
    except ConfigError as err:
        messages.put(("error", "config", str(err)))
    except ResourceError as err:
        messages.put(("error", "resource", str(err)))
    except DatasetError as err:
        messages.put(("error", "dataset", str(err)))


def _take(messages: Any, progress: Callable[[], None], timeout_s: float | None) -> tuple[bool, tuple[str, str] | None]:
    """Handle one worker message (waiting up to ``timeout_s``; None: do not wait): (got one, error it reported)."""
    try:
        msg = messages.get(timeout=timeout_s) if timeout_s is not None else messages.get_nowait()
    except queue_mod.Empty:
        return False, None
    if msg[0] == "frame":
        progress()
        return True, None
    return True, (msg[1], msg[2])


def _run_workers(jobs: list[ShardJob], progress: Callable[[], None]) -> None:
    ctx = multiprocessing.get_context("spawn")  # never fork: a forked child of a GL process hangs in EGL
    messages = ctx.Queue()
    procs = [
        ctx.Process(target=_shard_main, args=(job, messages), name=f"uav-dataset-{k}") for k, job in enumerate(jobs)
    ]
    for p in procs:
        p.start()
    error: tuple[str, str] | None = None
    stop_all = True
    try:
        # until a worker reports an error, or every worker has ended (well or not)
        while error is None and any(p.is_alive() for p in procs):
            got, error = _take(messages, progress, 0.5)
            if not got and any(p.exitcode not in (None, 0) for p in procs):
                break  # a worker died: stop the others below
        while True:  # frames journaled before the loop ended
            got, late = _take(messages, progress, None)
            if not got:
                break
            error = error or late
        stop_all = error is not None or any(p.exitcode not in (None, 0) for p in procs)
    finally:  # an error, a dead worker or an interrupt (Ctrl-C) stops every worker; their journals stay
        for p in procs:
            if stop_all and p.is_alive():
                p.terminate()
        for p in procs:
            p.join()
    if error is not None:
        kind, text = error
        if kind == "resource":
            raise RenderError(text)
        raise _KINDS.get(kind, DatasetError)(text)
    dead = [(k, p.exitcode) for k, p in enumerate(procs) if p.exitcode != 0]
    if dead:
        what = ", ".join(f"worker {k} (exit code {code})" for k, code in dead)
        msg = f"{what} died; the frames made so far are kept: run the same command again to resume"
        raise WorkerError(msg)


def _identity(cfg: DatasetConfig, worlds: dict[int, tuple[str, str, str]], extra: dict[str, Any]) -> dict[str, Any]:
    return {
        "config": cfg.to_mapping(),
        "worlds": {str(s): {"name": n, "hash": h, "split": sp} for s, (n, h, sp) in sorted(worlds.items())},
        **extra,
    }


_Planned = tuple[dict[int, WorldConfig], list[FramePlan], CameraModel, float, dict[str, Any]]


def _plan_viewpoints(cfg: DatasetConfig, cache: Path) -> _Planned:
    """Worlds, frames, camera, rate and identity of a sampled-viewpoint dataset (worlds generated and cached here,
    in the parent, which never creates a GL context)."""
    world_cfgs = world_configs(cfg)
    loaded = {seed: load_world(wc, cache) for seed, wc in world_cfgs.items()}
    split_of = {seed: name for name, s in cfg.splits.items() for seed in s.world_seeds}
    worlds = {seed: (w.config.name, w.hash, split_of[seed]) for seed, w in loaded.items()}
    return world_cfgs, plan_viewpoints(cfg, cfg.frame_limit or 0), cfg.camera.model(), 1.0, _identity(cfg, worlds, {})


def _plan_flight(cfg: DatasetConfig, cache: Path, out_dir: Path, run: Path | None) -> _Planned:
    """The same for a flight: a recorded run, or the scenario flown now into ``out_dir/source_run``."""
    spec = cfg.flight
    assert spec is not None  # DatasetConfig: source flight has a flight section
    source = run or spec.run
    if source is None:  # fly the scenario now, inside the dataset folder (the same identity before and after)
        identity = _identity(cfg, {}, {"flight": {"scenario": str(spec.scenario)}})
        prepare_folder(out_dir, _manifest(cfg, identity, 0))
        source = fly_scenario(spec, out_dir / "source_run", out_dir / "source_run.log")
        flight, world = load_flight(cfg, source, lambda wc: load_world(wc, cache))
    else:
        flight, world = load_flight(cfg, source, lambda wc: load_world(wc, cache))
        worlds = {flight.world_config.seed: (world.config.name, world.hash, spec.split)}
        run_info = {"run": str(source.resolve()), "bag_bytes": flight.bag.stat().st_size, "sequence": flight.sequence}
        identity = _identity(cfg, worlds, {"flight": run_info})
    world_cfgs = {flight.world_config.seed: flight.world_config}
    return world_cfgs, list(flight.frames), flight.camera, flight.rate_hz, identity


def generate(
    cfg: DatasetConfig,
    out_dir: Path,
    *,
    workers: int = 1,
    cache_dir: Path | None = None,
    run: Path | None = None,
    progress: Progress | None = None,
    encoder_process: bool = True,
) -> GenerateResult:
    """Generate (or resume, or find complete) the dataset ``cfg`` describes in ``out_dir``.

    Args:
        cfg: the dataset config (``--frames`` and ``--seed`` already applied).
        out_dir: the dataset folder.
        workers: processes that render in parallel (1: this process).
        cache_dir: the world cache (default ``~/.cache/uav_test_range/worlds``).
        run: a recorded run to use instead of ``flight.run`` (flights only).
        progress: called with ``(frames done, frames planned)`` as frames finish.
        encoder_process: each worker hands its images to a helper process that encodes and writes them
            (moderngl holds the GIL while it renders, so threads would not overlap); False: inline.

    Raises:
        DatasetConfigError: the config cannot be made (world, camera, run).
        DatasetFolderError: ``out_dir`` holds something else.
        SamplingError: no valid viewpoint in a world.
        FlightError: the run cannot be read or flown.
        WorkerError: a worker process died (progress is kept).
        RenderError: no GL context.
    """
    if workers < 1:
        msg = f"--workers must be >= 1, got {workers}"
        raise DatasetConfigError(msg)
    cache = cache_dir or DEFAULT_CACHE_DIR
    t0 = time.monotonic()
    out_dir = Path(out_dir)
    made = _plan_viewpoints(cfg, cache) if cfg.source == "viewpoints" else _plan_flight(cfg, cache, out_dir, run)
    world_cfgs, plan, camera, rate_hz, identity = made
    manifest = _manifest(cfg, identity, len(plan))
    if prepare_folder(out_dir, manifest):
        return GenerateResult(out_dir, len(plan), 0, 0, time.monotonic() - t0, True, read_manifest(out_dir))
    write_manifest(out_dir, manifest)  # the planned frame count (a live flight's is known only now)
    remove_temporaries(out_dir)  # what an interrupted run was writing when it stopped
    done = journal_records(out_dir)
    done = {i: r for i, r in done.items() if i < len(plan)}
    todo = [p for p in plan if p.index not in done]
    resumed = len(done)
    count = [resumed]

    def tick(_index: int | None = None) -> None:
        count[0] += 1
        if progress is not None:
            progress(count[0], len(plan))

    if progress is not None:
        progress(resumed, len(plan))
    t_frames = time.monotonic()
    if todo:
        token = f"{os.getpid()}-{int(time.time() * 1000) % 10**9}"
        shards = shard(todo, workers)
        jobs = [
            ShardJob(
                out_dir,
                cfg,
                world_cfgs,
                cache,
                camera,
                tuple(s),
                out_dir / PROGRESS / f"journal-{token}-{k}.jsonl",
                encoder_process,
            )
            for k, s in enumerate(shards)
        ]
        if len(jobs) == 1:
            run_shard(jobs[0], tick)
        else:
            _run_workers(jobs, tick)
    seconds = time.monotonic() - t_frames
    records = journal_records(out_dir)
    missing = [p.index for p in plan if p.index not in records]
    if missing:
        msg = f"{len(missing)} frames were not made (first: {missing[:5]}); run the same command again to resume"
        raise WorkerError(msg)
    final = assemble(out_dir, cfg, [records[p.index] for p in plan], manifest, rate_hz=rate_hz)
    return GenerateResult(out_dir, len(plan), len(todo), resumed, seconds, False, final)


def _manifest(cfg: DatasetConfig, identity: dict[str, Any], frames: int) -> dict[str, Any]:
    return {
        "format": "uav-dataset",
        "engine_version": ENGINE_VERSION,
        "name": cfg.name,
        "fingerprint": fingerprint(identity),
        "identity": identity,
        "frames_planned": frames,
        "complete": False,
    }
