"""geolocator: any detector's image boxes -> positions in ``map`` with an uncertainty, and which surface said so.

The detector contract's consumer side: a detector is any node publishing ``vision_msgs/Detection2DArray``
for a camera image; this node screens its boxes (NaN, empty, out-of-image, unknown class, bad score:
counted and discarded), places each kept box on the depth image, else the map server's elevation layer
(over the prior terrain model), else the terrain model (``uav_perception.core.detection.geolocation``), and
passes every kept box on, placed or not (NaN position, ``position_source: unplaced:<reason>``).

ROS interface:

Subscribes:
    ``~detections`` (vision_msgs/Detection2DArray): the detector's boxes; ``header.frame_id`` is the camera's
    optical frame (frames of another camera are counted and skipped; an empty frame_id means this camera).
    ``~camera_info`` (sensor_msgs/CameraInfo, undistorted): intrinsics and image size.
    ``/tf``, ``/tf_static``: ``map_frame -> <optical frame>`` at the image stamp.
    ``~depth`` (sensor_msgs/Image 32FC1, z-depth; optional): the same camera's depth, matched by stamp.
    ``~elevation`` (uav_msgs/GridLayers with ``elevation_m``; optional): the latest map layers.
Publishes:
    ``~detections`` (uav_msgs/DetectionArray): one message per input frame, same header; instance_id 0,
    class name (``config/detection_classes.yaml``), score, inclusive pixel box, range, position and
    covariance in map, position_source (``depth`` | ``elevation`` | ``terrain`` | ``unplaced:<reason>``),
    and the frame's discarded counts by reason.
    ``~status`` (uav_msgs/GeolocatorStatus): running totals after every frame.
Parameters (``uav_perception.ros.params.GeolocatorParams``):
    ``~camera`` (``forward``), ``~detections`` (input topic, "" = ``/detections/<camera>/ground_truth``),
    ``~detector`` (its name in the output), ``~camera_info`` ("" = ``/cameras/<camera>/color/camera_info``),
    ``~depth`` (""), ``~elevation`` (""), ``~terrain_dem`` (file, ""), ``~classes`` (class map, ""),
    ``~map_frame`` (``map``), ``~tf_timeout_s`` (0.5: wall seconds after a frame arrived), ``~depth_wait_s`` (1.0),
    ``~box_margin_px`` (2),
    ``~geolocation`` (dict: ``GeolocationConfig`` keys). A missing or malformed terrain model file stops
    the node (exit code 3, naming the file); any unknown parameter too (exit code 2).

Frames are handled in arrival order by one worker thread; a frame waiting for its depth image is handled
once that image arrives, once a later depth image shows it will not, or after ``~depth_wait_s``.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, OrderedDict, deque
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import rospy
from rospy.numpy_msg import numpy_msg
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header
from vision_msgs.msg import Detection2DArray

from uav_common.ros.arrays import MessageLayoutError, image_to_depth_m
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params
from uav_msgs.msg import DetectionArray, GeolocatorStatus, GridLayers
from uav_perception.core.depth.types import CameraPose, PinholeCamera
from uav_perception.core.detection.boxes import screen
from uav_perception.core.detection.geolocation import Placement, Surfaces, place
from uav_perception.core.detection.heightfield import HeightGrid
from uav_perception.errors import DepthError, DetectionError, PerceptionConfigError, PerceptionError
from uav_perception.ros.conversions import camera_from_info, pose_from_transform
from uav_perception.ros.params import GeolocatorParams, detection_classes
from uav_perception.ros.tf_wait import lookup_until
from uav_perception.ros.vision import elevation_from_layers, geolocated_array_msg, raw_detections_from_msg, status_msg
from uav_perception.shell.dem import load_dem

_DEPTH_KEEP = 30
_STAMP_TOL_NS = 1_000_000
#: Steps between a frame and when its placements are consumed, in the causal lockstep (docs/lockstep.md).
LOOKAHEAD_STEPS = 3


@dataclass
class _Frame:
    msg: Detection2DArray
    #: When it arrived: wall seconds (``time.monotonic``), or in the causal lockstep the step's simulated time.
    received_wall: float


class GeolocatorNode:
    def __init__(self, params: GeolocatorParams, terrain: HeightGrid | None) -> None:
        self.p = params
        self.classes = detection_classes(params.classes)
        self.terrain = terrain
        self.cam = params.camera
        self.lock = threading.Condition()
        self.frames: deque[_Frame] = deque()
        self.camera: PinholeCamera | None = None
        self.optical_frame = ""
        self.depths: OrderedDict[int, npt.NDArray[np.float32]] = OrderedDict()
        self.newest_depth_ns = -1
        self.elevation: HeightGrid | None = None
        self.n_frames = 0
        self.n_other = 0
        self.received = 0
        self.discarded: Counter[str] = Counter()
        self.placed: Counter[str] = Counter()
        self.unplaced: Counter[str] = Counter()

    def start(self, ls: Participant) -> None:
        p = self.p
        self.ls = ls
        self.pub = ls.publisher("~detections", DetectionArray, queue_size=50)
        self.pub_status = ls.publisher("~status", GeolocatorStatus, queue_size=10)
        self.tf_buffer = ls.tf_buffer(cache_s=30.0)
        info = p.camera_info or f"/cameras/{self.cam}/color/camera_info"
        ls.subscribe(info, CameraInfo, self.on_info, queue_size=5)
        if p.depth:
            ls.subscribe(p.depth, Image, self.on_depth, queue_size=5, buff_size=2**24)
        if p.elevation:
            ls.subscribe(p.elevation, numpy_msg(GridLayers), self.on_layers, queue_size=1, buff_size=2**26)
        topic = p.detections or f"/detections/{self.cam}/ground_truth"
        ls.subscribe(topic, Detection2DArray, self.on_detections, queue_size=100)
        if ls.causal:
            ls.on_step(lambda _step, now_s: self._work_step(now_s))
        else:
            threading.Thread(target=self._work, name="geolocator", daemon=True).start()
        surfaces = [s for s, on in (("depth", p.depth), ("elevation", p.elevation), ("terrain", self.terrain)) if on]
        rospy.loginfo(
            f"geolocator: {topic} ({p.detector}) on camera {self.cam}; surfaces: {', '.join(surfaces) or 'none'}"
        )

    # ---- callbacks ---------------------------------------------------------------------------

    def on_info(self, msg: CameraInfo) -> None:
        try:
            camera = camera_from_info(msg)
        except DepthError as err:
            rospy.logerr_throttle(10.0, f"geolocator: unusable camera_info: {err}")
            return
        with self.lock:
            self.camera = camera
            self.optical_frame = msg.header.frame_id
            self.lock.notify()

    def on_depth(self, msg: Image) -> None:
        try:
            depth = image_to_depth_m(msg)
        except MessageLayoutError as err:
            rospy.logwarn_throttle(10.0, f"geolocator: depth image skipped: {err}")
            return
        stamp = msg.header.stamp.to_nsec()
        with self.lock:
            self.depths[stamp] = depth
            while len(self.depths) > _DEPTH_KEEP:
                self.depths.popitem(last=False)
            self.newest_depth_ns = max(self.newest_depth_ns, stamp)
            self.lock.notify()

    def on_layers(self, msg: Any) -> None:
        grid = elevation_from_layers(msg)
        if grid is not None:
            with self.lock:
                self.elevation = grid

    def on_detections(self, msg: Detection2DArray) -> None:
        with self.lock:
            self.frames.append(_Frame(msg, self.ls.now_s() if self.ls.causal else time.monotonic()))
            self.lock.notify()

    # ---- worker ------------------------------------------------------------------------------

    def _depth_for(self, stamp_ns: int) -> npt.NDArray[np.float32] | None:
        for s, img in self.depths.items():
            if abs(s - stamp_ns) <= _STAMP_TOL_NS:
                return img
        return None

    def _ready(self, frame: _Frame, now: float | None = None) -> bool:
        """Its depth image is here, or cannot come any more (a newer one came), or it waited ``depth_wait_s``
        (wall seconds; in the causal lockstep ``now`` is the step's simulated time)."""
        if not self.p.depth:
            return True
        stamp = frame.msg.header.stamp.to_nsec()
        if self._depth_for(stamp) is not None or self.newest_depth_ns > stamp + _STAMP_TOL_NS:
            return True
        return (time.monotonic() if now is None else now) - frame.received_wall >= self.p.depth_wait_s

    def _work_step(self, now_s: float) -> None:
        """Causal lockstep: place the frames whose depth and pose are known at this step, in arrival order; a
        frame waits (and the ones after it) while its pose may still come: ``~tf_timeout_s`` of simulated time
        after its stamp. The same frames are placed at the same step in every run."""
        while self.frames:
            frame = self.frames[0]
            if not self._ready(frame, now_s):
                return
            stamp = frame.msg.header.stamp
            frame_id = frame.msg.header.frame_id or self.optical_frame
            waiting = frame_id and frame.msg.detections and now_s - stamp.to_sec() < self.p.tf_timeout_s
            if waiting and not self.tf_buffer.can_transform(self.p.map_frame, frame_id, stamp):
                return  # its pose is not here yet
            self.frames.popleft()
            depth = self._depth_for(stamp.to_nsec()) if self.p.depth else None
            try:
                self._handle(frame, self.camera, self.optical_frame, depth, self.elevation)
            except Exception as err:  # one bad frame must not stop the node
                rospy.logerr(f"geolocator: frame at {stamp.to_sec():.3f} s failed: {type(err).__name__}: {err}")

    def _work(self) -> None:
        while not rospy.is_shutdown():
            with self.lock:
                if not self.frames:
                    self.lock.wait(timeout=1.0)  # woken by the next frame
                    continue
                if not self._ready(self.frames[0]):
                    self.lock.wait(timeout=0.05)  # its depth image may still come
                    continue
                frame = self.frames.popleft()
                depth = self._depth_for(frame.msg.header.stamp.to_nsec()) if self.p.depth else None
                camera, optical, elevation = self.camera, self.optical_frame, self.elevation
            try:
                self._handle(frame, camera, optical, depth, elevation)
            except Exception as err:  # one bad frame must not stop the node
                rospy.logerr(
                    f"geolocator: frame at {frame.msg.header.stamp.to_sec():.3f} s failed: {type(err).__name__}: {err}"
                )

    def _pose(self, frame_id: str, stamp: rospy.Time, received_wall: float) -> CameraPose | None:
        """The camera's pose at ``stamp``, waited for at most ``~tf_timeout_s`` after the frame *arrived*
        (:func:`uav_perception.ros.tf_wait.lookup_until`: a frame that waited in the queue does not wait again).
        In the causal lockstep the step has decided already: it is in the buffer now or never."""
        deadline = 0.0 if self.ls.causal else received_wall + self.p.tf_timeout_s
        tf, why = lookup_until(self.tf_buffer, self.p.map_frame, frame_id, stamp, deadline, stop=rospy.is_shutdown)
        if tf is None:
            rospy.logwarn_throttle(5.0, f"geolocator: no pose of {frame_id} at {stamp.to_sec():.3f} s: {why}")
            return None
        return pose_from_transform(tf.transform)

    def _handle(
        self,
        frame: _Frame,
        camera: PinholeCamera | None,
        optical: str,
        depth: npt.NDArray[np.float32] | None,
        elevation: HeightGrid | None,
    ) -> None:
        t0 = time.perf_counter()
        msg = frame.msg
        frame_id = msg.header.frame_id or optical
        if camera is not None and optical and frame_id != optical:
            self.n_other += 1
            rospy.logwarn_throttle(30.0, f"geolocator: frames of {frame_id!r} skipped (this is {optical!r})")
            return
        raw = raw_detections_from_msg(msg)
        width = camera.width_px if camera is not None else None
        height = camera.height_px if camera is not None else None
        boxes, discarded = screen(raw, self.classes, width_px=width, height_px=height, margin_px=self.p.box_margin_px)
        if discarded:
            rospy.logwarn_throttle(
                10.0,
                f"geolocator: discarded {dict(discarded)} of {len(raw)} detections "
                f"at {msg.header.stamp.to_sec():.3f} s",
            )
        pose = self._pose(frame_id, msg.header.stamp, frame.received_wall) if boxes and frame_id else None
        if depth is not None and camera is not None and depth.shape != camera.shape:
            rospy.logwarn_throttle(
                10.0, f"geolocator: depth image {depth.shape[::-1]} does not match camera_info; not used"
            )
            depth = None
        surfaces = Surfaces(depth_m=depth, elevation=elevation, terrain=self.terrain)
        placements: list[Placement] = []
        for box in boxes:
            try:
                pl = place(
                    box,
                    camera,
                    pose,
                    surfaces,
                    self.p.geolocation,
                    footprint_radius_m=self.classes.footprint_radius_m(box.class_name),
                )
            except DetectionError as err:
                rospy.logwarn_throttle(10.0, f"geolocator: cannot place a box: {err}")
                pl = Placement.unplaced("no_surface_model")
            placements.append(pl)
        self.n_frames += 1
        self.received += len(raw)
        self.discarded.update(discarded)
        for pl in placements:
            if pl.placed:
                self.placed[pl.source] += 1
            else:
                self.unplaced[pl.reason] += 1
        header = Header(stamp=msg.header.stamp, frame_id=frame_id)
        self.pub.publish(
            geolocated_array_msg(
                header, camera=self.cam, source=self.p.detector, boxes=boxes, placements=placements, discarded=discarded
            )
        )
        self.pub_status.publish(
            status_msg(
                header,
                camera=self.cam,
                detector=self.p.detector,
                frames=self.n_frames,
                frames_other_camera=self.n_other,
                received=self.received,
                discarded=self.discarded,
                placed=self.placed,
                unplaced=self.unplaced,
                processing_ms=1e3 * (time.perf_counter() - t0),
            )
        )


def main() -> None:
    run_participant("geolocator", _build, lookahead_steps=LOOKAHEAD_STEPS, errors=(PerceptionError,))


def _build(ls: Participant) -> None:
    params = node_params(GeolocatorParams, "geolocator")
    terrain = load_dem(Path(params.terrain_dem).expanduser()) if params.terrain_dem else None
    if terrain is None and not params.elevation and not params.depth:
        msg = "geolocator: no surface to place boxes on: give ~depth, ~elevation or ~terrain_dem"
        raise PerceptionConfigError(msg)
    node = GeolocatorNode(params, terrain)
    node.start(ls)
