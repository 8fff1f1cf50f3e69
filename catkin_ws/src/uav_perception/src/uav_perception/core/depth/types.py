"""Value types shared by the depth estimator and the depth evaluator.

Conventions:

* Camera frames are *optical* frames (REP 103 ``camera_<cam>_optical``): z along
  the optical axis, x to the image right, y to the image bottom.
* A :class:`CameraPose` holds ``rotation_map_optical`` (3x3, maps optical-frame
  vectors into ``map``) and the optical centre ``position_map_m`` in ``map`` (ENU).
* Images are numpy arrays indexed ``[row, col]`` = ``[v, u]``; pixel ``(u, v)``
  has its centre at integer coordinates (OpenCV convention).
* Depth is z-depth in metres along the optical axis, float32, NaN = no value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from uav_perception.errors import DepthGeometryError, DepthInputError

__all__ = [
    "BoolImage",
    "CameraPose",
    "ColorFrame",
    "FloatArray",
    "FloatImage",
    "PinholeCamera",
    "RgbImage",
    "check_rgb_image",
]

FloatArray = npt.NDArray[np.float64]
FloatImage = npt.NDArray[np.float32]
RgbImage = npt.NDArray[np.uint8]
BoolImage = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class PinholeCamera:
    """Intrinsics of an undistorted pinhole camera, in pixels.

    Attributes:
        width_px: image width (columns).
        height_px: image height (rows).
        fx_px, fy_px: focal lengths.
        cx_px, cy_px: principal point.
    """

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            msg = f"camera size must be positive, got {self.width_px}x{self.height_px}"
            raise DepthInputError(msg)
        values = (self.fx_px, self.fy_px, self.cx_px, self.cy_px)
        if not all(math.isfinite(v) for v in values) or self.fx_px <= 0 or self.fy_px <= 0:
            msg = f"camera intrinsics must be finite with positive focal lengths, got {values}"
            raise DepthInputError(msg)

    @classmethod
    def from_matrix(cls, k: npt.ArrayLike, width_px: int, height_px: int) -> PinholeCamera:
        """Build from a 3x3 intrinsic matrix ``K`` (skew must be zero)."""
        mat = np.asarray(k, dtype=np.float64)
        if mat.shape != (3, 3):
            msg = f"intrinsic matrix must be 3x3, got shape {mat.shape}"
            raise DepthInputError(msg)
        if abs(mat[0, 1]) > 1e-9 or not np.allclose(mat[2], [0.0, 0.0, 1.0]):
            msg = f"intrinsic matrix must be [[fx,0,cx],[0,fy,cy],[0,0,1]], got {mat.tolist()}"
            raise DepthInputError(msg)
        return cls(width_px, height_px, float(mat[0, 0]), float(mat[1, 1]), float(mat[0, 2]), float(mat[1, 2]))

    @property
    def matrix(self) -> FloatArray:
        """The 3x3 intrinsic matrix ``K``."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])

    @property
    def shape(self) -> tuple[int, int]:
        """``(height_px, width_px)``, the numpy shape of a single-channel image."""
        return (self.height_px, self.width_px)

    def pixel_rays(self) -> FloatArray:
        """Rays ``K^-1 [u, v, 1]`` of every pixel, ``(H, W, 3)`` float64, z = 1."""
        u, v = np.meshgrid(np.arange(self.width_px, dtype=np.float64), np.arange(self.height_px, dtype=np.float64))
        return np.stack([(u - self.cx_px) / self.fx_px, (v - self.cy_px) / self.fy_px, np.ones_like(u)], axis=-1)


@dataclass(frozen=True, eq=False)
class CameraPose:
    """Pose of an optical camera frame in ``map``.

    Attributes:
        rotation_map_optical: ``(3, 3)`` rotation; ``v_map = R @ v_optical``.
        position_map_m: ``(3,)`` optical centre in ``map`` (ENU), metres.
    """

    rotation_map_optical: FloatArray
    position_map_m: FloatArray

    def __post_init__(self) -> None:
        rot = np.asarray(self.rotation_map_optical, dtype=np.float64)
        pos = np.asarray(self.position_map_m, dtype=np.float64)
        if rot.shape != (3, 3) or pos.shape != (3,):
            msg = f"pose needs a 3x3 rotation and a 3-vector, got shapes {rot.shape} and {pos.shape}"
            raise DepthGeometryError(msg)
        object.__setattr__(self, "rotation_map_optical", rot)
        object.__setattr__(self, "position_map_m", pos)

    @property
    def is_valid(self) -> bool:
        """True when finite and the rotation is orthonormal with determinant +1 (to 1e-3)."""
        rot = self.rotation_map_optical
        if not (np.all(np.isfinite(rot)) and np.all(np.isfinite(self.position_map_m))):
            return False
        return bool(np.allclose(rot.T @ rot, np.eye(3), atol=1e-3) and abs(np.linalg.det(rot) - 1.0) < 1e-3)

    @property
    def optical_axis_map(self) -> FloatArray:
        """Unit optical axis (optical z) expressed in ``map``."""
        return np.asarray(self.rotation_map_optical[:, 2], dtype=np.float64)

    def compose(self, rotation_self_child: npt.ArrayLike, translation_self_child_m: npt.ArrayLike) -> CameraPose:
        """Pose of a child frame given its fixed transform from this frame (``x_self = R x_child + t``)."""
        rot = np.asarray(rotation_self_child, dtype=np.float64)
        trans = np.asarray(translation_self_child_m, dtype=np.float64)
        return CameraPose(self.rotation_map_optical @ rot, self.position_map_m + self.rotation_map_optical @ trans)

    def relative_to(self, other: CameraPose) -> tuple[FloatArray, FloatArray]:
        """``(R, t)`` mapping points from this camera's frame into ``other``'s: ``x_o = R x + t``."""
        r_other_t = other.rotation_map_optical.T
        rot = r_other_t @ self.rotation_map_optical
        trans = r_other_t @ (self.position_map_m - other.position_map_m)
        return rot, trans


@dataclass(frozen=True, eq=False)
class ColorFrame:
    """One color image with its stamp and the camera pose at that stamp.

    Attributes:
        stamp_ns: image stamp (simulation time), nanoseconds.
        rgb: ``(H, W, 3)`` uint8 RGB image.
        pose: camera pose at ``stamp_ns``.
    """

    stamp_ns: int
    rgb: RgbImage
    pose: CameraPose

    @property
    def stamp_s(self) -> float:
        """The stamp in seconds."""
        return self.stamp_ns * 1e-9


def check_rgb_image(rgb: npt.NDArray[np.generic], camera: PinholeCamera, what: str = "image") -> RgbImage:
    """Return ``rgb`` as a uint8 ``(H, W, 3)`` array matching ``camera``.

    Raises:
        DepthInputError: wrong dtype, channel count or size.
    """
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        msg = f"{what} must be (H, W, 3) uint8 RGB, got {rgb.dtype} of shape {rgb.shape}"
        raise DepthInputError(msg)
    if rgb.shape[:2] != camera.shape:
        msg = (
            f"{what} is {rgb.shape[1]}x{rgb.shape[0]} but the camera is {camera.width_px}x{camera.height_px}; "
            "camera_info and image must describe the same stream"
        )
        raise DepthInputError(msg)
    return np.asarray(rgb, dtype=np.uint8)
