"""robot_description: the airframe's static transforms from its one description file.

ROS interface:

Publishes:
    ``/tf_static`` (latched): ``base_link -> camera_<name>`` (the mount) and ``camera_<name> ->
    camera_<name>_optical`` for every camera of the robot description (:mod:`uav_common.robot`).
Parameters:
    ``~file`` (str, default: the project's ``config/robot.yaml``): the robot description. A missing file,
    an unknown key or a bad value stops the node (exit code 2) naming the file and key.

On a real vehicle this is where the camera extrinsics come from; in a scenario run the simulator renders
each camera from the same file, so the two can never disagree.

Causal lockstep (docs/lockstep.md): a participant that publishes its transforms once, before the first step
(its start-up count), and then only reports each step done.
"""

from __future__ import annotations

from pathlib import Path

import rospy
from geometry_msgs.msg import TransformStamped
from std_msgs.msg import Header

from uav_autonomy.errors import AutonomyConfigError, UavAutonomyError
from uav_autonomy.ros.params import RobotDescriptionParams
from uav_common.config import config_errors_as
from uav_common.paths import config_file
from uav_common.robot import RobotDescription, StaticTransform, load_robot_description
from uav_common.ros.lockstep import Participant
from uav_common.ros.node import run_participant
from uav_common.ros.params import node_params

__all__ = ["main", "transform_msgs"]

#: A static participant of the causal lockstep (docs/lockstep.md): it publishes nothing after start-up, so no step
#: waits for it and it gets no ticks.
NO_OUTPUTS_LOOKAHEAD = 0


def transform_msgs(description: RobotDescription) -> list[TransformStamped]:
    """The description's static transforms as messages (stamp 0: valid at any time)."""
    return [_msg(t) for t in description.static_transforms()]


def _msg(t: StaticTransform) -> TransformStamped:
    msg = TransformStamped()
    msg.header = Header(stamp=rospy.Time(0), frame_id=t.parent)
    msg.child_frame_id = t.child
    msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = t.translation_m
    w, x, y, z = t.q_wxyz
    r = msg.transform.rotation
    r.x, r.y, r.z, r.w = x, y, z, w
    return msg


def main() -> None:
    run_participant("robot_description", _build, lookahead_steps=NO_OUTPUTS_LOOKAHEAD, errors=(UavAutonomyError,))


def _build(ls: Participant) -> None:
    params = node_params(RobotDescriptionParams, "robot_description")
    with config_errors_as(AutonomyConfigError):
        path = Path(params.file).expanduser() if params.file else config_file("robot.yaml")
        description = load_robot_description(path)
    broadcaster = ls.tf_broadcaster(static=True)
    msgs = transform_msgs(description)
    broadcaster.sendTransform(msgs)
    rospy.loginfo(
        f"robot_description: {len(description.cameras)} camera(s) from {path}: "
        + ", ".join(f"{m.header.frame_id} -> {m.child_frame_id}" for m in msgs)
    )
