#!/usr/bin/env python3
"""The rostest harness talks to a real master: publish and receive one message."""

import unittest

import rospy
import rostest
from std_msgs.msg import String


class HarnessSelfTest(unittest.TestCase):
    def test_round_trip_through_master(self) -> None:
        rospy.init_node("harness_selftest")
        got: list[str] = []
        rospy.Subscriber("/harness/echo", String, lambda m: got.append(m.data))
        pub = rospy.Publisher("/harness/echo", String, queue_size=1)
        deadline = rospy.Time.now() + rospy.Duration(10.0)
        while not got and rospy.Time.now() < deadline and not rospy.is_shutdown():
            pub.publish(String("ping"))
            rospy.sleep(0.1)
        self.assertEqual(got[:1], ["ping"])


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "harness_selftest", HarnessSelfTest)
