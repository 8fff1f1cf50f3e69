"""The cameras' effects stages (:mod:`uav_sim_bridge.core.camera_effects`) in a process of their own.

Why a process and not a thread: moderngl holds Python's GIL for the whole of a GL call, and with llvmpipe a
frame's read-back is where the rasteriser does its work (most of a render). A thread doing the camera effects
beside it was starved: a thread running OpenCV calls got 5-12 % of its solo throughput while the GL thread
rendered (measured 2026-11-27), so the effects ran mostly *after* the renders instead of beside them. A process
has no GIL to wait for: it runs whenever a core is free (while the GL thread prepares the next frame in Python),
at a lower priority (``nice``) than the renderer it must not slow down.

How it works:

* the parent (:class:`EffectsProcess`) starts ``python -m uav_sim_bridge.cli.effects_worker FD`` with one end
  of a socket pair, and sends it each camera's stage (:class:`StageSpec`: its effects, size, intrinsics and
  seed); the child builds the same :class:`~uav_sim_bridge.core.camera_effects.CameraEffects` (the same seeded
  generator), so its images are bit-identical to the stage run in the parent;
* the images travel through shared memory (a file in ``/dev/shm``, unlinked as soon as both sides have mapped
  it, so nothing is left behind even if both die): a few slots per camera for the rendered colour (or the
  unshaded colour and its lit fraction, which the child finishes: :class:`~uav_sim_bridge.core.shading.UnshadedColor`),
  the depth and the result. Only small messages (which slot, simulation time, camera motion) go through the
  socket;
* one child, frames in submission order: auto-exposure and the random streams see the frames in the same order
  as before, so a lockstep run is reproduced exactly;
* failures are errors, never lost frames: an exception in the child comes back as a
  :class:`~uav_sim_bridge.errors.CameraEffectsError` for that frame; a child that dies or stops answering fails
  every frame it held and every later one, with its exit code and what to do.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.camera_effects import (
    CameraEffects,
    CameraEffectsConfig,
    CameraMotion,
    EffectsResult,
    camera_rng,
)
from uav_sim_bridge.core.shading import UnshadedColor
from uav_sim_bridge.errors import CameraEffectsError

__all__ = ["EffectsJob", "EffectsProcess", "StageSpec"]

#: Slots (frames in flight) per camera. A delayed camera holds its frames until their latency has passed; when
#: every slot is taken, the oldest frame's result is fetched (copied out) to free one, so no frame waits on it.
SLOTS_PER_CAMERA = 3
#: The child's niceness: below the GL thread, so the effects use the cores the renderer leaves idle.
NICE = 10
#: How long a frame may take in the child before the parent gives up on it (a hung child).
REPLY_TIMEOUT_S = 60.0
#: How long the child may take to start (import numpy and OpenCV, map the memory).
START_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class StageSpec:
    """What the child needs to build one camera's effects stage exactly as the parent would."""

    cfg: CameraEffectsConfig
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    seed: int  # the environment's seed: the stage's generator is ``camera_rng(seed, camera)``

    def build(self, camera: str) -> CameraEffects:
        return CameraEffects(
            self.cfg, self.width, self.height, self.fx, self.fy, self.cx, self.cy, camera_rng(self.seed, camera)
        )


@dataclass(frozen=True)
class _Layout:
    """Byte offsets of one slot's arrays (colour in, depth, lit fraction, colour out) in a camera's memory."""

    width: int
    height: int

    @property
    def pixels(self) -> int:
        return self.width * self.height

    @property
    def slot_bytes(self) -> int:
        return 12 * self.pixels  # RGBA in (4) + depth (4) + lit fraction (<= 1) + RGB out (3)

    def views(self, mem: npt.NDArray[np.uint8], slot: int) -> tuple[Any, Any, Any, Any]:
        """``(colour_in (H*W*4 bytes), depth (H, W) float32, lit (H*W bytes), colour_out (H, W, 3))``."""
        n, h, w = self.pixels, self.height, self.width
        base = slot * self.slot_bytes
        colour_in = mem[base : base + 4 * n]
        depth = mem[base + 4 * n : base + 8 * n].view(np.float32).reshape(h, w)
        lit = mem[base + 8 * n : base + 9 * n]
        out = mem[base + 9 * n : base + 12 * n].reshape(h, w, 3)
        return colour_in, depth, lit, out


class EffectsJob:
    """One frame's effects, done in the child: :meth:`result` waits for them (FIFO with the other frames)."""

    __slots__ = ("_error", "_owner", "_result", "camera", "seq", "slot")

    def __init__(self, owner: EffectsProcess, seq: int, camera: str, slot: int) -> None:
        self._owner = owner
        self.seq = seq
        self.camera = camera
        self.slot = slot
        self._result: EffectsResult | None = None
        self._error: CameraEffectsError | None = None

    def done(self) -> bool:
        return self._result is not None or self._error is not None

    def settle(self, result: EffectsResult | None = None, error: CameraEffectsError | None = None) -> None:
        """Record the frame's outcome (the process does, when the child's reply comes in or it fails)."""
        self._result, self._error = result, error

    def result(self) -> EffectsResult:
        """The frame's image and exposure.

        Raises:
            CameraEffectsError: the child failed on this frame, died or stopped answering.
        """
        while not self.done():
            self._owner.receive_one()
        if self._error is not None:
            raise self._error
        assert self._result is not None
        return self._result


class EffectsProcess:
    """The effects stages of ``stages`` (camera name -> :class:`StageSpec`) in a child process.

    Use from one thread. :meth:`close` stops the child (also done when the parent exits: the child sees its
    socket close).

    Raises:
        CameraEffectsError: the child could not be started.
    """

    def __init__(self, stages: Mapping[str, StageSpec], *, slots: int = SLOTS_PER_CAMERA, nice: int = NICE) -> None:
        if not stages:
            msg = "an effects process needs at least one camera's stage"
            raise CameraEffectsError(msg)
        self._layouts = {name: _Layout(s.width, s.height) for name, s in stages.items()}
        self._free = {name: list(range(slots)) for name in stages}
        self._pending: deque[EffectsJob] = deque()
        self._seq = 0
        self._failure: CameraEffectsError | None = None
        self._mem: dict[str, npt.NDArray[np.uint8]] = {}
        paths: dict[str, str] = {}
        parent_sock, child_sock = socket.socketpair()
        # blocking file descriptors, whatever socket.setdefaulttimeout() a library set (rospy's nodes have one: the
        # child's end was non-blocking there, and its first read failed with EAGAIN)
        parent_sock.setblocking(True)
        child_sock.setblocking(True)
        self._proc: subprocess.Popen[bytes] | None = None
        try:
            for name, layout in self._layouts.items():
                fd, path = tempfile.mkstemp(prefix=f"uav_effects_{os.getpid()}_", dir=_shm_dir())
                paths[name] = path
                with os.fdopen(fd, "wb") as f:
                    f.truncate(slots * layout.slot_bytes)
                self._mem[name] = np.memmap(path, dtype=np.uint8, mode="r+")
            env = dict(os.environ)
            roots = {str(Path(m.__file__).resolve().parents[1]) for m in _packages()}
            env["PYTHONPATH"] = os.pathsep.join([*sorted(roots), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
            # glibc would serve each frame's multi-megabyte temporaries with fresh mmap()s and give them back: in a
            # young process that is ~2700 page faults a frame, half its CPU (7.6 against 2.9 ms a frame, measured).
            # From the heap, and kept there, they are reused.
            env.setdefault("MALLOC_MMAP_THRESHOLD_", str(32 << 20))
            env.setdefault("MALLOC_TRIM_THRESHOLD_", str(256 << 20))
            child_fd = child_sock.fileno()
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "uav_sim_bridge.cli.effects_worker", str(child_fd)],
                pass_fds=(child_fd,),
                env=env,
                stdin=subprocess.DEVNULL,
            )
            child_sock.close()
            self._conn = Connection(parent_sock.detach())
            self._conn.send(("init", dict(stages), paths, nice))
            reply = self._recv(START_TIMEOUT_S, "to start")
            if reply != ("ready",):
                msg = f"the camera-effects process did not start: {reply!r}"
                raise CameraEffectsError(msg)
        except BaseException:
            self._kill()
            raise
        finally:
            for path in paths.values():  # both sides have it mapped (or never will): nothing to leave behind
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(path)
            with contextlib.suppress(OSError):
                child_sock.close()

    # ------------------------------------------------------------------ frames
    def submit(
        self,
        camera: str,
        depth_m: npt.NDArray[np.float32],
        t_s: float,
        motion: CameraMotion | None,
        *,
        color_rgb: npt.NDArray[np.uint8] | None = None,
        unshaded: UnshadedColor | None = None,
    ) -> EffectsJob:
        """Send one frame (its finished colour, or its unshaded colour for the child to finish) to the child.

        Raises:
            CameraEffectsError: the child has failed before; an unknown camera; images of the wrong size.
        """
        if self._failure is not None:
            raise self._failure
        layout = self._layouts.get(camera)
        if layout is None:
            msg = f"no effects stage for camera {camera!r} (stages: {sorted(self._layouts)})"
            raise CameraEffectsError(msg)
        h, w = layout.height, layout.width
        if (color_rgb is None) == (unshaded is None):
            msg = "submit needs exactly one of color_rgb and unshaded"
            raise CameraEffectsError(msg)
        image = color_rgb if color_rgb is not None else unshaded.rgba if unshaded is not None else None
        assert image is not None
        if image.shape[:2] != (h, w) or depth_m.shape != (h, w):
            msg = f"camera {camera!r} frames are {w}x{h}, got colour {image.shape} and depth {depth_m.shape}"
            raise CameraEffectsError(msg)
        while not self._free[camera]:
            self.receive_one()  # frees the oldest frame's slot (results come back in order)
        slot = self._free[camera].pop(0)
        colour_in, depth, lit, _ = layout.views(self._mem[camera], slot)
        depth[...] = depth_m
        lit_shape: tuple[int, int] | None = None
        if unshaded is not None:
            colour_in[...] = unshaded.rgba.reshape(-1)
            lit_shape = (int(unshaded.lit_low.shape[0]), int(unshaded.lit_low.shape[1]))
            lit[: unshaded.lit_low.size] = unshaded.lit_low.reshape(-1)
        else:
            assert color_rgb is not None
            colour_in[: 3 * layout.pixels] = np.ascontiguousarray(color_rgb).reshape(-1)
        self._seq += 1
        job = EffectsJob(self, self._seq, camera, slot)
        self._pending.append(job)
        try:
            self._conn.send(("job", job.seq, camera, slot, float(t_s), motion, lit_shape))
        except OSError:
            self._fail("exited before it could take a frame", raise_=False)  # this job (and the rest) fail on result()
        return job

    def receive_one(self) -> None:
        """Take the child's next reply (the oldest frame in flight); fail everything if the child is gone."""
        if not self._pending:
            return
        if self._failure is not None:
            self._fail_pending()
            return
        reply = self._recv(REPLY_TIMEOUT_S, "to finish a frame")
        job = self._pending.popleft()
        kind, seq = reply[0], reply[1]
        if seq != job.seq:  # pragma: no cover - one child, one socket: replies come in order
            self._fail(f"replied to frame {seq} while frame {job.seq} was the oldest")
            return
        layout = self._layouts[job.camera]
        if kind == "done":
            _, _, exposure_s, gain, blur_px = reply
            out = layout.views(self._mem[job.camera], job.slot)[3]
            job._result = EffectsResult(np.array(out), float(exposure_s), float(gain), float(blur_px))
        else:
            job._error = CameraEffectsError(f"camera effects of {job.camera!r} failed on a frame: {reply[2]}")
        self._free[job.camera].append(job.slot)

    def wait_all(self) -> None:
        """Wait until every frame submitted so far is done (their errors are raised by their own jobs)."""
        while self._pending and self._failure is None:
            self.receive_one()

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else None

    def close(self) -> None:
        """Stop the child (frames still in flight are failed) and release the shared memory."""
        if self._proc is not None and self._proc.poll() is None:
            with contextlib.suppress(OSError):
                self._conn.send(("close",))
            try:
                self._proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self._kill()
        if self._failure is None:
            self._failure = CameraEffectsError("the camera-effects process was closed")
        self._fail_pending()
        with contextlib.suppress(OSError, AttributeError):
            self._conn.close()
        self._mem.clear()

    # ------------------------------------------------------------------ internals
    def _recv(self, timeout_s: float, doing: str) -> Any:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                if self._conn.poll(min(1.0, max(0.0, deadline - time.monotonic()))):
                    return self._conn.recv()
            except (EOFError, OSError):
                self._fail(f"exited while it had {doing}")
            if self._proc is not None and self._proc.poll() is not None:
                self._fail(f"exited while it had {doing}")
            if time.monotonic() >= deadline:
                self._fail(f"took more than {timeout_s:.0f} s {doing}")

    def _fail(self, what: str, *, raise_: bool = True) -> None:
        code = None
        if self._proc is not None:
            with contextlib.suppress(subprocess.TimeoutExpired):
                code = self._proc.wait(timeout=0.5)  # a child that just died: its exit code
        how = "" if code is None else f" (killed by signal {-code})" if code < 0 else f" (exit code {code})"
        self._failure = CameraEffectsError(
            f"the camera-effects process (pid {self.pid}) {what}{how}; its frames are lost. Its own error, if any, "
            "is in this node's log just above; restart the node (and report it if it happens again)"
        )
        self._kill()
        self._fail_pending()
        if raise_:
            raise self._failure

    def _fail_pending(self) -> None:
        while self._pending:
            job = self._pending.popleft()
            job._error = self._failure
            self._free[job.camera].append(job.slot)

    def _kill(self) -> None:
        if self._proc is not None and self._proc.poll() is None:
            self._proc.kill()
            with contextlib.suppress(subprocess.TimeoutExpired):
                self._proc.wait(timeout=5.0)


def _shm_dir() -> str | None:
    """``/dev/shm`` when it can be used (memory, not disk), else the default temporary directory."""
    shm = Path("/dev/shm")
    return str(shm) if shm.is_dir() and os.access(shm, os.W_OK) else None


def _packages() -> list[Any]:
    import uav_common  # noqa: PLC0415
    import uav_sim_bridge  # noqa: PLC0415

    return [m for m in (uav_common, uav_sim_bridge) if getattr(m, "__file__", None)]


# ---------------------------------------------------------------------- the child
def serve(conn: Connection) -> int:
    """The child's loop: build the stages, then apply them to each frame until told to stop or orphaned."""
    import cv2  # noqa: PLC0415

    # Ctrl-C and roslaunch's SIGINT are for the node: it closes the socket, and the child ends on that (so a
    # stopping node's frames still finish, and no KeyboardInterrupt traceback lands in its log)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    msg = conn.recv()
    _, stages, paths, nice = msg
    if nice:
        os.nice(int(nice))
    cv2.setNumThreads(1)  # the other core is the renderer's: OpenCV's own pool would only compete with it
    effects = {name: spec.build(name) for name, spec in stages.items()}
    layouts = {name: _Layout(spec.width, spec.height) for name, spec in stages.items()}
    mem = {name: np.memmap(path, dtype=np.uint8, mode="r+") for name, path in paths.items()}
    conn.send(("ready",))
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return 0  # the parent is gone
        if msg[0] == "close":
            return 0
        _, seq, camera, slot, t_s, motion, lit_shape = msg
        try:
            layout = layouts[camera]
            h, w = layout.height, layout.width
            colour_in, depth, lit, out = layout.views(mem[camera], slot)
            if lit_shape is not None:
                rgba = np.array(colour_in).reshape(h, w, 4)
                lit_low = np.array(lit[: lit_shape[0] * lit_shape[1]]).reshape(lit_shape)
                color = UnshadedColor(rgba, lit_low).finish()
            else:
                color = np.array(colour_in[: 3 * layout.pixels]).reshape(h, w, 3)
            r = effects[camera].apply(color, np.asarray(depth), t_s, motion)
            out[...] = r.color_rgb
            conn.send(("done", seq, r.exposure_s, r.gain, r.blur_px))
        except Exception as exc:
            conn.send(("error", seq, f"{type(exc).__name__}: {exc}"))


def serve_fd(fd: int) -> int:
    """The child's entry (:mod:`uav_sim_bridge.cli.effects_worker`): serve the parent on socket ``fd``."""
    os.set_blocking(fd, True)
    return serve(Connection(fd))
