"""numpy / core types -> ROS messages for the bridge (and the inverse where tests need it)."""

from __future__ import annotations

import math

import rospy
from geometry_msgs.msg import Point, Pose, Quaternion, TransformStamped, Vector3
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header
from vision_msgs.msg import BoundingBox2D, Detection2D, Detection2DArray, ObjectHypothesisWithPose

from uav_common.detection_classes import DetectionClasses
from uav_common.frames import wxyz_to_ros_xyzw
from uav_msgs.msg import Collision, Detection, DetectionArray, ObjectStateArray, SimState
from uav_msgs.msg import ObjectState as ObjectStateMsg
from uav_sim_bridge.core.camera import CameraModel
from uav_sim_bridge.core.detections import GroundTruthDetection
from uav_sim_bridge.core.objects import ObjectState
from uav_sim_bridge.core.transforms import RigidTransform
from uav_sim_bridge.core.vehicle_state import VehicleState

__all__ = [
    "camera_info",
    "clock",
    "collision_msg",
    "detection_array",
    "ground_truth_boxes",
    "header",
    "object_states_msg",
    "odometry",
    "quaternion",
    "sim_state",
    "stamp",
    "transform_stamped",
]


def stamp(sim_time_s: float) -> rospy.Time:
    """The ROS time of a simulation instant, to the nearest nanosecond (``rospy.Time.from_sec`` truncates:
    8.1 s would be stamped 8.099999999)."""
    ns = round(max(0.0, sim_time_s) * 1e9)
    return rospy.Time(ns // 1_000_000_000, ns % 1_000_000_000)


def header(sim_time_s: float, frame_id: str) -> Header:
    return Header(stamp=stamp(sim_time_s), frame_id=frame_id)


def quaternion(t: RigidTransform) -> Quaternion:
    x, y, z, w = wxyz_to_ros_xyzw(t.quat_wxyz)
    return Quaternion(x=x, y=y, z=z, w=w)


def clock(sim_time_s: float) -> Clock:
    return Clock(clock=stamp(sim_time_s))


def transform_stamped(sim_time_s: float, parent: str, child: str, t_parent_child: RigidTransform) -> TransformStamped:
    msg = TransformStamped()
    msg.header = header(sim_time_s, parent)
    msg.child_frame_id = child
    tx, ty, tz = (float(v) for v in t_parent_child.translation_m)
    msg.transform.translation = Vector3(x=tx, y=ty, z=tz)
    msg.transform.rotation = quaternion(t_parent_child)
    return msg


def odometry(state: VehicleState, frame_id: str, child_frame_id: str) -> Odometry:
    """Pose in ``frame_id``, twist in ``child_frame_id`` (REP 105)."""
    msg = Odometry()
    msg.header = header(state.sim_time_s, frame_id)
    msg.child_frame_id = child_frame_id
    px, py, pz = (float(v) for v in state.position_m)
    msg.pose.pose.position = Point(x=px, y=py, z=pz)
    msg.pose.pose.orientation = quaternion(state.t_map_base)
    vx, vy, vz = (float(v) for v in state.velocity_body_mps)
    wx, wy, wz = (float(v) for v in state.angular_velocity_body_radps)
    msg.twist.twist.linear = Vector3(x=vx, y=vy, z=vz)
    msg.twist.twist.angular = Vector3(x=wx, y=wy, z=wz)
    return msg


def camera_info(camera: CameraModel, hdr: Header) -> CameraInfo:
    """Ideal pinhole (no distortion), ``P = [K | 0]``."""
    k = camera.k
    msg = CameraInfo(header=hdr, height=camera.height, width=camera.width, distortion_model="plumb_bob")
    msg.D = [0.0] * 5
    msg.K = [float(v) for v in k.ravel()]
    msg.R = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.P = [float(k[0, 0]), 0.0, float(k[0, 2]), 0.0, 0.0, float(k[1, 1]), float(k[1, 2]), 0.0, 0.0, 0.0, 1.0, 0.0]
    return msg


def detection_array(hdr: Header, camera: str, dets: list[GroundTruthDetection]) -> DetectionArray:
    """The truth, for scoring: instance ids, true centres (covariance zero), ranges, visible fractions."""
    out = DetectionArray(header=hdr, camera=camera, source="ground_truth")
    for d in dets:
        x, y, z = d.position_m
        out.detections.append(
            Detection(
                instance_id=d.instance_id,
                class_name=d.object_class.label,
                score=1.0,
                x_min=d.x_min,
                y_min=d.y_min,
                x_max=d.x_max,
                y_max=d.y_max,
                range_m=d.range_m,
                visible_fraction=d.visible_fraction,
                position=Point(x=x, y=y, z=z),
                position_covariance=[0.0] * 9,
                position_source="ground_truth",
            )
        )
    return out


def object_states_msg(t_s: float, frame_id: str, states: list[ObjectState]) -> ObjectStateArray:
    """The moving people and vehicles of one instant."""
    out = ObjectStateArray(header=header(t_s, frame_id))
    for st in states:
        o = st.obj
        x, y, z = o.pose.position_m
        half = 0.5 * o.pose.yaw_rad
        pose = Pose(
            position=Point(x=x, y=y, z=z), orientation=Quaternion(x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))
        )
        vx, vy, vz = st.velocity_mps
        out.objects.append(
            ObjectStateMsg(
                instance_id=o.instance_id,
                name=o.name,
                class_name=o.object_class.label,
                kind=o.kind,
                pose=pose,
                size=Vector3(x=o.size_m[0], y=o.size_m[1], z=o.size_m[2]),
                velocity=Vector3(x=vx, y=vy, z=vz),
                moving=st.moving,
            )
        )
    return out


def ground_truth_boxes(hdr: Header, dets: list[GroundTruthDetection], classes: DetectionClasses) -> Detection2DArray:
    """The same objects as a box-only detector (the detector contract): a box per object (centre and size
    of its inclusive pixel box) and one hypothesis (class id from the class map, score 1, pose unset). No
    instance id and no position: those are the truth's, on the truth topic."""
    out = Detection2DArray(header=hdr)
    for d in dets:
        det = Detection2D(header=hdr)
        det.bbox = BoundingBox2D()
        det.bbox.center.x = 0.5 * (d.x_min + d.x_max)
        det.bbox.center.y = 0.5 * (d.y_min + d.y_max)
        det.bbox.size_x = float(d.x_max - d.x_min + 1)
        det.bbox.size_y = float(d.y_max - d.y_min + 1)
        det.results = [ObjectHypothesisWithPose(id=classes.id_of(d.object_class.label), score=1.0)]
        out.detections.append(det)
    return out


def sim_state(
    sim_time_s: float,
    frame_id: str,
    *,
    rtf: float,
    armed: bool,
    crashed: bool,
    lockstep: bool,
    motors: tuple[float, ...],
) -> SimState:
    return SimState(
        header=header(sim_time_s, frame_id),
        sim_time_s=sim_time_s,
        real_time_factor=rtf,
        armed=armed,
        crashed=crashed,
        lockstep=lockstep,
        motor_outputs=list(motors),
    )


def collision_msg(
    sim_time_s: float,
    frame_id: str,
    *,
    instance_id: int,
    class_name: str,
    point_m: tuple[float, float, float],
    speed_mps: float,
) -> Collision:
    x, y, z = point_m
    return Collision(
        header=header(sim_time_s, frame_id),
        instance_id=instance_id,
        class_name=class_name,
        position=Point(x=x, y=y, z=z),
        speed_mps=speed_mps,
    )
