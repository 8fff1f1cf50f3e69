"""The camera-effects process (uav_sim_bridge.shell.effects_process): the same images as the stage run in-process,
failures as clear errors, nothing left in shared memory."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from sim_worlds import small_config

from uav_common.config import from_mapping
from uav_sim_bridge.config import resolve_environment
from uav_sim_bridge.core.camera import CameraModel, look_at
from uav_sim_bridge.core.camera_effects import CameraEffectsConfig, CameraMotion, SensorNoiseConfig
from uav_sim_bridge.core.environment import EnvironmentConfig
from uav_sim_bridge.core.lighting import lighting_for
from uav_sim_bridge.core.world import World
from uav_sim_bridge.errors import CameraEffectsError
from uav_sim_bridge.render import RenderedFrame, Renderer
from uav_sim_bridge.shell.effects_process import EffectsProcess, StageSpec
from uav_sim_bridge.shell.world_store import generate_world

SEED = 6


@pytest.fixture(scope="module")
def world() -> World:
    return generate_world(small_config(seed=3))


@pytest.fixture(scope="module")
def frames(world: World) -> Iterator[list[RenderedFrame]]:
    """Six shadowed frames (their colour still unshaded) of a camera flying over a village."""
    env = from_mapping(EnvironmentConfig, resolve_environment({"preset": "stress_all"}), source="stress_all")
    r = Renderer(world)
    try:
        r.set_lighting(lighting_for(env, 47.4))
        cam = CameraModel.simple(320, 240, 90.0, name="nadir")
        vx, vy = world.roads.villages_m[0]
        out = []
        for k in range(6):
            x = vx - 15.0 + 6.0 * k
            out.append(r.render(cam, look_at([x, vy, float(world.height_at(x, vy)) + 35.0], [x + 20.0, vy, 0.0])))
        yield out
    finally:
        r.close()


def _spec(cfg: CameraEffectsConfig) -> tuple[CameraModel, StageSpec]:
    cam = CameraModel.simple(320, 240, 90.0, name="nadir")
    return cam, StageSpec(cfg, cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy, SEED)


def _stress_cfg() -> CameraEffectsConfig:
    env = from_mapping(EnvironmentConfig, resolve_environment({"preset": "stress_all"}), source="stress_all")
    return env.effects_for("nadir")


def _own_files() -> list[Path]:
    shm = Path("/dev/shm")
    return sorted(shm.glob(f"uav_effects_{os.getpid()}_*")) if shm.is_dir() else []


def test_the_process_gives_the_in_process_stages_images_bit_for_bit(frames: list[RenderedFrame]) -> None:
    # every effect of the stress preset (auto-exposure carrying over frames, noise, blur, defocus, JPEG), on frames
    # whose shadows the child finishes, and on frames finished here
    cfg = _stress_cfg()
    _, spec = _spec(cfg)
    motion = CameraMotion((6.0, 0.0, 0.5), (0.0, 0.3, 0.1))
    local = spec.build("nadir")
    proc = EffectsProcess({"nadir": spec}, slots=2)
    try:
        assert _own_files() == []  # unlinked once both sides had it mapped
        jobs = []
        for k, f in enumerate(frames):
            unshaded = f.unshaded
            assert unshaded is not None  # the stress preset has shadows: the colour is finished where it is used
            if k % 2:
                jobs.append(proc.submit("nadir", f.depth_m, 0.1 * k, motion, unshaded=unshaded))
            else:
                jobs.append(proc.submit("nadir", f.depth_m, 0.1 * k, motion, color_rgb=unshaded.finish()))
        for k, (f, job) in enumerate(zip(frames, jobs, strict=True)):
            want = local.apply(f.color_rgb, f.depth_m, 0.1 * k, motion)
            got = job.result()
            assert np.array_equal(got.color_rgb, want.color_rgb), f"frame {k}"
            assert (got.exposure_s, got.gain, got.blur_px) == (want.exposure_s, want.gain, want.blur_px)
            assert not np.array_equal(got.color_rgb, f.color_rgb)  # the effects did change the image
    finally:
        proc.close()


def test_a_dead_effects_process_fails_its_frames_with_a_clear_error(frames: list[RenderedFrame]) -> None:
    _, spec = _spec(CameraEffectsConfig(noise=SensorNoiseConfig()))
    proc = EffectsProcess({"nadir": spec})
    try:
        f = frames[0]
        first = proc.submit("nadir", f.depth_m, 0.0, None, color_rgb=f.color_rgb)
        assert first.result().color_rgb.shape == (240, 320, 3)
        assert proc.pid is not None
        os.kill(proc.pid, signal.SIGKILL)
        lost = proc.submit("nadir", f.depth_m, 0.1, None, color_rgb=f.color_rgb)
        lost_msg = r"exited .*\(killed by signal 9\); its frames are lost.*restart the node"
        with pytest.raises(CameraEffectsError, match=lost_msg):
            lost.result()
        with pytest.raises(CameraEffectsError, match="exited"):  # and every later frame, at once
            proc.submit("nadir", f.depth_m, 0.2, None, color_rgb=f.color_rgb)
    finally:
        proc.close()


def test_a_frame_the_child_cannot_process_fails_alone(frames: list[RenderedFrame]) -> None:
    _, spec = _spec(_stress_cfg())
    proc = EffectsProcess({"nadir": spec})
    try:
        f = frames[1]
        bad = proc.submit("nadir", f.depth_m, 0.0, "sideways", color_rgb=f.color_rgb)  # type: ignore[arg-type]
        good = proc.submit("nadir", f.depth_m, 0.1, None, color_rgb=f.color_rgb)
        with pytest.raises(CameraEffectsError, match=r"camera effects of 'nadir' failed on a frame: AttributeError"):
            bad.result()
        assert good.result().color_rgb.shape == (240, 320, 3)
    finally:
        proc.close()


def test_the_process_refuses_frames_it_cannot_take(frames: list[RenderedFrame]) -> None:
    _, spec = _spec(CameraEffectsConfig(vignetting=0.3))
    proc = EffectsProcess({"nadir": spec})
    try:
        f = frames[0]
        with pytest.raises(CameraEffectsError, match=r"no effects stage for camera 'forward'"):
            proc.submit("forward", f.depth_m, 0.0, None, color_rgb=f.color_rgb)
        with pytest.raises(CameraEffectsError, match=r"frames are 320x240, got colour \(120, 160, 3\)"):
            proc.submit("nadir", f.depth_m[::2, ::2], 0.0, None, color_rgb=f.color_rgb[::2, ::2])
        pid = proc.pid
    finally:
        proc.close()
    assert pid is not None
    with pytest.raises(ProcessLookupError):  # closing stopped the child
        os.kill(pid, 0)
    with pytest.raises(CameraEffectsError, match="closed"):
        proc.submit("nadir", frames[0].depth_m, 0.0, None, color_rgb=frames[0].color_rgb)


def test_the_process_works_under_a_default_socket_timeout(frames: list[RenderedFrame]) -> None:
    # rospy's nodes run with socket.setdefaulttimeout() set: sockets made then are non-blocking underneath, and the
    # child's end of the pair failed its first read with EAGAIN (the bridge node died on its first effected frame)
    before = socket.getdefaulttimeout()
    socket.setdefaulttimeout(3.0)
    try:
        _, spec = _spec(CameraEffectsConfig(noise=SensorNoiseConfig()))
        proc = EffectsProcess({"nadir": spec})
    finally:
        socket.setdefaulttimeout(before)
    try:
        f = frames[2]
        jobs = [proc.submit("nadir", f.depth_m, 0.1 * k, None, color_rgb=f.color_rgb) for k in range(4)]
        assert all(j.result().color_rgb.shape == (240, 320, 3) for j in jobs)
    finally:
        proc.close()


def test_the_worker_says_what_it_is_when_run_by_hand() -> None:
    cmd = [sys.executable, "-m", "uav_sim_bridge.cli.effects_worker"]
    res = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    assert "the bridge starts it itself" in res.stderr


def test_the_child_ends_when_its_parent_dies_without_a_word() -> None:
    # a bridge node killed outright leaves no effects process behind: the child sees its socket close and exits
    script = (
        "import os, sys\n"
        "from uav_sim_bridge.core.camera_effects import CameraEffectsConfig\n"
        "from uav_sim_bridge.shell.effects_process import EffectsProcess, StageSpec\n"
        "spec = StageSpec(CameraEffectsConfig(vignetting=0.2), 32, 24, 16.0, 16.0, 15.5, 11.5, 1)\n"
        "p = EffectsProcess({'nadir': spec})\n"
        "print(p.pid, flush=True)\n"
        "os._exit(0)\n"
    )
    # not run(): the child inherits the parent's stdout, so waiting for that pipe to close would wait for the child
    with subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True) as parent:
        assert parent.stdout is not None
        child = int(parent.stdout.readline())
        assert parent.wait(timeout=60) == 0
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline:
        try:
            os.kill(child, 0)
        except ProcessLookupError:
            return
        if Path(f"/proc/{child}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z":
            return  # gone, only its exit status left for init to collect
        time.sleep(0.05)
    pytest.fail(f"the effects process {child} outlived its parent by 10 s")
