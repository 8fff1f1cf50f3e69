"""scorer: scores a scenario run live (or in a ``rosbag play`` replay) and writes its metrics.

ROS interface:

Subscribes:
    ``/uav/ground_truth/odom`` (nav_msgs/Odometry), ``/uav/battery`` (sensor_msgs/BatteryState),
    ``/map_server/layers`` (uav_msgs/GridLayers), ``/autonomy/features`` (uav_msgs/GridLayers),
    ``/detections/ground_truth`` (the truth) and ``/geolocator/detections`` (the detector under test, its boxes
    placed in map) (uav_msgs/DetectionArray),
    ``/scenario/tracks`` (uav_msgs/TrackArray), ``/sim/collision`` (uav_msgs/Collision),
    ``/autonomy/goal_reason`` (uav_msgs/GoalReason), ``/uav/controller/state`` (uav_msgs/ControllerState),
    ``/scenario/faults`` (uav_msgs/FaultEvent: scripted faults), ``/autonomy/path`` (nav_msgs/Path: the
    commanded path, for the setpoint tracking error),
    ``/depth_evaluator/metrics`` (uav_msgs/DepthMetrics, when depth is estimated),
    ``/scenario/status`` (uav_msgs/ScenarioStatus: run start, completion, stop);
    with ``pose_source: autopilot``: ``/uav/autopilot/odom`` (nav_msgs/Odometry, the estimate the autonomy flew
    on: its error against the ground truth) and ``/autopilot_odometry/status`` (uav_msgs/EstimateStatus:
    its changes of state, e.g. STALE with the reason, are events) and ``/autopilot_odometry/target``
    (geometry_msgs/PointStamped: the autopilot's own position target, for ``autopilot_tracking``);
    camera images ``/cameras/<cam>/{color,depth,instance}/image_raw`` only around snapshot times, and the
    detector camera's color images when the detector is not the ground truth (``scoring.gallery_size`` > 0:
    the gallery of its worst mistakes is cut from them); the color images of each camera the scenario scripts
    a fault for (``unit: camera_<cam>``): whether its frames stop, freeze or turn to noise follows the fault.
Publishes:
    ``/scenario/metrics`` (uav_msgs/RunMetrics) at ``scoring.metrics_rate_hz`` (sim time) and once at the end;
    ``/scenario/snapshot/layers`` and ``/scenario/snapshot/features`` (uav_msgs/GridLayers, at most
    ``scoring.snapshot_max_cells`` per side) and ``/scenario/snapshot/<cam>/{color,depth,instance}``
    (sensor_msgs/Image) at ``scoring.snapshot_times_s`` and at the end, for the report;
    ``/scenario/snapshot/gallery`` (sensor_msgs/Image rgb8, latched): the worst false positives and misses,
    at the end (metadata in the metrics' ``detection.gallery``).
Calls:
    ``/map_server/export_occupied`` (uav_msgs/ExportVoxels) every ``scoring.map_accuracy_period_s`` of
    simulation time and at the end: the map's occupied voxels against the world's surface voxels.
Parameters:
    ``~scenario`` (str, required): the scenario file.
    ``~run_dir`` (str, default ""): where ``metrics.json``, ``timeseries.csv`` and ``scenario.yaml`` are
    written (atomically, every metrics period, so a crash keeps what was scored); "" writes nothing.
    ``~world_cache_dir`` (str, ""): the bridge's world cache (the ground truth is the bridge's world).
    ``~run/person`` (dict): the person of interest ``{name, instance_id, x_m, y_m}`` (scenario_params).
    ``~run/camera_pitch_deg`` (dict): camera mount pitches (view-angle context of depth frames).
    ``~cameras`` (list, default [nadir, forward]); ``~map_server`` (str, default ``/map_server``).
    Any other private parameter stops the node (exit code 2, docs/architecture.md).

Scoring itself is :class:`uav_scenarios.core.scoring.run.RunScorer`; the ground truth comes from
:func:`uav_scenarios.shell.world_store.scene_truth` (surface voxels are computed in the background
the first time, then cached on disk).

Causal lockstep (docs/lockstep.md): a participant with a lookahead of 10 steps (the mission manager's ``mapped_pct``
stop criterion reads its metrics, so it is in the loop, but up to a second of simulated time behind it costs the
loop nothing: its scoring is the heaviest Python of a run, and comes in bursts).
Every record it scores is a counted input, its timer fires from the step, the ground truth is loaded before the
first step, and the map export is applied at the step boundary the protocol names: the time series and the
metrics are the same in every run. Only the report's camera snapshots are taken from whatever frame comes
first (pictures for the report, not metrics).
"""

from __future__ import annotations

import csv
import heapq
import io
import itertools
import json
import math
import os
import tempfile
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np
import rospy
from geometry_msgs.msg import PointStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from rosgraph_msgs.msg import Clock
from rospy.numpy_msg import numpy_msg
from sensor_msgs.msg import BatteryState, Image
from std_msgs.msg import Header

from uav_common.config import ConfigError
from uav_common.detection_classes import load_detection_classes
from uav_common.paths import config_file
from uav_common.ros.arrays import MessageLayoutError, image_msg
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import (
    Collision,
    ControllerState,
    DepthMetrics,
    DetectionArray,
    EstimateStatus,
    FaultEvent,
    GoalReason,
    GridLayers,
    MapInsertStats,
    ObjectStateArray,
    RunMetrics,
    ScenarioStatus,
    TrackArray,
)
from uav_msgs.srv import ExportVoxels, ExportVoxelsRequest
from uav_scenarios.core.config import (
    ESTIMATE_STATUS_TOPIC,
    GEOLOCATED_TOPIC,
    TARGET_TOPIC,
    DetectorKind,
    PoseSource,
    Scenario,
    effective_yaml,
    estimate_topic,
    load_scenario,
)
from uav_scenarios.core.faults import camera_name
from uav_scenarios.core.scoring.gallery import crop_tile, mosaic
from uav_scenarios.core.scoring.metrics import voxel_accuracy, voxel_keys_from_indices
from uav_scenarios.core.scoring.run import RunScorer, swath_width_m
from uav_scenarios.core.scoring.types import SceneTruth
from uav_scenarios.errors import ScenarioConfigError, ScenarioError
from uav_scenarios.ros.messages import downsampled_layers_msg, json_safe, metrics_msg
from uav_scenarios.ros.params import ScorerParams
from uav_scenarios.ros.records import (
    battery_from_msg,
    camera_frame_from_msg,
    collision_from_msg,
    controller_from_msg,
    depth_metrics_from_msg,
    detections_from_msg,
    estimate_status_from_msg,
    fault_from_msg,
    goal_from_msg,
    grid_from_msg,
    image_from_msg,
    object_states_from_msg,
    path_from_msg,
    pose_from_odometry,
    stamp_s,
    target_from_msg,
    tracks_from_msg,
)
from uav_scenarios.shell.versions import run_versions
from uav_scenarios.shell.world_store import load_world, scene_truth, world_summary

IMAGE_KINDS = {"color": "color/image_raw", "depth": "depth/image_raw", "instance": "instance/image_raw"}
#: Subscriber queues: deep enough that a replay at full speed loses nothing.
QUEUE = 2000
#: Records are scored in stamp order once ROS time is this far past their stamp (late messages
#: from other processes still count in order); the run's end cuts at the stop instant exactly.
HOLD_S = 0.5
#: Tracking metrics (py-motmetrics and HOTA, over the whole run so far) are first recomputed this long (simulation s)
#: after the start, then each time the run has doubled (20 s, 40 s, 80 s...): a fixed period made their cost grow
#: with the square of the run's length (a 30-minute run: 90 recomputations, each slower than the last); doubling
#: keeps the live ones under twice the final summary's cost.
TRACKING_PERIOD_S = 20.0
#: Detector-camera images kept for cutting the gallery's crops (frames are scored HOLD_S after their stamp).
GALLERY_IMAGES = 40
#: Steps between its inputs and when its metrics are consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 10


def default_truth(scenario: Scenario) -> SceneTruth:
    """The scene's bounds from the scenario (square of ``world.size_m`` around home), until the world is loaded."""
    half = scenario.world.size_m / 2.0
    return SceneTruth(bounds_m=(-half, -half, half, half))


def write_atomic(path: Path, text: str) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


class ScorerNode:
    def __init__(
        self,
        scenario: Scenario,
        run_dir: Path | None,
        cameras: list[str],
        *,
        person: dict[str, Any],
        camera_pitch_deg: dict[str, float],
        map_camera_hfov_deg: float = 90.0,
        map_camera_aspect: float = 0.75,
        world_cache_dir: Path | None,
        map_server_ns: str = "/map_server",
    ) -> None:
        self.scenario = scenario
        self.run_dir = run_dir
        self.cameras = cameras
        self.world_cache_dir = world_cache_dir
        self.map_server_ns = map_server_ns.rstrip("/")
        perception = scenario.perception
        self.detection_camera = perception.camera
        try:
            classes = load_detection_classes(config_file("detection_classes.yaml")).names
        except ConfigError as err:
            raise ScenarioConfigError(str(err)) from err
        self.scorer = RunScorer(
            spec=scenario.scoring,
            truth=default_truth(scenario),
            detection_source=perception.source,
            person_id=int(person.get("instance_id", 0)),
            tracked_camera=perception.camera,
            cruise_speed_mps=scenario.autonomy.cruise_speed_mps,
            swath_m_per_m=swath_width_m(1.0, map_camera_hfov_deg),
            footprint_aspect=map_camera_aspect,
            camera_pitch_deg=dict(camera_pitch_deg) or {"nadir": 90.0, "forward": 25.0},
            spec_resolution_m=scenario.map.resolution_m,
            score_threshold=perception.score_threshold,
            classes=classes,
        )
        # The ground truth scored against itself has no mistakes to show: no gallery, no extra render.
        self.gallery_images: OrderedDict[int, Any] | None = (
            OrderedDict()
            if scenario.scoring.gallery_size > 0 and perception.detector is not DetectorKind.GROUND_TRUTH
            else None
        )
        self.gallery_tiles: dict[int, Any] = {}
        self.gallery_missing = 0
        self.person = person
        self.lock = threading.Lock()
        self.start_s: float | None = None
        self.stopped = False
        self.finished = False
        self._finish_lock = threading.Lock()
        self._final = False
        self.rows: list[dict[str, Any]] = []
        self._csv_fields: list[str] = []  # columns and rows already in timeseries.csv
        self._csv_rows = 0
        self.snapshots_due = list(scenario.scoring.snapshot_times_s)
        self.last_layers: GridLayers | None = None
        self.last_features: GridLayers | None = None
        self.image_subs: list[rospy.Subscriber] = []
        self.pubs: dict[str, Any] = {}
        self.metrics_pub: Any = None
        self.world_info: dict[str, Any] = {}
        self.truth_note = "loading the world"
        self._accuracy_busy = threading.Lock()
        self._pending: list[tuple[float, int, str, Any]] = []
        self._seq = itertools.count()
        self._pending_lock = threading.Lock()
        self.end_s: float | None = None
        self._finish_at_s: float | None = None
        self._next_tracking_s = -math.inf
        self._next_accuracy_s = -math.inf
        self._export_dir = Path(tempfile.mkdtemp(prefix="uav_scorer_"))
        self._exports_made = 0
        #: Causal lockstep: exports on their way, (step their answer is taken at, time, file, future), and the final
        #: one (started when the stop is seen).
        self._exports: list[tuple[int, float, Path, Any]] = []
        self._final_export: tuple[int, float, Path, Any] | None = None
        self.versions = run_versions()
        self.map_input: dict[str, int] = {}  # the map server's cloud totals (its last ~insert_stats)

    # ---- wiring --------------------------------------------------------------------------

    def start(self, ls: Participant) -> None:
        self.ls = ls
        self.metrics_pub = ls.publisher("/scenario/metrics", RunMetrics, queue_size=5, latch=True)
        self.pubs["layers"] = ls.publisher("/scenario/snapshot/layers", GridLayers, queue_size=10, latch=True)
        self.pubs["features"] = ls.publisher("/scenario/snapshot/features", GridLayers, queue_size=10, latch=True)
        for cam in self.cameras:
            for kind in IMAGE_KINDS:
                self.pubs[f"{cam}/{kind}"] = ls.publisher(
                    f"/scenario/snapshot/{cam}/{kind}", Image, queue_size=10, latch=True
                )
        sub = ls.subscribe
        sub("/uav/ground_truth/odom", Odometry, self._feed(pose_from_odometry, "add_pose"), queue_size=QUEUE)
        if self.scenario.pose_source is PoseSource.AUTOPILOT:
            topic = estimate_topic(self.scenario)
            sub(topic, Odometry, self._feed(pose_from_odometry, "add_estimate"), queue_size=QUEUE)
            status = self._feed(estimate_status_from_msg, "add_estimate_status")
            sub(ESTIMATE_STATUS_TOPIC, EstimateStatus, status, queue_size=QUEUE)
            sub(TARGET_TOPIC, PointStamped, self._feed(target_from_msg, "add_target"), queue_size=QUEUE)
        sub("/uav/battery", BatteryState, self._feed(battery_from_msg, "add_battery"), queue_size=QUEUE)
        # numpy_msg: the float32[] of big grids deserialises into an array, not a Python tuple.
        sub("/map_server/layers", numpy_msg(GridLayers), self.on_layers, queue_size=2, buff_size=2**26)
        sub("/autonomy/features", numpy_msg(GridLayers), self.on_features, queue_size=2, buff_size=2**26)
        sub("/detections/ground_truth", DetectionArray, self.on_truth_detections, queue_size=QUEUE)
        sub(GEOLOCATED_TOPIC, DetectionArray, self.on_detector, queue_size=QUEUE)
        self.pubs["gallery"] = ls.publisher("/scenario/snapshot/gallery", Image, queue_size=1, latch=True)
        if self.gallery_images is not None:
            sub(
                f"/cameras/{self.detection_camera}/color/image_raw",
                Image,
                self.on_detector_image,
                queue_size=5,
                buff_size=2**24,
            )
        sub("/scenario/tracks", TrackArray, self._feed(tracks_from_msg, "add_tracks"), queue_size=QUEUE)
        sub("/sim/collision", Collision, self._feed(collision_from_msg, "add_collision"), queue_size=QUEUE)
        sub(
            "/sim/object_states",
            ObjectStateArray,
            self._feed(object_states_from_msg, "add_object_states"),
            queue_size=QUEUE,
        )
        sub("/autonomy/goal_reason", GoalReason, self._feed(goal_from_msg, "add_goal"), queue_size=QUEUE)
        sub("/uav/controller/state", ControllerState, self.on_controller, queue_size=QUEUE)
        sub("/scenario/faults", FaultEvent, self._feed(fault_from_msg, "add_fault"), queue_size=QUEUE)
        for cam in sorted({camera_name(f.unit) for f in self.scenario.faults} - {""}):
            sub(f"/cameras/{cam}/color/image_raw", Image, self._camera_frame(cam), queue_size=50, buff_size=2**24)
        sub("/autonomy/path", PathMsg, self._feed(path_from_msg, "add_path"), queue_size=QUEUE)
        sub(
            "/depth_evaluator/metrics",
            DepthMetrics,
            self._feed(depth_metrics_from_msg, "add_depth_metrics"),
            queue_size=QUEUE,
        )
        sub("/scenario/status", ScenarioStatus, self.on_status, queue_size=QUEUE)
        sub(f"{self.map_server_ns}/insert_stats", MapInsertStats, self.on_insert_stats, queue_size=QUEUE)
        if ls.causal:
            # The exports' answers at their step, the final summary at the first step past the stop (on_clock's
            # rule), and the whole truth before the first step: a row must not depend on when a thread finished.
            ls.on_step(lambda step, _now: self._take_exports(step))
            ls.on_step(lambda _step, now: self._finish_due(now))
            self._load_truth()
        else:
            sub("/clock", Clock, self.on_clock, queue_size=10)
            threading.Thread(target=self._load_truth, name="scorer-truth", daemon=True).start()
        ls.timer(1.0 / self.scenario.scoring.metrics_rate_hz, self.on_tick, name="metrics")
        rospy.on_shutdown(self.finish)
        if self.run_dir is not None and not (self.run_dir / "scenario.yaml").exists():
            write_atomic(self.run_dir / "scenario.yaml", effective_yaml(self.scenario))

    def _load_truth(self) -> None:
        """World -> bounds, ground, objects at once; surface voxels later (slow the first time)."""
        t0 = time.monotonic()
        try:
            world = load_world(self.scenario, self.world_cache_dir)
            moved = {}
            if self.person.get("instance_id"):
                moved[int(self.person["instance_id"])] = (float(self.person["x_m"]), float(self.person["y_m"]))
            quick = scene_truth(world, resolution_m=None, cache_dir=self.world_cache_dir, moved=moved)
            with self.lock:
                self.scorer.truth = quick
            self.world_info = world_summary(world, self.world_cache_dir)
            self.truth_note = "computing surface voxels"
            full = scene_truth(
                world, resolution_m=self.scenario.map.resolution_m, cache_dir=self.world_cache_dir, moved=moved
            )
            with self.lock:
                self.scorer.truth = full
            self.truth_note = ""
            rospy.loginfo(
                f"scorer: ground truth of world {world.config.name} ({world.hash[:12]}): "
                f"{full.surface_keys.size} surface voxels at {self.scenario.map.resolution_m} m "
                f"in {time.monotonic() - t0:.1f} s"
            )
        except ScenarioError as err:
            self.truth_note = f"no ground truth: {err}"
            rospy.logerr(f"scorer: {self.truth_note}; % mapped uses world.size_m, no map IoU")

    def _camera_frame(self, camera: str) -> Any:
        def callback(msg: Image) -> None:
            try:
                record = camera_frame_from_msg(msg, camera)
            except MessageLayoutError as err:
                rospy.logwarn_throttle(10.0, f"scorer: /cameras/{camera}/color/image_raw: {err}")
                return
            self._push(record.t_s, "add_camera_frame", record)

        return callback

    def _feed(self, convert: Any, method: str) -> Any:
        def callback(msg: Any) -> None:
            record = convert(msg)
            self._push(record.t_s, method, record)

        return callback

    def _push(self, t_s: float, method: str, record: Any) -> None:
        with self._pending_lock:
            if self.end_s is None or t_s <= self.end_s:
                heapq.heappush(self._pending, (t_s, next(self._seq), method, record))

    def _flush_scored(self, upto_s: float) -> None:
        """Score held records up to ``upto_s``, once the run's start is known (earlier records are dropped:
        what happens before the mission starts is not part of the run, and a replay may not have it)."""
        if self.start_s is None:
            return
        self._flush(upto_s)

    def _flush(self, upto_s: float) -> None:
        """Score every held record stamped up to ``upto_s``, in stamp order (arrival order on ties)."""
        batch = []
        with self._pending_lock:
            while self._pending and self._pending[0][0] <= upto_s:
                batch.append(heapq.heappop(self._pending))
        if not batch:
            return
        with self.lock:
            for t_s, _seq, method, record in batch:
                if (self.end_s is not None and t_s > self.end_s) or (self.start_s is not None and t_s < self.start_s):
                    continue
                try:
                    if method == "truth_detections":
                        self.scorer.add_detections(record, is_truth=True)
                    elif method == "detector":
                        self.scorer.add_detections(record, is_truth=False)
                    else:
                        getattr(self.scorer, method)(record)
                except ScenarioError as err:
                    rospy.logwarn_throttle(10.0, f"scorer: record at {t_s:.2f} s rejected: {err}")
            self._cut_gallery()

    # ---- callbacks -----------------------------------------------------------------------

    def on_layers(self, msg: GridLayers) -> None:
        if self.end_s is None or msg.header.stamp.to_sec() <= self.end_s:
            self.last_layers = msg
        self._feed(grid_from_msg, "add_layers")(msg)

    def on_features(self, msg: GridLayers) -> None:
        if self.end_s is None or msg.header.stamp.to_sec() <= self.end_s:
            self.last_features = msg

    def on_truth_detections(self, msg: DetectionArray) -> None:
        frame = detections_from_msg(msg)
        self._push(frame.t_s, "truth_detections", frame)

    def on_detector(self, msg: DetectionArray) -> None:
        frame = detections_from_msg(msg)
        self._push(frame.t_s, "detector", frame)

    def on_detector_image(self, msg: Image) -> None:
        """Keep the detector camera's latest images, to cut the gallery's crops from once frames are scored."""
        if self.gallery_images is None:
            return
        key = round(stamp_s(msg.header.stamp) * 1e4)
        with self._pending_lock:
            self.gallery_images[key] = msg
            while len(self.gallery_images) > GALLERY_IMAGES:
                self.gallery_images.popitem(last=False)

    def _cut_gallery(self) -> None:
        """Crops of the gallery items scored since the last call (from the kept images)."""
        items = self.scorer.take_gallery_items()
        if not items or self.gallery_images is None:
            return
        for item in items:
            with self._pending_lock:
                msg = self.gallery_images.get(round(item.t_s * 1e4))
            if msg is None:
                self.gallery_missing += 1
                continue
            try:
                self.gallery_tiles[item.key] = crop_tile(image_from_msg(msg), item)
            except ScenarioError as err:
                rospy.logwarn_throttle(30.0, f"scorer: no gallery crop: {err}")

    def _publish_gallery(self) -> None:
        """The gallery's mosaic (worst false positives, then worst misses), once, at the end."""
        with self.lock:
            kept = [i for i in self.scorer.gallery_items() if i.key in self.gallery_tiles]
        tiles: dict[str, list[Any]] = {}
        for item in kept:
            tiles.setdefault(item.kind, []).append(self.gallery_tiles[item.key])
        image = mosaic(tiles, self.scenario.scoring.gallery_size)
        if image is not None:
            stamp = rospy.Time.from_sec(self.end_s if self.end_s is not None else rospy.get_time())
            self.pubs["gallery"].publish(image_msg(image, "rgb8", Header(stamp=stamp, frame_id="gallery")))

    def on_insert_stats(self, msg: MapInsertStats) -> None:
        """Totals since the map server started: how many clouds reached the map (dropped ones cost coverage)."""
        dropped = {
            "queue_full": int(msg.clouds_dropped_queue_full),
            "no_transform": int(msg.clouds_dropped_no_transform),
            "empty": int(msg.clouds_dropped_empty),
            "bad_layout": int(msg.clouds_dropped_bad_layout),
            "too_large": int(msg.clouds_dropped_too_large),
            "unsynchronized": int(msg.clouds_dropped_unsynchronized),
        }
        with self.lock:
            if int(msg.clouds_inserted) + sum(dropped.values()) >= self.map_input.get("clouds_received", 0):
                self.map_input = {
                    "clouds_received": int(msg.clouds_inserted) + sum(dropped.values()),
                    "clouds_inserted": int(msg.clouds_inserted),
                    **{f"dropped_{k}": v for k, v in dropped.items()},
                }

    def on_controller(self, msg: ControllerState) -> None:
        sample = controller_from_msg(msg, rospy.get_time())
        self._push(sample.t_s, "add_controller", sample)

    def on_status(self, msg: ScenarioStatus) -> None:
        t = msg.header.stamp.to_sec()
        with self.lock:
            if self.start_s is None:
                self.start_s = t - msg.sim_time_s
                self.scorer.start_t_s = self.start_s  # the run starts with the mission, not the first record
            self.scorer.set_candidates_rejected(t, int(getattr(msg, "candidates_rejected", 0)))
            if msg.target_found:
                p = msg.target_position
                self.scorer.mark_confirmed(t, (p.x, p.y, p.z))
            if math.isfinite(msg.complete_time_s):
                self.scorer.mark_complete(
                    self.start_s + msg.complete_time_s, "person confirmed" if msg.target_found else "mission complete"
                )
            first_stop = msg.stop and not self.stopped
            if first_stop:
                self.stopped = True
                self.scorer.add_event(t, f"stop: {msg.stop_reason}")
        if first_stop:
            with self._pending_lock:
                self.end_s = t
            # The final metrics are taken at the stop instant (not whenever a callback runs), so a live run
            # and its replay end on the same sample; records stamped up to the stop may still be on their
            # way, so the summary is made at the first /clock 2 x HOLD_S later (on_clock), and the map is
            # exported then (in the causal lockstep the final export is started now, when the stop is seen, and
            # taken a lookahead later: the map as it is then, in every run).
            self._finish_at_s = t + 2 * HOLD_S
            if self.ls.causal:
                self._final_export = self._start_export(t)

    def on_clock(self, msg: Clock) -> None:
        self._finish_due(msg.clock.to_sec())

    def _finish_due(self, now: float) -> None:
        at = self._finish_at_s
        if at is None or self.finished or now < at:
            return
        final = self._final_export
        if final is not None and (self.ls.processing_step or 0) < final[0]:
            return  # causal lockstep: the final export's answer is taken at its step
        assert self.end_s is not None
        self.finish(at_s=self.end_s)

    def on_tick(self, now: float) -> None:
        if now <= 0 or self.finished or self._finish_lock.locked() or self.end_s is not None:
            return
        if now >= self._next_accuracy_s:
            # In this callback, not in a thread: the value lands in the same row of every run (in the causal
            # lockstep it is started here and taken a lookahead later, in the same step of every run).
            self._next_accuracy_s = now + self.scenario.scoring.map_accuracy_period_s
            self._map_accuracy(now, wait=not self.ls.causal)
        scored_to = now - HOLD_S
        self._flush_scored(scored_to)
        elapsed = now - self.start_s if self.start_s is not None else None
        tracking = now >= self._next_tracking_s
        if tracking:
            self._next_tracking_s = now + max(TRACKING_PERIOD_S, elapsed or 0.0)
        self._emit(scored_to, tracking=tracking)
        if elapsed is None or not self.snapshots_due:
            return
        if elapsed >= self.snapshots_due[0] - 1.0 / self.scenario.scoring.metrics_rate_hz and not self.image_subs:
            self._grab_images()
        if elapsed >= self.snapshots_due[0]:
            self.snapshots_due.pop(0)
            self._publish_grids()

    # ---- map accuracy ----------------------------------------------------------------------

    def _map_accuracy(self, t_s: float, *, wait: bool = False) -> None:
        """Export the map's occupied voxels and compare them with the truth (off every lock but our own).

        In the causal lockstep an export during the run is started here and taken ``L`` steps later
        (:meth:`_take_exports`): the map server applies it at the boundary the protocol names, and a scorer with a
        long lookahead would stand still until then. The final one (``wait``) is taken at once."""
        if self.ls.causal and not wait:
            started = self._start_export(t_s)
            if started is not None:
                self._exports.append(started)
            return
        if not self._accuracy_busy.acquire(blocking=wait):
            return  # the previous export is still running
        try:
            self._take_exports(math.inf)  # any export still on its way comes first
            service = f"{self.map_server_ns}/export_occupied"
            path = self._export_path()
            try:
                request = ExportVoxelsRequest(path=str(path), resolution_m=self.scenario.map.resolution_m)
                resp = self.ls.call(service, ExportVoxels, request, wait_s=1.0)
            except (rospy.ROSException, rospy.ServiceException) as err:
                rospy.logwarn_throttle(30.0, f"scorer: {service} unavailable ({err}); no map IoU yet")
                return
            self._apply_export(t_s, path, resp, final=wait)
        finally:
            self._accuracy_busy.release()

    def _export_path(self) -> Path:
        self._exports_made += 1
        return self._export_dir / f"occupied_{self._exports_made}.npy"

    def _start_export(self, t_s: float) -> tuple[int, float, Path, Any] | None:
        """Causal lockstep: start an export (``call_later``); the periodic ones are queued for their step."""
        if self.scorer.truth.surface_keys.size == 0:
            return None
        path = self._export_path()
        request = ExportVoxelsRequest(path=str(path), resolution_m=self.scenario.map.resolution_m)
        due, future = self.ls.call_later(f"{self.map_server_ns}/export_occupied", ExportVoxels, request, wait_s=1.0)
        return due, t_s, path, future

    def _take_exports(self, step: float) -> None:
        """Causal lockstep: the exports due by ``step`` (their answers are there: the map server applied them at
        the boundary the protocol names), in the order they were started."""
        while self._exports and self._exports[0][0] <= step:
            _due, t_s, path, future = self._exports.pop(0)
            try:
                resp = future.result()
            except (rospy.ROSException, rospy.ServiceException) as err:
                rospy.logwarn_throttle(30.0, f"scorer: {self.map_server_ns}/export_occupied failed ({err}); no map IoU")
                continue
            self._apply_export(t_s, path, resp, final=False)

    def _apply_export(self, t_s: float, path: Path, resp: Any, *, final: bool) -> None:
        truth = self.scorer.truth  # one truth for the keys and their columns (it is replaced once loaded)
        truth_keys = truth.surface_keys
        if truth_keys.size == 0:
            return
        if not resp.success:
            rospy.logwarn_throttle(30.0, f"scorer: {self.map_server_ns}/export_occupied failed: {resp.message}")
            return
        try:
            cells = np.load(path)
        except (OSError, ValueError) as err:
            rospy.logwarn_throttle(30.0, f"scorer: cannot read the exported voxels {path}: {err}")
            return
        path.unlink(missing_ok=True)
        keys = voxel_keys_from_indices(cells.reshape(-1, 3))
        accuracy = voxel_accuracy(keys, truth_keys, truth.surface_columns)
        with self.lock:
            if not self.finished or final:
                self.scorer.set_map_accuracy(t_s, accuracy)
                self.scorer.evaluate_trails(t_s, keys)

    # ---- output --------------------------------------------------------------------------

    def _summary(self, now: float, *, tracking: bool = True) -> tuple[dict[str, Any], dict[str, Any]]:
        with self.lock:
            row = self.scorer.sample(now)
            summary = self.scorer.summary(now, tracking=tracking, coco=self._final)
        if self.gallery_missing:
            summary["detection"]["gallery_crops_missing"] = self.gallery_missing
        summary["scenario"] = self.scenario.name
        summary["stop_reason"] = next(
            (e["what"][6:] for e in reversed(summary["events"]) if e["what"].startswith("stop: ")), ""
        )
        summary["world"] = self.world_info
        with self.lock:
            summary["map_input"] = dict(self.map_input)
        if self.person:
            summary["person"] = dict(self.person)
        if self.truth_note:
            summary["notes"] = [self.truth_note]
        summary["versions"] = self.versions
        summary["final"] = self._final
        return row, summary

    def _emit(self, now: float, *, tracking: bool = True) -> None:
        row, summary = self._summary(now, tracking=tracking)
        self.rows.append(row)
        if self.metrics_pub is not None:
            self.metrics_pub.publish(metrics_msg(rospy.Time.from_sec(now), row, summary))
        if self.run_dir is not None:
            self._write(summary)

    def _write(self, summary: dict[str, Any]) -> None:
        assert self.run_dir is not None
        try:
            write_atomic(self.run_dir / "metrics.json", json.dumps(json_safe(summary), indent=2))
            self._write_rows()
        except OSError as err:
            rospy.logerr_throttle(30.0, f"scorer: cannot write metrics to {self.run_dir}: {err}")

    def _write_rows(self) -> None:
        """The time series: new rows are appended (rewriting it every tick grew with the run); it is written
        whole, atomically, when it starts or its columns change."""
        assert self.run_dir is not None
        path = self.run_dir / "timeseries.csv"
        fields = list(self.rows[0])
        whole = self._csv_fields != fields or any(list(r) != fields for r in self.rows[self._csv_rows :])
        if whole:
            tmp = path.with_suffix(".csv.tmp")
            with tmp.open("w", newline="") as fh:
                writer = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
                writer.writeheader()
                writer.writerows(self.rows)
            os.replace(tmp, path)
        else:
            buf = io.StringIO()  # one write() per tick: a reader sees whole rows
            csv.DictWriter(buf, fieldnames=fields).writerows(self.rows[self._csv_rows :])
            with path.open("a", newline="") as fh:
                fh.write(buf.getvalue())
        self._csv_fields = fields
        self._csv_rows = len(self.rows)

    def _grab_images(self) -> None:
        for cam in self.cameras:
            for kind, suffix in IMAGE_KINDS.items():
                topic = f"/cameras/{cam}/{suffix}"
                holder: dict[str, rospy.Subscriber] = {}

                def once(msg: Image, key: str = f"{cam}/{kind}", holder: dict[str, rospy.Subscriber] = holder) -> None:
                    sub = holder.pop("sub", None)
                    if sub is None:
                        return
                    sub.unregister()
                    self.pubs[key].publish(msg)

                # In the causal lockstep the topic may be a counted input of this node too: rospy shares one queue
                # per topic in a node, so this must not bound it (queue_size None keeps it as it is).
                queue = None if self.ls.causal else 1
                holder["sub"] = rospy.Subscriber(topic, Image, once, queue_size=queue, buff_size=2**24)
                self.image_subs.append(holder["sub"])

    def _publish_grids(self) -> None:
        self.image_subs = []
        max_cells = self.scenario.scoring.snapshot_max_cells
        if self.last_layers is not None:
            self.pubs["layers"].publish(downsampled_layers_msg(self.last_layers, max_cells))
        if self.last_features is not None:
            self.pubs["features"].publish(downsampled_layers_msg(self.last_features, max_cells))

    def finish(self, at_s: float | None = None) -> None:
        """Final map accuracy, metrics (``"final": true``) and snapshots, once (stop status or shutdown)."""
        with self._finish_lock:
            if self.finished:
                return
            now = at_s if at_s is not None else (self.end_s if self.end_s is not None else rospy.get_time())
            self._flush_scored(now)
            final, self._final_export = self._final_export, None
            if final is not None:  # causal lockstep: started at the stop, taken now
                self._take_exports(math.inf)
                self._exports.append(final)
                self._take_exports(math.inf)
            elif now > 0 and not rospy.is_shutdown():
                self._map_accuracy(now, wait=True)
            if now > 0:
                self._publish_grids()
                self._final = True
                self._emit(now)
                self._publish_gallery()
            self.finished = True


def main() -> None:
    run_participant("scorer", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(ScenarioError,))


def _build(ls: Participant) -> None:
    params = node_params(ScorerParams, "scorer")
    scenario = load_scenario(Path(params.scenario))
    run_dir = Path(params.run_dir) if params.run_dir else None
    if run_dir is not None:
        try:
            run_dir.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            msg = f"~run_dir {run_dir}: cannot create it: {err.strerror}"
            raise ScenarioConfigError(msg) from err
    run = params.run
    node = ScorerNode(
        scenario,
        run_dir,
        list(params.cameras),
        person=dict(run.person),
        camera_pitch_deg=dict(run.camera_pitch_deg),
        map_camera_hfov_deg=run.map_camera_hfov_deg,
        map_camera_aspect=run.map_camera_aspect,
        world_cache_dir=Path(params.world_cache_dir).expanduser() if params.world_cache_dir else None,
        map_server_ns=params.map_server,
    )
    node.start(ls)
