"""depth_evaluator: per-frame accuracy of estimated depth against ground truth.

Every estimated depth image is compared with the ground-truth depth of the same
camera at the same stamp (``uav_perception.core.depth.metrics``): coverage, share
within the absolute and relative tolerances, delta < 1.25, AbsRel, RMSE, overall
and per ground-truth range band and per class (from the instance image and the
world's object list).

ROS interface:

Subscribes:
    ``~estimate_topic`` (sensor_msgs/Image 32FC1, default ``/depth_estimator/depth/image_raw``).
    ``/cameras/<camera>/depth/image_raw`` (sensor_msgs/Image 32FC1, ground truth).
    ``/cameras/<camera>/instance/image_raw`` (sensor_msgs/Image 16UC1), for the per-class breakdown.
Publishes:
    ``~metrics`` (uav_msgs/DepthMetrics), one per evaluated estimate.
Parameters:
    ``~config`` (str, default: the project's ``config/depth.yaml``), section ``evaluator``;
    ``~overrides`` (dict, default {}).
    ``~camera`` (str, default ``nadir``).
    ``~estimate_topic`` (str, default ``/depth_estimator/depth/image_raw``).
    ``~objects_file`` (str, default ""): the world's object list (``objects.json``:
    ``instance_id`` -> ``class``). When empty, ``<world_dir>/objects.json`` is used as soon
    as the parameter named by ``~world_dir_param`` (default ``/sim_bridge/world_dir``, set by
    the sim bridge) exists. Without an object list the per-class entries are empty.
    ``~run_dir`` (str, default ""): when set, per-frame JSON lines go to
    ``<run_dir>/depth_metrics.jsonl`` and the aggregate to ``<run_dir>/depth_summary.json``.
    Any other private parameter stops the node (exit code 2, docs/architecture.md).

An estimate waits (at most ``_MAX_PENDING`` of them) until ground truth with its
stamp (within ``max_stamp_diff_s``) arrives; once the ground-truth stream has
moved ``_GIVE_UP_S`` past it, the estimate is dropped and counted.

Causal lockstep (docs/lockstep.md): a participant with a lookahead of 3 steps (its inputs are counted, so what
it evaluates is the same in every run).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import numpy as np
import numpy.typing as npt
import rospy
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from uav_common.ros.arrays import MessageLayoutError, image_to_depth_m, image_to_ids
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import DepthMetrics
from uav_perception.core.depth.config import EvaluatorConfig
from uav_perception.core.depth.metrics import class_index_image, class_lut, evaluate_depth
from uav_perception.core.depth.sync import StampBuffer
from uav_perception.errors import DepthError, PerceptionConfigError, PerceptionError
from uav_perception.ros.conversions import instance_classes_from_json, metrics_msg
from uav_perception.ros.params import EvaluatorParams, depth_section
from uav_perception.shell.runlog import DepthRunLog

_TRUTH_CAPACITY = 40
_MAX_PENDING = 20
_GIVE_UP_S = 2.0
_SUMMARY_EVERY = 20

T = TypeVar("T")


class DepthEvaluatorNode:
    """Pairs estimates with ground truth by stamp and publishes/logs the metrics."""

    def __init__(
        self,
        config: EvaluatorConfig,
        *,
        camera_name: str,
        estimate_topic: str,
        lut: npt.NDArray[np.int16] | None,
        run_log: DepthRunLog | None,
        world_dir_param: str = "",
    ) -> None:
        self.config = config
        self.camera_name = camera_name
        self.estimate_topic = estimate_topic
        self.lut = lut
        self.run_log = run_log
        self.world_dir_param = world_dir_param
        self._next_lut_try_s = 0.0
        self._lock = threading.Lock()
        self._truth: StampBuffer[npt.NDArray[np.float32]] = StampBuffer(_TRUTH_CAPACITY)
        self._instances: StampBuffer[npt.NDArray[np.uint16]] = StampBuffer(_TRUTH_CAPACITY)
        self._pending: deque[tuple[Header, npt.NDArray[np.float32]]] = deque()
        self.evaluated = 0
        self.dropped_no_truth = 0
        self.bad_input = 0

    def start(self, ls: Participant) -> None:
        """Publishers and subscribers."""
        self.pub = ls.publisher("~metrics", DepthMetrics, queue_size=10)
        base = f"/cameras/{self.camera_name}"
        ls.subscribe(f"{base}/depth/image_raw", Image, self.on_truth, queue_size=10, buff_size=2**25)
        if self.lut is not None or self.world_dir_param:
            ls.subscribe(f"{base}/instance/image_raw", Image, self.on_instances, queue_size=10, buff_size=2**24)
        ls.subscribe(self.estimate_topic, Image, self.on_estimate, queue_size=10, buff_size=2**25)
        rospy.on_shutdown(self.shutdown)

    def on_truth(self, msg: Image) -> None:
        depth = self._convert(msg, image_to_depth_m)
        if depth is None:
            return
        with self._lock:
            self._truth.put(msg.header.stamp.to_nsec(), depth)
        self._drain()

    def on_instances(self, msg: Image) -> None:
        inst = self._convert(msg, image_to_ids)
        if inst is None:
            return
        with self._lock:
            self._instances.put(msg.header.stamp.to_nsec(), inst)
        self._drain()

    def _ensure_lut(self) -> None:
        """Load the object list named by the sim bridge's world folder, once it is known (retried every 5 s)."""
        if self.lut is not None or not self.world_dir_param or time.monotonic() < self._next_lut_try_s:
            return
        self._next_lut_try_s = time.monotonic() + 5.0
        world_dir = rospy.get_param(self.world_dir_param, "")
        if not world_dir:
            return
        try:
            lut = _load_lut(str(Path(world_dir) / "objects.json"), self.config)
        except PerceptionConfigError as err:
            rospy.logwarn_throttle(30.0, f"depth_evaluator: no per-class metrics: {err}")
            return
        with self._lock:
            self.lut = lut
        rospy.loginfo(f"depth_evaluator: classes from {world_dir}/objects.json")

    def on_estimate(self, msg: Image) -> None:
        self._ensure_lut()
        est = self._convert(msg, image_to_depth_m)
        if est is None:
            return
        with self._lock:
            self._pending.append((msg.header, est))
            while len(self._pending) > _MAX_PENDING:
                self._pending.popleft()
                self.dropped_no_truth += 1
        self._drain()

    def _convert(self, msg: Image, fn: Callable[[Image], T]) -> T | None:
        try:
            return fn(msg)
        except (DepthError, MessageLayoutError) as err:
            with self._lock:
                self.bad_input += 1
            rospy.logwarn_throttle(5.0, f"depth_evaluator: image on {msg.header.frame_id!r} skipped: {err}")
            return None

    def _drain(self) -> None:
        """Evaluate every pending estimate whose ground truth is here; drop hopeless ones."""
        tol_ns = round(self.config.max_stamp_diff_s * 1e9)
        ready = []
        with self._lock:
            newest_truth = self._truth.newest_stamp_ns()
            newest_inst = self._instances.newest_stamp_ns()
            keep: deque[tuple[Header, npt.NDArray[np.float32]]] = deque()
            for header, est in self._pending:
                stamp = header.stamp.to_nsec()
                found = self._truth.closest(stamp, tol_ns)
                inst_ready = self.lut is None or (newest_inst is not None and newest_inst >= stamp - tol_ns)
                give_up = newest_truth is not None and newest_truth > stamp + round(_GIVE_UP_S * 1e9)
                if found is not None and (inst_ready or give_up):
                    ready.append((header, est, found, self._instances.closest(stamp, tol_ns)))
                elif give_up:
                    self.dropped_no_truth += 1
                else:
                    keep.append((header, est))
            self._pending = keep
        for header, est, (truth_stamp_ns, truth_m), inst in ready:
            self._evaluate(header, est, truth_stamp_ns, truth_m, inst)

    def _evaluate(
        self,
        header: Header,
        est: npt.NDArray[np.float32],
        truth_stamp_ns: int,
        truth: npt.NDArray[np.float32],
        inst: tuple[int, npt.NDArray[np.uint16]] | None,
    ) -> None:
        classes = None
        if self.lut is not None and inst is not None and inst[1].shape == truth.shape:
            classes = class_index_image(inst[1], self.lut)
        try:
            evaluation = evaluate_depth(est, truth, self.config, classes)
        except DepthError as err:
            with self._lock:
                self.bad_input += 1
            rospy.logwarn_throttle(5.0, f"depth_evaluator: estimate skipped: {err}")
            return
        stamp_diff_s = abs(header.stamp.to_nsec() - truth_stamp_ns) * 1e-9
        self.evaluated += 1
        # The run log first: a frame evaluated while the node shuts down is still kept (the log appends it
        # after its close too).
        if self.run_log is not None:
            self.run_log.add(header.stamp.to_sec(), stamp_diff_s, evaluation)
            if self.evaluated % _SUMMARY_EVERY == 0:
                self.run_log.write_summary(self._counters())
        try:
            self.pub.publish(metrics_msg(evaluation, header, self.camera_name, self.config, stamp_diff_s))
        except rospy.ROSException:
            if not rospy.is_shutdown():
                raise
            # rospy closed the topic under this callback during shutdown; the run log has the frame.

    def _counters(self) -> dict[str, int]:
        return {"dropped_no_truth": self.dropped_no_truth, "bad_input": self.bad_input}

    def shutdown(self) -> None:
        """Write the final summary."""
        if self.run_log is not None:
            path = self.run_log.write_summary(self._counters())
            self.run_log.close()
            rospy.loginfo(f"depth_evaluator: {self.evaluated} frames evaluated; summary in {path}")


def _load_lut(objects_file: str, config: EvaluatorConfig) -> npt.NDArray[np.int16] | None:
    if not objects_file:
        return None
    path = Path(objects_file)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        msg = f"~objects_file {path}: cannot read: {err.strerror}"
        raise PerceptionConfigError(msg) from err
    try:
        return class_lut(instance_classes_from_json(text), config.classes)
    except DepthError as err:
        msg = f"~objects_file {path}: {err}"
        raise PerceptionConfigError(msg) from err


def main() -> None:
    run_participant("depth_evaluator", _build, lookahead_steps=3, errors=(PerceptionError,))


def _build(ls: Participant) -> None:
    params = node_params(EvaluatorParams, "depth_evaluator")
    config = depth_section(EvaluatorConfig, "evaluator", params.config, params.overrides)
    lut = _load_lut(params.objects_file, config)
    try:
        run_log = DepthRunLog(Path(params.run_dir), params.camera, config) if params.run_dir else None
    except OSError as err:
        msg = f"~run_dir {params.run_dir}: cannot write the depth run log there: {err.strerror}"
        raise PerceptionConfigError(msg) from err
    node = DepthEvaluatorNode(
        config,
        camera_name=params.camera,
        estimate_topic=params.estimate_topic,
        lut=lut,
        run_log=run_log,
        world_dir_param=params.world_dir_param,
    )
    node.start(ls)
    classes = "on" if lut is not None else "from the sim bridge's world_dir when it is set"
    log = f"in {run_log.run_dir}" if run_log else "off"
    rospy.loginfo(f"depth_evaluator: running on camera {params.camera!r}; classes {classes}; run log {log}")
