"""tracker: a position-only multi-object tracker over a detection topic.

ROS interface:

Subscribes:
    ``~detections`` (uav_msgs/DetectionArray, default ``/geolocator/detections``: any detector's boxes
    placed in map by the geolocator): only frames from ``~camera`` are tracked; a detection needs a
    ``position`` (map ENU) and a score of at least ``~min_score``; the others are counted and reported
    in every TrackArray (``detections_unplaced``, ``detections_below_threshold``).
    ``/scenario/status`` (uav_msgs/ScenarioStatus): the tracker starts afresh when the run starts and
    ignores frames from before (so a live run and its replay track the same frames); frames that
    arrive before the first status are held and tracked once it comes, if they belong to the run.
Publishes:
    ``/scenario/tracks`` (uav_msgs/TrackArray): confirmed tracks after each frame, stamped
    with the frame's stamp (so the scorer pairs them with the ground truth of that image).
Parameters:
    ``~camera`` (str, default ``forward``); ``~gate_m`` (float, 5.0); ``~min_hits`` (int, 2);
    ``~max_coast_s`` (float, 3.0); ``~min_score`` (float, 0.0: the operating threshold); ``~detections`` (str).
    Any other private parameter stops the node (exit code 2).

The tracker never reads ground-truth ids: identities are its own (core: ``tracking.PositionTracker``).
Causal lockstep (docs/lockstep.md): a participant with a lookahead of 2 steps.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Any

import rospy

from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import DetectionArray, ScenarioStatus, TrackArray
from uav_scenarios.core.tracking import PositionTracker, TrackerConfig
from uav_scenarios.errors import ScenarioConfigError, ScenarioError, ScoringError
from uav_scenarios.ros.messages import tracks_msg
from uav_scenarios.ros.params import TrackerParams
from uav_scenarios.ros.records import detections_from_msg

#: Frames kept while the run's start is unknown (a frame may arrive just before the first status).
EARLY_FRAMES = 50
#: Steps between its inputs and when its tracks are consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 2


class TrackerNode:
    def __init__(self, camera: str, config: TrackerConfig) -> None:
        self.camera = camera
        self.tracker = PositionTracker(config)
        self.pub: Any = None
        self.run_start_s: float | None = None
        self.lock = threading.Lock()
        self.early: deque[DetectionArray] = deque(maxlen=EARLY_FRAMES)

    def start(self, ls: Participant, detections_topic: str) -> None:
        self.pub = ls.publisher("/scenario/tracks", TrackArray, queue_size=200)
        ls.subscribe(detections_topic, DetectionArray, self.on_detections, queue_size=200)
        ls.subscribe("/scenario/status", ScenarioStatus, self.on_status, queue_size=10)

    def on_status(self, msg: ScenarioStatus) -> None:
        with self.lock:
            if self.run_start_s is not None:
                return
            self.run_start_s = msg.header.stamp.to_sec() - msg.sim_time_s
            self.tracker = PositionTracker(self.tracker.config)
            # frames of the run that overtook the first status (separate connections are not ordered)
            early = sorted(self.early, key=lambda m: m.header.stamp.to_sec())
            self.early.clear()
            for frame_msg in early:
                self._track(frame_msg)

    def on_detections(self, msg: DetectionArray) -> None:
        with self.lock:
            if self.run_start_s is None:
                self.early.append(msg)
                return
            self._track(msg)

    def _track(self, msg: DetectionArray) -> None:
        frame = detections_from_msg(msg)
        if frame.camera != self.camera or self.pub is None:
            return
        if self.run_start_s is None or frame.t_s < self.run_start_s:
            return
        try:
            tracks = self.tracker.update(frame.t_s, frame.detections)
        except ScoringError as err:  # e.g. /clock jumped back after a bag loop: start over
            rospy.logwarn_throttle(5.0, f"tracker reset: {err}")
            self.tracker = PositionTracker(self.tracker.config)
            tracks = self.tracker.update(frame.t_s, frame.detections)
        tr = self.tracker
        self.pub.publish(
            tracks_msg(
                msg.header.stamp,
                frame.camera,
                tracks,
                received=tr.received,
                unplaced=tr.unplaced,
                below_threshold=tr.below_threshold,
            )
        )
        if tr.unplaced and frame.detections and not all(d.placed for d in frame.detections):
            rospy.logwarn_throttle(
                30.0, f"tracker: {tr.unplaced} of {tr.received} detections so far had no position and were not tracked"
            )


def main() -> None:
    run_participant("tracker", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(ScenarioError,))


def _build(ls: Participant) -> None:
    params = node_params(TrackerParams, "tracker")
    try:
        config = TrackerConfig(
            gate_m=params.gate_m, min_hits=params.min_hits, max_coast_s=params.max_coast_s, min_score=params.min_score
        )
    except ValueError as err:
        msg = f"tracker: bad parameter: {err}"
        raise ScenarioConfigError(msg) from err
    node = TrackerNode(params.camera, config)
    node.start(ls, params.detections)
