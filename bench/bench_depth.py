"""Benchmark of the motion-stereo depth estimator over a fixed flight above the default world.

The flight: two straight legs at 50 m above the terrain, 8 m/s, nadir camera at
10 Hz (the bridge's default nadir camera runs at 5 Hz; 10 Hz is kept so figures stay
comparable over time, and the pairing gate picks a baseline of ~7.5 m at either rate),
with a 4 deg cruise pitch and a +-1.5 deg attitude wobble. Each leg starts with 2 s of
unscored run-up, as in continuous flight.
Leg A crosses the village at (-250, -55) heading east; leg B crosses the village
at (243, 162) heading north-east, so the rectified images are rotated by 90 and
45 deg from the originals. Frames are rendered by the project's GL
renderer (``uav_sim_bridge.render.Renderer``) with their exact depth and
instance ids, so every estimate is scored pixel by pixel against ground truth.

Results (``bench/results/latest.jsonl``):

* ``depth.rate_hz.640x480`` / ``depth.rate_hz.320x240``: estimates per second
  (pairing + pose refinement + rectification + SGBM with full left-right check +
  filters + triangulation + cloud packing), baseline: plain SGBM on the same
  unrectified pairs. Target >= 5 Hz at 640x480.
* ``depth.within_1m_pct.50m``: share of covered pixels within 1 m of the truth,
  baseline: plain SGBM. Target >= 90 %.
* ``depth.coverage_pct.50m``, ``depth.abs_rel.50m``: the same flight.
* ``depth.within_1m_pct.50m_pose_noise``: with the bridge's default pose noise
  (``uav_sim_bridge.core.sensor_noise.PoseNoise``), baseline: the estimator with
  pose refinement off.

The plain SGBM baseline: the two raw images, flipped/transposed so the image
motion is horizontal and left-to-right (nothing else: no rotation compensation,
no filters beyond SGBM's own), the same SGBM parameters and window, and
``z = f |B| / d``.

Usage: ``scripts/in_env python bench/bench_depth.py [--frames N] [--save DIR]``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np
import numpy.typing as npt
from benchlib import REPO, median, record

from uav_common.config import load_config
from uav_common.pointcloud import pack_xyzrgb
from uav_perception.core.depth.config import DepthConfig, LrCheck, PoseRefineConfig
from uav_perception.core.depth.estimator import DepthEstimate, MotionStereoEstimator
from uav_perception.core.depth.matching import disparity_search
from uav_perception.core.depth.metrics import (
    DepthAccumulator,
    DepthEvaluation,
    class_index_image,
    class_lut,
    evaluate_depth,
)
from uav_perception.core.depth.types import CameraPose, ColorFrame, PinholeCamera
from uav_sim_bridge.core.camera import CameraConfig, CameraModel, MountConfig
from uav_sim_bridge.core.sensor_noise import PoseNoise, PoseNoiseConfig
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import load_world_config
from uav_sim_bridge.shell.world_store import load_or_generate

RATE_HZ = 10.0
SPEED_MPS = 8.0
AGL_M = 50.0
CRUISE_PITCH_DEG = 4.0
WOBBLE_DEG = 1.5
RUN_UP_FRAMES = 20
LEGS = (((-300.0, -55.0), (-200.0, -55.0)), ((205.0, 124.0), (275.0, 194.0)))
WORLD_CACHE = Path("~/.cache/uav_test_range/worlds").expanduser()


@dataclass(frozen=True)
class FlightFrame:
    """One rendered frame of the flight, with its exact truth."""

    stamp_ns: int
    leg: int
    scored: bool
    pose: CameraPose
    rgb: npt.NDArray[np.uint8]
    depth_m: npt.NDArray[np.float32]
    instances: npt.NDArray[np.uint16]
    t_map_base: RigidTransform


def load_world() -> World:
    """The default world (cached on disk after the first generation)."""
    return load_or_generate(load_world_config(REPO / "config/worlds/default.yaml"), WORLD_CACHE)


def nadir_camera(width: int, height: int) -> CameraModel:
    """The bridge's default nadir camera (90 deg HFOV) at the given size."""
    cfg = CameraConfig(width=width, height=height, hfov_deg=90.0, mount=MountConfig(rpy_deg=(0.0, 90.0, 0.0)))
    return CameraModel.from_config("nadir", cfg)


def pinhole(cam: CameraModel) -> PinholeCamera:
    return PinholeCamera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)


def flight_poses(world: World, frames_per_leg: int) -> Iterator[tuple[int, int, bool, RigidTransform]]:
    """``(stamp_ns, leg, scored, T_map_base)`` along the legs, 50 m above the terrain under the vehicle.

    Each leg starts with ``RUN_UP_FRAMES`` unscored frames before its start point, as
    if the vehicle had been flying already (the estimator's history fills up).
    """
    for leg, ((x0, y0), (x1, y1)) in enumerate(LEGS):
        heading = math.atan2(y1 - y0, x1 - x0)
        length = math.hypot(x1 - x0, y1 - y0)
        n = min(frames_per_leg, int(length / (SPEED_MPS / RATE_HZ)))
        for i in range(-RUN_UP_FRAMES, n):
            s = i * SPEED_MPS / RATE_HZ
            x, y = x0 + s * math.cos(heading), y0 + s * math.sin(heading)
            z = float(world.height_at(np.array([x]), np.array([y]))[0]) + AGL_M
            t = i / RATE_HZ
            roll = math.radians(WOBBLE_DEG) * math.sin(2 * math.pi * 0.3 * t)
            pitch = math.radians(CRUISE_PITCH_DEG + WOBBLE_DEG * math.sin(2 * math.pi * 0.2 * t + 1.0))
            yaw = heading + math.radians(WOBBLE_DEG) * math.sin(2 * math.pi * 0.1 * t)
            yield round((100 * (leg + 1) + t) * 1e9), leg, i >= 0, RigidTransform.from_rpy([x, y, z], roll, pitch, yaw)


def render_flight(world: World, cam: CameraModel, frames_per_leg: int) -> list[FlightFrame]:
    """Render every frame of the flight (GL context created and used in this thread)."""
    from uav_sim_bridge.render import Renderer  # noqa: PLC0415 - GL only when rendering

    renderer = Renderer(world)
    out = []
    try:
        for stamp_ns, leg, scored, t_map_base in flight_poses(world, frames_per_leg):
            t_opt = cam.optical_pose(t_map_base)
            f = renderer.render(cam, t_opt)
            pose = CameraPose(t_opt.rotation, t_opt.translation_m)
            out.append(FlightFrame(stamp_ns, leg, scored, pose, f.color_rgb, f.depth_m, f.instance_id, t_map_base))
    finally:
        renderer.close()
    return out


def plain_sgbm_depth(
    ref: FlightFrame, partner: FlightFrame, camera: PinholeCamera, est: DepthEstimate, config: DepthConfig
) -> npt.NDArray[np.float32]:
    """Baseline: SGBM straight on the raw pair (only flipped/transposed to make the motion left-to-right)."""
    base_cam = ref.pose.rotation_map_optical.T @ (partner.pose.position_map_m - ref.pose.position_map_m)
    gray = [cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY) for f in (ref, partner)]
    transpose = abs(base_cam[1]) > abs(base_cam[0])
    flip = (base_cam[1] if transpose else base_cam[0]) < 0
    imgs = [g.T if transpose else g for g in gray]
    imgs = [np.ascontiguousarray(i[:, ::-1]) if flip else np.ascontiguousarray(i) for i in imgs]
    m = config.estimator.matching
    focal = camera.fx_px
    baseline = float(np.linalg.norm(base_cam))
    search = disparity_search(
        focal_px=focal,
        baseline_m=baseline,
        depth_prior_m=est.depth_prior_m,
        prior=config.estimator.depth_prior,
        matching=m,
        min_depth_m=config.estimator.filtering.min_depth_m,
    )
    num = search.max_px + (-search.max_px) % 16
    area = m.block_size_px**2
    sgbm = cv2.StereoSGBM.create(
        minDisparity=0, numDisparities=num, blockSize=m.block_size_px, P1=m.p1_factor * area, P2=m.p2_factor * area,
        uniquenessRatio=m.uniqueness_ratio_pct, speckleWindowSize=100, speckleRange=2, preFilterCap=m.pre_filter_cap,
        mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )  # fmt: skip
    disp = sgbm.compute(imgs[0], imgs[1]).astype(np.float32) / 16.0
    with np.errstate(divide="ignore"):
        depth = np.where(disp > 0, focal * baseline / disp, np.nan).astype(np.float32)
    if flip:
        depth = depth[:, ::-1]
    return np.ascontiguousarray(depth.T if transpose else depth)


@dataclass
class FlightResult:
    """What one pass over the flight measured."""

    ours: DepthAccumulator
    plain: DepthAccumulator
    times_s: list[float]
    cpu_s: list[float]
    plain_times_s: list[float]
    estimates: int
    frames: int
    examples: list[tuple[FlightFrame, npt.NDArray[np.float32], npt.NDArray[np.float32]]]


def run_flight(
    frames: list[FlightFrame],
    camera: PinholeCamera,
    config: DepthConfig,
    *,
    noisy_poses: list[CameraPose] | None = None,
    with_plain: bool = True,
    lut: npt.NDArray[np.int16] | None = None,
) -> FlightResult:
    """Feed the frames through the estimator (and the plain baseline) and score every estimate."""
    est = MotionStereoEstimator(camera, config.estimator)
    by_stamp = {f.stamp_ns: f for f in frames}
    res = FlightResult(DepthAccumulator(), DepthAccumulator(), [], [], [], 0, sum(f.scored for f in frames), [])
    eval_cfg = config.evaluator
    for i, f in enumerate(frames):
        pose = noisy_poses[i] if noisy_poses is not None else f.pose
        t0, c0 = time.perf_counter(), time.process_time()
        out = est.process(ColorFrame(f.stamp_ns, f.rgb, pose))
        if not isinstance(out, DepthEstimate) or not f.scored:
            continue
        cloud = est.cloud(out, ColorFrame(f.stamp_ns, f.rgb, pose))
        pack_xyzrgb(cloud.xyz_m, cloud.rgb)
        res.times_s.append(time.perf_counter() - t0)
        res.cpu_s.append(time.process_time() - c0)
        res.estimates += 1
        classes = class_index_image(f.instances, lut) if lut is not None else None
        ev = evaluate_depth(out.depth_m, f.depth_m, eval_cfg, classes)
        res.ours.add(ev)
        plain = None
        if with_plain:
            t1 = time.perf_counter()
            plain = plain_sgbm_depth(f, by_stamp[out.partner_stamp_ns], camera, out, config)
            res.plain_times_s.append(time.perf_counter() - t1)
            res.plain.add(evaluate_depth(plain, f.depth_m, eval_cfg, classes))
        if len(res.examples) < 2 and f.leg == len(res.examples) and res.estimates > 5:
            res.examples.append((f, out.depth_m, plain if plain is not None else np.full_like(out.depth_m, np.nan)))
    return res


def noisy_pose_sequence(frames: list[FlightFrame], cam: CameraModel, seed: int = 0) -> list[CameraPose]:
    """Camera poses through the bridge's pose-noise model (its default parameters)."""
    noise = PoseNoise(PoseNoiseConfig())
    rng = np.random.default_rng(seed)
    out = []
    for f in frames:
        t_noisy = cam.optical_pose(noise.apply(f.t_map_base, f.stamp_ns * 1e-9, rng))
        out.append(CameraPose(t_noisy.rotation, t_noisy.translation_m))
    return out


def _depth_png(depth: npt.NDArray[np.float32], lo: float, hi: float) -> npt.NDArray[np.uint8]:
    vis = np.clip(255 * (hi - np.nan_to_num(depth, nan=hi)) / (hi - lo), 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(vis, cv2.COLORMAP_TURBO)
    out[~np.isfinite(depth)] = 0
    return out


def save_examples(result: FlightResult, folder: Path) -> list[Path]:
    """Color | truth | ours | plain SGBM | |error| (white = 2 m), one row per leg."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for f, ours, plain in result.examples:
        lo, hi = float(np.nanpercentile(f.depth_m, 1)) - 5, float(np.nanpercentile(f.depth_m, 99)) + 5
        err = np.clip(np.nan_to_num(np.abs(ours - f.depth_m), nan=0.0) / 2.0 * 255, 0, 255).astype(np.uint8)
        row = np.hstack(
            [
                cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR),
                _depth_png(f.depth_m, lo, hi),
                _depth_png(ours, lo, hi),
                _depth_png(plain, lo, hi),
                cv2.cvtColor(err, cv2.COLOR_GRAY2BGR),
            ]
        )
        path = folder / f"depth_leg{f.leg}_{f.rgb.shape[1]}x{f.rgb.shape[0]}.png"
        cv2.imwrite(str(path), row)
        paths.append(path)
    return paths


def _pct(x: float) -> float:
    return 100.0 * x


def _class_note(ev: DepthEvaluation) -> str:
    parts = [f"{c.label} {_pct(c.within_abs):.0f}%/{c.sums.n_covered}" for c in ev.classes if c.sums.n_covered]
    return "within 1 m per class (%/pixels): " + ", ".join(parts)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60, help="frames per leg (default 60 = 48 m)")
    parser.add_argument("--save", type=Path, default=REPO / "artifacts" / "bench_depth", help="example images")
    args = parser.parse_args()
    config = load_config(DepthConfig, REPO / "config/depth.yaml")
    eval_cfg = replace(config.evaluator, abs_tol_m=1.0)
    config = replace(config, evaluator=eval_cfg)
    t0 = time.perf_counter()
    world = load_world()
    lut = class_lut({o.instance_id: o.object_class.label for o in world.objects}, eval_cfg.classes)
    ready_s = time.perf_counter() - t0
    print(f"world {world.config.name} ({world.hash[:12]}) ready in {ready_s:.1f} s; cv2 threads {cv2.getNumThreads()}")
    caveat = "2 cores shared with other work; wall-clock medians"
    results = {}
    for width, height in ((640, 480), (320, 240)):
        cam = nadir_camera(width, height)
        t0 = time.perf_counter()
        frames = render_flight(world, cam, args.frames)
        print(f"{width}x{height}: rendered {len(frames)} frames in {time.perf_counter() - t0:.1f} s")
        res = run_flight(frames, pinhole(cam), config, lut=lut)
        results[(width, height)] = (frames, cam, res)
        save_examples(res, args.save)
        rate = 1.0 / median(res.times_s)
        plain_rate = 1.0 / median(res.plain_times_s)
        cpu_rate = 1.0 / median(res.cpu_s)
        record(
            f"depth.rate_hz.{width}x{height}",
            rate,
            "Hz",
            plain_rate,
            target=">= 5" if width == 640 else "",
            met=rate >= 5.0 if width == 640 else None,
            notes=f"{res.estimates}/{res.frames} frames estimated; p90 {1e3 * np.percentile(res.times_s, 90):.0f} ms; "
            f"baseline plain SGBM on the same pairs; {caveat}",
        )
        record(
            f"depth.rate_hz_per_cpu_core.{width}x{height}",
            cpu_rate,
            "Hz",
            rate,
            target=">= 5" if width == 640 else "",
            met=cpu_rate >= 5.0 if width == 640 else None,
            notes="1 / CPU seconds (all threads) per estimate: the rate one free core sustains, insensitive to "
            "other load; 2 free cores do at least as well; baseline: the wall-clock rate of this run",
        )
    frames, cam, res = results[(640, 480)]
    ours, plain = res.ours.result(), res.plain.result()
    o, p = ours.overall, plain.overall
    record(
        "depth.within_1m_pct.50m",
        _pct(o.within_abs),
        "%",
        _pct(p.within_abs),
        target=">= 90",
        met=_pct(o.within_abs) >= 90.0,
        notes=f"640x480, {res.estimates} estimates, 50 m AGL; covered pixels; {_class_note(ours)}; baseline plain SGBM",
    )
    record("depth.coverage_pct.50m", _pct(o.coverage), "%", _pct(p.coverage), notes="640x480; baseline plain SGBM")
    record(
        "depth.abs_rel.50m",
        o.abs_rel,
        "",
        p.abs_rel,
        notes=f"640x480; rmse {o.rmse_m:.2f} m (plain {p.rmse_m:.2f}); delta1 {_pct(o.delta1):.1f}% "
        f"(plain {_pct(p.delta1):.1f}%); bias {o.bias_m:+.2f} m; lower is better",
    )
    full_cfg = replace(
        config,
        estimator=replace(config.estimator, filtering=replace(config.estimator.filtering, lr_check=LrCheck.FULL)),
    )
    res_full = run_flight(frames, pinhole(cam), full_cfg, with_plain=False, lut=lut)
    f_all = res_full.ours.result().overall
    record(
        "depth.rate_hz.640x480_full_lr",
        1.0 / median(res_full.times_s),
        "Hz",
        1.0 / median(res.times_s),
        notes=f"lr_check: full (second SGBM pass); within 1 m {_pct(f_all.within_abs):.2f}% "
        f"(internal {_pct(o.within_abs):.2f}%), coverage {_pct(f_all.coverage):.1f}%; baseline: lr_check internal; "
        + caveat,
    )
    small = results[(320, 240)][2].ours.result().overall
    record(
        "depth.within_1m_pct.50m_320x240",
        _pct(small.within_abs),
        "%",
        _pct(results[(320, 240)][2].plain.result().overall.within_abs),
        notes=f"coverage {_pct(small.coverage):.1f}%; abs_rel {small.abs_rel:.4f}; baseline plain SGBM",
    )
    noisy = noisy_pose_sequence(frames, cam)
    res_noisy = run_flight(frames, pinhole(cam), config, noisy_poses=noisy, with_plain=False, lut=lut)
    cfg_off = replace(config, estimator=replace(config.estimator, pose_refine=PoseRefineConfig(enabled=False)))
    res_off = run_flight(frames, pinhole(cam), cfg_off, noisy_poses=noisy, with_plain=False, lut=lut)
    n_on, n_off = res_noisy.ours.result().overall, res_off.ours.result().overall
    record(
        "depth.within_1m_pct.50m_pose_noise",
        _pct(n_on.within_abs),
        "%",
        _pct(n_off.within_abs),
        notes=f"bridge default pose noise (0.05 m jitter + drift, 0.1/0.3 deg); coverage {_pct(n_on.coverage):.1f}% "
        f"(no refine {_pct(n_off.coverage):.1f}%); abs_rel {n_on.abs_rel:.4f}; baseline: pose refinement off",
    )
    print(f"example images: {args.save}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
