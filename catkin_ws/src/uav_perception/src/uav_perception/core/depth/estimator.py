"""Motion-stereo depth estimation: pairing, rectification, matching, filtering, triangulation.

:class:`MotionStereoEstimator` keeps a short history of posed color frames. For
each new frame it asks the pairing gate for a partner, optionally refines the
relative pose from image features, rectifies the pair, matches it with SGBM,
filters the disparities and returns a z-depth image in the new frame's own
(unrectified) camera. It is pure: no clocks, no ROS; frames come in, estimates
or counted skips come out.
"""

from __future__ import annotations

import enum
import math
from collections import Counter, deque
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

from uav_perception.core.depth.config import EstimatorConfig
from uav_perception.core.depth.matching import DisparitySearch, disparity_search, match_rectified
from uav_perception.core.depth.motion import estimate_jitter_m, fit_trajectory
from uav_perception.core.depth.pairing import PairGeometry, PairVerdict, initial_depth_prior_m, select_partner
from uav_perception.core.depth.rectify import coverage_mask, rectify_pair, warp_to_rectified
from uav_perception.core.depth.refine import RefineOutcome, refine_relative_pose
from uav_perception.core.depth.triangulate import ColoredPoints, points_from_depth, reference_depth
from uav_perception.core.depth.types import CameraPose, ColorFrame, FloatImage, PinholeCamera, check_rgb_image
from uav_perception.errors import DepthGeometryError

__all__ = ["DepthEstimate", "EstimatorStats", "MotionStereoEstimator", "SkipReason", "SkippedFrame"]

_MIN_PRIOR_PIXELS = 500


class SkipReason(enum.Enum):
    """Why a frame produced no depth image."""

    NO_HISTORY = "no_history"
    INVALID_POSE = "invalid_pose"
    NO_PARTNER = "no_partner"
    DEGENERATE_GEOMETRY = "degenerate_geometry"
    NO_DEPTH = "no_depth"
    BUSY = "busy"


@dataclass(frozen=True)
class SkippedFrame:
    """A frame that was not turned into depth.

    Attributes:
        stamp_ns: the frame's stamp.
        reason: the skip reason.
        pairing: for ``NO_PARTNER``, the gate's verdict (most common candidate rejection).
        detail: a human-readable explanation.
    """

    stamp_ns: int
    reason: SkipReason
    pairing: PairVerdict | None = None
    detail: str = ""


@dataclass(frozen=True, eq=False)
class DepthEstimate:
    """A depth image for a reference frame.

    Attributes:
        stamp_ns: the reference frame's stamp (the depth is valid at this time).
        partner_stamp_ns: the partner frame's stamp.
        depth_m: ``(H, W)`` float32 z-depth in the reference camera, NaN = no estimate.
        geometry: the pair geometry from the poses.
        search: the disparity window searched.
        refine: the pose refinement outcome (None when disabled).
        coverage: fraction of pixels with a depth.
        depth_prior_m: the prior used to size the search.
        pose_smoothed: the relative translation came from the trajectory fit.
        pose_jitter_m: the estimated position jitter of the poses (NaN: unknown or smoothing off).
    """

    stamp_ns: int
    partner_stamp_ns: int
    depth_m: FloatImage
    geometry: PairGeometry
    search: DisparitySearch
    refine: RefineOutcome | None
    coverage: float
    depth_prior_m: float
    pose_smoothed: bool = False
    pose_jitter_m: float = float("nan")


@dataclass
class EstimatorStats:
    """Running counters (the node publishes them).

    Attributes:
        frames_in: frames offered (processed or remembered).
        estimates: depth images produced.
        skipped: frames skipped, per reason.
        pair_rejections: candidate pairs rejected by the gate, per verdict.
    """

    frames_in: int = 0
    estimates: int = 0
    skipped: Counter[SkipReason] = field(default_factory=Counter)
    pair_rejections: Counter[PairVerdict] = field(default_factory=Counter)


class MotionStereoEstimator:
    """Depth from a moving monocular camera with known (possibly noisy) poses."""

    def __init__(self, camera: PinholeCamera, config: EstimatorConfig) -> None:
        self.camera = camera
        self.config = config
        self.stats = EstimatorStats()
        self._history: deque[ColorFrame] = deque(maxlen=config.pairing.history_size)
        self._gray: dict[int, npt.NDArray[np.uint8]] = {}
        self._depth_prior_m: float | None = None

    @property
    def history(self) -> tuple[ColorFrame, ...]:
        """Frames available as partners, oldest first."""
        return tuple(self._history)

    def depth_prior_m(self, pose: CameraPose) -> float:
        """The expected scene depth for a frame at ``pose``."""
        if self._depth_prior_m is not None:
            return self._depth_prior_m
        return initial_depth_prior_m(pose, self.config.depth_prior)

    def remember(self, frame: ColorFrame) -> SkippedFrame:
        """Add ``frame`` to the history without estimating depth for it (counted as ``BUSY``).

        Raises:
            DepthInputError: the image does not match the camera.
        """
        check_rgb_image(frame.rgb, self.camera)
        self.stats.frames_in += 1
        if not frame.pose.is_valid:
            return self._skip(frame, SkipReason.INVALID_POSE, detail="pose is not finite and orthonormal")
        self._push(frame)
        return self._skip(frame, SkipReason.BUSY, detail="a newer frame arrived before this one was processed")

    def process(self, frame: ColorFrame) -> DepthEstimate | SkippedFrame:
        """Estimate depth for ``frame`` against the history, then add it to the history.

        Raises:
            DepthInputError: the image does not match the camera.
        """
        check_rgb_image(frame.rgb, self.camera)
        self.stats.frames_in += 1
        if not frame.pose.is_valid:
            return self._skip(frame, SkipReason.INVALID_POSE, detail="pose is not finite and orthonormal")
        prior = self.depth_prior_m(frame.pose)
        self._prune(frame.stamp_ns)
        selection = select_partner(frame, self._history, prior, self.config.pairing)
        self.stats.pair_rejections.update(selection.rejections)
        self._push(frame)
        if selection.partner is None or selection.geometry is None:
            reason = SkipReason.NO_HISTORY if selection.verdict is PairVerdict.NO_HISTORY else SkipReason.NO_PARTNER
            return self._skip(frame, reason, pairing=selection.verdict, detail=f"pairing: {selection.verdict.value}")
        partner = selection.partner
        refine: RefineOutcome | None = None
        partner_pose, smoothed, jitter = self._smoothed_partner_pose(frame, partner)
        if self.config.pose_refine.enabled:
            refine = refine_relative_pose(
                self._gray_of(frame),
                self._gray_of(partner),
                camera=self.camera,
                ref_pose=frame.pose,
                partner_pose=partner_pose,
                config=self.config.pose_refine,
                depth_prior_m=prior,
            )
            partner_pose = refine.pose
        try:
            depth, search = self._depth_for_pair(frame, partner, partner_pose, prior)
        except DepthGeometryError as err:
            return self._skip(frame, SkipReason.DEGENERATE_GEOMETRY, detail=str(err))
        valid = np.isfinite(depth)
        n_valid = int(valid.sum())
        if n_valid == 0:
            return self._skip(frame, SkipReason.NO_DEPTH, detail="no pixel survived matching and filtering")
        if n_valid >= _MIN_PRIOR_PIXELS:
            self._depth_prior_m = float(np.median(depth[valid]))
        self.stats.estimates += 1
        return DepthEstimate(
            stamp_ns=frame.stamp_ns,
            partner_stamp_ns=partner.stamp_ns,
            depth_m=depth,
            geometry=selection.geometry,
            search=search,
            refine=refine,
            coverage=n_valid / depth.size,
            depth_prior_m=prior,
            pose_smoothed=smoothed,
            pose_jitter_m=jitter,
        )

    def cloud(self, estimate: DepthEstimate, frame: ColorFrame) -> ColoredPoints:
        """The colored cloud of an estimate, in the reference optical frame."""
        return points_from_depth(estimate.depth_m, frame.rgb, self.camera, self.config.cloud_stride_px)

    def _smoothed_partner_pose(self, frame: ColorFrame, partner: ColorFrame) -> tuple[CameraPose, bool, float]:
        """The partner pose, its translation from the trajectory fit when the poses jitter; and the jitter."""
        cfg = self.config.pose_smoothing
        if not cfg.enabled:
            return partner.pose, False, math.nan
        window_ns = int(max(cfg.window_s, cfg.jitter_window_s) * 1e9)
        recent = [f for f in self._history if 0 <= frame.stamp_ns - f.stamp_ns <= window_ns]
        times = np.array([(f.stamp_ns - frame.stamp_ns) * 1e-9 for f in recent])
        positions = np.array([f.pose.position_map_m for f in recent]).reshape(-1, 3)
        jitter = estimate_jitter_m(times, positions, cfg.jitter_window_s)
        if jitter is None or jitter < cfg.min_jitter_m:
            return partner.pose, False, math.nan if jitter is None else jitter
        in_window = times >= -cfg.window_s
        fit = fit_trajectory(times[in_window], positions[in_window], cfg.degree)
        if partner not in recent or fit is None or fit.residual_rms_m > cfg.max_residual_m:
            return partner.pose, False, jitter
        rel = fit.at((partner.stamp_ns - frame.stamp_ns) * 1e-9) - fit.at(0.0)
        return CameraPose(partner.pose.rotation_map_optical, frame.pose.position_map_m + rel), True, jitter

    def _depth_for_pair(
        self, frame: ColorFrame, partner: ColorFrame, partner_pose: CameraPose, prior_m: float
    ) -> tuple[FloatImage, DisparitySearch]:
        cfg = self.config
        rect0 = rectify_pair(self.camera, frame.pose, partner_pose, cfg.rectification)
        search = disparity_search(
            focal_px=rect0.camera.fx_px,
            baseline_m=rect0.baseline_m,
            depth_prior_m=prior_m,
            prior=cfg.depth_prior,
            matching=cfg.matching,
            min_depth_m=cfg.filtering.min_depth_m,
        )
        rect = rectify_pair(self.camera, frame.pose, partner_pose, cfg.rectification, right_shift_px=search.shift_px)
        left = warp_to_rectified(self._gray_of(frame), rect.homography_ref, rect.camera)
        right = warp_to_rectified(self._gray_of(partner), rect.homography_partner, rect.camera)
        margin = cfg.matching.block_size_px // 2 + 1
        left_valid = coverage_mask(self.camera, rect.homography_ref, rect.camera, margin)
        right_valid = coverage_mask(self.camera, rect.homography_partner, rect.camera, margin)
        disparity = match_rectified(
            left,
            right,
            left_valid=left_valid,
            right_valid=right_valid,
            search=search,
            matching=cfg.matching,
            filtering=cfg.filtering,
        )
        depth = reference_depth(
            disparity, self.camera, rect, min_depth_m=cfg.filtering.min_depth_m, max_depth_m=cfg.filtering.max_depth_m
        )
        return depth, search

    def _gray_of(self, frame: ColorFrame) -> npt.NDArray[np.uint8]:
        gray = self._gray.get(frame.stamp_ns)
        if gray is None:
            gray = np.asarray(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY), dtype=np.uint8)
            self._gray[frame.stamp_ns] = gray
        return gray

    def _push(self, frame: ColorFrame) -> None:
        if self._history and frame.stamp_ns <= self._history[-1].stamp_ns:
            # Out of order or repeated stamp (e.g. a replayed bag jumped back): start over.
            self._history.clear()
        self._history.append(frame)
        keep = {f.stamp_ns for f in self._history}
        for stamp in [s for s in self._gray if s not in keep]:
            del self._gray[stamp]

    def _prune(self, now_ns: int) -> None:
        max_age_ns = int(self.config.pairing.max_age_s * 1e9)
        while self._history and now_ns - self._history[0].stamp_ns > max_age_ns:
            self._history.popleft()

    def _skip(
        self, frame: ColorFrame, reason: SkipReason, *, pairing: PairVerdict | None = None, detail: str = ""
    ) -> SkippedFrame:
        self.stats.skipped[reason] += 1
        return SkippedFrame(frame.stamp_ns, reason, pairing, detail)
