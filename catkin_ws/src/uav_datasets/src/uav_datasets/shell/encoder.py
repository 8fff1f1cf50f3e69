"""Encoding and writing a frame's images off the rendering thread: in this process, or in a helper process.

moderngl holds Python's GIL during every GL call, including the read-back that waits ~10 ms for
llvmpipe to finish a frame, so encoder *threads* of the rendering process hardly run while it renders
(measured: an encoder thread got ~20 % of its time, and slowed the render by half). A
:class:`ProcessWriter` instead hands each frame's colour, depth and instance ids to one helper process
(started with ``spawn``) through shared memory: a few slots, each holding one frame's arrays, reused in
turn, so a frame costs the renderer one copy of ~3 MB and no pickling. The helper encodes the PNGs
(class ids from the instance ids and the world's class table), writes each file atomically (the label
texts too: on a busy disk an ``open`` can take milliseconds, which the renderer should not wait for)
and reports the frame done; the renderer journals it only then. :class:`InlineWriter` does the same work
synchronously (one process, no helper: tests and tiny datasets).
"""

from __future__ import annotations

import multiprocessing
import queue as queue_mod
import signal
from dataclasses import dataclass
from multiprocessing import shared_memory
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_common.shell.processes import die_with_parent
from uav_datasets.errors import WorkerError
from uav_datasets.shell.writers import atomic_write, encode_color, encode_depth, encode_ids

__all__ = ["FramePayload", "InlineWriter", "ProcessWriter", "write_payload"]


@dataclass(frozen=True)
class FramePayload:
    """One frame's images and where each goes (paths relative to the dataset folder).

    Attributes:
        key: the frame's index (reported back when its files are written).
        color, depth, ids: the render (``ids`` is the instance-id image).
        image, depth_file, instance_file, class_file: relative paths; "" = not written.
        image_format, jpeg_quality, depth_format, png_level: the outputs' settings (``png_level`` 0 stores the
            colour and depth PNGs uncompressed).
        lut_key: which class table turns instance ids into class ids (one per world).
        texts: small text files (YOLO, KITTI labels and calibration): ``(relative path, content)``.
    """

    key: int
    color: npt.NDArray[np.uint8]
    depth: npt.NDArray[np.float32]
    ids: npt.NDArray[np.uint16]
    image: str
    depth_file: str
    instance_file: str
    class_file: str
    image_format: str
    jpeg_quality: int
    depth_format: str
    lut_key: int
    texts: tuple[tuple[str, str], ...] = ()
    png_level: int = 1


def write_payload(
    out_dir: Path,
    p: FramePayload,
    images: tuple[npt.NDArray[np.uint8], npt.NDArray[np.float32], npt.NDArray[np.uint16]],
    lut: npt.NDArray[np.uint16],
) -> None:
    """Encode and write one frame's images ``(colour, depth, instance ids)`` and texts (each file atomically)."""
    color, depth, ids = images
    for rel, text in p.texts:
        atomic_write(out_dir / rel, text)
    if p.image:
        atomic_write(out_dir / p.image, encode_color(color, p.image_format, p.jpeg_quality, p.png_level))
    if p.depth_file:
        atomic_write(out_dir / p.depth_file, encode_depth(depth, p.depth_format, p.png_level)[0])
    if p.instance_file:
        atomic_write(out_dir / p.instance_file, encode_ids(ids))
    if p.class_file:
        atomic_write(out_dir / p.class_file, encode_ids(np.take(lut, ids, mode="clip")))


class InlineWriter:
    """Writes each frame when it is submitted (no helper process)."""

    def __init__(self, out_dir: Path) -> None:
        self.out_dir = out_dir
        self._luts: dict[int, npt.NDArray[np.uint16]] = {}
        self._done: list[int] = []

    def submit(self, payload: FramePayload, lut: npt.NDArray[np.uint16]) -> None:
        write_payload(self.out_dir, payload, (payload.color, payload.depth, payload.ids), lut)
        self._done.append(payload.key)

    def completed(self, *, block: bool = False) -> list[int]:
        del block
        out, self._done = self._done, []
        return out

    @property
    def pending(self) -> int:
        return 0

    def close(self) -> None:
        return None


def _slot_layout(height: int, width: int) -> tuple[int, int, int, int]:
    """Byte offsets of colour, depth and ids in a slot, and the slot's size."""
    color = height * width * 3
    depth = height * width * 4
    ids = height * width * 2
    return 0, color, color + depth, color + depth + ids


def _views(
    buf: Any, height: int, width: int
) -> tuple[npt.NDArray[np.uint8], npt.NDArray[np.float32], npt.NDArray[np.uint16]]:
    c0, d0, i0, _ = _slot_layout(height, width)
    color: npt.NDArray[np.uint8] = np.ndarray((height, width, 3), dtype=np.uint8, buffer=buf, offset=c0)
    depth: npt.NDArray[np.float32] = np.ndarray((height, width), dtype=np.float32, buffer=buf, offset=d0)
    ids: npt.NDArray[np.uint16] = np.ndarray((height, width), dtype=np.uint16, buffer=buf, offset=i0)
    return color, depth, ids


@dataclass(frozen=True)
class _Slots:
    """Where a helper finds the frames: the dataset folder, the shared-memory blocks and the frame size."""

    out_dir: str
    names: tuple[str, ...]
    height: int
    width: int


def _encoder_main(slots: _Slots, inbox: Any, outbox: Any) -> None:
    """The helper process: encode the frame in each slot it is told about, answer ``(slot, key, error)``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the renderer, which closes this helper
    parent = multiprocessing.parent_process()
    if parent is not None and parent.pid is not None:
        # A renderer that dies (killed, or a worker stopped by the command) takes this helper with it at once:
        # otherwise it would go on writing the frames it holds after the command has ended, into a folder that
        # the next run (the resume) writes too.
        die_with_parent(parent.pid)
    shms = [shared_memory.SharedMemory(name=n) for n in slots.names]
    height, width, out_dir = slots.height, slots.width, slots.out_dir
    luts: dict[int, npt.NDArray[np.uint16]] = {}
    try:
        while True:
            try:
                msg = inbox.get(timeout=1.0)
            except queue_mod.Empty:
                if parent is not None and not parent.is_alive():
                    return  # the renderer was killed: do not outlive it
                continue
            if msg is None:
                return
            slot, payload, lut = msg
            if lut is not None:
                luts[payload.lut_key] = lut
            try:
                images = _views(shms[slot].buf, height, width)
                write_payload(Path(out_dir), payload, images, luts[payload.lut_key])
                outbox.put((slot, payload.key, ""))
            except Exception as err:
                outbox.put((slot, payload.key, f"{type(err).__name__}: {err}"))
    finally:
        for shm in shms:
            shm.close()


class ProcessWriter:
    """Writes frames in a helper process fed through shared memory (see the module docstring).

    Args:
        out_dir: the dataset folder.
        height, width: the frames' size.
        slots: frames in flight at most (the renderer waits for a free slot).
    """

    def __init__(self, out_dir: Path, height: int, width: int, slots: int = 3) -> None:
        self.out_dir = out_dir
        self.shape = (height, width)
        size = _slot_layout(height, width)[3]
        self._shms = [shared_memory.SharedMemory(create=True, size=size) for _ in range(slots)]
        self._free = list(range(slots))
        self._sent_luts: set[int] = set()
        ctx = multiprocessing.get_context("spawn")  # never fork a process that holds a GL context
        self._inbox = ctx.Queue()
        self._outbox = ctx.Queue()
        self._proc = ctx.Process(
            target=_encoder_main,
            args=(_Slots(str(out_dir), tuple(s.name for s in self._shms), height, width), self._inbox, self._outbox),
            name="uav-dataset-encoder",
        )
        self._proc.start()
        self._in_flight = 0
        self._done: list[int] = []

    @property
    def pending(self) -> int:
        return self._in_flight

    @property
    def helper_pid(self) -> int | None:
        """The helper process's id (for CPU accounting)."""
        return self._proc.pid

    def _collect(self, block: bool) -> None:
        while self._in_flight:
            try:
                slot, key, error = self._outbox.get(timeout=1.0) if block else self._outbox.get_nowait()
            except queue_mod.Empty:
                if not block:
                    return
                if not self._proc.is_alive():
                    msg = f"the encoder process died (exit code {self._proc.exitcode}); run the same command to resume"
                    raise WorkerError(msg) from None
                continue
            self._in_flight -= 1
            self._free.append(slot)
            if error:
                msg = f"writing frame {key} failed in the encoder process: {error}"
                raise WorkerError(msg)
            self._done.append(key)
            block = False  # one result was enough; take the others that are ready

    def submit(self, payload: FramePayload, lut: npt.NDArray[np.uint16]) -> None:
        """Copy the frame into a free slot (waiting for one) and hand it to the helper."""
        if payload.color.shape[:2] != self.shape:
            msg = f"frame of shape {payload.color.shape[:2]}, the writer was made for {self.shape}"
            raise ValueError(msg)
        while not self._free:
            self._collect(block=True)
        slot = self._free.pop()
        color, depth, ids = _views(self._shms[slot].buf, *self.shape)
        np.copyto(color, payload.color)
        np.copyto(depth, payload.depth)
        np.copyto(ids, payload.ids)
        send_lut = None if payload.lut_key in self._sent_luts else lut
        self._sent_luts.add(payload.lut_key)
        light = FramePayload(**{**payload.__dict__, "color": _EMPTY_U8, "depth": _EMPTY_F32, "ids": _EMPTY_U16})
        self._inbox.put((slot, light, send_lut))
        self._in_flight += 1

    def completed(self, *, block: bool = False) -> list[int]:
        """Frames whose files are all written since the last call (``block``: wait for at least one)."""
        self._collect(block and not self._done)
        out, self._done = self._done, []
        return out

    def close(self) -> None:
        """Wait for the frames in flight, stop the helper and free the shared memory."""
        try:
            while self._in_flight:
                self._collect(block=True)
        finally:
            if self._proc.is_alive():
                self._inbox.put(None)
                self._proc.join(10)
                if self._proc.is_alive():
                    self._proc.terminate()
                    self._proc.join()
            for shm in self._shms:
                shm.close()
                shm.unlink()


_EMPTY_U8 = np.zeros((0, 0, 3), np.uint8)
_EMPTY_F32 = np.zeros((0, 0), np.float32)
_EMPTY_U16 = np.zeros((0, 0), np.uint16)
