"""Benchmark of the detector contract's consumers: box geolocation in the default world, and the run scorer's
detector and tracker scores on a long run.

Geolocation. For people and vehicles of the default world, the forward camera (640x480, 90 deg, 25 deg down)
is put 40 m above the ground 70 m south of the object, looking at it, and rendered by the project's renderer;
the object's ground-truth box (its visible pixels) is placed by the geolocator's core on (a) the rendered depth
image, (b) an elevation layer as the map server builds it (highest point of each 1 m column, here from one
high nadir render over the area) over the world's terrain model, (c) the terrain model alone, and compared with
the object's true ground position (horizontal error). Baseline: the naive placement, the ray through the *box
centre* on the terrain model (no ground-contact point, no footprint), which lands behind a standing person.

* ``perception.geolocation.error_median_m.{depth,elevation,terrain}`` (baseline: box centre on the terrain)
* ``perception.geolocation.within_95_pct.{...}``: share of errors inside the stated 95 % ellipse
* ``perception.geolocation.ms_per_box.{depth,elevation,terrain}`` (baseline: depth)

Scores. A 10-minute run of the forward camera at 10 Hz (6000 frames, 40 % with two people and a detector's
boxes, a false box now and then, tracks): the scorer's final summary with the COCO matching done image by image
during the run (every 200 frames, as the scorer does every 20 s of simulation), against matching everything at the
end (baseline); and the tracking summary's HOTA against py-motmetrics' MOTA/IDF1 over the same frames.

* ``perception.scoring.final_coco_s`` (baseline: all at the end; target < 10 s: the mission manager waits at most
  30 s for the final metrics)
* ``perception.scoring.hota_s`` (baseline: motmetrics)

Usage: ``scripts/in_env python bench/bench_perception.py [--objects N]``.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from benchlib import REPO, median, record

from uav_perception.core.depth.types import CameraPose, PinholeCamera
from uav_perception.core.detection.boxes import Box
from uav_perception.core.detection.geolocation import GeolocationConfig, Placement, Surfaces, place
from uav_perception.core.detection.heightfield import HeightGrid
from uav_perception.shell.dem import load_dem
from uav_scenarios.core.config import ScoringSpec
from uav_scenarios.core.scoring.coco import CocoScores, ContextBands
from uav_scenarios.core.scoring.hota import HotaAccumulator, ground_similarity
from uav_scenarios.core.scoring.types import Detection
from uav_scenarios.core.tracking import MotScorer
from uav_scenarios.shell.world_store import terrain_dem
from uav_sim_bridge.core.camera import CameraConfig, CameraModel, MountConfig, depth_to_points, look_at
from uav_sim_bridge.core.detections import DetectionConfig, ground_truth_detections
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world_config import ObjectClass, load_world_config
from uav_sim_bridge.render import Renderer
from uav_sim_bridge.shell.world_store import load_or_generate

CACHE = Path("~/.cache/uav_test_range/worlds").expanduser()
CFG = GeolocationConfig()
FOOTPRINT = {ObjectClass.PERSON: 0.2, ObjectClass.VEHICLE: 1.5}


def elevation_layer(renderer: Renderer, centre: tuple[float, float], half_m: float) -> HeightGrid:
    """The map server's elevation layer, near enough: the highest rendered point of each 1 m column, from one nadir
    render 450 m above the area (about 1.4 m per pixel, every column of the area hit several times)."""
    cam = CameraModel.simple(1280, 1280, 90.0, name="survey")
    pose = look_at([centre[0], centre[1], 450.0], [centre[0], centre[1], 0.0], up=(0.0, 1.0, 0.0))
    frame = renderer.render(cam, pose)
    pts = depth_to_points(frame.depth_m, cam.k).reshape(-1, 3).astype(np.float64)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    world = pts @ pose.rotation.T + pose.translation_m
    x0, y0 = centre[0] - half_m, centre[1] - half_m
    n = round(2 * half_m)
    cols = np.floor(world[:, 0] - x0).astype(int)
    rows = np.floor(world[:, 1] - y0).astype(int)
    ok = (cols >= 0) & (cols < n) & (rows >= 0) & (rows < n)
    grid = np.full((n, n), -np.inf)
    np.maximum.at(grid, (rows[ok], cols[ok]), world[ok, 2])
    grid[~np.isfinite(grid)] = np.nan
    return HeightGrid(grid, x0, y0, 1.0, "nearest", "elevation")


def geolocation_bench(n_objects: int) -> None:
    world = load_or_generate(load_world_config(REPO / "config/worlds/default.yaml"), CACHE)
    terrain = load_dem(terrain_dem(world, CACHE))
    renderer = Renderer(world)
    cam = CameraModel.from_config(
        "forward", CameraConfig(hfov_deg=90.0, mount=MountConfig(xyz_m=(0.12, 0.0, -0.04), rpy_deg=(0.0, 25.0, 0.0)))
    )
    camera = PinholeCamera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)
    det_cfg = DetectionConfig(max_range_m=150.0)
    objects = [o for o in world.objects if o.object_class in FOOTPRINT]
    rng = np.random.default_rng(0)
    picks = [objects[i] for i in rng.choice(len(objects), size=min(n_objects, len(objects)), replace=False)]
    errors: dict[str, list[float]] = {"depth": [], "elevation": [], "terrain": [], "centre": []}
    inside: dict[str, list[bool]] = {"depth": [], "elevation": [], "terrain": []}
    times: dict[str, list[float]] = {"depth": [], "elevation": [], "terrain": []}
    for obj in picks:
        ox, oy, _ = obj.pose.position_m
        ground = float(world.height_at(ox, oy))
        base = RigidTransform.from_rpy([ox, oy - 70.0, ground + 40.0], yaw_rad=math.pi / 2)
        t_opt = cam.optical_pose(base)
        frame = renderer.render(cam, t_opt)
        dets = [d for d in ground_truth_detections(frame.instance_id, t_opt, [obj], det_cfg) if d.visible_pixels >= 4]
        if not dets:
            continue
        d = dets[0]
        box = Box(obj.object_class.label, 0, 1.0, d.x_min - 0.5, d.y_min - 0.5, d.x_max + 0.5, d.y_max + 0.5)
        pose = CameraPose(t_opt.rotation, t_opt.translation_m)
        elevation = elevation_layer(renderer, (ox, oy - 35.0), 80.0)
        radius = FOOTPRINT[obj.object_class]
        for name, surfaces in (
            ("depth", Surfaces(depth_m=frame.depth_m, elevation=elevation, terrain=terrain)),
            ("elevation", Surfaces(elevation=elevation, terrain=terrain)),
            ("terrain", Surfaces(terrain=terrain)),
        ):
            t0 = time.perf_counter()
            p = place(box, camera, pose, surfaces, CFG, footprint_radius_m=radius)
            times[name].append(time.perf_counter() - t0)
            if p.placed:
                err = np.array([p.position_m[0] - ox, p.position_m[1] - oy])
                errors[name].append(float(np.linalg.norm(err)))
                cov = np.array(p.covariance_m2).reshape(3, 3)[:2, :2]
                inside[name].append(float(err @ np.linalg.solve(cov, err)) <= 5.991)
        centre = box.center
        naive = Box(box.class_name, 0, 1.0, centre[0] - 0.01, centre[1] - 0.01, centre[0] + 0.01, centre[1] + 0.01)
        p = place(naive, camera, pose, Surfaces(terrain=terrain), CFG)
        if isinstance(p, Placement) and p.placed:
            errors["centre"].append(math.hypot(p.position_m[0] - ox, p.position_m[1] - oy))
    renderer.close()
    baseline = median(errors["centre"])
    n = len(errors["centre"])
    for name in ("depth", "elevation", "terrain"):
        record(
            f"perception.geolocation.error_median_m.{name}",
            median(errors[name]),
            "m",
            baseline,
            notes=f"{len(errors[name])} people and vehicles 40 m up, 70 m away; baseline: the box centre's ray on the "
            f"terrain ({n} placed); p90 {np.percentile(errors[name], 90):.2f} m",
        )
        record(
            f"perception.geolocation.within_95_pct.{name}",
            100.0 * float(np.mean(inside[name])),
            "%",
            95.0,
            notes="share of errors inside the placement's own 95 % ellipse; baseline: the nominal 95 %",
        )
    for name in ("depth", "elevation", "terrain"):
        record(
            f"perception.geolocation.ms_per_box.{name}",
            1e3 * median(times[name]),
            "ms",
            1e3 * median(times["depth"]),
            notes="geolocator core per box, with its covariance (finite differences); baseline: depth",
        )


def scoring_bench(frames: int = 6000) -> None:
    rng = np.random.default_rng(1)
    spec = ScoringSpec()
    objects = {"range": ContextBands(spec.range_bands_m, "m"), "pixel_size": ContextBands(spec.pixel_size_bands_px)}
    objects |= {
        "view_angle": ContextBands(spec.view_angle_bands_deg),
        "visible_fraction": ContextBands((0, 0.2, 0.65, 1)),
    }
    frame_ctx = {"altitude": ContextBands(spec.altitude_bands_m), "clutter": ContextBands(spec.clutter_bands)}
    steps, at_end = (
        CocoScores(object_contexts=objects, frame_contexts=frame_ctx),
        CocoScores(object_contexts=objects, frame_contexts=frame_ctx),
    )
    hota, mot = HotaAccumulator(), MotScorer(5.0)
    step_times = []
    for k in range(frames):
        busy = k % 10 < 4
        truth, hyps = [], []
        if busy:
            for i in range(2):
                x, y = 200 + 60 * i + int(k % 37), 240 + int(k % 13)
                truth.append(Detection(i + 1, "person", 1.0, (x, y, x + 5, y + 12), 80.0, 0.9, (i * 8.0, k * 0.1, 0.9)))
                if rng.random() < 0.8:
                    hyps.append(
                        Detection(0, "person", float(rng.uniform(0.4, 1)), (x + 1, y, x + 6, y + 12), 79.0, math.nan)
                    )
            if rng.random() < 0.2:
                hyps.append(Detection(0, "vehicle", float(rng.uniform(0.3, 0.9)), (400, 100, 420, 110), 90.0, math.nan))
        values = {"range": 80.0, "pixel_size": 8.0, "view_angle": 63.0}
        for scores in (steps, at_end):
            scores.add_image(
                truth,
                [{**values, "visible_fraction": 0.9}] * len(truth),
                hyps,
                [values] * len(hyps),
                {"altitude": 40.0, "clutter": len(truth)},
            )
        if k % 200 == 199:
            t0 = time.perf_counter()
            steps.update()
            step_times.append(time.perf_counter() - t0)
        if busy:
            gt_xy = np.array([t.position_m[:2] for t in truth])
            tr_xy = gt_xy + rng.normal(0, 0.8, gt_xy.shape)
            ids = [1, 2] if k < frames // 2 else [3, 2]  # one identity switch
            hota.update([1, 2], ids, ground_similarity(gt_xy, tr_xy, 5.0))
            mot.update([1, 2], gt_xy, ids, tr_xy)
    t0 = time.perf_counter()
    final = steps.evaluate()
    final_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    again = at_end.evaluate()
    all_s = time.perf_counter() - t0
    assert final == again, "matching image by image gave other scores"
    record(
        "perception.scoring.final_coco_s",
        final_s,
        "s",
        all_s,
        target="< 10",
        met=final_s < 10.0,
        notes=f"{frames} frames ({frames * 4 // 10} with people); COCO AP50 {final['AP50']:.3f}; the matching during "
        f"the run cost {median(step_times):.2f} s per 200 frames; baseline: matching everything at the end",
    )
    t0 = time.perf_counter()
    h = hota.result()
    hota_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    m = mot.result()
    mot_s = time.perf_counter() - t0
    record(
        "perception.scoring.hota_s",
        hota_s,
        "s",
        mot_s,
        notes=f"HOTA {h.hota:.3f} over {h.frames} frames; baseline: py-motmetrics MOTA {m.mota:.3f}, IDF1 {m.idf1:.3f}",
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--objects", type=int, default=40, help="people and vehicles to place")
    args = ap.parse_args()
    geolocation_bench(args.objects)
    scoring_bench()


if __name__ == "__main__":
    main()
