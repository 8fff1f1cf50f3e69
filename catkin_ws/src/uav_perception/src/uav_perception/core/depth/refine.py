"""Refinement of a noisy relative pose from the images themselves.

SGBM needs rows aligned to a fraction of a pixel, and a 0.1 deg rotation error
is already half a pixel at 320 px focal length. Poses from a degraded odometry
are worse than that, so before rectifying:

1. Shi-Tomasi corners of the reference are tracked with pyramidal Lucas-Kanade
   into the partner image turned to the reference's orientation (by the prior
   rotation, so the patches are not rotated), seeded by the prior pose and the
   depth prior, and kept only if tracking back lands within 0.5 px.
2. The relative rotation (3 DoF) and the baseline *direction* (2 DoF) are
   refined by iteratively reweighted Gauss-Newton on the Sampson epipolar error
   (Cauchy weights), starting at the prior. The baseline *length* cannot be seen
   in the images and stays as the poses give it.

The epipolar constraint cannot see a rotation that slides points *along* the
epipolar lines (about the rectified y axis, to first order): that component
stays as uncertain as the prior, and shows up as a depth bias. A weak prior term
keeps it from drifting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt

from uav_perception.core.depth.config import PoseRefineConfig
from uav_perception.core.depth.types import CameraPose, FloatArray, PinholeCamera

__all__ = ["RefineOutcome", "pose_from_relative", "refine_relative_pose", "sampson_px", "skew"]

_FB_MAX_PX = 0.5
_PRIOR_SIGMA_RAD = 0.02
_MIN_SCALE_PX = 0.02
FloatArray32 = npt.NDArray[np.float32]


@dataclass(frozen=True, eq=False)
class RefineOutcome:
    """Result of :func:`refine_relative_pose`.

    Attributes:
        pose: the partner pose to use (refined when ``applied``, else the prior).
        applied: whether the refinement was used.
        tracks: correspondences that passed the forward-backward check.
        inliers: correspondences within ``inlier_threshold_px`` after refinement.
        rms_before_px: RMS Sampson error of the inliers under the prior pose.
        rms_after_px: ... under the refined pose.
        correction_deg: angle of the rotation correction.
        detail: why it was not applied, if so.
    """

    pose: CameraPose
    applied: bool
    tracks: int
    inliers: int
    rms_before_px: float
    rms_after_px: float
    correction_deg: float
    detail: str = ""


def skew(v: FloatArray) -> FloatArray:
    """Cross-product matrix ``[v]x``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _exp_so3(w: FloatArray) -> FloatArray:
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.asarray(np.eye(3) + skew(w), dtype=np.float64)
    k = skew(w / angle)
    return np.asarray(np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k), dtype=np.float64)


def sampson_px(rot: FloatArray, trans: FloatArray, x1: FloatArray, x2: FloatArray, focal_px: float) -> FloatArray:
    """Sampson distances (pixels) of normalised correspondences ``(N, 3)`` under ``x2 = R x1 + t``."""
    ess = skew(trans / np.linalg.norm(trans)) @ rot
    ex1 = x1 @ ess.T
    etx2 = x2 @ ess
    num = np.einsum("ij,ij->i", x2, ex1)
    den = ex1[:, 0] ** 2 + ex1[:, 1] ** 2 + etx2[:, 0] ** 2 + etx2[:, 1] ** 2
    return np.asarray(focal_px * num / np.sqrt(np.maximum(den, 1e-18)), dtype=np.float64)


def pose_from_relative(ref: CameraPose, rot: FloatArray, trans: FloatArray) -> CameraPose:
    """The partner pose for which ``x_partner = rot @ x_ref + trans``."""
    r_map_partner = ref.rotation_map_optical @ rot.T
    return CameraPose(r_map_partner, ref.position_map_m - r_map_partner @ trans)


def _lk(
    img0: npt.NDArray[np.uint8], img1: npt.NDArray[np.uint8], pts0: FloatArray32, guess: FloatArray32
) -> tuple[FloatArray32, npt.NDArray[np.uint8]]:
    """Pyramidal Lucas-Kanade from ``img0`` to ``img1`` starting at ``guess``: points and status."""
    pts1, status, _ = cv2.calcOpticalFlowPyrLK(
        img0,
        img1,
        pts0,
        guess,
        winSize=(21, 21),
        maxLevel=4,
        criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01),
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    return np.asarray(pts1, dtype=np.float32), np.asarray(status, dtype=np.uint8)


def _apply_h(h: FloatArray, pts: FloatArray) -> FloatArray:
    """Apply a homography to ``(N, 2)`` points."""
    p = np.hstack([pts, np.ones((len(pts), 1))]) @ h.T
    return np.asarray(p[:, :2] / p[:, 2:], dtype=np.float64)


def _track(
    gray_ref: npt.NDArray[np.uint8],
    gray_partner: npt.NDArray[np.uint8],
    *,
    camera: PinholeCamera,
    rot: FloatArray,
    trans: FloatArray,
    depth_prior_m: float,
    config: PoseRefineConfig,
) -> tuple[FloatArray, FloatArray]:
    corners = cv2.goodFeaturesToTrack(gray_ref, config.max_corners, 0.01, 8, blockSize=7)
    if corners is None or len(corners) < config.min_inliers:
        return np.zeros((0, 2)), np.zeros((0, 2))
    p1 = corners.reshape(-1, 2).astype(np.float64)
    k = camera.matrix
    rays = np.linalg.solve(k, np.vstack([p1.T, np.ones(len(p1))]))
    guess_h = k @ (rot @ (rays * depth_prior_m) + trans[:, None])
    # Track against the partner turned into the reference's orientation (the infinite
    # homography K R K^-1 of the prior rotation): Lucas-Kanade models translation only,
    # and rotated patches would bias it; only the parallax is left to track.
    h_inf = k @ rot @ np.linalg.inv(k)
    derotated = np.asarray(
        cv2.warpPerspective(
            gray_partner, h_inf, (camera.width_px, camera.height_px), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        ),
        dtype=np.uint8,
    )
    guess = _apply_h(np.linalg.inv(h_inf), (guess_h[:2] / guess_h[2]).T)
    p1f = p1.astype(np.float32).reshape(-1, 1, 2)
    qf, st = _lk(gray_ref, derotated, p1f, np.ascontiguousarray(guess, dtype=np.float32).reshape(-1, 1, 2))
    p2 = _apply_h(h_inf, qf.reshape(-1, 2).astype(np.float64))
    # The consistency check tracks back from the original partner image.
    back, st_back = _lk(
        gray_partner, gray_ref, np.ascontiguousarray(p2, dtype=np.float32).reshape(-1, 1, 2), p1f.copy()
    )
    fb = np.linalg.norm(back.reshape(-1, 2) - p1, axis=1)
    ok = (st.ravel() == 1) & (st_back.ravel() == 1) & (fb < _FB_MAX_PX)
    h, w = camera.shape
    ok &= (p2[:, 0] >= 0) & (p2[:, 0] <= w - 1) & (p2[:, 1] >= 0) & (p2[:, 1] <= h - 1)
    return p1[ok], p2[ok]


def refine_relative_pose(
    gray_ref: npt.NDArray[np.uint8],
    gray_partner: npt.NDArray[np.uint8],
    *,
    camera: PinholeCamera,
    ref_pose: CameraPose,
    partner_pose: CameraPose,
    config: PoseRefineConfig,
    depth_prior_m: float = 50.0,
) -> RefineOutcome:
    """Refine the partner pose relative to the reference (see the module docstring).

    Returns the prior pose with ``applied=False`` when there are too few tracks or
    inliers, or when the correction exceeds ``max_correction_deg``.
    """
    rot0, trans0 = ref_pose.relative_to(partner_pose)
    base_len = float(np.linalg.norm(trans0))
    p1, p2 = _track(
        gray_ref, gray_partner, camera=camera, rot=rot0, trans=trans0, depth_prior_m=depth_prior_m, config=config
    )

    def fail(detail: str, tracks: int) -> RefineOutcome:
        return RefineOutcome(partner_pose, False, tracks, 0, math.nan, math.nan, 0.0, detail)

    if len(p1) < config.min_inliers or base_len <= 0:
        return fail(f"only {len(p1)} tracked corners (need {config.min_inliers})", len(p1))
    k_inv = np.linalg.inv(camera.matrix)
    x1 = np.hstack([p1, np.ones((len(p1), 1))]) @ k_inv.T
    x2 = np.hstack([p2, np.ones((len(p2), 1))]) @ k_inv.T
    focal = math.sqrt(camera.fx_px * camera.fy_px)
    t_dir0 = trans0 / base_len
    # Orthonormal tangent basis of the unit sphere at t_dir0.
    helper = np.array([1.0, 0.0, 0.0]) if abs(t_dir0[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u_axis = np.cross(t_dir0, helper)
    u_axis /= np.linalg.norm(u_axis)
    v_axis = np.cross(t_dir0, u_axis)

    def model(p: FloatArray) -> tuple[FloatArray, FloatArray]:
        t_dir = t_dir0 + p[3] * u_axis + p[4] * v_axis
        return _exp_so3(p[:3]) @ rot0, t_dir / np.linalg.norm(t_dir)

    def residuals(p: FloatArray) -> FloatArray:
        rot, t_dir = model(p)
        return sampson_px(rot, t_dir, x1, x2, focal)

    params = np.zeros(5)
    for _ in range(config.iterations):
        r = residuals(params)
        # Cauchy IRLS with a robust (MAD) scale: tracks on occlusion edges ("phantom"
        # corners) are consistent outliers that a fixed scale would let bias the result.
        scale = max(_MIN_SCALE_PX, 1.4826 * float(np.median(np.abs(r))))
        weights = 1.0 / (1.0 + (r / scale) ** 2)
        prior_w = (scale / _PRIOR_SIGMA_RAD) ** 2
        jac = np.empty((len(r), 5))
        for j in range(5):
            step = np.zeros(5)
            step[j] = 1e-6
            jac[:, j] = (residuals(params + step) - r) / 1e-6
        jw = jac * weights[:, None]
        lhs = jac.T @ jw + prior_w * np.eye(5)
        rhs = -(jw.T @ r) - prior_w * params
        delta = np.linalg.solve(lhs, rhs)
        params = params + delta
        if float(np.linalg.norm(delta)) < 1e-9:
            break
    r_before = np.abs(sampson_px(rot0, t_dir0, x1, x2, focal))
    r_after = np.abs(residuals(params))
    inliers = r_after < config.inlier_threshold_px
    n_in = int(inliers.sum())
    rot, t_dir = model(params)
    correction_deg = math.degrees(float(np.linalg.norm(params[:3])))
    if n_in < config.min_inliers:
        return fail(f"only {n_in} inliers after refinement (need {config.min_inliers})", len(p1))
    if correction_deg > config.max_correction_deg:
        return fail(f"correction {correction_deg:.2f} deg exceeds {config.max_correction_deg} deg", len(p1))
    return RefineOutcome(
        pose=pose_from_relative(ref_pose, rot, t_dir * base_len),
        applied=True,
        tracks=len(p1),
        inliers=n_in,
        rms_before_px=float(np.sqrt(np.mean(r_before[inliers] ** 2))),
        rms_after_px=float(np.sqrt(np.mean(r_after[inliers] ** 2))),
        correction_deg=correction_deg,
    )
