"""Configuration of the motion-stereo depth estimator and its evaluator.

Loaded once from ``config/depth.yaml`` with :func:`uav_common.config.load_config`
(unknown keys are errors). Units are in the field names; ratios and fractions are
unitless. Every default here is the documented default of ``config/depth.yaml``.
"""

from __future__ import annotations

import enum
import itertools
import math
from dataclasses import dataclass, field

__all__ = [
    "DepthConfig",
    "DepthPriorConfig",
    "EstimatorConfig",
    "EvaluatorConfig",
    "FilterConfig",
    "LrCheck",
    "MatchingConfig",
    "PairingConfig",
    "PoseRefineConfig",
    "PoseSmoothingConfig",
    "RectificationConfig",
    "SgbmMode",
]


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


class SgbmMode(enum.Enum):
    """OpenCV StereoSGBM modes (``cv2.STEREO_SGBM_MODE_*``)."""

    SGBM = "sgbm"
    HH = "hh"
    SGBM_3WAY = "sgbm_3way"
    HH4 = "hh4"


class LrCheck(enum.Enum):
    """Left-right consistency check.

    ``full`` matches right-to-left as well (a second SGBM pass on mirrored images);
    ``internal`` uses SGBM's own ``disp12MaxDiff`` check from the same cost volume;
    ``off`` disables it.
    """

    FULL = "full"
    INTERNAL = "internal"
    OFF = "off"


@dataclass(frozen=True)
class PairingConfig:
    """Tolerances of the pairing gate.

    The *baseline ratio* is baseline length over the expected scene depth; it sets
    the disparity of the scene (``f * ratio`` pixels) and therefore the depth
    resolution. The *axial angle* is the angle between the baseline and the
    reference image plane: 0 deg is sideways motion (ideal), 90 deg is motion
    along the optical axis (epipole in the image centre, no usable disparity).
    """

    history_size: int = 40
    max_age_s: float = 6.0
    min_baseline_m: float = 0.5
    max_baseline_m: float = 40.0
    min_baseline_ratio: float = 0.05
    max_baseline_ratio: float = 0.3
    target_baseline_ratio: float = 0.15
    max_rotation_deg: float = 15.0
    max_axial_angle_deg: float = 25.0

    def __post_init__(self) -> None:
        _require(self.history_size >= 1, f"history_size must be >= 1, got {self.history_size}")
        _require(self.max_age_s > 0, f"max_age_s must be > 0, got {self.max_age_s}")
        _require(
            0 < self.min_baseline_m <= self.max_baseline_m,
            f"need 0 < min_baseline_m <= max_baseline_m, got {self.min_baseline_m}, {self.max_baseline_m}",
        )
        _require(
            0 < self.min_baseline_ratio <= self.target_baseline_ratio <= self.max_baseline_ratio,
            "need 0 < min_baseline_ratio <= target_baseline_ratio <= max_baseline_ratio, got "
            f"{self.min_baseline_ratio}, {self.target_baseline_ratio}, {self.max_baseline_ratio}",
        )
        _require(0 < self.max_rotation_deg < 60, f"max_rotation_deg must be in (0, 60), got {self.max_rotation_deg}")
        _require(
            0 < self.max_axial_angle_deg < 60,
            f"max_axial_angle_deg must be in (0, 60), got {self.max_axial_angle_deg}",
        )


@dataclass(frozen=True)
class DepthPriorConfig:
    """Expected scene depth, which sizes the baseline and the disparity search window.

    Before the first estimate, the prior is the camera height above ``map`` z = 0
    divided by the cosine of the optical axis to the vertical (for a camera looking
    down more than ``min_down_angle_deg``), else ``initial_depth_m``. After that it
    is the median of the last estimate. The search window covers depths from
    ``near_factor * prior`` to ``far_factor * prior``: with 0.4, objects up to 60 % of
    the camera's height above the ground are measured (the default world's tallest,
    15.5 m trees, from 26 m up); the SGBM cost grows with the window.
    """

    initial_depth_m: float = 50.0
    min_down_angle_deg: float = 30.0
    near_factor: float = 0.4
    far_factor: float = 2.5

    def __post_init__(self) -> None:
        _require(self.initial_depth_m > 0, f"initial_depth_m must be > 0, got {self.initial_depth_m}")
        _require(
            0 < self.near_factor < 1 < self.far_factor,
            f"need 0 < near_factor < 1 < far_factor, got {self.near_factor}, {self.far_factor}",
        )
        _require(0 <= self.min_down_angle_deg <= 90, "min_down_angle_deg must be in [0, 90]")


@dataclass(frozen=True)
class RectificationConfig:
    """Rectified image grid.

    ``scale`` multiplies the focal length of the rectified cameras (0.5 matches at
    half resolution); ``max_area_ratio`` caps the rectified area relative to the
    scaled input image area (a rotated image needs a larger bounding box).
    """

    scale: float = 1.0
    max_area_ratio: float = 1.6

    def __post_init__(self) -> None:
        _require(0.1 <= self.scale <= 2.0, f"scale must be in [0.1, 2], got {self.scale}")
        _require(self.max_area_ratio >= 1.0, f"max_area_ratio must be >= 1, got {self.max_area_ratio}")


@dataclass(frozen=True)
class MatchingConfig:
    """OpenCV StereoSGBM parameters (P1/P2 follow OpenCV's ``k * channels * block_size^2`` rule)."""

    mode: SgbmMode = SgbmMode.SGBM_3WAY
    block_size_px: int = 5
    p1_factor: int = 8
    p2_factor: int = 32
    uniqueness_ratio_pct: int = 5
    pre_filter_cap: int = 31
    max_num_disparities: int = 256
    min_num_disparities: int = 32

    def __post_init__(self) -> None:
        _require(
            self.block_size_px % 2 == 1 and 1 <= self.block_size_px <= 15,
            f"block_size_px must be odd in [1, 15], got {self.block_size_px}",
        )
        _require(0 < self.p1_factor < self.p2_factor, "need 0 < p1_factor < p2_factor")
        _require(0 <= self.uniqueness_ratio_pct <= 50, "uniqueness_ratio_pct must be in [0, 50]")
        _require(1 <= self.pre_filter_cap <= 63, "pre_filter_cap must be in [1, 63]")
        _require(
            16 <= self.min_num_disparities <= self.max_num_disparities
            and self.min_num_disparities % 16 == 0
            and self.max_num_disparities % 16 == 0,
            "min/max_num_disparities must be multiples of 16 with 16 <= min <= max",
        )


@dataclass(frozen=True)
class FilterConfig:
    """Filters that remove unreliable disparities.

    Attributes:
        lr_check: left-right consistency mode.
        lr_max_diff_px: largest allowed left/right disparity disagreement.
        min_texture_std: minimum grey-level standard deviation in a
            ``texture_window_px`` window of the reference image (textureless
            pixels are dropped).
        speckle_window_px: connected regions of disparity smaller than this are removed (0 = off).
        speckle_range_px: disparity step that separates speckle regions.
        min_depth_m, max_depth_m: depths outside this range are dropped.
    """

    lr_check: LrCheck = LrCheck.INTERNAL
    lr_max_diff_px: float = 1.0
    min_texture_std: float = 2.0
    texture_window_px: int = 7
    speckle_window_px: int = 100
    speckle_range_px: float = 2.0
    min_depth_m: float = 0.5
    max_depth_m: float = 400.0

    def __post_init__(self) -> None:
        _require(self.lr_max_diff_px > 0, "lr_max_diff_px must be > 0")
        _require(self.min_texture_std >= 0, "min_texture_std must be >= 0")
        _require(self.texture_window_px % 2 == 1 and self.texture_window_px >= 3, "texture_window_px: odd and >= 3")
        _require(self.speckle_window_px >= 0 and self.speckle_range_px > 0, "speckle window >= 0, range > 0")
        _require(0 < self.min_depth_m < self.max_depth_m, "need 0 < min_depth_m < max_depth_m")


@dataclass(frozen=True)
class PoseRefineConfig:
    """Refinement of the relative rotation and baseline direction from image features.

    Poses from a degraded odometry are too noisy for rectification: 0.1 deg of
    rotation error is about 0.5 px of epipolar error at 640 px. When enabled,
    Shi-Tomasi corners tracked with pyramidal Lucas-Kanade refine the relative
    rotation and the baseline direction (5 degrees of freedom) by robust
    Gauss-Newton on the epipolar (Sampson) error, starting from the pose prior.
    The baseline *length* always comes from the poses.
    """

    enabled: bool = True
    max_corners: int = 600
    min_inliers: int = 40
    inlier_threshold_px: float = 1.0
    max_correction_deg: float = 5.0
    iterations: int = 8

    def __post_init__(self) -> None:
        _require(self.max_corners >= 20, "max_corners must be >= 20")
        _require(self.min_inliers >= 8, "min_inliers must be >= 8")
        _require(self.inlier_threshold_px > 0, "inlier_threshold_px must be > 0")
        _require(self.max_correction_deg > 0, "max_correction_deg must be > 0")
        _require(self.iterations >= 1, "iterations must be >= 1")


@dataclass(frozen=True)
class PoseSmoothingConfig:
    """Least-squares polynomial fit of the recent camera positions (see ``depth_motion``).

    When the positions jitter by more than ``min_jitter_m`` (estimated over the last
    ``jitter_window_s``), the relative translation of a pair is taken from the fit of
    the frames of the last ``window_s`` seconds, unless the fit residual exceeds
    ``max_residual_m``. Exact poses are used as they are.
    """

    enabled: bool = True
    window_s: float = 3.0
    degree: int = 3
    max_residual_m: float = 0.3
    min_jitter_m: float = 0.01
    jitter_window_s: float = 1.0

    def __post_init__(self) -> None:
        _require(self.window_s > 0, "window_s must be > 0")
        _require(1 <= self.degree <= 3, "degree must be in [1, 3]")
        _require(self.max_residual_m > 0, "max_residual_m must be > 0")
        _require(self.min_jitter_m >= 0, "min_jitter_m must be >= 0")
        _require(self.jitter_window_s > 0, "jitter_window_s must be > 0")


@dataclass(frozen=True)
class EstimatorConfig:
    """Everything the depth estimator core needs."""

    pairing: PairingConfig = field(default_factory=PairingConfig)
    depth_prior: DepthPriorConfig = field(default_factory=DepthPriorConfig)
    rectification: RectificationConfig = field(default_factory=RectificationConfig)
    matching: MatchingConfig = field(default_factory=MatchingConfig)
    filtering: FilterConfig = field(default_factory=FilterConfig)
    pose_refine: PoseRefineConfig = field(default_factory=PoseRefineConfig)
    pose_smoothing: PoseSmoothingConfig = field(default_factory=PoseSmoothingConfig)
    cloud_stride_px: int = 1

    def __post_init__(self) -> None:
        _require(1 <= self.cloud_stride_px <= 16, f"cloud_stride_px must be in [1, 16], got {self.cloud_stride_px}")


@dataclass(frozen=True)
class EvaluatorConfig:
    """Per-frame depth accuracy metrics.

    Attributes:
        abs_tol_m: a covered pixel is *within tolerance* if ``|est - gt| < abs_tol_m``.
        rel_tol: ... and *within relative tolerance* if ``|est - gt| / gt < rel_tol``.
        range_bands_m: ascending edges of the ground-truth depth bands
            (``[0, 25, 50]`` gives bands [0, 25) and [25, 50)); the last edge may be ``.inf``.
        min_gt_depth_m, max_gt_depth_m: ground truth outside this range is not evaluated.
        classes: class names reported per class, in order.
        max_stamp_diff_s: largest stamp difference between estimate and ground truth.
    """

    abs_tol_m: float = 1.0
    rel_tol: float = 0.05
    range_bands_m: tuple[float, ...] = (0.0, 20.0, 40.0, 60.0, 80.0, 120.0, math.inf)
    min_gt_depth_m: float = 0.1
    max_gt_depth_m: float = 1000.0
    classes: tuple[str, ...] = ("terrain", "road", "building", "tree", "person", "vehicle")
    max_stamp_diff_s: float = 0.001

    def __post_init__(self) -> None:
        _require(self.abs_tol_m > 0 and self.rel_tol > 0, "abs_tol_m and rel_tol must be > 0")
        bands = self.range_bands_m
        _require(
            len(bands) >= 2 and all(a < b for a, b in itertools.pairwise(bands)) and bands[0] >= 0,
            f"range_bands_m must be >= 2 ascending non-negative edges, got {bands}",
        )
        _require(0 <= self.min_gt_depth_m < self.max_gt_depth_m, "need 0 <= min_gt_depth_m < max_gt_depth_m")
        _require(len(set(self.classes)) == len(self.classes), f"classes must be unique, got {self.classes}")
        _require(self.max_stamp_diff_s >= 0, "max_stamp_diff_s must be >= 0")


@dataclass(frozen=True)
class DepthConfig:
    """The whole of ``config/depth.yaml``."""

    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    evaluator: EvaluatorConfig = field(default_factory=EvaluatorConfig)
