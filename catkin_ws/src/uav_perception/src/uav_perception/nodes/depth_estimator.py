"""depth_estimator: motion-stereo depth from one moving color camera (Epidepth-style).

For each new color frame it picks a partner from a short history through the
pairing gate, refines the relative pose from tracked corners, rectifies, matches
with SGBM, filters and triangulates (see ``uav_perception.core.depth.estimator``).
The output has the formats of the ground-truth camera streams, so the map server
takes either.

ROS interface:

Subscribes:
    ``/cameras/<camera>/color/image_raw`` (sensor_msgs/Image, rgb8/bgr8).
    ``/cameras/<camera>/color/camera_info`` (sensor_msgs/CameraInfo; undistorted).
    ``/tf``, ``/tf_static``: ``map_frame -> <image frame_id>`` at the image stamp
    (``pose_source: tf``), or only ``base_frame -> <image frame_id>`` (static) plus
    ``~odom_topic`` (nav_msgs/Odometry, ``pose_source: odom``).
Publishes:
    ``~depth/image_raw`` (sensor_msgs/Image 32FC1, metres z-depth, NaN = none): in the
    reference image's own camera, header = the color image's header.
    ``~depth/camera_info`` (sensor_msgs/CameraInfo): the color camera's, same header.
    ``~points`` (sensor_msgs/PointCloud2 ``x y z rgb`` float32, point_step 16, frame
    ``camera_<camera>_optical``, unorganised, finite points): the ground-truth cloud format.
    ``~status`` (uav_msgs/DepthEstimatorStatus): counters, skip reasons, last pair.
Parameters:
    ``~config`` (str, default: the project's ``config/depth.yaml``), section ``estimator``;
    ``~overrides`` (dict, default {}): merged over that section.
    ``~camera`` (str, default ``nadir``).
    ``~pose_source`` (``tf`` | ``odom``, default ``tf``).
    ``~map_frame`` (str, default ``map``), ``~base_frame`` (str, default ``base_link``).
    ``~odom_topic`` (str, default ``/uav/ground_truth/odom``).
    ``~tf_timeout_s`` (float, default 0.3): wait for the pose of the newest image.
    Any other private parameter stops the node (exit code 2, docs/architecture.md).

Frames are converted in the subscriber callback and processed by one worker
thread. When frames arrive faster than they are processed, only the newest is
estimated; the others still join the history as partners (counted as ``busy``).

Causal lockstep (docs/lockstep.md): a participant with a lookahead of 3 steps and no worker thread: every frame
is estimated, in order, in the first step at which its pose is known (``~tf_timeout_s`` of simulated time after
its stamp at the latest, then it is skipped as ``no_pose``), the same in every run.
"""

from __future__ import annotations

import copy
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Header

from uav_common.ros.arrays import MessageLayoutError, image_msg, image_to_rgb
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import DepthEstimatorStatus
from uav_perception.core.depth.config import EstimatorConfig
from uav_perception.core.depth.estimator import DepthEstimate, MotionStereoEstimator, SkippedFrame
from uav_perception.core.depth.sync import PoseHistory
from uav_perception.core.depth.types import CameraPose, ColorFrame, PinholeCamera, check_rgb_image
from uav_perception.errors import DepthError, PerceptionConfigError, PerceptionError
from uav_perception.ros.conversions import (
    camera_from_info,
    colored_cloud_msg,
    estimator_status_msg,
    pose_from_odometry,
    pose_from_transform,
)
from uav_perception.ros.params import EstimatorParams, depth_section

_QUEUE_MAX = 64
_TIME_JUMP_NS = 1_000_000_000
#: Steps between a frame and when its depth is consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 3
_ODOM_CAPACITY = 2000


@dataclass(frozen=True)
class _Pending:
    header: Header
    rgb: npt.NDArray[np.uint8]


class DepthEstimatorNode:
    """Thin shell around :class:`MotionStereoEstimator`: messages in, messages out."""

    def __init__(
        self,
        config: EstimatorConfig,
        *,
        camera_name: str,
        pose_source: str,
        map_frame: str,
        base_frame: str,
        odom_topic: str,
        tf_timeout_s: float,
    ) -> None:
        if pose_source not in ("tf", "odom"):
            msg = f"~pose_source must be 'tf' or 'odom', got {pose_source!r}"
            raise PerceptionConfigError(msg)
        self.config = config
        self.camera_name = camera_name
        self.pose_source = pose_source
        self.map_frame = map_frame
        self.base_frame = base_frame
        self.odom_topic = odom_topic
        self.tf_timeout_s = tf_timeout_s
        self._lock = threading.Condition()
        self._queue: deque[_Pending] = deque(maxlen=_QUEUE_MAX)
        self._info: CameraInfo | None = None
        self._camera: PinholeCamera | None = None
        self._core: MotionStereoEstimator | None = None
        self._extra_skips: Counter[str] = Counter()
        self._last_estimate: DepthEstimate | None = None
        self._last_posed_ns = -1
        self._odom = PoseHistory(_ODOM_CAPACITY, max_gap_ns=200_000_000, max_extrapolation_ns=50_000_000)
        self._extrinsic: dict[str, CameraPose] = {}

    def start(self, ls: Participant) -> None:
        """Create publishers, subscribers and the worker thread (in the causal lockstep: the step hook)."""
        base = f"/cameras/{self.camera_name}/color"
        self.ls = ls
        self.pub_depth = ls.publisher("~depth/image_raw", Image, queue_size=2)
        self.pub_info = ls.publisher("~depth/camera_info", CameraInfo, queue_size=2)
        self.pub_points = ls.publisher("~points", PointCloud2, queue_size=2)
        self.pub_status = ls.publisher("~status", DepthEstimatorStatus, queue_size=5)
        self.tf_buffer = ls.tf_buffer(cache_s=30.0)
        ls.subscribe(f"{base}/camera_info", CameraInfo, self.on_info, queue_size=2)
        ls.subscribe(f"{base}/image_raw", Image, self.on_image, queue_size=8, buff_size=2**25)
        if self.pose_source == "odom":
            ls.subscribe(self.odom_topic, Odometry, self.on_odom, queue_size=100)
        if ls.causal:
            self._queue = deque()  # every frame is estimated: nothing is dropped for being busy
            ls.on_step(lambda _step, now: self._step(now))
            return
        self._worker = threading.Thread(target=self._run, name="depth_estimator", daemon=True)
        self._worker.start()

    # --- callbacks: convert and queue, nothing slow -------------------------------------------

    def on_info(self, msg: CameraInfo) -> None:
        try:
            camera = camera_from_info(msg)
        except DepthError as err:
            rospy.logerr_throttle(10.0, f"depth_estimator: unusable camera_info: {err}")
            return
        with self._lock:
            self._info = msg
            if camera != self._camera:
                if self._camera is not None:
                    rospy.logwarn(f"depth_estimator: camera intrinsics changed to {camera}; history reset")
                self._camera = camera
                self._core = MotionStereoEstimator(camera, self.config)

    def on_image(self, msg: Image) -> None:
        with self._lock:
            camera = self._camera
            if camera is None:
                self._extra_skips["no_camera_info"] += 1
                rospy.logwarn_throttle(5.0, "depth_estimator: no camera_info yet; image skipped")
                return
        try:
            rgb = check_rgb_image(image_to_rgb(msg), camera)
        except (DepthError, MessageLayoutError) as err:
            with self._lock:
                self._extra_skips["bad_input"] += 1
            rospy.logwarn_throttle(5.0, f"depth_estimator: image skipped: {err}")
            return
        with self._lock:
            if len(self._queue) == self._queue.maxlen:
                self._extra_skips["busy"] += 1
            self._queue.append(_Pending(msg.header, rgb))
            self._lock.notify()

    def on_odom(self, msg: Odometry) -> None:
        pose = pose_from_odometry(msg)
        with self._lock:
            self._odom.add(msg.header.stamp.to_nsec(), pose)

    # --- worker ---------------------------------------------------------------------------------

    def _run(self) -> None:
        while not rospy.is_shutdown():
            with self._lock:
                if not self._queue:
                    self._lock.wait(timeout=0.5)
                    continue
                batch = list(self._queue)
                self._queue.clear()
                core = self._core
            if core is None:
                continue
            try:
                self._handle(core, batch)
            except Exception as err:  # the node must survive any single bad frame
                rospy.logerr(f"depth_estimator: frame failed: {type(err).__name__}: {err}")
                with self._lock:
                    self._extra_skips["error"] += 1

    def _posed(self, header: Header) -> bool:
        """Is the pose of this image known now (causal lockstep: the step's inputs decide)?"""
        if self.pose_source == "tf":
            return bool(self.tf_buffer.can_transform(self.map_frame, header.frame_id, header.stamp))
        with self._lock:
            return self._odom.at(header.stamp.to_nsec()) is not None

    def _step(self, now_s: float) -> None:
        """Causal lockstep: estimate each waiting frame, in order, once its pose is known (or it waited
        ``tf_timeout_s`` of simulated time: then it is counted as ``no_pose``)."""
        core = self._core
        while self._queue and core is not None:
            head = self._queue[0]
            if not self._posed(head.header) and now_s - head.header.stamp.to_sec() < self.tf_timeout_s:
                return
            self._queue.popleft()
            try:
                self._handle(core, [head])
            except Exception as err:  # the node must survive any single bad frame
                rospy.logerr(f"depth_estimator: frame failed: {type(err).__name__}: {err}")
                self._extra_skips["error"] += 1

    def _handle(self, core: MotionStereoEstimator, batch: list[_Pending]) -> None:
        newest = batch[-1]
        if newest.header.stamp.to_nsec() < self._last_posed_ns - _TIME_JUMP_NS:
            # A bag loop or a restarted simulation: old transforms would be wrong now.
            rospy.logwarn("depth_estimator: time went backwards; clearing the tf buffer")
            self.tf_buffer.clear()
            self._last_posed_ns = -1
        for item in batch[:-1]:
            frame = self._frame(item, wait=False)
            if frame is not None:
                try:
                    core.remember(frame)
                except DepthError as err:
                    self._count_bad_input(err)
        frame = self._frame(newest, wait=True)
        if frame is None:
            self._publish_status(newest.header, core, 0.0)
            return
        t0 = time.perf_counter()
        try:
            result = core.process(frame)
        except DepthError as err:
            self._count_bad_input(err)
            return
        elapsed = time.perf_counter() - t0
        if isinstance(result, SkippedFrame):
            rospy.logdebug(f"depth_estimator: skipped ({result.reason.value}): {result.detail}")
        else:
            self._last_estimate = result
            self._publish(newest.header, frame, core, result)
        self._publish_status(newest.header, core, elapsed)

    def _count_bad_input(self, err: DepthError) -> None:
        with self._lock:
            self._extra_skips["bad_input"] += 1
        rospy.logwarn_throttle(5.0, f"depth_estimator: frame skipped: {err}")

    def _frame(self, item: _Pending, *, wait: bool) -> ColorFrame | None:
        pose = self._pose(item.header, wait=wait)
        if pose is None:
            with self._lock:
                self._extra_skips["no_pose"] += 1
            return None
        self._last_posed_ns = max(self._last_posed_ns, item.header.stamp.to_nsec())
        return ColorFrame(item.header.stamp.to_nsec(), item.rgb, pose)

    def _lookup(self, target: str, source: str, stamp: rospy.Time, wait: bool) -> TransformStamped:
        """tf lookup that waits in *wall* time: a paused simulation clock must not block the worker."""
        deadline = time.monotonic() + (self.tf_timeout_s if wait and not self.ls.causal else 0.0)
        while True:
            try:
                return self.tf_buffer.lookup_transform(target, source, stamp)
            except (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException):
                if time.monotonic() >= deadline or rospy.is_shutdown():
                    raise
            time.sleep(0.01)

    def _pose(self, header: Header, *, wait: bool) -> CameraPose | None:
        try:
            if self.pose_source == "tf":
                tf = self._lookup(self.map_frame, header.frame_id, header.stamp, wait)
                return pose_from_transform(tf.transform)
            extrinsic = self._extrinsic.get(header.frame_id)
            if extrinsic is None:
                tf = self._lookup(self.base_frame, header.frame_id, rospy.Time(0), wait)
                extrinsic = pose_from_transform(tf.transform)
                self._extrinsic[header.frame_id] = extrinsic
        except (tf2_ros.LookupException, tf2_ros.ExtrapolationException, tf2_ros.ConnectivityException) as err:
            stamp_s = header.stamp.to_sec()
            rospy.logwarn_throttle(5.0, f"depth_estimator: no pose for {header.frame_id} at {stamp_s:.3f} s: {err}")
            return None
        with self._lock:
            body = self._odom.at(header.stamp.to_nsec())
        if body is None:
            rospy.logwarn_throttle(5.0, f"depth_estimator: no odometry around {header.stamp.to_sec():.3f} s")
            return None
        return body.compose(extrinsic.rotation_map_optical, extrinsic.position_map_m)

    # --- output ---------------------------------------------------------------------------------

    def _publish(self, header: Header, frame: ColorFrame, core: MotionStereoEstimator, est: DepthEstimate) -> None:
        out_header = Header(stamp=header.stamp, frame_id=header.frame_id)
        self.pub_depth.publish(image_msg(est.depth_m, "32FC1", out_header))
        with self._lock:
            info = self._info
        if info is not None:
            info_out = copy.copy(info)
            info_out.header = out_header
            self.pub_info.publish(info_out)
        self.pub_points.publish(colored_cloud_msg(core.cloud(est, frame), out_header))

    def _publish_status(self, header: Header, core: MotionStereoEstimator, elapsed_s: float) -> None:
        with self._lock:
            extra = dict(self._extra_skips)
        msg = estimator_status_msg(
            Header(stamp=header.stamp, frame_id=header.frame_id),
            camera=self.camera_name,
            stats=core.stats,
            extra_skips=extra,
            last=self._last_estimate,
            processing_time_s=elapsed_s,
        )
        self.pub_status.publish(msg)


def main() -> None:
    run_participant("depth_estimator", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(PerceptionError,))


def _build(ls: Participant) -> None:
    params = node_params(EstimatorParams, "depth_estimator")
    config = depth_section(EstimatorConfig, "estimator", params.config, params.overrides)
    node = DepthEstimatorNode(
        config,
        camera_name=params.camera,
        pose_source=params.pose_source,
        map_frame=params.map_frame,
        base_frame=params.base_frame,
        odom_topic=params.odom_topic,
        tf_timeout_s=params.tf_timeout_s,
    )
    node.start(ls)
    rospy.loginfo(f"depth_estimator: running on camera {node.camera_name!r}, poses from {node.pose_source}")
