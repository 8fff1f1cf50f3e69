"""The one place where autonomy ROS messages meet core types (no rospy import).

Grids: ``uav_msgs/GridLayers`` is layer-major, ``data[k*H*W + row*W + col]`` with
row 0 the southern-most row (like ``nav_msgs/OccupancyGrid``). Images are
published north-up for people: image row 0 is the grid's last (northern-most) row,
so pixel ``(r, c)`` covers ``x = origin_x + c*res``, ``y = origin_y + (H-1-r)*res``;
``nav_msgs/MapMetaData`` on the ``info`` topic carries resolution and origin.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import numpy.typing as npt
from geometry_msgs.msg import Point, PointStamped, Pose, PoseStamped, Quaternion
from nav_msgs.msg import MapMetaData, Odometry, Path
from rospy.numpy_msg import numpy_msg
from sensor_msgs.msg import BatteryState, Image
from std_msgs.msg import Header

from uav_autonomy.core.controller import ControllerStatus
from uav_autonomy.core.features import Target
from uav_autonomy.core.grid_geometry import GridSpec
from uav_autonomy.core.mcdm import GoalDecision
from uav_autonomy.core.pose_estimate import PoseEstimate
from uav_autonomy.errors import InvalidInputError
from uav_autonomy.mavlink.link import OdometryReading
from uav_common.ros.arrays import image_msg
from uav_msgs.msg import ControllerState, FeatureWeights, GoalReason, GridLayers, SearchTarget

# GridLayers whose float32[] (millions of cells for 1 km^2) (de)serialises as one numpy buffer: genpy's plain
# class turns it into a tuple of Python floats, which took most of the autonomy nodes' CPU. Same wire format.
NumpyGridLayers = numpy_msg(GridLayers)

__all__ = [
    "NumpyGridLayers",
    "OctomapBlob",
    "battery_msg",
    "color_image_msg",
    "controller_state_msg",
    "float_image_msg",
    "goal_msgs",
    "grid_layers_from_msg",
    "grid_layers_msg",
    "map_meta_data",
    "octomap_from_buffer",
    "odometry_msg",
    "path_from_msg",
    "path_msg",
    "points_from_msgs",
    "search_target_msg",
    "target_from_points",
    "weights_msg",
    "yaw_from_quaternion",
]


def grid_layers_from_msg(msg: GridLayers) -> tuple[GridSpec, dict[str, npt.NDArray[np.float32]]]:
    """Grid and ``name -> (H, W)`` float32 arrays (read-only views of one copy).

    Raises:
        InvalidInputError: bad geometry, duplicate names or a data length mismatch.
    """
    spec = GridSpec(
        float(msg.resolution_m), float(msg.origin_x_m), float(msg.origin_y_m), int(msg.width), int(msg.height)
    )
    names = list(msg.names)
    if len(set(names)) != len(names):
        msg_ = f"GridLayers has duplicate layer names: {names}"
        raise InvalidInputError(msg_)
    expected = len(names) * spec.width * spec.height
    data = np.asarray(msg.data, dtype=np.float32)
    if data.size != expected:
        msg_ = (
            f"GridLayers data has {data.size} values, expected {expected} "
            f"({len(names)} layers x {spec.height} rows x {spec.width} cols)"
        )
        raise InvalidInputError(msg_)
    cube = data.reshape(len(names), spec.height, spec.width)
    cube.flags.writeable = False
    return spec, {name: cube[k] for k, name in enumerate(names)}


def grid_layers_msg(spec: GridSpec, layers: Mapping[str, npt.NDArray[np.float32]], header: Header) -> GridLayers:
    """Pack ``(H, W)`` layers (in mapping order) into one GridLayers (a :data:`NumpyGridLayers`: ``data`` is
    a float32 array, serialised as one buffer)."""
    msg = NumpyGridLayers()
    msg.header = header
    msg.resolution_m = spec.resolution_m
    msg.origin_x_m = spec.origin_x_m
    msg.origin_y_m = spec.origin_y_m
    msg.width = spec.width
    msg.height = spec.height
    msg.names = list(layers)
    stacked = np.stack([np.asarray(layers[n], dtype=np.float32) for n in layers]) if layers else np.zeros(0)
    msg.data = np.ascontiguousarray(stacked, dtype=np.float32).ravel()
    return msg


@dataclass(frozen=True)
class OctomapBlob:
    """An ``octomap_msgs/Octomap`` read straight from its serialized bytes (``data`` stays bytes)."""

    frame_id: str
    stamp_s: float
    binary: bool
    tree_id: str
    resolution_m: float
    data: bytes


def octomap_from_buffer(buff: bytes) -> OctomapBlob:
    """Parse a serialized ``octomap_msgs/Octomap`` (as a ``rospy.AnyMsg`` subscriber receives it).

    genpy turns the ``int8[] data`` of a large map into millions of Python ints; reading the ROS
    serialization directly keeps it one ``bytes`` object. Layout: Header (uint32 seq, time stamp,
    string frame_id), bool binary, string id, float64 resolution, int8[] data; little-endian,
    strings and arrays prefixed by a uint32 length.

    Raises:
        InvalidInputError: the buffer is shorter than its lengths say, or has bytes left over.
    """
    view = memoryview(buff)
    pos = 0

    def take(n: int) -> memoryview:
        nonlocal pos
        if pos + n > len(view):
            msg = f"octomap message truncated: needs {pos + n} bytes, has {len(view)}"
            raise InvalidInputError(msg)
        out = view[pos : pos + n]
        pos += n
        return out

    def string() -> str:
        (n,) = struct.unpack("<I", take(4))
        return bytes(take(n)).decode("utf-8", errors="replace")

    _seq, secs, nsecs = struct.unpack("<III", take(12))
    frame_id = string()
    (binary,) = struct.unpack("<B", take(1))
    tree_id = string()
    (resolution,) = struct.unpack("<d", take(8))
    (n_data,) = struct.unpack("<I", take(4))
    data = bytes(take(n_data))
    if pos != len(view):
        msg = f"octomap message has {len(view) - pos} bytes after its data"
        raise InvalidInputError(msg)
    return OctomapBlob(frame_id, secs + nsecs * 1e-9, bool(binary), tree_id, float(resolution), data)


def map_meta_data(spec: GridSpec, stamp: object) -> MapMetaData:
    """Resolution, size and origin of the published feature images."""
    info = MapMetaData()
    info.map_load_time = stamp
    info.resolution = spec.resolution_m
    info.width = spec.width
    info.height = spec.height
    info.origin = Pose()
    info.origin.position.x = spec.origin_x_m
    info.origin.position.y = spec.origin_y_m
    info.origin.orientation.w = 1.0
    return info


def float_image_msg(layer: npt.NDArray[np.float32], header: Header) -> Image:
    """32FC1 image, north-up (the grid flipped vertically)."""
    msg: Image = image_msg(np.flipud(np.asarray(layer, dtype=np.float32)), "32FC1", header)
    return msg


def color_image_msg(layer: npt.NDArray[np.float32], header: Header, *, unit_range: bool) -> Image:
    """rgb8 viridis rendering, north-up; NaN is black.

    ``unit_range`` maps ``[0, 1]`` to the colour scale (features); otherwise the
    finite min..max of the layer is used (elevation, score).
    """
    values = np.asarray(layer, dtype=np.float32)
    finite = np.isfinite(values)
    lo, hi = (
        (0.0, 1.0)
        if unit_range
        else (float(values[finite].min()), float(values[finite].max()))
        if finite.any()
        else (0.0, 1.0)
    )
    span = hi - lo if hi > lo else 1.0
    scaled = np.clip((np.where(finite, values, lo) - lo) / span, 0.0, 1.0)
    gray = (scaled * 255.0).astype(np.uint8)
    rgb = cv2.cvtColor(cv2.applyColorMap(gray, cv2.COLORMAP_VIRIDIS), cv2.COLOR_BGR2RGB)
    rgb[~finite] = 0
    msg: Image = image_msg(np.flipud(rgb), "rgb8", header)
    return msg


def yaw_from_quaternion(q: Quaternion) -> float:
    """ENU yaw of a ROS ``[x, y, z, w]`` quaternion (rad)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def path_msg(path_enu_m: npt.NDArray[np.float64], header: Header) -> Path:
    """``(N, 3)`` ENU waypoints to nav_msgs/Path; each pose faces along its next leg."""
    out = Path()
    out.header = header
    yaw = 0.0
    for i, p in enumerate(path_enu_m):
        if i + 1 < len(path_enu_m):
            d = path_enu_m[i + 1] - p
            if math.hypot(d[0], d[1]) > 1e-3:
                yaw = math.atan2(d[1], d[0])
        pose = PoseStamped()
        pose.header = header
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (float(v) for v in p)
        pose.pose.orientation.z = math.sin(yaw / 2.0)
        pose.pose.orientation.w = math.cos(yaw / 2.0)
        out.poses.append(pose)
    return out


def path_from_msg(msg: Path) -> npt.NDArray[np.float64]:
    """nav_msgs/Path to ``(N, 3)`` ENU waypoints (validated by the consumer)."""
    return np.array(
        [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in msg.poses], dtype=np.float64
    ).reshape(-1, 3)


def goal_msgs(decision: GoalDecision, header: Header) -> tuple[PointStamped, GoalReason]:
    """Goal point (z = known elevation at the goal, NaN unknown) and its reason."""
    point = Point(decision.goal_xy_m[0], decision.goal_xy_m[1], decision.elevation_m)
    goal = PointStamped(header=header, point=point)
    reason = GoalReason()
    reason.header = header
    reason.goal = point
    reason.score = decision.score
    names = list(decision.values)
    reason.features = names
    reason.weights = [decision.weights[n] for n in names]
    reason.values = [decision.values[n] for n in names]
    reason.contributions = [decision.contributions[n] for n in names]
    reason.reason = decision.reason.value
    return goal, reason


def points_from_msgs(points: Sequence[Point]) -> list[tuple[float, float, float]]:
    return [(float(p.x), float(p.y), float(p.z)) for p in points]


def target_from_points(points: Sequence[Point]) -> Target | None:
    """No points: None; else a :class:`Target` (raises InvalidInputError on 2 points or NaN)."""
    if not points:
        return None
    return Target(tuple((float(p.x), float(p.y)) for p in points))


def search_target_msg(target: Target | None, header: Header, source: str) -> SearchTarget:
    msg = SearchTarget()
    msg.header = header
    msg.source = source
    if target is not None:
        msg.points = [Point(x, y, 0.0) for x, y in target.points_xy_m]
    return msg


def weights_msg(weights: Mapping[str, float], header: Header) -> FeatureWeights:
    msg = FeatureWeights()
    msg.header = header
    msg.features = list(weights)
    msg.weights = [float(weights[k]) for k in weights]
    return msg


def controller_state_msg(status: ControllerStatus, header: Header) -> ControllerState:
    msg = ControllerState()
    msg.header = header
    msg.state = status.state.value
    msg.autopilot_mode = status.autopilot_mode
    msg.armed = status.armed
    msg.in_air = status.in_air
    msg.link_ok = status.link_ok
    msg.last_event = status.last_event
    return msg


def odometry_msg(odom: OdometryReading | PoseEstimate, header: Header, child_frame_id: str = "base_link") -> Odometry:
    """nav_msgs/Odometry ``header.frame_id -> child_frame_id`` from the autopilot's estimate (with its covariances)."""
    msg = Odometry()
    msg.header = header
    msg.child_frame_id = child_frame_id
    if odom.pose_covariance:
        msg.pose.covariance = list(odom.pose_covariance)
    if odom.twist_covariance:
        msg.twist.covariance = list(odom.twist_covariance)
    p = msg.pose.pose.position
    p.x, p.y, p.z = odom.position_enu_m
    w, x, y, z = odom.q_enu_flu_wxyz
    q = msg.pose.pose.orientation
    q.x, q.y, q.z, q.w = x, y, z, w
    v = msg.twist.twist.linear
    v.x, v.y, v.z = odom.velocity_flu_mps
    a = msg.twist.twist.angular
    a.x, a.y, a.z = odom.angular_flu_radps
    return msg


def battery_msg(
    header: Header,
    *,
    voltage_v: float,
    current_a: float,
    remaining_frac: float,
    consumed_mah: float,
    capacity_mah: float | None,
) -> BatteryState:
    """sensor_msgs/BatteryState from autopilot telemetry (NaN where unknown).

    ``charge`` and ``capacity`` (Ah) are filled only when the pack capacity is
    configured: ``charge = capacity - consumed``.
    """
    msg = BatteryState()
    msg.header = header
    msg.voltage = voltage_v
    msg.current = -current_a if math.isfinite(current_a) else math.nan  # ROS: negative while discharging
    msg.percentage = remaining_frac
    known = capacity_mah is not None and math.isfinite(consumed_mah)
    msg.capacity = capacity_mah / 1000.0 if capacity_mah is not None else math.nan
    msg.design_capacity = msg.capacity
    msg.charge = (capacity_mah - consumed_mah) / 1000.0 if known and capacity_mah is not None else math.nan
    msg.power_supply_status = BatteryState.POWER_SUPPLY_STATUS_DISCHARGING
    msg.power_supply_health = BatteryState.POWER_SUPPLY_HEALTH_UNKNOWN
    msg.power_supply_technology = BatteryState.POWER_SUPPLY_TECHNOLOGY_LIPO
    msg.present = True
    msg.location = "autopilot"
    return msg
