"""Pairing gate: which earlier frame makes a good stereo partner for a new frame.

A motion-stereo pair is only as good as its geometry:

* the baseline must be long enough for depth resolution and short enough for the
  views to overlap and look alike, which is a *ratio* to the scene depth;
* the baseline must lie close to the image plane: motion along the optical axis
  puts the epipole inside the image, where disparity vanishes;
* the two views must not be rotated too far apart, or rectification stretches
  the images and the patches no longer look alike;
* both poses must be valid (finite, orthonormal).

Every candidate gets a :class:`PairVerdict`; the accepted candidate whose baseline
ratio is closest to the configured target wins (the most recent on ties).
"""

from __future__ import annotations

import enum
import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from uav_perception.core.depth.config import DepthPriorConfig, PairingConfig
from uav_perception.core.depth.types import CameraPose, ColorFrame, FloatArray

__all__ = [
    "PairGeometry",
    "PairVerdict",
    "PartnerSelection",
    "check_pair",
    "initial_depth_prior_m",
    "pair_geometry",
    "select_partner",
]


class PairVerdict(enum.Enum):
    """Outcome of the pairing gate for one candidate (or for a frame without any)."""

    OK = "ok"
    NO_HISTORY = "no_history"
    INVALID_POSE = "invalid_pose"
    NOT_OLDER = "not_older"
    TOO_OLD = "too_old"
    ROTATION_TOO_LARGE = "rotation_too_large"
    AXIAL_MOTION = "axial_motion"
    BASELINE_TOO_SHORT = "baseline_too_short"
    BASELINE_TOO_LONG = "baseline_too_long"
    RATIO_TOO_SMALL = "ratio_too_small"
    RATIO_TOO_LARGE = "ratio_too_large"


@dataclass(frozen=True)
class PairGeometry:
    """Geometry of a candidate pair.

    Attributes:
        baseline_m: distance between the optical centres.
        baseline_ratio: ``baseline_m / depth_prior_m``.
        rotation_deg: angle of the relative rotation between the two cameras.
        axial_angle_deg: largest angle between the baseline and either image plane.
        age_s: reference stamp minus candidate stamp.
    """

    baseline_m: float
    baseline_ratio: float
    rotation_deg: float
    axial_angle_deg: float
    age_s: float


@dataclass(frozen=True)
class PartnerSelection:
    """Result of :func:`select_partner`.

    Attributes:
        partner: the chosen frame, or None.
        geometry: its pair geometry, or None.
        verdict: ``OK`` when a partner was chosen, else why the frame is skipped
            (the most common rejection, or ``NO_HISTORY``).
        rejections: how many candidates were rejected, per verdict.
    """

    partner: ColorFrame | None
    geometry: PairGeometry | None
    verdict: PairVerdict
    rejections: dict[PairVerdict, int]


def _rotation_angle_deg(rot: FloatArray) -> float:
    cos = (float(np.trace(rot)) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def pair_geometry(ref: ColorFrame, cand: ColorFrame, depth_prior_m: float) -> PairGeometry:
    """Geometry of the pair (``ref``, ``cand``); poses must be valid."""
    base = cand.pose.position_map_m - ref.pose.position_map_m
    baseline_m = float(np.linalg.norm(base))
    if baseline_m > 0:
        unit = base / baseline_m
        sin_ref = abs(float(unit @ ref.pose.optical_axis_map))
        sin_cand = abs(float(unit @ cand.pose.optical_axis_map))
        axial_deg = math.degrees(math.asin(min(1.0, max(sin_ref, sin_cand))))
    else:
        axial_deg = 90.0
    rel = ref.pose.rotation_map_optical.T @ cand.pose.rotation_map_optical
    return PairGeometry(
        baseline_m=baseline_m,
        baseline_ratio=baseline_m / depth_prior_m,
        rotation_deg=_rotation_angle_deg(rel),
        axial_angle_deg=axial_deg,
        age_s=(ref.stamp_ns - cand.stamp_ns) * 1e-9,
    )


def check_pair(
    ref: ColorFrame, cand: ColorFrame, depth_prior_m: float, config: PairingConfig
) -> tuple[PairVerdict, PairGeometry | None]:
    """Run the gate on one candidate; returns the verdict and (valid poses only) the geometry."""
    if not (ref.pose.is_valid and cand.pose.is_valid):
        return PairVerdict.INVALID_POSE, None
    geom = pair_geometry(ref, cand, depth_prior_m)
    verdict = PairVerdict.OK
    if geom.age_s <= 0:
        verdict = PairVerdict.NOT_OLDER
    elif geom.age_s > config.max_age_s:
        verdict = PairVerdict.TOO_OLD
    elif geom.baseline_m < config.min_baseline_m:
        verdict = PairVerdict.BASELINE_TOO_SHORT
    elif geom.baseline_m > config.max_baseline_m:
        verdict = PairVerdict.BASELINE_TOO_LONG
    elif geom.rotation_deg > config.max_rotation_deg:
        verdict = PairVerdict.ROTATION_TOO_LARGE
    elif geom.axial_angle_deg > config.max_axial_angle_deg:
        verdict = PairVerdict.AXIAL_MOTION
    elif geom.baseline_ratio < config.min_baseline_ratio:
        verdict = PairVerdict.RATIO_TOO_SMALL
    elif geom.baseline_ratio > config.max_baseline_ratio:
        verdict = PairVerdict.RATIO_TOO_LARGE
    return verdict, geom


def select_partner(
    ref: ColorFrame, candidates: Sequence[ColorFrame], depth_prior_m: float, config: PairingConfig
) -> PartnerSelection:
    """Choose the best partner for ``ref`` among ``candidates`` (any order).

    Args:
        ref: the new (reference) frame.
        candidates: earlier frames.
        depth_prior_m: expected scene depth, > 0.
        config: gate tolerances.
    """
    rejections: Counter[PairVerdict] = Counter()
    best: tuple[float, int, ColorFrame, PairGeometry] | None = None
    for cand in candidates:
        verdict, geom = check_pair(ref, cand, depth_prior_m, config)
        if verdict is not PairVerdict.OK or geom is None:
            rejections[verdict] += 1
            continue
        key = (abs(geom.baseline_ratio - config.target_baseline_ratio), -cand.stamp_ns)
        if best is None or key < best[:2]:
            best = (key[0], key[1], cand, geom)
    if best is not None:
        return PartnerSelection(best[2], best[3], PairVerdict.OK, dict(rejections))
    if not rejections:
        return PartnerSelection(None, None, PairVerdict.NO_HISTORY, {})
    order = list(PairVerdict)
    reason = max(rejections, key=lambda v: (rejections[v], -order.index(v)))
    return PartnerSelection(None, None, reason, dict(rejections))


def initial_depth_prior_m(pose: CameraPose, config: DepthPriorConfig) -> float:
    """Scene depth to expect before any estimate exists.

    For a camera looking down by more than ``min_down_angle_deg`` with its centre
    above ``map`` z = 0 (the home ground level), the depth along the optical axis
    to that level; otherwise ``initial_depth_m``.
    """
    if not pose.is_valid:
        return config.initial_depth_m
    down = -float(pose.optical_axis_map[2])
    height_m = float(pose.position_map_m[2])
    if down > math.sin(math.radians(config.min_down_angle_deg)) and height_m > 1.0:
        return height_m / down
    return config.initial_depth_m
