"""The run scorer: accumulates a run's observations and turns them into metrics.

One :class:`RunScorer` is fed records (``uav_scenarios.core.scoring.types``) in simulation-time
order by the live scorer node, a replay or the offline bag reader. At any time
:meth:`RunScorer.sample` gives one time-series row and :meth:`RunScorer.summary`
the nested metric dictionary written to ``metrics.json``. Every statistic with a
natural context is also broken down by context: clutter (objects in view), view
angle, range, altitude band, pixel size (TinyPerson's bins) and visible fraction.

The detector under test is scored per image against the ground truth of the same camera and
stamp: TP/FP/FN at the operating threshold (optimal IoU >= 0.5 matching), COCO AP/AP50/AR and
precision-recall curves with pycocotools over every score (:mod:`.coco`), how well its boxes
were placed on the ground (:mod:`.geolocation`) and its worst mistakes (:mod:`.gallery`). Its
tracks (from the geolocated boxes) are scored with py-motmetrics (MOTA, IDF1) and HOTA
(:mod:`.hota`).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_scenarios.core.config import ScoringSpec
from uav_scenarios.core.mission import CONFIRM_RADIUS_M
from uav_scenarios.core.scoring.cameras import CameraFrameSample, CameraWatch
from uav_scenarios.core.scoring.coco import CocoScores, ContextBands
from uav_scenarios.core.scoring.faults import (
    distance_to_polyline_m,
    fault_summary,
    target_tracking_stats,
    tracking_stats,
)
from uav_scenarios.core.scoring.gallery import Gallery, GalleryItem
from uav_scenarios.core.scoring.geolocation import GeolocationScores
from uav_scenarios.core.scoring.hota import HotaAccumulator, ground_similarity
from uav_scenarios.core.scoring.metrics import (
    VoxelAccuracy,
    altitude_stats,
    band_label,
    band_of,
    battery_use,
    coverage_efficiency,
    mapped_area_m2,
    match_detections,
    mean_cell_age_s,
    pose_error,
    view_angle_deg,
    voxel_accuracy,
)
from uav_scenarios.core.scoring.trails import ObjectStateRecord, TrailStats, TrailTracker
from uav_scenarios.core.scoring.types import (
    BatterySample,
    CollisionEvent,
    ControllerSample,
    DepthMetricsSample,
    Detection,
    DetectionFrame,
    EstimateStatusSample,
    FaultSample,
    GoalSample,
    GridSnapshot,
    PathSample,
    PoseSample,
    SceneTruth,
    TargetSample,
    TrackFrame,
)
from uav_scenarios.core.tracking import MotScorer
from uav_scenarios.errors import ScoringError

__all__ = ["CONTEXTS", "DetectionCounts", "RunScorer", "swath_width_m"]

#: Context dimensions of the breakdown and the unit of their bands.
CONTEXTS = {
    "clutter": "objects",
    "view_angle": "deg",
    "range": "m",
    "altitude": "m",
    "pixel_size": "px",
    "visible_fraction": "",
}
#: Contexts of an object (the others are of a frame).
OBJECT_CONTEXTS = ("range", "view_angle", "pixel_size", "visible_fraction")
_FRAME_KEY_DIGITS = 4  # stamps are matched to 0.1 ms
#: Pose estimates are scored at most this often (simulation seconds).
ESTIMATE_PERIOD_S = 0.1
#: The autopilot's position target is compared with the truth only while it is this fresh (it streams at 10 Hz).
TARGET_FRESH_S = 1.0


def swath_width_m(altitude_m: float, fov_deg: float) -> float:
    """Ground swath of a nadir camera: ``2 h tan(fov/2)``."""
    return 2.0 * altitude_m * math.tan(math.radians(fov_deg) / 2.0)


@dataclass
class DetectionCounts:
    tp: int = 0
    fp: int = 0
    fn: int = 0

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else math.nan

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else math.nan

    def as_dict(self) -> dict[str, float]:
        return {"tp": self.tp, "fp": self.fp, "fn": self.fn, "precision": self.precision, "recall": self.recall}


@dataclass(frozen=True)
class _DepthFrame:
    sample: DepthMetricsSample
    ctx: dict[str, str]

    @property
    def values(self) -> dict[str, float]:
        return self.sample.values


@dataclass
class _FirstDetection:
    t_s: float
    range_m: float


@dataclass
class RunScorer:
    """Accumulates one run. Feed records in time order; read ``sample()`` / ``summary()``.

    Args:
        spec: scoring settings (floors, bands, gates).
        truth: the scene's ground truth (bounds, surface voxels, ground heights).
        detection_source: the ``DetectionFrame.source`` of the detector under test
            (``ground_truth`` when the ground truth itself is the detector).
        person_id: instance id of the person of interest, 0 if none.
        tracked_camera: camera whose detections the tracker follows.
        swath_m_per_m: nadir swath width per metre of altitude (``2 tan(fov/2)``), for the
            coverage efficiency; 0 if unknown.
        camera_pitch_deg: each camera's mount pitch (90 = nadir), for the view-angle context
            of per-frame depth statistics.
    """

    spec: ScoringSpec
    truth: SceneTruth
    detection_source: str = "ground_truth"
    person_id: int = 0
    tracked_camera: str = "forward"
    cruise_speed_mps: float = math.nan
    swath_m_per_m: float = 0.0
    start_t_s: float = math.nan
    camera_pitch_deg: dict[str, float] = field(default_factory=lambda: {"nadir": 90.0, "forward": 25.0})
    #: Along-track over across-track footprint of the map camera (image height / width for a nadir camera).
    footprint_aspect: float = 0.75
    #: The map's voxel size (trail voxels use it until the truth's surface voxels are known).
    spec_resolution_m: float = 0.5
    #: The detector's operating threshold: TP/FP/FN, tracking and the gallery use detections at or above it;
    #: AP and the precision-recall curves use every detection.
    score_threshold: float = 0.0
    #: Classes scored by COCO (the class map's).
    classes: tuple[str, ...] = ("person", "vehicle")
    _poses: list[PoseSample] = field(default_factory=list)
    #: The pose estimate the autonomy flew on (``pose_source: autopilot``), against ``_poses`` (the truth).
    _estimates: list[PoseSample] = field(default_factory=list)
    _estimate_status: EstimateStatusSample | None = None
    _agl: list[float] = field(default_factory=list)
    _distance_m: float = 0.0
    _battery: list[BatterySample] = field(default_factory=list)
    _layers: GridSnapshot | None = None
    _mapped_m2: float = 0.0
    _map_accuracy: VoxelAccuracy | None = None
    _map_accuracy_t_s: float = math.nan
    _collisions: list[CollisionEvent] = field(default_factory=list)
    _goals: list[GoalSample] = field(default_factory=list)
    _controller: list[ControllerSample] = field(default_factory=list)
    _depth: list[_DepthFrame] = field(default_factory=list)
    _pending_truth: dict[tuple[str, float], DetectionFrame] = field(default_factory=dict)
    _pending_hyp: dict[tuple[str, float], DetectionFrame] = field(default_factory=dict)
    _pending_tracks: dict[tuple[str, float], TrackFrame] = field(default_factory=dict)
    _det_total: DetectionCounts = field(default_factory=DetectionCounts)
    _det_by_context: dict[str, dict[int, DetectionCounts]] = field(
        default_factory=lambda: {c: defaultdict(DetectionCounts) for c in CONTEXTS}
    )
    _det_frames: int = 0
    _first_person_seen: _FirstDetection | None = None
    _first_person_detected: _FirstDetection | None = None
    _first_detection_any: _FirstDetection | None = None
    _mot: MotScorer | None = None
    _mot_by_context: dict[str, dict[int, MotScorer]] = field(default_factory=dict)
    _hota: HotaAccumulator = field(default_factory=HotaAccumulator)
    _hota_by_context: dict[str, dict[int, HotaAccumulator]] = field(default_factory=dict)
    _track_inputs: dict[str, int] = field(default_factory=dict)
    _coco: CocoScores | None = None
    _coco_cache: dict[str, Any] | None = None
    _geo: GeolocationScores = field(default_factory=GeolocationScores)
    _gallery: Gallery | None = None
    _events: list[tuple[float, str]] = field(default_factory=list)
    #: Scripted faults sent, and every autopilot mode / controller / estimate change (what followed them).
    _faults: list[FaultSample] = field(default_factory=list)
    _changes: list[tuple[float, str]] = field(default_factory=list)
    #: The frames of the cameras with scripted faults (their changes go to ``_changes``).
    _camera_watch: CameraWatch = field(default_factory=CameraWatch)
    #: The path the autonomy commands (map ENU) and the vehicle's distance from it while AUTONOMOUS.
    _path_m: npt.NDArray[np.float64] | None = None
    _tracking_errors_m: list[float] = field(default_factory=list)
    _tracking_last_t_s: float = -math.inf
    #: The autopilot's latest position target and the vehicle's (3D, horizontal) distance from it, any mode.
    _target: TargetSample | None = None
    _target_errors_m: list[tuple[float, float]] = field(default_factory=list)
    _target_errors_by_mode: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    _target_last_t_s: float = -math.inf
    _clutter: dict[tuple[str, float], int] = field(default_factory=dict)
    _tracking_cache: dict[str, Any] | None = None
    _takeoff_t_s: float | None = None
    _complete_t_s: float = math.nan
    _complete_what: str = ""
    _confirmed: tuple[float, tuple[float, float, float]] | None = None
    _candidates_rejected: int = 0
    _last_t_s: float = -math.inf
    #: Voxels moving objects left behind and what the map did with them (None until object states arrive).
    _trails: TrailTracker | None = None

    # ---- feeding -------------------------------------------------------------------------

    def _advance(self, t_s: float) -> None:
        if not math.isfinite(t_s):
            msg = f"record with non-finite time {t_s}"
            raise ScoringError(msg)
        if math.isnan(self.start_t_s):
            self.start_t_s = t_s
        self._last_t_s = max(self._last_t_s, t_s)

    def add_pose(self, pose: PoseSample) -> None:
        self._advance(pose.t_s)
        if self._poses:
            prev = self._poses[-1]
            if pose.t_s < prev.t_s:
                return  # a stale duplicate (e.g. bag re-ordering); never count it twice
            self._distance_m += math.dist(prev.position_m, pose.position_m)
        self._poses.append(pose)
        self._agl.append(self._ground_clearance(pose))
        self._track_setpoint(pose)
        self._track_target(pose)

    def add_path(self, sample: PathSample) -> None:
        """The path the autonomy commands (``/autonomy/path``, map ENU); an empty or non-finite one is ignored."""
        self._advance(sample.t_s)
        path = np.asarray(sample.points_m, dtype=np.float64).reshape(-1, 3)
        if path.shape[0] and np.isfinite(path).all():
            self._path_m = path

    def _track_setpoint(self, pose: PoseSample) -> None:
        """Setpoint tracking error: the vehicle's distance from the commanded path, at most 10 times a second,
        while the controller flies it (AUTONOMOUS)."""
        ctrl = self._controller[-1] if self._controller else None
        if ctrl is None or ctrl.state != "AUTONOMOUS" or self._path_m is None:
            return
        if pose.t_s - self._tracking_last_t_s < ESTIMATE_PERIOD_S - 1e-6:
            return
        self._tracking_last_t_s = pose.t_s
        self._tracking_errors_m.append(distance_to_polyline_m(pose.position_m, self._path_m))

    def add_target(self, sample: TargetSample) -> None:
        """The autopilot's own position target (``/autopilot_odometry/target``, map ENU); a non-finite one is
        ignored."""
        self._advance(sample.t_s)
        if all(math.isfinite(v) for v in sample.position_m):
            self._target = sample

    def _track_target(self, pose: PoseSample) -> None:
        """The vehicle's (ground truth) distance from the autopilot's position target, in any mode, at most 10
        times a second, while the target is fresh, also per autopilot mode (the controller's view of it): in
        HOLD the error of the autopilot's own position control, which wind and turbulence grow; in OFFBOARD the
        distance to the streamed setpoint, which the controller's carrot puts ahead of the vehicle on purpose."""
        target = self._target
        if target is None or abs(pose.t_s - target.t_s) > TARGET_FRESH_S:
            return
        if pose.t_s - self._target_last_t_s < ESTIMATE_PERIOD_S - 1e-6:
            return
        self._target_last_t_s = pose.t_s
        d = np.subtract(pose.position_m, target.position_m)
        error = (float(np.linalg.norm(d)), float(math.hypot(d[0], d[1])))
        self._target_errors_m.append(error)
        mode = (self._controller[-1].autopilot_mode if self._controller else "") or "unknown"
        self._target_errors_by_mode.setdefault(mode, []).append(error)

    def add_fault(self, fault: FaultSample) -> None:
        """A scripted fault the mission manager sent and the autopilot's answer (an event; ``faults`` section)."""
        self._advance(fault.t_s)
        self._faults.append(fault)
        detail = f" ({fault.detail})" if fault.detail else ""
        self._events.append((fault.t_s, f"fault {fault.label}: {fault.result}{detail}"))

    def add_camera_frame(self, frame: CameraFrameSample) -> None:
        """A colour frame of a camera with a scripted fault: its stops, gaps, frozen or noise pictures are changes
        (what followed the faults)."""
        self._advance(frame.t_s)
        self._changes.extend(self._camera_watch.add(frame))

    def add_estimate(self, pose: PoseSample) -> None:
        """A pose estimate (the autopilot's, as the autonomy used it), scored against the true trajectory."""
        self._advance(pose.t_s)
        if self._estimates and pose.t_s - self._estimates[-1].t_s < ESTIMATE_PERIOD_S:
            return  # 10 samples a second describe the error; the estimate itself comes at 30-50 Hz
        self._estimates.append(pose)

    def add_estimate_status(self, status: EstimateStatusSample) -> None:
        """The estimate's state; each change (OK, STALE, INVALID...) is an event with its reason."""
        self._advance(status.t_s)
        previous = self._estimate_status
        if previous is None or previous.state != status.state:
            why = f": {status.reason}" if status.reason else ""
            self._events.append((status.t_s, f"pose estimate {status.state}{why}"))
            self._changes.append((status.t_s, f"pose estimate {status.state}{why}"))
        self._estimate_status = status

    def add_battery(self, sample: BatterySample) -> None:
        self._advance(sample.t_s)
        self._battery.append(sample)

    def add_layers(self, layers: GridSnapshot) -> None:
        self._advance(layers.t_s)
        self._layers = layers
        self._mapped_m2 = mapped_area_m2(layers, self.truth.bounds_m)

    def add_map_keys(self, t_s: float, keys: np.ndarray[Any, np.dtype[np.int64]]) -> VoxelAccuracy | None:
        """Occupied voxel keys of the map at ``t_s`` (same resolution as the truth)."""
        if self.truth.surface_keys.size == 0:
            self._advance(t_s)
            return None
        self.set_map_accuracy(t_s, voxel_accuracy(keys, self.truth.surface_keys, self.truth.surface_columns))
        return self._map_accuracy

    def add_object_states(self, record: ObjectStateRecord) -> None:
        """Ground truth of the moving people and vehicles at one instant (``/sim/object_states``)."""
        self._advance(record.t_s)
        if self._trails is None:
            res = self.truth.surface_resolution_m or self.spec_resolution_m
            self._trails = TrailTracker(res)
        self._trails.add(record)

    def evaluate_trails(self, t_s: float, map_keys: np.ndarray[Any, np.dtype[np.int64]]) -> TrailStats | None:
        """The map's occupied voxels (packed keys, the truth's resolution) against the moving objects' trails."""
        if self._trails is None:
            return None
        if self._trails.static_keys.size == 0 and self.truth.surface_keys.size:
            self._trails.static_keys = self.truth.surface_keys
        layers = self._layers
        last_seen = None
        if layers is not None and "last_seen_s" in layers.layers:
            grid = np.asarray(layers.layers["last_seen_s"], dtype=np.float64)

            def last_seen(x: np.ndarray[Any, Any], y: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
                col = np.floor((x - layers.origin_x_m) / layers.resolution_m).astype(np.int64)
                row = np.floor((y - layers.origin_y_m) / layers.resolution_m).astype(np.int64)
                ok = (row >= 0) & (row < grid.shape[0]) & (col >= 0) & (col < grid.shape[1])
                out = np.full(len(x), np.nan)
                out[ok] = grid[row[ok], col[ok]]
                return out

        return self._trails.evaluate(t_s, map_keys, last_seen)

    def set_map_accuracy(self, t_s: float, accuracy: VoxelAccuracy) -> None:
        """A map accuracy computed elsewhere (:func:`voxel_accuracy` is slow on big maps: off the lock)."""
        self._advance(t_s)
        self._map_accuracy = accuracy
        self._map_accuracy_t_s = t_s

    def add_collision(self, event: CollisionEvent) -> None:
        self._advance(event.t_s)
        self._collisions.append(event)
        self._events.append((event.t_s, f"collision with {event.class_name} {event.instance_id}"))

    def add_goal(self, goal: GoalSample) -> None:
        self._advance(goal.t_s)
        self._goals.append(goal)

    def add_controller(self, sample: ControllerSample) -> None:
        self._advance(sample.t_s)
        prev = self._controller[-1] if self._controller else None
        if prev is None or prev.autopilot_mode != sample.autopilot_mode:
            self._changes.append((sample.t_s, f"autopilot {sample.autopilot_mode or '(no mode)'}"))
        if prev is None or prev.state != sample.state or prev.last_event != sample.last_event:
            why = f": {sample.last_event}" if sample.last_event else ""
            self._changes.append((sample.t_s, f"controller {sample.state}{why}"))
        if not self._controller or self._controller[-1].state != sample.state:
            self._events.append((sample.t_s, f"controller {sample.state}"))
            if sample.state in ("IDLE", "RTL", "LAND") and sample.last_event and self._controller:
                self._events.append((sample.t_s, f"controller {sample.state} because: {sample.last_event}"))
        self._controller.append(sample)

    def add_depth_metrics(self, sample: DepthMetricsSample) -> None:
        self._advance(sample.t_s)
        self._depth.append(_DepthFrame(sample, self._depth_context(sample)))

    def add_event(self, t_s: float, text: str) -> None:
        self._advance(t_s)
        self._events.append((t_s, text))

    def mark_complete(self, t_s: float, what: str) -> None:
        """The mission's task is done (person confirmed, area mapped); the first call wins."""
        self._advance(t_s)
        if math.isnan(self._complete_t_s):
            self._complete_t_s = t_s
            self._complete_what = what
            self._events.append((t_s, f"complete: {what}"))

    def mark_confirmed(self, t_s: float, position_m: tuple[float, float, float]) -> None:
        """The mission confirmed a person at ``position_m``; the first call wins."""
        self._advance(t_s)
        if self._confirmed is None and all(math.isfinite(v) for v in position_m):
            self._confirmed = (t_s, position_m)

    def set_candidates_rejected(self, t_s: float, count: int) -> None:
        """The mission's running count of candidates its operator check turned down (bystanders)."""
        if count > self._candidates_rejected:
            self._advance(t_s)
            self._events.append((t_s, f"candidate turned down (not the person searched for), {count} so far"))
            self._candidates_rejected = count

    def _search_summary(self) -> dict[str, Any]:
        """Whether the person confirmed is the person of interest: within ``CONFIRM_RADIUS_M`` of them (a box-only
        detector cannot tell people apart; confirming a bystander is a failed search)."""
        if not self.person_id:
            return {}
        rows = self.truth.objects
        match = rows[rows[:, 0] == self.person_id] if rows.size else rows
        person = tuple(float(v) for v in match[0, 1:4]) if len(match) else (math.nan, math.nan, math.nan)
        out: dict[str, Any] = {
            "person_position_m": list(person),
            "confirmed": self._confirmed is not None,
            "candidates_rejected": self._candidates_rejected,
        }
        if self._confirmed is not None:
            t_s, pos = self._confirmed
            err = math.hypot(pos[0] - person[0], pos[1] - person[1])
            out.update(
                confirmed_t_s=t_s - self.start_t_s,
                confirmed_position_m=list(pos),
                error_m=err,
                correct=bool(err <= CONFIRM_RADIUS_M) if math.isfinite(err) else None,
            )
        return out

    def add_detections(self, frame: DetectionFrame, *, is_truth: bool) -> None:
        """A frame of ground-truth detections, of the detector under test, or both.

        Frames are paired by ``(camera, stamp)``: a ground-truth frame is scored once
        the detector's frame of the same image arrives (detectors may skip images;
        skipped images are not scored).
        """
        self._advance(frame.t_s)
        key = (frame.camera, round(frame.t_s, _FRAME_KEY_DIGITS))
        both = is_truth and frame.source == self.detection_source
        if is_truth:
            self._note_person_seen(frame)
            self._pending_truth[key] = frame
            self._clutter[key] = len(frame.detections)
        if both or not is_truth:
            self._pending_hyp[key] = frame
        self._score_pending(key)
        self._prune(frame.t_s)

    def add_tracks(self, frame: TrackFrame) -> None:
        self._advance(frame.t_s)
        key = (frame.camera, round(frame.t_s, _FRAME_KEY_DIGITS))
        self._pending_tracks[key] = frame
        self._score_pending(key)

    # ---- internals -----------------------------------------------------------------------

    def _ground_clearance(self, pose: PoseSample) -> float:
        x, y, z = pose.position_m
        ground = math.nan
        if self.truth.ground is not None:
            ground = self.truth.ground.value_at("elevation_m", x, y)
        if math.isnan(ground) and self._layers is not None:
            ground = self._layers.value_at("elevation_m", x, y)
        if math.isnan(ground):
            ground = 0.0  # home level: the terrain under home is z = 0 by convention
        return z - ground

    def _pose_at(self, t_s: float) -> tuple[PoseSample | None, float]:
        if not self._poses:
            return None, math.nan
        times = [p.t_s for p in self._poses[-200:]]
        k = int(np.argmin(np.abs(np.asarray(times) - t_s)))
        return self._poses[-200:][k], self._agl[-200:][k]

    def _note_person_seen(self, frame: DetectionFrame) -> None:
        if self._first_person_seen is not None or not self.person_id:
            return
        for d in frame.detections:
            if d.instance_id == self.person_id:
                self._first_person_seen = _FirstDetection(frame.t_s, d.range_m)
                self._events.append((frame.t_s, f"person in view at {d.range_m:.0f} m"))

    def _score_pending(self, key: tuple[str, float]) -> None:
        truth = self._pending_truth.get(key)
        hyp = self._pending_hyp.pop(key, None)
        if truth is not None and hyp is not None:
            self._score_detection_frame(truth, hyp)
        elif hyp is not None:
            self._pending_hyp[key] = hyp
        tracks = self._pending_tracks.get(key)
        if truth is not None and tracks is not None:
            self._score_track_frame(truth, tracks)
            del self._pending_tracks[key]

    def _prune(self, now_s: float) -> None:
        horizon = now_s - 10.0
        for pending in (self._pending_truth, self._pending_hyp, self._pending_tracks, self._clutter):
            for k in [k for k in pending if k[1] < horizon]:
                del pending[k]

    def _frame_values(self, truth: DetectionFrame) -> dict[str, float]:
        _, agl = self._pose_at(truth.t_s)
        return {"clutter": float(len(truth.detections)), "altitude": agl}

    def _frame_context(self, truth: DetectionFrame) -> dict[str, int]:
        return {name: band_of(v, self._bands(name)[0]) for name, v in self._frame_values(truth).items()}

    @staticmethod
    def _object_values(det: Detection, camera_m: tuple[float, ...]) -> dict[str, float]:
        """An object's context values (NaN where unknown: a detection's visible fraction, an unplaced one's range)."""
        angle = math.nan
        if len(camera_m) == 3:
            angle = view_angle_deg((camera_m[0], camera_m[1], camera_m[2]), det.position_m)
        return {
            "range": det.range_m,
            "view_angle": angle,
            "pixel_size": det.size_px,
            "visible_fraction": det.visible_fraction,
        }

    def _object_context(self, det: Detection, frame_ctx: dict[str, int], camera_m: tuple[float, ...]) -> dict[str, int]:
        values = self._object_values(det, camera_m)
        return {**frame_ctx, **{name: band_of(v, self._bands(name)[0]) for name, v in values.items()}}

    def _track_frame_context(self, truth: DetectionFrame) -> dict[str, int]:
        """A tracking frame's context: clutter and altitude, plus the median of each object context over its objects."""
        ctx = self._frame_context(truth)
        pose, _ = self._pose_at(truth.t_s)
        camera_m: tuple[float, ...] = pose.position_m if pose is not None else ()
        values = [self._object_values(d, camera_m) for d in truth.detections]
        for name in OBJECT_CONTEXTS:
            finite = [v[name] for v in values if math.isfinite(v[name])]
            ctx[name] = band_of(float(np.median(finite)) if finite else math.nan, self._bands(name)[0])
        return ctx

    def _count(self, ctx: dict[str, int], kind: str) -> None:
        for name, band in ctx.items():
            counts = self._det_by_context[name][band]
            setattr(counts, kind, getattr(counts, kind) + 1)
        setattr(self._det_total, kind, getattr(self._det_total, kind) + 1)

    def _score_detection_frame(self, truth: DetectionFrame, hyp: DetectionFrame) -> None:
        self._det_frames += 1
        self._coco_cache = None
        pose, _ = self._pose_at(truth.t_s)
        camera_m: tuple[float, ...] = pose.position_m if pose is not None else ()
        frame_ctx = self._frame_context(truth)
        if hyp is not truth:
            self._geo.add_frame(hyp)
        if self._coco is None:
            self._coco = CocoScores(
                self.classes,
                {n: ContextBands(*self._bands(n)) for n in OBJECT_CONTEXTS},
                {n: ContextBands(*self._bands(n)) for n in CONTEXTS if n not in OBJECT_CONTEXTS},
            )
        self._coco.add_image(
            truth.detections,
            [self._object_values(d, camera_m) for d in truth.detections],
            hyp.detections,
            [self._object_values(d, camera_m) for d in hyp.detections],
            self._frame_values(truth),
        )
        if self._gallery is None:
            self._gallery = Gallery(self.spec.gallery_size)
        operating = [d for d in hyp.detections if d.score >= self.score_threshold]
        matches, missed, false = match_detections(truth.detections, operating)
        range_edges, range_unit = self._bands("range")
        for i, j in matches:
            t_det = truth.detections[i]
            self._count(self._object_context(t_det, frame_ctx, camera_m), "tp")
            band = band_label(band_of(t_det.range_m, range_edges), range_edges, range_unit)
            self._geo.add_match(t_det, operating[j], band)
            if self._first_detection_any is None:
                self._first_detection_any = _FirstDetection(truth.t_s, t_det.range_m)
            if self.person_id and t_det.instance_id == self.person_id and self._first_person_detected is None:
                # the person's true range then (the detector's own is its geolocator's estimate)
                self._first_person_detected = _FirstDetection(truth.t_s, t_det.range_m)
                self._events.append((truth.t_s, f"person detected at {t_det.range_m:.0f} m"))
        for i in missed:
            self._count(self._object_context(truth.detections[i], frame_ctx, camera_m), "fn")
            self._gallery.miss(truth.t_s, truth.camera, truth.detections[i])
        for j in false:
            self._count(self._object_context(operating[j], frame_ctx, camera_m), "fp")
            self._gallery.false_positive(truth.t_s, truth.camera, operating[j])

    def _score_track_frame(self, truth: DetectionFrame, tracks: TrackFrame) -> None:
        if self._mot is None:
            self._mot = MotScorer(self.spec.track_gate_m)
        self._track_inputs = {
            "detections_received": tracks.detections_received,
            "detections_unplaced": tracks.detections_unplaced,
            "detections_below_threshold": tracks.detections_below_threshold,
        }
        finite = [d for d in truth.detections if d.placed]
        t_ids = [d.instance_id for d in finite]
        t_xy = np.array([d.position_m[:2] for d in finite]).reshape(-1, 2)
        h_ids = [t.track_id for t in tracks.tracks]
        h_xy = np.array([t.position_m[:2] for t in tracks.tracks]).reshape(-1, 2)
        sim = ground_similarity(t_xy, h_xy, self.spec.track_gate_m)
        self._mot.update(t_ids, t_xy, h_ids, h_xy)
        self._hota.update(t_ids, h_ids, sim)
        for name, band in self._track_frame_context(truth).items():
            per = self._mot_by_context.setdefault(name, {})
            if band not in per:
                per[band] = MotScorer(self.spec.track_gate_m)
            per[band].update(t_ids, t_xy, h_ids, h_xy)
            hota = self._hota_by_context.setdefault(name, {})
            if band not in hota:
                hota[band] = HotaAccumulator()
            hota[band].update(t_ids, h_ids, sim)

    def take_gallery_items(self) -> list[GalleryItem]:
        """Gallery items kept since the last call: the node crops their images."""
        return self._gallery.take_new() if self._gallery is not None else []

    def gallery_items(self) -> list[GalleryItem]:
        """The gallery now: worst false positives, then worst misses."""
        return self._gallery.items() if self._gallery is not None else []

    # ---- reading -------------------------------------------------------------------------

    def _cruise_speed_mps(self, now_s: float) -> float:
        """90th percentile of the horizontal ground speed while airborne (the speed legs are flown at)."""
        if self._takeoff_t_s is None or len(self._poses) < 3:
            return math.nan
        pts = np.array([(p.t_s, p.position_m[0], p.position_m[1]) for p in self._poses if p.t_s <= now_s])
        pts = pts[pts[:, 0] >= self._takeoff_t_s]
        if len(pts) < 3:
            return math.nan
        dt = np.diff(pts[:, 0])
        ok = dt > 1e-6
        speeds = np.hypot(np.diff(pts[:, 1]), np.diff(pts[:, 2]))[ok] / dt[ok]
        return float(np.percentile(speeds, 90)) if speeds.size else math.nan

    def _airborne_s(self, now_s: float) -> float:
        """Time from the first pose 1 m above the ground to ``now_s`` (or the last record, if earlier)."""
        if self._takeoff_t_s is None:
            for pose, agl in zip(self._poses, self._agl, strict=True):
                if agl >= 1.0:
                    self._takeoff_t_s = pose.t_s
                    break
        if self._takeoff_t_s is None:
            return 0.0
        return max(0.0, min(now_s, self._last_t_s) - self._takeoff_t_s)

    def sample(self, now_s: float) -> dict[str, float | str]:
        """One time-series row at ``now_s`` (the CSV columns; NaN where unknown)."""
        pose = self._poses[-1] if self._poses else None
        bat = self._battery[-1] if self._battery else None
        layers = self._layers
        acc = self._map_accuracy
        goal = self._goals[-1] if self._goals else None
        ctrl = self._controller[-1] if self._controller else None
        trail = self._trails.last if self._trails is not None else None
        nan = math.nan
        return {
            "t_s": now_s,
            "x_m": pose.position_m[0] if pose else nan,
            "y_m": pose.position_m[1] if pose else nan,
            "z_m": pose.position_m[2] if pose else nan,
            "agl_m": self._agl[-1] if self._agl else nan,
            "distance_m": self._distance_m,
            "battery_pct": bat.remaining_pct if bat else nan,
            "voltage_v": bat.voltage_v if bat else nan,
            "battery_used_mah": battery_use(self._battery).used_mah if bat else nan,
            "mapped_m2": self._mapped_m2,
            "mapped_pct": 100.0 * self._mapped_m2 / self.truth.area_m2 if self.truth.area_m2 else nan,
            "observed_cells": float(np.count_nonzero(layers.layers["observed"] > 0.5))
            if layers is not None and "observed" in layers.layers
            else nan,
            "mean_cell_age_s": mean_cell_age_s(layers, now_s) if layers is not None else nan,
            "occupied_voxels": float(acc.n_map) if acc else nan,
            "map_iou": acc.iou if acc else nan,
            "map_precision": acc.precision if acc else nan,
            "map_recall": acc.recall if acc else nan,
            "goal_x_m": goal.goal_m[0] if goal else nan,
            "goal_y_m": goal.goal_m[1] if goal else nan,
            "controller_state": ctrl.state if ctrl else "",
            "det_tp": float(self._det_total.tp),
            "det_fp": float(self._det_total.fp),
            "det_fn": float(self._det_total.fn),
            "collisions": float(len(self._collisions)),
            "trail_ghost_voxels": float(trail.ghosts) if trail else nan,
            "trail_cleared_voxels": float(trail.cleared) if trail else nan,
            "pose_error_m": self._latest_pose_error_m(),
        }

    def _latest_pose_error_m(self) -> float:
        """The error of the latest scored estimate (NaN: none, or no truth around its stamp)."""
        if not self._estimates:
            return math.nan
        e = self._estimates[-1]
        truth = self._poses[-100:]
        err = pose_error(
            [p.t_s for p in truth], [p.position_m for p in truth], [p.yaw_rad for p in truth],
            est_t_s=[e.t_s], est_xyz_m=[e.position_m], est_yaw_rad=[e.yaw_rad],
        )  # fmt: skip
        return err.position_mean_m

    def summary(self, now_s: float, *, tracking: bool = True, coco: bool = False) -> dict[str, Any]:
        """Every metric of the run so far, as plain JSON-able data (NaN -> None by the writer).

        Args:
            tracking: recompute the MOT metrics (py-motmetrics takes ~50 ms per accumulator on
                a long run); ``False`` reuses the last computed ones.
            coco: run the COCO evaluation (pycocotools, seconds on a long run: the final summary);
                ``False`` reuses the last one, if any.
        """
        spec = self.spec
        if tracking and self._coco is not None:
            self._coco.update()  # the COCO matching of the frames scored since, so the final summary is quick
        times = np.array([p.t_s for p in self._poses])
        alt = altitude_stats(times, np.array(self._agl), spec.altitude_floor_m)
        bat = battery_use(self._battery)
        airborne_s = self._airborne_s(now_s)
        mapped_pct = 100.0 * self._mapped_m2 / self.truth.area_m2 if self.truth.area_m2 else math.nan
        coverage_rate = self._mapped_m2 / airborne_s if airborne_s > 0 else math.nan
        cov = coverage_efficiency(
            self._mapped_m2,
            airborne_s,
            swath_m=self.swath_m_per_m * alt.mean_m,
            along_m=self.swath_m_per_m * self.footprint_aspect * alt.mean_m,
            speed_mps=self._cruise_speed_mps(now_s),
        )
        acc = self._map_accuracy
        out: dict[str, Any] = {
            "time": {
                "start_s": self.start_t_s,
                "end_s": now_s,
                "duration_s": now_s - self.start_t_s if math.isfinite(self.start_t_s) else 0.0,
                "airborne_s": airborne_s,
                "complete_s": self._complete_t_s - self.start_t_s if math.isfinite(self._complete_t_s) else math.nan,
                "complete_what": self._complete_what,
            },
            "coverage": {
                "scene_area_m2": self.truth.area_m2,
                "mapped_m2": self._mapped_m2,
                "mapped_pct": mapped_pct,
                "rate_m2_per_s": coverage_rate,
                "cruise_speed_mps": cov.speed_mps,
                "configured_cruise_speed_mps": self.cruise_speed_mps,
                "swath_m": cov.swath_m,
                "swath_limit_m2_per_s": cov.limit_m2_per_s,
                "efficiency": cov.efficiency,
            },
            "map_accuracy": {
                "t_s": self._map_accuracy_t_s,
                "iou": acc.iou if acc else math.nan,
                "precision": acc.precision if acc else math.nan,
                "recall": acc.recall if acc else math.nan,
                "recall_observed": acc.recall_observed if acc else math.nan,
                "iou_observed": acc.iou_observed if acc else math.nan,
                "occupied_voxels": acc.n_map if acc else math.nan,
                "truth_voxels": acc.n_truth if acc else int(self.truth.surface_keys.size),
            },
            "flight": {
                "distance_m": self._distance_m,
                "agl_min_m": alt.min_m,
                "agl_mean_m": alt.mean_m,
                "time_below_floor_s": alt.time_below_floor_s,
                "altitude_floor_m": spec.altitude_floor_m,
                "goals": len({g.goal_m for g in self._goals}),
            },
            "battery": {
                "used_mah": bat.used_mah,
                "used_pct": bat.used_pct,
                "start_pct": bat.start_pct,
                "end_pct": bat.end_pct,
                "min_voltage_v": bat.min_voltage_v,
            },
            "collisions": {
                "count": len(self._collisions),
                "events": [
                    {"t_s": c.t_s, "instance_id": c.instance_id, "class": c.class_name, "speed_mps": c.speed_mps}
                    for c in self._collisions
                ],
            },
            "detection": self._detection_summary(coco=coco),
            "search": self._search_summary(),
            "tracking": self._tracking_summary() if tracking or self._tracking_cache is None else self._tracking_cache,
            "depth": self._depth_summary(),
            "moving_objects": self._trail_summary(),
            "pose_estimate": self._estimate_summary(now_s),
            "faults": fault_summary(
                self._faults,
                [*self._changes, *self._camera_watch.open_gaps(now_s)],
                start_s=self.start_t_s,
                end_s=now_s,
                cameras=self._camera_watch,
            ),
            "setpoint_tracking": {
                "reference": "distance from the commanded path (/autonomy/path) while AUTONOMOUS, ground truth",
                **tracking_stats(self._tracking_errors_m),
            },
            "autopilot_tracking": {
                "reference": "distance from the autopilot's own position target (POSITION_TARGET_LOCAL_NED), any mode,"
                " ground truth",
                **target_tracking_stats(self._target_errors_m),
                "by_mode": {m: target_tracking_stats(e) for m, e in sorted(self._target_errors_by_mode.items())},
            },
            "events": [{"t_s": t, "what": w} for t, w in sorted(self._events, key=lambda e: e[0])],
        }
        return out

    def _trail_summary(self) -> dict[str, Any]:
        trails = self._trails
        if trails is None:
            return {"movers": 0}
        last = trails.last
        if last is None:
            return {"movers": len(trails.movers), "distance_m": trails.distance_m, "evaluated_t_s": math.nan}
        return {"evaluated_t_s": last.t_s - self.start_t_s, **last.as_dict()}

    def _estimate_summary(self, now_s: float) -> dict[str, Any]:
        """The estimate the autonomy flew on against the truth (empty samples: ground-truth runs)."""
        est = [e for e in self._estimates if e.t_s <= now_s]
        truth = self._poses
        err = pose_error(
            [p.t_s for p in truth],
            [p.position_m for p in truth],
            [p.yaw_rad for p in truth],
            est_t_s=[e.t_s for e in est],
            est_xyz_m=[e.position_m for e in est],
            est_yaw_rad=[e.yaw_rad for e in est],
        )
        st = self._estimate_status
        stale = sum(1 for _, what in self._events if what.startswith(("pose estimate STALE", "pose estimate INVALID")))
        return {
            "estimates": len(est),
            "error": err.as_dict(),
            "source": st.source if st else "",
            "state": st.state if st else "",
            "time_sync": st.time_sync if st else "",
            "time_offset_s": st.time_offset_s if st else math.nan,
            "covariance_from_autopilot": st.covariance_from_autopilot if st else False,
            "invalid": st.invalid if st else 0,
            "late": st.late if st else 0,
            "out_of_order": st.out_of_order if st else 0,
            "stale_or_invalid_events": stale,
        }

    def _bands(self, name: str) -> tuple[tuple[float, ...], str]:
        spec = self.spec
        edges = {
            "clutter": spec.clutter_bands,
            "view_angle": spec.view_angle_bands_deg,
            "range": spec.range_bands_m,
            "altitude": spec.altitude_bands_m,
            "pixel_size": spec.pixel_size_bands_px,
            "visible_fraction": spec.visible_fraction_bands,
        }[name]
        return edges, CONTEXTS[name]

    def coco_summary(self) -> dict[str, Any]:
        """COCO AP/AP50/AR and precision-recall curves of the detector, overall and by context (slow)."""
        if self._coco is None:
            return {"images": 0}
        if self._coco_cache is None:
            self._coco_cache = self._coco.evaluate()
        return self._coco_cache

    def _detection_summary(self, *, coco: bool = False) -> dict[str, Any]:
        def first(fd: _FirstDetection | None) -> dict[str, float]:
            if fd is None:
                return {"t_s": math.nan, "range_m": math.nan}
            return {"t_s": fd.t_s - self.start_t_s, "range_m": fd.range_m}

        by_context: dict[str, dict[str, dict[str, float]]] = {}
        for name, per in self._det_by_context.items():
            edges, unit = self._bands(name)
            by_context[name] = {band_label(k, edges, unit): per[k].as_dict() for k in sorted(per)}
        out: dict[str, Any] = {
            "source": self.detection_source,
            "frames": self._det_frames,
            "score_threshold": self.score_threshold,
            **self._det_total.as_dict(),
            "first_detection": first(self._first_detection_any),
            "person_first_in_view": first(self._first_person_seen),
            "person_first_detected": first(self._first_person_detected),
            "by_context": by_context,
            "geolocation": self._geo.summary(),
            "gallery": [item.as_dict() for item in self._gallery.items()] if self._gallery is not None else [],
        }
        if coco:
            out["coco"] = self.coco_summary()
        elif self._coco_cache is not None:
            out["coco"] = self._coco_cache
        return out

    def _tracking_summary(self) -> dict[str, Any]:
        self._tracking_cache = self._tracking_summary_now()
        return self._tracking_cache

    def _tracking_summary_now(self) -> dict[str, Any]:
        if self._mot is None:
            return {"frames": 0}

        def both(mot: MotScorer, hota: HotaAccumulator) -> dict[str, float]:
            h = hota.result()
            return {**mot.result().as_dict(), "hota": h.hota, "deta": h.deta, "assa": h.assa, "loca": h.loca}

        by_context: dict[str, dict[str, dict[str, float]]] = {}
        for name, per in self._mot_by_context.items():
            edges, unit = self._bands(name)
            hotas = self._hota_by_context[name]
            by_context[name] = {band_label(k, edges, unit): both(per[k], hotas[k]) for k in sorted(per)}
        return {
            **both(self._mot, self._hota),
            "hota_detail": self._hota.result().as_dict(),
            "inputs": dict(self._track_inputs),
            "by_context": by_context,
        }

    def _depth_context(self, sample: DepthMetricsSample) -> dict[str, str]:
        """Altitude, view angle (of the camera's axis) and clutter (objects in that camera's frame) of a depth frame."""
        pose, agl = self._pose_at(sample.t_s)
        pitch = self.camera_pitch_deg.get(sample.camera, 90.0)
        angle = pose.camera_off_nadir_deg(pitch) if pose is not None else math.nan
        key = (sample.camera, round(sample.t_s, _FRAME_KEY_DIGITS))
        clutter = float(self._clutter[key]) if key in self._clutter else math.nan
        out = {}
        for name, value in (("altitude", agl), ("view_angle", angle), ("clutter", clutter)):
            edges, unit = self._bands(name)
            out[name] = band_label(band_of(value, edges), edges, unit)
        return out

    def _depth_summary(self) -> dict[str, Any]:
        if not self._depth:
            return {"frames": 0}
        keys = sorted({k for s in self._depth for k in s.values})

        def mean_of(samples: list[dict[str, float]]) -> dict[str, float]:
            names = sorted({k for v in samples for k in v})
            return {"frames": len(samples), **{k: _nanmean([v.get(k, math.nan) for v in samples]) for k in names}}

        overall = {k: _nanmean([s.values.get(k, math.nan) for s in self._depth]) for k in keys}
        grouped: dict[str, dict[str, list[dict[str, float]]]] = defaultdict(lambda: defaultdict(list))
        for s in self._depth:
            for context, label in s.ctx.items():
                grouped[context][label].append(s.values)
            for context, per in s.sample.breakdown.items():
                for label, values in per.items():
                    grouped[context][label].append(values)
        return {
            "frames": len(self._depth),
            **overall,
            "by_context": {c: {label: mean_of(v) for label, v in sorted(per.items())} for c, per in grouped.items()},
        }

    @property
    def collisions(self) -> int:
        return len(self._collisions)

    @property
    def mapped_pct(self) -> float:
        return 100.0 * self._mapped_m2 / self.truth.area_m2 if self.truth.area_m2 else math.nan


def _nanmean(values: list[float]) -> float:
    arr = np.asarray(values, dtype=np.float64)
    arr = arr[np.isfinite(arr)]
    return float(arr.mean()) if arr.size else math.nan
