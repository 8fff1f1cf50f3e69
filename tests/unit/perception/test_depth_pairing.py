from __future__ import annotations

import math

import numpy as np
import pytest
from synthetic_scene import nadir_rotation, rotation_about

from uav_perception.core.depth.config import DepthPriorConfig, PairingConfig
from uav_perception.core.depth.pairing import (
    PairVerdict,
    check_pair,
    initial_depth_prior_m,
    pair_geometry,
    select_partner,
)
from uav_perception.core.depth.types import CameraPose, ColorFrame

IMG = np.zeros((4, 4, 3), np.uint8)
CFG = PairingConfig()  # ratio 0.05..0.3 (target 0.15), baseline 0.5..40 m, rotation <= 15 deg, axial <= 25 deg
HEADING = 0.4
FWD = np.array([math.cos(HEADING), math.sin(HEADING), 0.0])


def frame(t_s: float, pos: list[float], rot: np.ndarray | None = None) -> ColorFrame:
    r = nadir_rotation(HEADING) if rot is None else rot
    return ColorFrame(round(t_s * 1e9), IMG, CameraPose(r, np.asarray(pos, dtype=float)))


REF = frame(10.0, [0.0, 0.0, 50.0])


def test_geometry_of_a_sideways_pair() -> None:
    cand = frame(9.0, list(np.array([0.0, 0.0, 50.0]) - 6.0 * FWD))
    g = pair_geometry(REF, cand, 50.0)
    assert g.baseline_m == pytest.approx(6.0)
    assert g.baseline_ratio == pytest.approx(0.12)
    assert g.rotation_deg == pytest.approx(0.0, abs=1e-6)
    assert g.axial_angle_deg == pytest.approx(0.0, abs=1e-6)
    assert g.age_s == pytest.approx(1.0)
    assert check_pair(REF, cand, 50.0, CFG)[0] is PairVerdict.OK


@pytest.mark.parametrize(
    ("cand", "verdict"),
    [
        (frame(9.9, [0.0, 0.2, 50.0]), PairVerdict.BASELINE_TOO_SHORT),  # hovering
        (frame(9.0, [45.0, 0.0, 50.0]), PairVerdict.BASELINE_TOO_LONG),
        (frame(9.0, [0.0, 0.0, 42.0]), PairVerdict.AXIAL_MOTION),  # climbing: along a nadir optical axis
        (frame(9.0, [4.0, 0.0, 47.0]), PairVerdict.AXIAL_MOTION),  # 37 deg out of the image plane
        (frame(9.0, [2.0, 0.0, 50.0]), PairVerdict.RATIO_TOO_SMALL),  # 0.04 of 50 m
        (frame(9.0, [18.0, 0.0, 50.0]), PairVerdict.RATIO_TOO_LARGE),  # 0.36 of 50 m
        (frame(9.0, [6.0, 0.0, 50.0], rotation_about([1, 0, 0], math.radians(20)) @ nadir_rotation(HEADING)),
         PairVerdict.ROTATION_TOO_LARGE),
        (frame(2.0, [6.0, 0.0, 50.0]), PairVerdict.TOO_OLD),
        (frame(10.0, [6.0, 0.0, 50.0]), PairVerdict.NOT_OLDER),
        (frame(11.0, [6.0, 0.0, 50.0]), PairVerdict.NOT_OLDER),
        (frame(9.0, [np.nan, 0.0, 50.0]), PairVerdict.INVALID_POSE),
    ],
)  # fmt: skip
def test_gate_rejects_bad_pairs(cand: ColorFrame, verdict: PairVerdict) -> None:
    assert check_pair(REF, cand, 50.0, CFG)[0] is verdict


def test_an_invalid_reference_pose_rejects_everything() -> None:
    bad_ref = frame(10.0, [0.0, 0.0, 50.0], np.full((3, 3), np.nan))
    assert check_pair(bad_ref, frame(9.0, [6.0, 0.0, 50.0]), 50.0, CFG)[0] is PairVerdict.INVALID_POSE


def test_selection_prefers_the_target_ratio_and_counts_rejections() -> None:
    cands = [
        frame(9.9, [0.0, 0.1, 50.0]),  # too short
        frame(9.8, [0.0, 0.2, 50.0]),  # too short
        frame(9.5, [4.0, 0.0, 50.0]),  # ratio 0.08
        frame(9.0, [7.0, 0.0, 50.0]),  # ratio 0.14: closest to 0.15
        frame(8.0, [12.0, 0.0, 50.0]),  # ratio 0.24
        frame(7.0, [0.0, 0.0, 40.0]),  # axial
    ]
    sel = select_partner(REF, cands, 50.0, CFG)
    assert sel.verdict is PairVerdict.OK
    assert sel.partner is cands[3]
    assert sel.geometry is not None
    assert sel.geometry.baseline_m == pytest.approx(7.0)
    assert sel.rejections == {PairVerdict.BASELINE_TOO_SHORT: 2, PairVerdict.AXIAL_MOTION: 1}


def test_selection_without_partner_reports_the_most_common_reason() -> None:
    assert select_partner(REF, [], 50.0, CFG).verdict is PairVerdict.NO_HISTORY
    hover = [frame(10.0 - 0.1 * k, [0.0, 0.01 * k, 50.0]) for k in range(1, 6)] + [frame(9.0, [0.0, 0.0, 40.0])]
    sel = select_partner(REF, hover, 50.0, CFG)
    assert sel.partner is None
    assert sel.verdict is PairVerdict.BASELINE_TOO_SHORT
    assert sel.rejections == {PairVerdict.BASELINE_TOO_SHORT: 5, PairVerdict.AXIAL_MOTION: 1}


def test_the_depth_prior_scales_the_acceptable_baseline() -> None:
    cand = frame(9.0, [3.0, 0.0, 50.0])
    assert check_pair(REF, cand, 50.0, CFG)[0] is PairVerdict.OK  # ratio 0.06
    assert check_pair(REF, cand, 100.0, CFG)[0] is PairVerdict.RATIO_TOO_SMALL  # ratio 0.03


def test_initial_depth_prior() -> None:
    cfg = DepthPriorConfig(initial_depth_m=42.0)
    nadir = CameraPose(nadir_rotation(0.0), np.array([5.0, 5.0, 30.0]))
    assert initial_depth_prior_m(nadir, cfg) == pytest.approx(30.0)
    tilted = CameraPose(rotation_about([1, 0, 0], math.radians(30)) @ nadir_rotation(0.0), np.array([0, 0, 30.0]))
    assert initial_depth_prior_m(tilted, cfg) == pytest.approx(30.0 / math.cos(math.radians(30)))
    forward = CameraPose(np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]]), np.array([0, 0, 30.0]))  # looking east
    assert initial_depth_prior_m(forward, cfg) == pytest.approx(42.0)
    on_ground = CameraPose(nadir_rotation(0.0), np.array([0, 0, 0.5]))
    assert initial_depth_prior_m(on_ground, cfg) == pytest.approx(42.0)
