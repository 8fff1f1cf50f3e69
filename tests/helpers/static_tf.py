"""A static map -> camera transform for rostest check nodes that play a fixed nadir camera."""

from __future__ import annotations

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped


def nadir_camera_tf(frame_id: str, z_m: float, stamp_s: float) -> tf2_ros.StaticTransformBroadcaster:
    """Latch ``map -> frame_id``: an optical frame ``z_m`` above the map origin looking straight down
    (180 deg about x: optical z down, y south). Keep the returned broadcaster alive while the test runs."""
    broadcaster = tf2_ros.StaticTransformBroadcaster()
    t = TransformStamped()
    t.header.stamp = rospy.Time.from_sec(stamp_s)
    t.header.frame_id = "map"
    t.child_frame_id = frame_id
    t.transform.translation.z = z_m
    t.transform.rotation.x = 1.0
    broadcaster.sendTransform(t)
    return broadcaster
