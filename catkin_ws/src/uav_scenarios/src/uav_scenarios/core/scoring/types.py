"""Domain records the scoring core consumes: one per kind of observation of a run.

The live scorer node and the offline bag reader both turn messages into these
(``uav_scenarios.ros.records``), so a run is scored by exactly the same code live, in a
``rosbag play`` replay and offline. Positions are metres in ``map`` (ENU), times
are simulation seconds.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from uav_common.voxel_keys import key_columns, sorted_unique

__all__ = [
    "BatterySample",
    "CollisionEvent",
    "ControllerSample",
    "DepthMetricsSample",
    "Detection",
    "DetectionFrame",
    "EstimateStatusSample",
    "FaultSample",
    "GoalSample",
    "GridSnapshot",
    "PathSample",
    "PoseSample",
    "SceneTruth",
    "Track",
    "TrackFrame",
]

FloatArray = npt.NDArray[np.float64]
Vec3 = tuple[float, float, float]
NAN3: Vec3 = (math.nan, math.nan, math.nan)


@dataclass(frozen=True)
class PoseSample:
    """Ground-truth vehicle pose (``quat_xyzw``: base_link -> map, ROS order)."""

    t_s: float
    position_m: Vec3
    yaw_rad: float = 0.0
    quat_xyzw: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)

    def camera_off_nadir_deg(self, mount_pitch_deg: float) -> float:
        """Off-nadir angle of a camera's optical axis: 0° looking straight down, 90° at the horizon.

        The camera looks along base_link x pitched down by ``mount_pitch_deg`` (REP 103 FLU mount,
        as the bridge's ``mount.rpy_deg[1]``: 90 = nadir).
        """
        x, y, z, w = self.quat_xyzw
        p = math.radians(mount_pitch_deg)
        axis = (math.cos(p), 0.0, -math.sin(p))
        # z component of R(q) @ axis
        r20 = 2.0 * (x * z - w * y)
        r21 = 2.0 * (y * z + w * x)
        r22 = 1.0 - 2.0 * (x * x + y * y)
        down = -(r20 * axis[0] + r21 * axis[1] + r22 * axis[2])
        return math.degrees(math.acos(max(-1.0, min(1.0, down))))


@dataclass(frozen=True)
class BatterySample:
    t_s: float
    voltage_v: float
    #: Remaining charge, percent (0-100); NaN if unknown.
    remaining_pct: float
    #: Charge drawn since start, mAh; NaN if the source does not say.
    consumed_mah: float = math.nan
    #: Current drawn, A (positive while discharging); NaN if unknown.
    current_a: float = math.nan


@dataclass(frozen=True)
class GridSnapshot:
    """Named 2D layers on one grid (``uav_msgs/GridLayers``): row 0 is the southern-most row."""

    t_s: float
    resolution_m: float
    origin_x_m: float
    origin_y_m: float
    layers: dict[str, FloatArray]

    @property
    def shape(self) -> tuple[int, int]:
        first = next(iter(self.layers.values()), None)
        return (0, 0) if first is None else (int(first.shape[0]), int(first.shape[1]))

    def cell_centers_m(self) -> tuple[FloatArray, FloatArray]:
        """``(xs, ys)``: the x of each column centre ``(W,)`` and the y of each row centre ``(H,)``."""
        rows, cols = self.shape
        xs = self.origin_x_m + (np.arange(cols) + 0.5) * self.resolution_m
        ys = self.origin_y_m + (np.arange(rows) + 0.5) * self.resolution_m
        return xs, ys

    def value_at(self, layer: str, x_m: float, y_m: float) -> float:
        """The layer's value in the cell containing ``(x, y)``; NaN outside the grid."""
        grid = self.layers.get(layer)
        if grid is None:
            return math.nan
        col = math.floor((x_m - self.origin_x_m) / self.resolution_m)
        row = math.floor((y_m - self.origin_y_m) / self.resolution_m)
        if 0 <= row < grid.shape[0] and 0 <= col < grid.shape[1]:
            return float(grid[row, col])
        return math.nan


@dataclass(frozen=True)
class Detection:
    """One object in one image: the ground truth's (instance id, true centre, visible fraction) or a
    detector's, placed by the geolocator (instance id 0, ground position with covariance, or NaN)."""

    instance_id: int
    class_name: str
    score: float
    #: Pixel box ``(x_min, y_min, x_max, y_max)``, inclusive.
    bbox_px: tuple[int, int, int, int]
    range_m: float
    visible_fraction: float
    position_m: Vec3 = NAN3
    #: Row-major 3x3 covariance of ``position_m`` (m²); empty or NaN when unknown.
    position_cov_m2: tuple[float, ...] = ()
    #: ``ground_truth`` | ``depth`` | ``elevation`` | ``terrain``, or ``unplaced:<reason>``; "" if unknown.
    position_source: str = ""

    @property
    def placed(self) -> bool:
        """Whether the detection has a position (a finite one)."""
        return all(math.isfinite(v) for v in self.position_m)

    @property
    def size_px(self) -> float:
        """Pixel size: the square root of the box's area (TinyPerson's absolute size)."""
        x0, y0, x1, y1 = self.bbox_px
        return math.sqrt(max(0, x1 - x0 + 1) * max(0, y1 - y0 + 1))

    @property
    def box_xywh(self) -> tuple[float, float, float, float]:
        """The box as COCO's ``[x, y, w, h]`` on pixel edges (pixel ``k`` spans ``[k - 0.5, k + 0.5]``)."""
        x0, y0, x1, y1 = self.bbox_px
        return (x0 - 0.5, y0 - 0.5, float(x1 - x0 + 1), float(y1 - y0 + 1))


@dataclass(frozen=True)
class DetectionFrame:
    t_s: float
    camera: str
    source: str
    detections: tuple[Detection, ...] = ()
    #: Detections of this image the producer discarded, by reason (NaN or out-of-image boxes...).
    discarded: tuple[tuple[str, int], ...] = ()


@dataclass(frozen=True)
class CollisionEvent:
    t_s: float
    instance_id: int
    class_name: str
    position_m: Vec3
    speed_mps: float


@dataclass(frozen=True)
class GoalSample:
    t_s: float
    goal_m: Vec3
    reason: str = ""


@dataclass(frozen=True)
class ControllerSample:
    t_s: float
    state: str
    autopilot_mode: str = ""
    armed: bool = False
    in_air: bool = False
    #: What last happened (e.g. why it stopped commanding).
    last_event: str = ""


@dataclass(frozen=True)
class PathSample:
    """The path the autonomy commands (``/autonomy/path``): ``(N, 3)`` map ENU points."""

    t_s: float
    points_m: tuple[Vec3, ...]


@dataclass(frozen=True)
class TargetSample:
    """The autopilot's own position target (POSITION_TARGET_LOCAL_NED in map ENU): the hold point in HOLD, the
    streamed setpoint in OFFBOARD, the navigator's in a mission (``/autopilot_odometry/target``)."""

    t_s: float
    position_m: Vec3


@dataclass(frozen=True)
class FaultSample:
    """A scripted fault the mission manager sent (uav_msgs/FaultEvent) and the autopilot's answer."""

    t_s: float
    index: int
    at_s: float
    unit: str
    failure_type: str
    instance: int = 0
    clear: bool = False
    result: str = ""
    detail: str = ""
    answered_s: float = math.nan

    @property
    def label(self) -> str:
        inst = f" {self.instance}" if self.instance else ""
        end = f" (end of fault {self.index})" if self.clear else ""
        return f"{self.unit}{inst} {self.failure_type}{end}"


@dataclass(frozen=True)
class EstimateStatusSample:
    """The autopilot odometry node's view of the pose estimate (uav_msgs/EstimateStatus)."""

    t_s: float
    state: str
    reason: str = ""
    source: str = ""
    time_sync: str = ""
    time_offset_s: float = math.nan
    published: int = 0
    invalid: int = 0
    late: int = 0
    out_of_order: int = 0
    covariance_from_autopilot: bool = False


@dataclass(frozen=True)
class DepthMetricsSample:
    """One frame's depth accuracy from the depth evaluator.

    Attributes:
        values: the whole frame's statistics, name -> value (``coverage``, ``within_abs``, ``abs_rel``...).
        breakdown: the evaluator's own breakdowns, context -> label -> statistics
            (``{"range": {"20-40m": {...}}, "class": {"building": {...}}}``).
        camera: the evaluated camera.
    """

    t_s: float
    values: dict[str, float]
    breakdown: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)
    camera: str = ""


@dataclass(frozen=True)
class Track:
    track_id: int
    class_name: str
    position_m: Vec3
    velocity_mps: Vec3 = (0.0, 0.0, 0.0)
    hits: int = 1


@dataclass(frozen=True)
class TrackFrame:
    t_s: float
    camera: str
    tracks: tuple[Track, ...] = ()
    #: The tracker's running counts: detections given, and those it could not use (no position; low score).
    detections_received: int = 0
    detections_unplaced: int = 0
    detections_below_threshold: int = 0


@dataclass(frozen=True)
class SceneTruth:
    """What the world generator knows and the map can be compared with.

    Attributes:
        bounds_m: ``(x_min, y_min, x_max, y_max)`` of the scene, the "% mapped" denominator.
        surface_keys: int64 voxel keys (:func:`uav_scenarios.core.scoring.metrics.voxel_keys`) of the observable
            surfaces at ``surface_resolution_m``; empty if unknown.
        ground: ground-truth surface height grid (layer ``elevation_m``) for altitude above
            ground; ``None`` to fall back to the map's elevation.
        objects: ``(N, 4)`` float64 rows ``(instance_id, x, y, z)`` of people and vehicles.
        object_classes: class name per row of ``objects``.
    """

    bounds_m: tuple[float, float, float, float]
    surface_keys: npt.NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    surface_resolution_m: float = 0.0
    ground: GridSnapshot | None = None
    objects: FloatArray = field(default_factory=lambda: np.zeros((0, 4)))
    object_classes: tuple[str, ...] = ()

    @functools.cached_property
    def surface_columns(self) -> npt.NDArray[np.int64]:
        """The (x, y) column of each of ``surface_keys`` (sorted and unique), computed once."""
        return key_columns(sorted_unique(self.surface_keys))

    @property
    def area_m2(self) -> float:
        x0, y0, x1, y1 = self.bounds_m
        return max(0.0, x1 - x0) * max(0.0, y1 - y0)
