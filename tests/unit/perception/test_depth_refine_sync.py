from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from depth_fixtures import Rendered
from synthetic_scene import rotation_about

from uav_perception.core.depth.config import PoseRefineConfig
from uav_perception.core.depth.refine import pose_from_relative, refine_relative_pose, sampson_px
from uav_perception.core.depth.sync import PoseHistory, StampBuffer
from uav_perception.core.depth.types import CameraPose, PinholeCamera


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(a.T @ b) - 1) / 2))))


def test_refinement_recovers_the_relative_rotation(camera: PinholeCamera, flight: list[Rendered]) -> None:
    ref, par = flight[1].frame, flight[0].frame
    gray = [cv2.cvtColor(f.rgb, cv2.COLOR_RGB2GRAY) for f in (ref, par)]
    true_rot, true_t = ref.pose.relative_to(par.pose)
    rng = np.random.default_rng(5)
    for _ in range(3):
        noisy = CameraPose(
            rotation_about(rng.normal(size=3), math.radians(1.0)) @ par.pose.rotation_map_optical,
            par.pose.position_map_m + rng.normal(0.0, 0.1, 3),
        )
        out = refine_relative_pose(
            gray[0], gray[1], camera=camera, ref_pose=ref.pose, partner_pose=noisy, config=PoseRefineConfig()
        )
        assert out.applied, out.detail
        rot, t = ref.pose.relative_to(out.pose)
        assert angle_deg(rot, true_rot) < 0.02  # from 1 deg
        cos_t = float(t @ true_t / np.linalg.norm(t) / np.linalg.norm(true_t))
        assert math.degrees(math.acos(min(1.0, cos_t))) < 0.1
        # The baseline length is kept from the (noisy) poses: images cannot see it.
        assert np.linalg.norm(t) == pytest.approx(np.linalg.norm(noisy.position_map_m - ref.pose.position_map_m))


def test_refinement_falls_back_to_the_prior_without_texture(camera: PinholeCamera, flight: list[Rendered]) -> None:
    flat = np.full(camera.shape, 90, np.uint8)
    out = refine_relative_pose(
        flat, flat, camera=camera, ref_pose=flight[1].frame.pose, partner_pose=flight[0].frame.pose,
        config=PoseRefineConfig(),
    )  # fmt: skip
    assert not out.applied
    assert "tracked corners" in out.detail
    assert out.pose is flight[0].frame.pose


def test_sampson_and_pose_from_relative() -> None:
    rng = np.random.default_rng(0)
    rot = rotation_about([0.2, 1, 0.1], 0.1)
    t = np.array([1.0, 0.2, 0.1])
    pts = np.column_stack([rng.uniform(-5, 5, 20), rng.uniform(-5, 5, 20), rng.uniform(10, 30, 20)])
    x1 = pts / pts[:, 2:]
    p2 = pts @ rot.T + t
    x2 = p2 / p2[:, 2:]
    assert np.abs(sampson_px(rot, t, x1, x2, 300.0)).max() < 1e-9
    x2_off = x2 + np.array([0.0, 1.0 / 300.0, 0.0])
    assert np.median(np.abs(sampson_px(rot, t, x1, x2_off, 300.0))) > 0.3
    ref = CameraPose(rotation_about([1, 0, 0], 0.3), np.array([1.0, 2.0, 3.0]))
    partner = pose_from_relative(ref, rot, t)
    rot2, t2 = ref.relative_to(partner)
    assert rot2 == pytest.approx(rot)
    assert t2 == pytest.approx(t)


def test_stamp_buffer() -> None:
    buf: StampBuffer[str] = StampBuffer(3)
    for stamp, item in [(30, "c"), (10, "a"), (20, "b")]:
        buf.put(stamp, item)
    assert buf.closest(21, 2) == (20, "b")
    assert buf.closest(25, 4) is None
    assert buf.closest(26, 5) == (30, "c")
    buf.put(40, "d")  # evicts the oldest
    assert len(buf) == 3
    assert buf.oldest_stamp_ns() == 20
    assert buf.newest_stamp_ns() == 40
    buf.put(40, "e")
    assert buf.closest(40, 0) == (40, "e")
    with pytest.raises(ValueError, match="capacity"):
        StampBuffer(0)


def test_pose_history_interpolates_and_refuses_gaps() -> None:
    hist = PoseHistory(10, max_gap_ns=200, max_extrapolation_ns=20)
    r0 = rotation_about([0, 0, 1], 0.0)
    r1 = rotation_about([0, 0, 1], 0.4)
    hist.add(100, CameraPose(r0, np.array([0.0, 0.0, 10.0])))
    hist.add(200, CameraPose(r1, np.array([4.0, 0.0, 10.0])))
    hist.add(600, CameraPose(r1, np.array([8.0, 0.0, 10.0])))
    mid = hist.at(125)
    assert mid is not None
    assert mid.position_map_m == pytest.approx([1.0, 0.0, 10.0])
    assert angle_deg(mid.rotation_map_optical, rotation_about([0, 0, 1], 0.1)) < 1e-9
    exact = hist.at(200)
    assert exact is not None
    assert exact.position_map_m == pytest.approx([4.0, 0.0, 10.0])
    assert hist.at(400) is None  # 400 ns gap between neighbours
    assert hist.at(90) is not None  # 10 ns before the first: within extrapolation
    assert hist.at(50) is None
    assert hist.at(700) is None
    hist.add(650, CameraPose(np.full((3, 3), np.nan), np.zeros(3)))
    assert hist.at(630) is None  # a NaN neighbour


def test_pose_compose() -> None:
    body = CameraPose(rotation_about([0, 0, 1], math.pi / 2), np.array([1.0, 2.0, 30.0]))
    cam = body.compose(np.eye(3), [0.5, 0.0, -0.1])  # 0.5 m forward, 0.1 m below
    assert cam.position_map_m == pytest.approx([1.0, 2.5, 29.9])
