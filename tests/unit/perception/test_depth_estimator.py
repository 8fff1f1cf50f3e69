"""The estimator on exactly known synthetic image pairs (ray-cast, exact depth)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from depth_fixtures import Rendered, flight_pose
from synthetic_scene import rotation_about

from uav_perception.core.depth.config import EstimatorConfig, EvaluatorConfig, PoseRefineConfig
from uav_perception.core.depth.estimator import DepthEstimate, MotionStereoEstimator, SkippedFrame, SkipReason
from uav_perception.core.depth.metrics import evaluate_depth
from uav_perception.core.depth.pairing import PairVerdict
from uav_perception.core.depth.types import CameraPose, ColorFrame, PinholeCamera
from uav_perception.errors import DepthInputError


def depth_png(depth: np.ndarray, max_m: float = 70.0) -> np.ndarray:
    vis = np.clip(255 * (1 - np.nan_to_num(depth, nan=max_m) / max_m), 0, 255).astype(np.uint8)
    out = cv2.applyColorMap(vis, cv2.COLORMAP_TURBO)
    out[~np.isfinite(depth)] = 0
    return out


def save_views(folder: Path, rendered: Rendered, est: np.ndarray) -> None:
    cv2.imwrite(str(folder / "color.png"), cv2.cvtColor(rendered.frame.rgb, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(folder / "depth_truth.png"), depth_png(rendered.depth_m))
    cv2.imwrite(str(folder / "depth_estimate.png"), depth_png(est))
    err = np.abs(est - rendered.depth_m)
    err_vis = np.clip(np.nan_to_num(err, nan=0.0) / 2.0 * 255, 0, 255).astype(np.uint8)  # white = 2 m or more
    cv2.imwrite(str(folder / "abs_error_0_to_2m.png"), err_vis)


def run_pair(camera: PinholeCamera, first: ColorFrame, second: ColorFrame, cfg: EstimatorConfig) -> DepthEstimate:
    est = MotionStereoEstimator(camera, cfg)
    skipped = est.process(first)
    assert isinstance(skipped, SkippedFrame)
    assert skipped.reason is SkipReason.NO_HISTORY
    out = est.process(second)
    assert isinstance(out, DepthEstimate), out
    return out


@pytest.mark.parametrize("refine", [False, True])
def test_exact_poses_give_depth_within_tolerance(
    camera: PinholeCamera, flight: list[Rendered], artifacts: Path, refine: bool
) -> None:
    cfg = EstimatorConfig(pose_refine=PoseRefineConfig(enabled=refine))
    out = run_pair(camera, flight[0].frame, flight[1].frame, cfg)
    truth = flight[1].depth_m
    save_views(artifacts, flight[1], out.depth_m)
    ev = evaluate_depth(out.depth_m, truth, EvaluatorConfig(abs_tol_m=1.0)).overall
    # 8 m of the 37 m along-track footprint is not seen by the partner: at most ~80 % is coverable.
    assert ev.coverage > 0.72
    assert ev.within_abs > 0.95
    assert ev.median_abs_err_m < 0.35
    assert ev.abs_rel < 0.02
    assert abs(ev.bias_m) < 0.2
    assert out.stamp_ns == flight[1].frame.stamp_ns
    assert out.partner_stamp_ns == flight[0].frame.stamp_ns
    assert out.geometry.baseline_m == pytest.approx(8.0)
    assert out.coverage == pytest.approx(np.isfinite(out.depth_m).mean())


def test_noisy_poses_are_repaired_by_refinement(camera: PinholeCamera, flight: list[Rendered], artifacts: Path) -> None:
    rng = np.random.default_rng(11)

    def degrade(frame: ColorFrame) -> ColorFrame:
        rot = rotation_about(rng.normal(size=3), math.radians(0.6)) @ frame.pose.rotation_map_optical
        pose = CameraPose(rot, frame.pose.position_map_m + rng.normal(0.0, 0.02, 3))
        return replace(frame, pose=pose)

    first, second = degrade(flight[0].frame), degrade(flight[1].frame)
    cfg_eval = EvaluatorConfig(abs_tol_m=1.0)
    raw = run_pair(camera, first, second, EstimatorConfig(pose_refine=PoseRefineConfig(enabled=False)))
    fixed = run_pair(camera, first, second, EstimatorConfig())
    save_views(artifacts, flight[1], fixed.depth_m)
    ev_raw = evaluate_depth(raw.depth_m, flight[1].depth_m, cfg_eval).overall
    ev_fixed = evaluate_depth(fixed.depth_m, flight[1].depth_m, cfg_eval).overall
    assert fixed.refine is not None
    assert fixed.refine.applied
    assert fixed.refine.rms_after_px < 0.2
    assert fixed.refine.rms_before_px > 3 * fixed.refine.rms_after_px
    assert ev_fixed.within_abs > 0.93
    assert ev_fixed.coverage > 0.72
    # 0.6 deg of rotation error is ~1.7 px at this focal length: unrefined, the depth is far off.
    assert ev_raw.within_abs < 0.5


def test_gate_skips_are_counted(camera: PinholeCamera, flight: list[Rendered]) -> None:
    est = MotionStereoEstimator(camera, EstimatorConfig())
    rgb = flight[0].frame.rgb
    # Hovering: every candidate is too close.
    for k in range(4):
        out = est.process(ColorFrame(k * 10**8, rgb, flight_pose(0.01 * k)))
    assert isinstance(out, SkippedFrame)
    assert out.reason is SkipReason.NO_PARTNER
    assert out.pairing is PairVerdict.BASELINE_TOO_SHORT
    # Climbing straight up: the baseline lies along the nadir optical axis.
    out = est.process(ColorFrame(2 * 10**9, rgb, flight_pose(0.0, altitude_m=60.0)))
    assert isinstance(out, SkippedFrame)
    assert out.pairing is PairVerdict.AXIAL_MOTION
    stats = est.stats
    assert stats.frames_in == 5
    assert stats.estimates == 0
    assert stats.skipped[SkipReason.NO_HISTORY] == 1
    assert stats.skipped[SkipReason.NO_PARTNER] == 4
    assert stats.pair_rejections[PairVerdict.BASELINE_TOO_SHORT] == 1 + 2 + 3
    assert stats.pair_rejections[PairVerdict.AXIAL_MOTION] == 4


def test_bad_input_is_an_error_or_a_counted_skip(camera: PinholeCamera, flight: list[Rendered]) -> None:
    est = MotionStereoEstimator(camera, EstimatorConfig())
    with pytest.raises(DepthInputError, match="camera is 320x240"):
        est.process(ColorFrame(1, np.zeros((240, 321, 3), np.uint8), flight_pose(0.0)))
    nan_pose = CameraPose(np.full((3, 3), np.nan), np.zeros(3))
    out = est.process(ColorFrame(2, flight[0].frame.rgb, nan_pose))
    assert isinstance(out, SkippedFrame)
    assert out.reason is SkipReason.INVALID_POSE
    assert est.history == ()  # never used as a partner
    assert isinstance(est.remember(flight[0].frame), SkippedFrame)
    assert est.stats.skipped[SkipReason.BUSY] == 1
    assert len(est.history) == 1
    # A frame remembered while busy is a valid partner.
    assert isinstance(est.process(flight[1].frame), DepthEstimate)
    # Time going backwards (a bag replayed from the start) resets the history.
    est.process(replace(flight[0].frame, stamp_ns=5))
    assert len(est.history) == 1


def test_cloud_matches_the_depth_image(camera: PinholeCamera, flight: list[Rendered]) -> None:
    est = MotionStereoEstimator(camera, EstimatorConfig())
    est.process(flight[0].frame)
    out = est.process(flight[1].frame)
    assert isinstance(out, DepthEstimate)
    cloud = est.cloud(out, flight[1].frame)
    n_valid = int(np.isfinite(out.depth_m).sum())
    assert cloud.xyz_m.shape == (n_valid, 3)
    assert np.isfinite(cloud.xyz_m).all()
    # Points re-project onto their pixels, with their pixel's depth and color.
    u = np.rint(cloud.xyz_m[:, 0] / cloud.xyz_m[:, 2] * camera.fx_px + camera.cx_px).astype(int)
    v = np.rint(cloud.xyz_m[:, 1] / cloud.xyz_m[:, 2] * camera.fy_px + camera.cy_px).astype(int)
    assert np.allclose(out.depth_m[v, u], cloud.xyz_m[:, 2])
    assert np.array_equal(cloud.rgb, flight[1].frame.rgb[v, u])
