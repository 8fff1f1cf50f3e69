"""The estimator on pairs rendered by the project's own GL renderer (uav_sim_bridge), with known poses.

A small world (tests/ros/sim_bridge/test_world.yaml: terrain, village, forest, people,
vehicles), the bridge's default nadir camera at 640x480, 50 m above a village. Stated
tolerances: >= 95 % of the covered pixels within 1 m, >= 70 % coverage, |bias| < 0.3 m,
for a flight with attitude changes and for a yawed pair; >= 90 % within 1 m with poses
degraded by the bridge's own pose-noise model (0.05 m jitter, 0.1/0.3 deg).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.paths import REPO

from uav_perception.core.depth.config import EstimatorConfig, EvaluatorConfig
from uav_perception.core.depth.estimator import DepthEstimate, MotionStereoEstimator
from uav_perception.core.depth.metrics import DepthAccumulator, class_index_image, class_lut, evaluate_depth
from uav_perception.core.depth.types import CameraPose, ColorFrame, PinholeCamera
from uav_sim_bridge.core.camera import CameraConfig, CameraModel, MountConfig
from uav_sim_bridge.core.sensor_noise import PoseNoise, PoseNoiseConfig
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import load_world_config
from uav_sim_bridge.shell.world_store import generate_world

WORLD_YAML = REPO / "tests" / "ros" / "sim_bridge" / "test_world.yaml"
EVAL = EvaluatorConfig(abs_tol_m=1.0)
START_EN_M = (30.0, 100.0)  # west of the test world's village (buildings around (80, 115))


@pytest.fixture(scope="module")
def world() -> World:
    return generate_world(load_world_config(WORLD_YAML))


@pytest.fixture(scope="module")
def nadir() -> CameraModel:
    cfg = CameraConfig(width=640, height=480, hfov_deg=90.0, mount=MountConfig((0.0, 0.0, -0.08), (0.0, 90.0, 0.0)))
    return CameraModel.from_config("nadir", cfg)


@pytest.fixture(scope="module")
def renderer(world: World) -> Iterator[object]:
    from uav_sim_bridge.render import Renderer  # noqa: PLC0415 - GL context in the test's thread

    r = Renderer(world)
    yield r
    r.close()


def base_pose(world: World, k: int, heading_rad: float, *, yaw_offset_rad: float = 0.0) -> RigidTransform:
    """Frame k of a flight at 8 m/s, 10 Hz, 50 m above the terrain, pitching and rolling slowly."""
    s = 0.8 * k
    x, y = START_EN_M[0] + s * math.cos(heading_rad), START_EN_M[1] + s * math.sin(heading_rad)
    z = float(world.height_at(np.array([x]), np.array([y]))[0]) + 50.0
    t = 0.1 * k
    roll = math.radians(1.5) * math.sin(2.0 * t)
    pitch = math.radians(4.0 + 1.5 * math.sin(1.3 * t))
    return RigidTransform.from_rpy([x, y, z], roll, pitch, heading_rad + yaw_offset_rad)


def camera_of(cam: CameraModel) -> PinholeCamera:
    return PinholeCamera(cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy)


def run(
    world: World,
    renderer: object,
    nadir: CameraModel,
    poses: list[RigidTransform],
    noisy: list[RigidTransform] | None,
    *,
    run_up: int = 0,
) -> tuple[DepthAccumulator, list[DepthEstimate], list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """Feed the frames in order; the first ``run_up`` only join the history (as when the node is busy)."""
    est = MotionStereoEstimator(camera_of(nadir), EstimatorConfig())
    lut = class_lut({o.instance_id: o.object_class.label for o in world.objects}, EVAL.classes)
    acc = DepthAccumulator()
    outs, views = [], []
    for k, t_base in enumerate(poses):
        t_opt = nadir.optical_pose(t_base)
        frame = renderer.render(nadir, t_opt)  # type: ignore[attr-defined]
        seen = nadir.optical_pose(noisy[k]) if noisy is not None else t_opt
        color = ColorFrame(k * 10**8, frame.color_rgb, CameraPose(seen.rotation, seen.translation_m))
        out = est.remember(color) if k < run_up else est.process(color)
        if isinstance(out, DepthEstimate):
            acc.add(evaluate_depth(out.depth_m, frame.depth_m, EVAL, class_index_image(frame.instance_id, lut)))
            outs.append(out)
            views.append((frame.color_rgb, frame.depth_m, out.depth_m))
    return acc, outs, views


def save(views: list[tuple[np.ndarray, np.ndarray, np.ndarray]], path: Path) -> None:
    rgb, truth, est = views[-1]
    lo, hi = float(np.nanmin(truth)) - 2, float(np.nanmax(truth)) + 2

    def color(d: np.ndarray) -> np.ndarray:
        out = cv2.applyColorMap(
            np.clip(255 * (hi - np.nan_to_num(d, nan=hi)) / (hi - lo), 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO
        )
        out[~np.isfinite(d)] = 0
        return out

    cv2.imwrite(str(path), np.hstack([cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), color(truth), color(est)]))


@pytest.mark.parametrize("heading_deg", [0.0, 45.0])
def test_gl_rendered_flight_within_tolerance(
    world: World, renderer: object, nadir: CameraModel, artifacts: Path, heading_deg: float
) -> None:
    poses = [base_pose(world, k, math.radians(heading_deg)) for k in range(12)]
    acc, outs, views = run(world, renderer, nadir, poses, None)
    save(views, artifacts / f"gl_flight_heading{heading_deg:.0f}.png")
    ev = acc.result()
    assert len(outs) >= 7
    assert ev.overall.within_abs >= 0.95
    assert ev.overall.coverage >= 0.70
    assert abs(ev.overall.bias_m) < 0.3
    classes = {c.label: c for c in ev.classes}
    assert classes["terrain"].within_abs >= 0.95


def test_gl_rendered_yawed_pair(world: World, renderer: object, nadir: CameraModel, artifacts: Path) -> None:
    """Two views 7.2 m apart whose headings differ by 10 degrees (the gate allows 15)."""
    poses = [base_pose(world, 0, 0.0), base_pose(world, 9, 0.0, yaw_offset_rad=math.radians(10.0))]
    acc, outs, views = run(world, renderer, nadir, poses, None)
    save(views, artifacts / "gl_yawed_pair.png")
    assert len(outs) == 1
    assert outs[0].geometry.rotation_deg == pytest.approx(10.0, abs=1.5)
    assert acc.result().overall.within_abs >= 0.95
    assert acc.result().overall.coverage >= 0.6


def test_gl_rendered_flight_with_the_bridges_pose_noise(
    world: World, renderer: object, nadir: CameraModel, artifacts: Path
) -> None:
    poses = [base_pose(world, k, math.radians(30.0)) for k in range(34)]
    noise, rng = PoseNoise(PoseNoiseConfig()), np.random.default_rng(3)
    noisy = [noise.apply(p, 0.1 * k, rng) for k, p in enumerate(poses)]
    # 2.5 s of flight fill the history (the trajectory fit needs it), then 9 frames are estimated.
    acc, outs, views = run(world, renderer, nadir, poses, noisy, run_up=25)
    save(views, artifacts / "gl_flight_pose_noise.png")
    assert len(outs) == 9
    assert all(o.refine is not None and o.refine.applied for o in outs)
    assert all(o.pose_smoothed for o in outs)
    assert np.median([o.pose_jitter_m for o in outs]) == pytest.approx(0.05, rel=0.5)
    # The baseline length still carries the (smoothed) jitter: a scale error of ~0.5 % per frame.
    assert acc.result().overall.within_abs >= 0.90
    assert acc.result().overall.coverage >= 0.70
