"""Pinhole camera model, its YAML configuration and depth back-projection (pure numpy).

Conventions (OpenCV / ROS ``sensor_msgs/CameraInfo``):

* pixel ``(u, v)``: ``u`` column to the right, ``v`` row downwards, the *centre* of
  pixel ``[row, col]`` is at ``(u, v) = (col, row)``;
* optical frame ``camera_<name>_optical``: x right, y down, z forward, metres;
* mount frame ``camera_<name>``: FLU (x along the optical axis, y left, z up), fixed
  on ``base_link`` by the configured mount pose (REP 103: positive pitch tilts the
  camera's x axis *down*, so a nadir camera has ``rpy_deg: [0, 90, 0]``);
* depth images hold *z-depth* (distance along the optical axis) in metres, NaN for
  no return.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import numpy.typing as npt

from uav_common.robot import CameraMount
from uav_sim_bridge.core.transforms import OPTICAL_FROM_FLU, FloatArray, RigidTransform, rotation_from_rpy
from uav_sim_bridge.errors import CameraError

__all__ = [
    "CameraConfig",
    "CameraModel",
    "MountConfig",
    "depth_to_points",
    "look_at",
]


#: Pose of the FLU camera frame ``camera_<name>`` on ``base_link``: the robot description's camera mount (the
#: bridge takes every mount from ``config/robot.yaml``).
MountConfig = CameraMount


@dataclass(frozen=True)
class CameraConfig:
    """One camera as written in ``config/sim_bridge.yaml`` under ``cameras.<name>``.

    Give either ``hfov_deg`` (square pixels, principal point at the image centre) or
    ``fx``/``fy`` (and optionally ``cx``/``cy``), not both.
    """

    width: int = 640
    height: int = 480
    hfov_deg: float | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    rate_hz: float = 10.0
    near_m: float = 0.5
    far_m: float = 2000.0
    mount: MountConfig = field(default_factory=MountConfig)

    def __post_init__(self) -> None:
        if not (1 <= self.width <= 8192 and 1 <= self.height <= 8192):
            msg = f"width and height must be in [1, 8192] pixels, got {self.width}x{self.height}"
            raise CameraError(msg)
        if self.hfov_deg is not None and (self.fx is not None or self.fy is not None):
            msg = "give either hfov_deg or fx/fy, not both"
            raise CameraError(msg)
        if self.hfov_deg is None and (self.fx is None or self.fy is None):
            msg = "give hfov_deg, or both fx and fy"
            raise CameraError(msg)
        if self.hfov_deg is not None and not 1.0 <= self.hfov_deg <= 170.0:
            msg = f"hfov_deg must be in [1, 170], got {self.hfov_deg}"
            raise CameraError(msg)
        for name in ("fx", "fy"):
            value = getattr(self, name)
            if value is not None and value <= 0:
                msg = f"{name} must be > 0 pixels, got {value}"
                raise CameraError(msg)
        if self.rate_hz <= 0:
            msg = f"rate_hz must be > 0, got {self.rate_hz}"
            raise CameraError(msg)
        if not 0 < self.near_m < self.far_m:
            msg = f"need 0 < near_m < far_m, got near_m={self.near_m}, far_m={self.far_m}"
            raise CameraError(msg)


@dataclass(frozen=True)
class CameraModel:
    """A calibrated pinhole camera rigidly mounted on ``base_link``.

    Attributes:
        name: camera name; frames are ``camera_<name>`` and ``camera_<name>_optical``.
        width, height: image size in pixels.
        fx, fy, cx, cy: intrinsics in pixels (OpenCV convention, see module docstring).
        rate_hz: publishing rate in simulation time.
        near_m, far_m: clip planes of the renderer.
        t_base_camera: ``T_base_link_camera`` (the FLU mount frame).
    """

    name: str
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    rate_hz: float = 10.0
    near_m: float = 0.5
    far_m: float = 2000.0
    t_base_camera: RigidTransform = field(default_factory=RigidTransform.identity)

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1 or self.fx <= 0 or self.fy <= 0:
            msg = f"camera {self.name!r}: invalid intrinsics {self.width}x{self.height} fx={self.fx} fy={self.fy}"
            raise CameraError(msg)

    @staticmethod
    def from_config(name: str, cfg: CameraConfig) -> CameraModel:
        """Intrinsics and mount from a :class:`CameraConfig`."""
        if cfg.hfov_deg is not None:
            fx = (cfg.width / 2.0) / math.tan(math.radians(cfg.hfov_deg) / 2.0)
            fy = fx
        else:
            fx = float(cfg.fx or 0.0)  # both set: checked by CameraConfig
            fy = float(cfg.fy or 0.0)
        cx = cfg.cx if cfg.cx is not None else (cfg.width - 1) / 2.0
        cy = cfg.cy if cfg.cy is not None else (cfg.height - 1) / 2.0
        roll, pitch, yaw = (math.radians(a) for a in cfg.mount.rpy_deg)
        mount = RigidTransform(rotation_from_rpy(roll, pitch, yaw), np.asarray(cfg.mount.xyz_m, dtype=np.float64))
        return CameraModel(name, cfg.width, cfg.height, fx, fy, cx, cy, cfg.rate_hz, cfg.near_m, cfg.far_m, mount)

    @staticmethod
    def simple(width: int, height: int, hfov_deg: float, *, name: str = "camera") -> CameraModel:
        """Centred pinhole with square pixels and the given horizontal field of view."""
        return CameraModel.from_config(name, CameraConfig(width=width, height=height, hfov_deg=hfov_deg))

    @property
    def frame_id(self) -> str:
        return f"camera_{self.name}"

    @property
    def optical_frame_id(self) -> str:
        return f"camera_{self.name}_optical"

    @property
    def k(self) -> FloatArray:
        """3x3 intrinsic matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def hfov_rad(self) -> float:
        return 2.0 * math.atan2(self.width / 2.0, self.fx)

    @cached_property
    def t_base_optical(self) -> RigidTransform:
        """``T_base_link_optical``: mount followed by the FLU -> optical axis swap (computed once per camera)."""
        return self.t_base_camera @ RigidTransform(OPTICAL_FROM_FLU, np.zeros(3))

    def optical_pose(self, t_map_base: RigidTransform) -> RigidTransform:
        """``T_map_optical`` of this camera on a vehicle at ``t_map_base``."""
        return t_map_base @ self.t_base_optical

    def with_size(self, width: int, height: int) -> CameraModel:
        """The same field of view at another resolution (intrinsics scaled)."""
        sx, sy = width / self.width, height / self.height
        return CameraModel(
            self.name,
            width,
            height,
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
            self.rate_hz,
            self.near_m,
            self.far_m,
            self.t_base_camera,
        )

    def project(self, points_optical_m: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Project ``(N, 3)`` optical-frame points to pixels.

        Returns:
            ``(uv, z_m)``: ``(N, 2)`` pixel coordinates and ``(N,)`` z-depths.  Points at
            or behind the camera (``z <= 0``) get NaN pixel coordinates.
        """
        pts = np.atleast_2d(np.asarray(points_optical_m, dtype=np.float64))
        z = pts[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_z = np.where(z > 0, 1.0 / z, np.nan)
        uv = np.stack([self.fx * pts[:, 0] * inv_z + self.cx, self.fy * pts[:, 1] * inv_z + self.cy], axis=1)
        return uv, z

    def unproject(self, uv: npt.ArrayLike, depth_m: npt.ArrayLike) -> FloatArray:
        """Pixels ``(N, 2)`` with z-depths ``(N,)`` -> ``(N, 3)`` optical-frame points."""
        uv_arr = np.atleast_2d(np.asarray(uv, dtype=np.float64))
        z = np.asarray(depth_m, dtype=np.float64).reshape(-1)
        x = (uv_arr[:, 0] - self.cx) / self.fx * z
        y = (uv_arr[:, 1] - self.cy) / self.fy * z
        return np.stack([x, y, z], axis=1)

    def in_image(self, uv: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Whether pixel coordinates fall on the image (pixel centres ± 0.5)."""
        uv_arr = np.atleast_2d(np.asarray(uv, dtype=np.float64))
        u, v = uv_arr[:, 0], uv_arr[:, 1]
        return (u >= -0.5) & (u < self.width - 0.5) & (v >= -0.5) & (v < self.height - 0.5)

    @cached_property
    def ray_grid(self) -> npt.NDArray[np.float32]:
        """``(H, W, 2)`` float32 normalised coordinates ``((u - cx)/fx, (v - cy)/fy)`` per pixel."""
        u = (np.arange(self.width, dtype=np.float64) - self.cx) / self.fx
        v = (np.arange(self.height, dtype=np.float64) - self.cy) / self.fy
        grid = np.empty((self.height, self.width, 2), dtype=np.float32)
        grid[..., 0] = u[None, :]
        grid[..., 1] = v[:, None]
        return grid

    def frustum_planes_optical(self) -> FloatArray:
        """``(6, 4)`` inward plane equations ``n·p + d >= 0`` (left, right, top, bottom, near, far) in optical frame.

        Near and far are planes at z-depth ``near_m`` and ``far_m``, as in the projection.
        """
        left = (-0.5 - self.cx) / self.fx
        right = (self.width - 0.5 - self.cx) / self.fx
        top = (-0.5 - self.cy) / self.fy
        bottom = (self.height - 0.5 - self.cy) / self.fy
        normals = np.array(
            [
                [1.0, 0.0, -left],
                [-1.0, 0.0, right],
                [0.0, 1.0, -top],
                [0.0, -1.0, bottom],
                [0.0, 0.0, 1.0],
                [0.0, 0.0, -1.0],
            ]
        )
        normals /= np.linalg.norm(normals, axis=1, keepdims=True)
        d = np.array([0.0, 0.0, 0.0, 0.0, -self.near_m, self.far_m])
        return np.concatenate([normals, d[:, None]], axis=1)


def depth_to_points(depth_m: npt.ArrayLike, k: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """Back-project a z-depth image into the optical frame.

    Args:
        depth_m: ``(H, W)`` z-depth in metres; NaN/inf/<= 0 means no return.
        k: 3x3 intrinsic matrix.

    Returns:
        ``(H, W, 3)`` float32 points in the optical frame (x right, y down, z forward),
        NaN wherever the depth is not a finite positive number.
    """
    depth = np.asarray(depth_m, dtype=np.float32)
    if depth.ndim != 2:
        msg = f"depth_m must be a 2-D image, got shape {depth.shape}"
        raise CameraError(msg)
    kk = np.asarray(k, dtype=np.float64)
    fx, fy, cx, cy = kk[0, 0], kk[1, 1], kk[0, 2], kk[1, 2]
    h, w = depth.shape
    x_n = ((np.arange(w) - cx) / fx).astype(np.float32)
    y_n = ((np.arange(h) - cy) / fy).astype(np.float32)
    z = np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(np.nan))
    out = np.empty((h, w, 3), dtype=np.float32)
    np.multiply(z, x_n[None, :], out=out[..., 0])
    np.multiply(z, y_n[:, None], out=out[..., 1])
    out[..., 2] = z
    return out


def look_at(eye_m: npt.ArrayLike, target_m: npt.ArrayLike, up: npt.ArrayLike = (0.0, 0.0, 1.0)) -> RigidTransform:
    """``T_map_optical`` of a camera at ``eye_m`` looking at ``target_m``.

    ``up`` is the world direction that should appear upwards in the image; when the
    view direction is parallel to it, map +y (north) is used instead, so a nadir
    view has north at the top of the image.
    """
    eye = np.asarray(eye_m, dtype=np.float64)
    fwd = np.asarray(target_m, dtype=np.float64) - eye
    norm = float(np.linalg.norm(fwd))
    if norm < 1e-9:
        msg = "look_at: eye and target coincide"
        raise CameraError(msg)
    z_axis = fwd / norm
    up_vec = np.asarray(up, dtype=np.float64)
    if abs(float(np.dot(z_axis, up_vec / np.linalg.norm(up_vec)))) > 0.999:
        up_vec = np.array([0.0, 1.0, 0.0])
    x_axis = np.cross(z_axis, up_vec)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    return RigidTransform(np.stack([x_axis, y_axis, z_axis], axis=1), eye)
