"""scorer: scores a scenario run live (or in a ``rosbag play`` replay) and writes its metrics.

ROS interface:

Subscribes:
    ``/uav/ground_truth/odom`` (nav_msgs/Odometry), ``/uav/battery`` (sensor_msgs/BatteryState),
    ``/map_server/layers`` (uav_msgs/GridLayers), ``/autonomy/features`` (uav_msgs/GridLayers),
    ``/detections/ground_truth`` and the scenario's ``search.detection_topic`` (uav_msgs/DetectionArray),
    ``/scenario/tracks`` (uav_msgs/TrackArray), ``/sim/collision`` (uav_msgs/Collision),
    ``/autonomy/goal_reason`` (uav_msgs/GoalReason), ``/uav/controller/state`` (uav_msgs/ControllerState),
    ``/scenario/status`` (uav_msgs/ScenarioStatus: run start, completion, stop);
    camera images ``/cameras/<cam>/{color,depth,instance}/image_raw`` only around snapshot times.
Publishes:
    ``/scenario/metrics`` (uav_msgs/RunMetrics) at ``scoring.metrics_rate_hz`` (sim time) and once at the end;
    ``/scenario/snapshot/layers`` and ``/scenario/snapshot/features`` (uav_msgs/GridLayers) and
    ``/scenario/snapshot/<cam>/{color,depth,instance}`` (sensor_msgs/Image) at ``scoring.snapshot_times_s``
    and at the end, for the report.
Parameters:
    ``~scenario`` (str, required): the scenario file.
    ``~run_dir`` (str, default ""): where ``metrics.json`` and ``timeseries.csv`` are written
    (atomically, every metrics period, so a crash keeps what was scored); "" writes nothing.
    ``~cameras`` (list, default [nadir, forward]).

Scoring itself is :class:`uav_autonomy.core.scoring_run.RunScorer`.
"""

from __future__ import annotations

import csv
import json
import math
import os
import sys
import threading
from pathlib import Path
from typing import Any

import rospy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import BatteryState, Image

from uav_autonomy.core.scenario_config import Scenario, load_scenario
from uav_autonomy.core.scenario_errors import ScenarioError
from uav_autonomy.core.scoring_convert import (
    battery_from_msg,
    collision_from_msg,
    controller_from_msg,
    detections_from_msg,
    goal_from_msg,
    grid_from_msg,
    pose_from_odometry,
    tracks_from_msg,
)
from uav_autonomy.core.scoring_run import RunScorer
from uav_autonomy.core.scoring_types import SceneTruth
from uav_autonomy.ros.scoring_msgs import json_safe, metrics_msg
from uav_common.config import ConfigError
from uav_msgs.msg import (
    Collision,
    ControllerState,
    DetectionArray,
    GoalReason,
    GridLayers,
    RunMetrics,
    ScenarioStatus,
    TrackArray,
)

IMAGE_KINDS = {"color": "color/image_raw", "depth": "depth/image_raw", "instance": "instance/image_raw"}


def default_truth(scenario: Scenario) -> SceneTruth:
    """The scene's bounds from the scenario (square of ``world.size_m`` around home)."""
    half = scenario.world.size_m / 2.0
    return SceneTruth(bounds_m=(-half, -half, half, half))


def write_atomic(path: Path, text: str) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


class ScorerNode:
    def __init__(self, scenario: Scenario, run_dir: Path | None, cameras: list[str]) -> None:
        self.scenario = scenario
        self.run_dir = run_dir
        self.cameras = cameras
        search = scenario.search
        self.detection_topic = search.detection_topic if search else "/detections/ground_truth"
        self.scorer = RunScorer(
            spec=scenario.scoring,
            truth=default_truth(scenario),
            detection_source="ground_truth" if self.detection_topic == "/detections/ground_truth" else "detector",
            tracked_camera=search.camera if search else "forward",
            cruise_speed_mps=scenario.autonomy.cruise_speed_mps,
        )
        self.lock = threading.Lock()
        self.start_s: float | None = None
        self.stopped = False
        self.finished = False
        self.rows: list[dict[str, Any]] = []
        self.snapshots_due = list(scenario.scoring.snapshot_times_s)
        self.last_layers: GridLayers | None = None
        self.last_features: GridLayers | None = None
        self.image_subs: list[rospy.Subscriber] = []
        self.pubs: dict[str, rospy.Publisher] = {}
        self.metrics_pub: rospy.Publisher | None = None

    # ---- wiring --------------------------------------------------------------------------

    def start(self) -> None:
        self.metrics_pub = rospy.Publisher("/scenario/metrics", RunMetrics, queue_size=5, latch=True)
        self.pubs["layers"] = rospy.Publisher("/scenario/snapshot/layers", GridLayers, queue_size=2, latch=True)
        self.pubs["features"] = rospy.Publisher("/scenario/snapshot/features", GridLayers, queue_size=2, latch=True)
        for cam in self.cameras:
            for kind in IMAGE_KINDS:
                self.pubs[f"{cam}/{kind}"] = rospy.Publisher(
                    f"/scenario/snapshot/{cam}/{kind}", Image, queue_size=2, latch=True
                )
        sub = rospy.Subscriber
        sub("/uav/ground_truth/odom", Odometry, self._feed(pose_from_odometry, "add_pose"), queue_size=50)
        sub("/uav/battery", BatteryState, self._feed(battery_from_msg, "add_battery"), queue_size=10)
        sub("/map_server/layers", GridLayers, self.on_layers, queue_size=1, buff_size=2**24)
        sub("/autonomy/features", GridLayers, self.on_features, queue_size=1, buff_size=2**24)
        sub("/detections/ground_truth", DetectionArray, self.on_truth_detections, queue_size=50)
        if self.detection_topic != "/detections/ground_truth":
            sub(self.detection_topic, DetectionArray, self.on_detector, queue_size=50)
        sub("/scenario/tracks", TrackArray, self._feed(tracks_from_msg, "add_tracks"), queue_size=50)
        sub("/sim/collision", Collision, self._feed(collision_from_msg, "add_collision"), queue_size=10)
        sub("/autonomy/goal_reason", GoalReason, self._feed(goal_from_msg, "add_goal"), queue_size=10)
        sub("/uav/controller/state", ControllerState, self.on_controller, queue_size=10)
        sub("/scenario/status", ScenarioStatus, self.on_status, queue_size=10)
        rospy.Timer(rospy.Duration(1.0 / self.scenario.scoring.metrics_rate_hz), self.on_tick)
        rospy.on_shutdown(self.finish)

    def _feed(self, convert: Any, method: str) -> Any:
        def callback(msg: Any) -> None:
            record = convert(msg)
            with self.lock:
                if not self.finished:
                    getattr(self.scorer, method)(record)

        return callback

    # ---- callbacks -----------------------------------------------------------------------

    def on_layers(self, msg: GridLayers) -> None:
        self.last_layers = msg
        self._feed(grid_from_msg, "add_layers")(msg)

    def on_features(self, msg: GridLayers) -> None:
        self.last_features = msg

    def on_truth_detections(self, msg: DetectionArray) -> None:
        frame = detections_from_msg(msg)
        with self.lock:
            self.scorer.add_detections(frame, is_truth=True)

    def on_detector(self, msg: DetectionArray) -> None:
        frame = detections_from_msg(msg)
        with self.lock:
            self.scorer.add_detections(frame, is_truth=False)

    def on_controller(self, msg: ControllerState) -> None:
        sample = controller_from_msg(msg, rospy.get_time())
        with self.lock:
            self.scorer.add_controller(sample)

    def on_status(self, msg: ScenarioStatus) -> None:
        t = msg.header.stamp.to_sec()
        with self.lock:
            if self.start_s is None:
                self.start_s = t - msg.sim_time_s
                self.scorer.start_t_s = self.start_s  # the run starts with the mission, not the first record
            if math.isfinite(msg.complete_time_s):
                self.scorer.mark_complete(
                    self.start_s + msg.complete_time_s, "person confirmed" if msg.target_found else "mission complete"
                )
            if msg.stop and not self.stopped:
                self.stopped = True
                self.scorer.add_event(t, f"stop: {msg.stop_reason}")
        if msg.stop:
            self.finish()

    def on_tick(self, _event: rospy.timer.TimerEvent) -> None:
        now = rospy.get_time()
        if now <= 0 or self.finished:
            return
        self._emit(now)
        elapsed = now - self.start_s if self.start_s is not None else None
        if elapsed is None or not self.snapshots_due:
            return
        if elapsed >= self.snapshots_due[0] - 1.0 / self.scenario.scoring.metrics_rate_hz and not self.image_subs:
            self._grab_images()
        if elapsed >= self.snapshots_due[0]:
            self.snapshots_due.pop(0)
            self._publish_grids()

    # ---- output --------------------------------------------------------------------------

    def _emit(self, now: float) -> None:
        with self.lock:
            row = self.scorer.sample(now)
            summary = self.scorer.summary(now)
        summary["scenario"] = self.scenario.name
        summary["stop_reason"] = next(
            (e["what"][6:] for e in reversed(summary["events"]) if e["what"].startswith("stop: ")), ""
        )
        self.rows.append(row)
        if self.metrics_pub is not None:
            self.metrics_pub.publish(metrics_msg(rospy.Time.from_sec(now), row, summary))
        if self.run_dir is not None:
            self._write(summary)

    def _write(self, summary: dict[str, Any]) -> None:
        assert self.run_dir is not None
        try:
            write_atomic(self.run_dir / "metrics.json", json.dumps(json_safe(summary), indent=2))
            tmp = self.run_dir / "timeseries.csv.tmp"
            with tmp.open("w", newline="") as fh:
                writer = csv.DictWriter(fh, fieldnames=list(self.rows[0]))
                writer.writeheader()
                writer.writerows(self.rows)
            os.replace(tmp, self.run_dir / "timeseries.csv")
        except OSError as err:
            rospy.logerr_throttle(30.0, f"scorer: cannot write metrics to {self.run_dir}: {err}")

    def _grab_images(self) -> None:
        for cam in self.cameras:
            for kind, suffix in IMAGE_KINDS.items():
                topic = f"/cameras/{cam}/{suffix}"
                holder: dict[str, rospy.Subscriber] = {}

                def once(msg: Image, key: str = f"{cam}/{kind}", holder: dict[str, rospy.Subscriber] = holder) -> None:
                    self.pubs[key].publish(msg)
                    sub = holder.pop("sub", None)
                    if sub is not None:
                        sub.unregister()

                holder["sub"] = rospy.Subscriber(topic, Image, once, queue_size=1, buff_size=2**24)
                self.image_subs.append(holder["sub"])

    def _publish_grids(self) -> None:
        self.image_subs = []
        if self.last_layers is not None:
            self.pubs["layers"].publish(self.last_layers)
        if self.last_features is not None:
            self.pubs["features"].publish(self.last_features)

    def finish(self) -> None:
        """Final metrics and snapshots; idempotent (stop status, then shutdown)."""
        if self.finished:
            return
        now = rospy.get_time()
        if now > 0:
            self._publish_grids()
            self._emit(now)
        self.finished = True


def main() -> None:
    rospy.init_node("scorer")
    try:
        scenario = load_scenario(Path(rospy.get_param("~scenario")))
    except KeyError:
        rospy.logfatal("scorer: the ~scenario parameter (path of the scenario file) is required")
        sys.exit(2)
    except (ConfigError, ScenarioError) as err:
        rospy.logfatal(f"scorer: {err}")
        sys.exit(2)
    run_dir_text = str(rospy.get_param("~run_dir", ""))
    run_dir = Path(run_dir_text) if run_dir_text else None
    if run_dir is not None:
        run_dir.mkdir(parents=True, exist_ok=True)
    node = ScorerNode(scenario, run_dir, list(rospy.get_param("~cameras", ["nadir", "forward"])))
    node.start()
    rospy.spin()
