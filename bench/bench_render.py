"""Renderer and sim-bridge benchmark.

Measures, on the default world:

* render rate of the two default cameras (nadir + forward pitched 25 deg) at 640x480
  and 320x240: color + depth + instance ids with readback, per vehicle pose along a
  loop 40 m above the ground; the baseline in the same run is a pure-numpy heightfield
  ray-cast render (terrain only, Lambert shading) of the same frames;
* latency from a SITL state (ODOMETRY sent on the sim link) to the published images,
  through a real roscore and the sim_bridge node; baseline: the bare render time;
* memory: RSS of the bridge node with the default world (target < 1 GB); baseline:
  RSS of a python process with numpy and rospy only.

Run: ``scripts/in_env python bench/bench_render.py`` (or ``make bench``).  The machine
is shared: other processes may load the 2 cores, so the load average is recorded too.
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
from benchlib import REPO

HERE = Path(__file__).resolve().parent

os.environ.setdefault("MAVLINK20", "1")

import rospy  # noqa: E402
from benchlib import median, percentile, record  # noqa: E402
from helpers.procs import Proc, roscore  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402
from sensor_msgs.msg import Image  # noqa: E402

from uav_sim_bridge.config import default_cameras  # noqa: E402
from uav_sim_bridge.core.camera import CameraModel  # noqa: E402
from uav_sim_bridge.core.terrain import Heightfield  # noqa: E402
from uav_sim_bridge.core.transforms import RigidTransform  # noqa: E402
from uav_sim_bridge.core.world import World  # noqa: E402
from uav_sim_bridge.core.world_config import load_world_config  # noqa: E402
from uav_sim_bridge.render import Renderer  # noqa: E402
from uav_sim_bridge.shell.world_store import load_or_generate  # noqa: E402

CACHE = Path(os.environ.get("UAV_ARTIFACTS", REPO / "artifacts")) / "world_cache"
POSES = 40
BASELINE_POSES = 4
SUN = np.array([0.4, 0.6, 0.7]) / np.linalg.norm([0.4, 0.6, 0.7])


def _load() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def _rss_mb(pid: int | str = "self") -> tuple[float, float]:
    """(current RSS, peak RSS) in MB from /proc."""
    cur = peak = 0.0
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            cur = int(line.split()[1]) / 1024
        elif line.startswith("VmHWM:"):
            peak = int(line.split()[1]) / 1024
    return cur, peak


def loop_poses(world: World, n: int, radius_m: float = 300.0, agl_m: float = 40.0) -> list[RigidTransform]:
    """Vehicle poses (T_map_base) on a circle, flying tangentially, ``agl_m`` above the terrain."""
    out = []
    for k in range(n):
        a = 2 * math.pi * k / n
        x, y = radius_m * math.cos(a), radius_m * math.sin(a)
        z = float(world.height_at(x, y)) + agl_m
        out.append(RigidTransform.from_rpy([x, y, z], yaw_rad=a + math.pi / 2))
    return out


# ---------------------------------------------------------------------- baseline: numpy ray casting
def heightfield_raycast(
    field: Heightfield, cam: CameraModel, pose: RigidTransform, max_iter: int = 400
) -> tuple[np.ndarray, np.ndarray]:
    """Terrain-only z-depth and Lambert-shaded gray image by Lipschitz-bounded ray marching."""
    grid = cam.ray_grid.reshape(-1, 2).astype(np.float64)
    d_cam = np.concatenate([grid, np.ones((len(grid), 1))], axis=1)  # camera z = 1: t is the z-depth
    d = d_cam @ pose.rotation.T
    o = pose.translation_m
    gy, gx = np.gradient(field.heights_m, field.resolution_m)
    lip = float(np.max(np.hypot(gx, gy))) * 1.05 + 1e-3
    t = np.full(len(d), cam.near_m)
    depth = np.full(len(d), np.nan)
    active = np.arange(len(d))
    x0, y0, x1, y1 = field.bounds_m
    dxy = np.hypot(d[:, 0], d[:, 1])
    for _ in range(max_iter):
        if len(active) == 0:
            break
        p = o + t[active, None] * d[active]
        gap = p[:, 2] - field.height_at(p[:, 0], p[:, 1])
        hit = gap < 0.01
        depth[active[hit]] = t[active[hit]]
        out = (p[:, 0] < x0) | (p[:, 0] > x1) | (p[:, 1] < y0) | (p[:, 1] > y1) | (t[active] > cam.far_m)
        keep = ~hit & ~out
        active = active[keep]
        gap = gap[keep]
        t[active] += np.maximum(gap / (np.abs(d[active, 2]) + lip * dxy[active]), 0.01)
    z = depth.reshape(cam.height, cam.width)
    shade = np.zeros(len(d))
    ok = np.isfinite(depth)
    if np.any(ok):
        p = o + depth[ok, None] * d[ok]
        r = field.resolution_m
        hx = (field.height_at(p[:, 0] + r, p[:, 1]) - field.height_at(p[:, 0] - r, p[:, 1])) / (2 * r)
        hy = (field.height_at(p[:, 0], p[:, 1] + r) - field.height_at(p[:, 0], p[:, 1] - r)) / (2 * r)
        n = np.stack([-hx, -hy, np.ones_like(hx)], 1)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        shade[ok] = 0.35 + 0.65 * np.clip(n @ SUN, 0, 1)
    return z, (255 * shade).astype(np.uint8).reshape(cam.height, cam.width)


# ---------------------------------------------------------------------- render rate
def bench_render_rate(world: World) -> dict[str, float]:
    cams = {n: CameraModel.from_config(n, c) for n, c in default_cameras().items()}
    poses = loop_poses(world, POSES)
    renderer = Renderer(world)
    results: dict[str, float] = {}
    try:
        for w, h in ((640, 480), (320, 240)):
            sized = {n: c.with_size(w, h) for n, c in cams.items()}
            for c in sized.values():  # warm-up: shader JIT, framebuffers
                renderer.render(c, c.optical_pose(poses[0]))
            per_pose = []
            per_cam: dict[str, list[float]] = {n: [] for n in sized}
            cpu0 = time.process_time()
            for pose in poses:
                t0 = time.perf_counter()
                for n, c in sized.items():
                    t1 = time.perf_counter()
                    renderer.render(c, c.optical_pose(pose))
                    per_cam[n].append(time.perf_counter() - t1)
                per_pose.append(time.perf_counter() - t0)
            # CPU seconds of this process (all llvmpipe threads) per camera pair: independent of other load
            results[f"gl_{w}x{h}_cpu_ms_per_pair"] = 1000 * (time.process_time() - cpu0) / len(poses)
            results[f"gl_{w}x{h}_hz"] = 1.0 / median(per_pose)
            results[f"gl_{w}x{h}_p95_ms"] = 1000 * percentile(per_pose, 95)
            for n in sized:
                results[f"gl_{w}x{h}_{n}_fps"] = 1.0 / median(per_cam[n])
            # baseline: the same frames (fewer poses: it is slow), numpy ray casting of the terrain
            base = []
            agree = []
            for pose in poses[:: POSES // BASELINE_POSES][:BASELINE_POSES]:
                depths = {}
                t0 = time.perf_counter()
                for n, c in sized.items():
                    depths[n], _ = heightfield_raycast(world.terrain, c, c.optical_pose(pose))
                base.append(time.perf_counter() - t0)
                for n, c in sized.items():  # sanity: both renderers see the same terrain
                    gl = renderer.render(c, c.optical_pose(pose))
                    terrain = (gl.instance_id == 1) & np.isfinite(depths[n])
                    if terrain.any():
                        rel = np.abs(depths[n][terrain] - gl.depth_m[terrain]) / gl.depth_m[terrain]
                        agree.append(float(np.median(rel)))
            results[f"numpy_{w}x{h}_hz"] = 1.0 / median(base)
            if agree:
                results[f"numpy_vs_gl_{w}x{h}_terrain_depth_median_rel_err"] = float(np.median(agree))
        results["triangles_static"] = float(renderer.static_triangles)
    finally:
        renderer.close()
    return results


# ---------------------------------------------------------------------- latency and memory
class _StateSender:
    """Plays the SITL's side of the sim link: ODOMETRY (+ HIL messages) at 50 Hz, free-run."""

    def __init__(self, world: World) -> None:
        self.mavlink = mavlink
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = int(self.sock.getsockname()[1])
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.sent_at: dict[int, float] = {}
        self.peer: tuple[str, int] | None = None
        self.world = world
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        m = self.mavlink
        self.sock.settimeout(0.01)
        k = 0
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                _, addr = self.sock.recvfrom(65535)
                self.peer = addr
            except TimeoutError:
                pass
            if self.peer is None or time.monotonic() < next_t:
                continue
            next_t += 0.02
            t = k * 0.02
            a = 0.05 * t
            east, north = 300 * math.cos(a), 300 * math.sin(a)
            up = float(self.world.height_at(east, north)) + 40.0
            yaw_ned = math.pi / 2 - (a + math.pi / 2)
            q = [math.cos(yaw_ned / 2), 0, 0, math.sin(yaw_ned / 2)]
            usec = round(t * 1e6)
            nan21 = [math.nan] + [0.0] * 20
            odo = m.MAVLink_odometry_message(
                usec, 1, 12, north, east, -up, q, 15, 0, 0, 0, 0, 0, nan21, nan21, 0, 0, 100
            )
            act = m.MAVLink_hil_actuator_controls_message(usec, [0.5] * 4 + [0.0] * 12, 128, 0)
            self.sent_at[usec] = time.monotonic()
            for msg in (odo, act):
                self.sock.sendto(msg.pack(self.mav), self.peer)
            k += 1

    def start(self) -> None:
        self.thread.start()

    def stop(self) -> None:
        self._stop.set()
        self.thread.join(2)
        self.sock.close()


def bench_latency_and_memory(world: World, world_yaml: Path) -> dict[str, float]:
    out: dict[str, float] = {}
    with roscore("roscore_bench_render") as env:
        sender = _StateSender(world)
        sender.start()
        bridge = Proc(
            "bench_sim_bridge",
            [
                "roslaunch", str(REPO / "catkin_ws/src/uav_sim_bridge/launch/sim_bridge.launch"),
                f"sim_port:={sender.port}", f"world:={world_yaml}", f"world_cache_dir:={CACHE}",
                "lockstep_role:=off",
            ],
            env=env,
        )  # fmt: skip
        lat: dict[str, list[float]] = {"nadir": [], "forward": []}
        lock = threading.Lock()

        def on_image(cam: str):
            def cb(msg: Image) -> None:
                now = time.monotonic()
                usec = round(msg.header.stamp.to_sec() * 1e6)
                sent = sender.sent_at.get(usec)
                if sent is not None:
                    with lock:
                        lat[cam].append(now - sent)

            return cb

        rospy.init_node("bench_render", anonymous=True, disable_signals=True)
        subs = [
            rospy.Subscriber(
                f"/cameras/{c}/{kind}/image_raw",
                Image,
                on_image(c) if kind == "color" else (lambda m: None),
                queue_size=2,
                buff_size=1 << 24,
            )
            for c in ("nadir", "forward")
            for kind in ("color", "depth")
        ]
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            with lock:
                if min(len(v) for v in lat.values()) >= 60:
                    break
            time.sleep(0.2)
        pid = _bridge_pid(bridge.pid)
        if pid is not None:
            out["bridge_rss_mb"], out["bridge_peak_rss_mb"] = _rss_mb(pid)
        for s in subs:
            s.unregister()
        bridge.stop()
        sender.stop()
    with lock:
        for cam, values in lat.items():
            if values:
                v = values[5:] or values  # skip start-up
                out[f"latency_{cam}_p50_ms"] = 1000 * median(v)
                out[f"latency_{cam}_p95_ms"] = 1000 * percentile(v, 95)
                out[f"latency_{cam}_frames"] = float(len(values))
    return out


def _bridge_pid(roslaunch_pid: int) -> int | None:
    """The sim_bridge node's pid (a child of roslaunch)."""
    try:
        children = subprocess.run(
            ["pgrep", "-P", str(roslaunch_pid)], capture_output=True, text=True, check=False
        ).stdout.split()
    except OSError:
        return None
    for c in children:
        cmd = Path(f"/proc/{c}/cmdline").read_bytes().decode(errors="replace")
        if "sim_bridge" in cmd:
            return int(c)
    return None


def _baseline_rss_mb() -> float:
    code = "import numpy, rospy, time; print(open('/proc/self/status').read())"
    text = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    for line in text.splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> int:
    os.environ.setdefault("MESA_SHADER_CACHE_DIR", str(REPO / "artifacts" / ".mesa_cache"))
    world_yaml = REPO / "config" / "worlds" / "default.yaml"
    t0 = time.perf_counter()
    world = load_or_generate(load_world_config(world_yaml), CACHE)
    load_s = time.perf_counter() - t0
    caveat = f"2 shared cores (loadavg {_load()} at start); world load {load_s:.1f} s"
    r = bench_render_rate(world)
    agree = r.get("numpy_vs_gl_640x480_terrain_depth_median_rel_err", float("nan"))
    notes = (
        f"{caveat}; CPU {r['gl_640x480_cpu_ms_per_pair']:.0f} ms per camera pair (all threads); "
        f"per camera 640x480: nadir {r['gl_640x480_nadir_fps']:.0f} fps, forward "
        f"{r['gl_640x480_forward_fps']:.0f} fps, p95 pair {r['gl_640x480_p95_ms']:.0f} ms; "
        f"{r['triangles_static']:.0f} static triangles; baseline = numpy heightfield ray cast (terrain only, "
        f"median rel. depth diff vs GL on terrain {agree:.1e})"
    )
    record("sim_bridge.render.two_cams_640x480", r["gl_640x480_hz"], "Hz", r["numpy_640x480_hz"],
           target=">= 30", met=r["gl_640x480_hz"] >= 30, notes=notes)  # fmt: skip
    record("sim_bridge.render.two_cams_320x240", r["gl_320x240_hz"], "Hz", r["numpy_320x240_hz"],
           notes=f"{caveat}; CPU {r['gl_320x240_cpu_ms_per_pair']:.0f} ms per pair; nadir "
                 f"{r['gl_320x240_nadir_fps']:.0f} fps, forward {r['gl_320x240_forward_fps']:.0f} fps")  # fmt: skip
    lm = bench_latency_and_memory(world, world_yaml)
    render_ms = 1000.0 / r["gl_640x480_hz"] / 2
    if "latency_nadir_p50_ms" in lm:
        record(
            "sim_bridge.latency.state_to_image_p50",
            lm["latency_nadir_p50_ms"],
            "ms",
            render_ms,
            notes=(
                f"ODOMETRY sent -> nadir color Image received via roscore, free-run 50 Hz states, both cameras "
                f"640x480 at 10 Hz with color+depth subscribed; p95 nadir {lm['latency_nadir_p95_ms']:.0f} ms, "
                f"forward p50 {lm.get('latency_forward_p50_ms', float('nan')):.0f} ms / p95 "
                f"{lm.get('latency_forward_p95_ms', float('nan')):.0f} ms; baseline = render time of one 640x480 "
                f"camera; loadavg {_load()}"
            ),
        )
    if "bridge_rss_mb" in lm:
        base_rss = _baseline_rss_mb()
        record(
            "sim_bridge.memory.bridge_rss",
            lm["bridge_peak_rss_mb"],
            "MB",
            base_rss,
            target="< 1024",
            met=lm["bridge_peak_rss_mb"] < 1024,
            notes=f"peak RSS of the sim_bridge node with the default world (current {lm['bridge_rss_mb']:.0f} MB); "
            "baseline = python with numpy + rospy imported",
        )
    rss, peak = _rss_mb()
    record("sim_bridge.memory.bench_process", peak, "MB", _baseline_rss_mb(),
           notes=f"this process: default world + one renderer (current {rss:.0f} MB)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
