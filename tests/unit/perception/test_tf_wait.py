"""Waiting for a transform with the message's own deadline (``uav_perception.ros.tf_wait``), on a real tf2 buffer.

The geolocator once fell behind for good: the first frames of a run came before the first transform, each waited
its full timeout while the lockstep simulation ran on, and every frame it reached afterwards was older than the
transforms still buffered. A frame that already waited in the queue must not wait again, and a stamp older than
the buffer's oldest transform must fail at once.
"""

from __future__ import annotations

import time

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped

from uav_perception.ros.tf_wait import lookup_until


def _buffer(times_s: list[float]) -> tf2_ros.Buffer:
    buffer = tf2_ros.Buffer(cache_time=rospy.Duration(30.0), debug=False)
    for t in times_s:
        msg = TransformStamped()
        msg.header.stamp = rospy.Time.from_sec(t)
        msg.header.frame_id = "map"
        msg.child_frame_id = "camera_optical"
        msg.transform.translation.x = t  # moves 1 m a second
        msg.transform.rotation.w = 1.0
        buffer.set_transform(msg, "test")
    return buffer


def test_a_buffered_pose_is_found_and_interpolated() -> None:
    buffer = _buffer([10.0, 11.0])
    tf, why = lookup_until(buffer, "map", "camera_optical", rospy.Time.from_sec(10.5), time.monotonic() + 1.0)
    assert tf is not None, why
    assert abs(tf.transform.translation.x - 10.5) < 1e-9


def test_a_stamp_older_than_the_buffer_fails_at_once() -> None:
    buffer = _buffer([40.0, 41.0])
    t0 = time.monotonic()
    tf, why = lookup_until(buffer, "map", "camera_optical", rospy.Time.from_sec(2.0), t0 + 5.0)
    assert tf is None
    assert "past" in why
    assert time.monotonic() - t0 < 0.5  # not the 5 s the deadline allowed


def test_a_frame_that_waited_in_the_queue_does_not_wait_again() -> None:
    """Twenty frames that arrived together a second ago, stamped after the newest transform: each fails at once
    (its deadline, arrival + 0.5 s, has passed), so the last is handled as soon as the first; a frame that has
    just arrived waits for its pose until its own deadline."""
    buffer = _buffer([1.0, 2.0])
    arrived = time.monotonic() - 1.0
    t0 = time.monotonic()
    for k in range(20):
        tf, why = lookup_until(buffer, "map", "camera_optical", rospy.Time.from_sec(3.0 + 0.1 * k), arrived + 0.5)
        assert tf is None
        assert "future" in why
    assert time.monotonic() - t0 < 0.5  # 20 x 0.5 s before
    t1 = time.monotonic()
    tf, _ = lookup_until(buffer, "map", "camera_optical", rospy.Time.from_sec(5.0), t1 + 0.2)
    assert tf is None
    assert time.monotonic() - t1 >= 0.2  # a fresh frame still gets its wait
