#!/usr/bin/env python3

"""rostest node: the real autopilot_odometry, robot_description and waypoint_controller nodes against a PX4-like
peer (fake_px4.py) whose clock started 1000 s before ROS time's.

Checked: odometry in ROS conventions with the autopilot's covariance, stamped with the autopilot's time mapped by
TIMESYNC (not by arrival); tf map -> odom -> base_link -> camera_nadir_optical; the fallback to LOCAL_POSITION_NED +
ATTITUDE_QUATERNION when ODOMETRY stops; a NaN estimate and then a stale one each stop the controller commanding
(no setpoint, the autopilot asked to hold, the reason in its state), and it flies again once the pose is fit.
"""

from __future__ import annotations

import math
import sys
import time
import unittest
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE), str(HERE.parents[1])]
import rospy  # noqa: E402
import rostest  # noqa: E402
import tf2_ros  # noqa: E402
from fake_px4 import FakePx4  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from helpers.paths import REPO  # noqa: E402
from helpers.procs import Proc, free_udp_port  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from nav_msgs.msg import Path as PathMsg  # noqa: E402

from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import ControllerState, EstimateStatus  # noqa: E402
from uav_msgs.srv import SetControllerState, SetControllerStateRequest  # noqa: E402

ODOM = "/uav/autopilot/odom"
BOOT_OFFSET_S = 1000.0


class AutopilotEstimate(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("estimate_check")
        cls.port, cls.est_port = free_udp_port(), free_udp_port()
        cls.odometry = Proc(
            "autonomy_autopilot_odometry",
            [
                "rosrun", "uav_autonomy", "autopilot_odometry",
                f"_config:={REPO / 'config/autonomy.yaml'}",
                f"_connection_url:=udpin:127.0.0.1:{cls.est_port}",
                "_overrides:={timesync_rate_hz: 5.0, status_rate_hz: 10.0}",
            ],
        )  # fmt: skip
        cls.robot = Proc("autonomy_robot_description", ["rosrun", "uav_autonomy", "robot_description"])
        cls.controller = Proc(
            "autonomy_controller_pose_watch",
            [
                "rosrun", "uav_autonomy", "waypoint_controller",
                f"_config:={REPO / 'config/autonomy.yaml'}",
                f"_connection_url:=udpin:127.0.0.1:{cls.port}",
                f"_pose_topic:={ODOM}",
                "_overrides:={mode_retry_s: 0.5, takeoff_height_m: 10.0, pose_timeout_s: 0.5, wall_floor_s: 0.0}",
            ],
        )  # fmt: skip
        # the autopilot booted 1000 s before "now": its stamps are 1000 s behind ROS time
        cls.peer = FakePx4(
            cls.port, estimate_port=cls.est_port, boot_offset_s=time.monotonic() - time.time() + BOOT_OFFSET_S
        )
        cls.peer.start()
        cls.odoms: list[tuple[float, Odometry]] = []
        cls.status: EstimateStatus | None = None
        cls.state: ControllerState | None = None
        rospy.Subscriber(ODOM, Odometry, lambda m: cls.odoms.append((rospy.get_time(), m)), queue_size=100)
        rospy.Subscriber("/autopilot_odometry/status", EstimateStatus, cls._on_status, queue_size=10)
        rospy.Subscriber("/uav/controller/state", ControllerState, cls._on_state, queue_size=10)
        cls.pub_path = rospy.Publisher("/autonomy/path", PathMsg, queue_size=1, latch=True)
        rospy.wait_for_service("/waypoint_controller/set_state", timeout=30.0)
        cls.set_state = rospy.ServiceProxy("/waypoint_controller/set_state", SetControllerState)
        cls.tf = tf2_ros.Buffer(rospy.Duration(30.0))
        cls.listener = tf2_ros.TransformListener(cls.tf)

    @classmethod
    def tearDownClass(cls) -> None:
        cls.peer.stop()
        for proc in (cls.controller, cls.odometry, cls.robot):
            proc.stop()

    @classmethod
    def _on_status(cls, msg: EstimateStatus) -> None:
        cls.status = msg

    @classmethod
    def _on_state(cls, msg: ControllerState) -> None:
        cls.state = msg

    def wait_status(self, state: str, timeout_s: float, source: str = "") -> EstimateStatus:
        return wait_until(
            lambda: self.status,
            lambda s: s is not None and s.state == state and (not source or s.source == source),
            timeout_s=timeout_s,
            describe=f"estimate {state} {source}",
        )

    def wait_state(self, name: str, timeout_s: float) -> ControllerState:
        return wait_until(lambda: self.state, lambda s: s is not None and s.state == name, timeout_s=timeout_s,
                          describe=f"controller {name}")  # fmt: skip

    def fly(self) -> None:
        path = PathMsg()
        path.header.frame_id = "map"
        for x, y, z in [(0, 0, 10), (200, 0, 10)]:
            pose = PoseStamped()
            pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = x, y, z
            pose.pose.orientation.w = 1.0
            path.poses.append(pose)
        self.pub_path.publish(path)
        resp = self.set_state(SetControllerStateRequest(state="AUTONOMOUS"))
        self.assertTrue(resp.success, resp.message)
        self.wait_state("AUTONOMOUS", 30.0)
        wait_until(lambda: self.peer.mode, lambda m: m == "OFFBOARD", timeout_s=10.0, describe="OFFBOARD")
        wait_until(self.peer.pos_enu, lambda p: p[0] > 5.0, timeout_s=10.0, describe="flying east")

    def stops_commanding(self, why: str, *, still_bad: bool = True) -> None:
        state = self.wait_state("IDLE", 5.0)
        t_stop = time.monotonic()
        self.assertIn(f"pose estimate on {ODOM} cannot be flown on", state.last_event)
        self.assertIn(why, state.last_event)
        wait_until(lambda: self.peer.mode, lambda m: m == "AUTO.LOITER", timeout_s=3.0, describe="asked to hold")
        self.assertTrue(any(r[1] == "AUTO.LOITER" and r[2] for r in self.peer.mode_requests))
        time.sleep(1.0)
        self.assertEqual(self.peer.setpoints_between(t_stop + 0.2, time.monotonic()), [])
        if still_bad:  # refused while the pose is unfit
            resp = self.set_state(SetControllerStateRequest(state="AUTONOMOUS"))
            self.assertFalse(resp.success)
            self.assertIn("cannot be flown on", resp.message)

    def test_estimate(self) -> None:
        peer = self.peer
        status = self.wait_status("OK", 30.0, source="ODOMETRY")
        wait_until(lambda: self.status, lambda s: s.time_sync == "timesync", timeout_s=10.0, describe="timesync")
        self.assertTrue(status.covariance_from_autopilot)
        self.assertGreater(peer.timesync_answers, 0)
        self.assertIn((331.0, 20000.0), peer.interval_requests)  # ODOMETRY asked for at 50 Hz
        # ROS time minus the autopilot's: the 1000 s offset, to a few ms (TIMESYNC, on one machine)
        self.assertAlmostEqual(self.status.time_offset_s, BOOT_OFFSET_S, delta=0.02)
        # odometry: odom -> base_link, ENU, the autopilot's covariance in ENU, stamped at most a few ms old
        wait_until(lambda: len(self.odoms), lambda n: n >= 50, timeout_s=10.0, describe="50 estimates")
        arrived, odom = self.odoms[-1]
        self.assertEqual((odom.header.frame_id, odom.child_frame_id), ("odom", "base_link"))
        self.assertLess(abs(arrived - odom.header.stamp.to_sec()), 0.1)
        n, e, d = peer.pos
        p = odom.pose.pose.position
        self.assertAlmostEqual(p.x, e, delta=0.5)
        self.assertAlmostEqual(p.y, n, delta=0.5)
        self.assertAlmostEqual(p.z, -d, delta=0.5)
        self.assertAlmostEqual(abs(odom.pose.pose.orientation.w), 1.0, delta=1e-6)  # heading east = ENU yaw 0
        cov = odom.pose.covariance
        self.assertEqual((cov[0], cov[7], cov[14]), (1.0, 0.25, 2.25))  # east, north, up variances
        stamps = [m.header.stamp.to_sec() for _, m in self.odoms[-20:]]
        self.assertEqual(stamps, sorted(stamps))
        # tf: map -> odom (identity) -> base_link (the estimate) -> camera (robot description)
        t = self.tf.lookup_transform("map", "camera_nadir_optical", rospy.Time(0), rospy.Duration(5.0))
        self.assertAlmostEqual(t.transform.translation.z, -d - 0.08, delta=0.5)

        # fly on it
        resp = self.set_state(SetControllerStateRequest(state="TAKEOFF"))
        self.assertTrue(resp.success, resp.message)
        self.wait_state("HOLD", 30.0)
        self.fly()

        # NaN from the autopilot: INVALID at once with the reason and nothing NaN is published, so the pose the
        # controller watches stops coming: it stops commanding after pose_timeout_s (0.5 s here)
        published = len(self.odoms)
        peer.estimate_mode = "nan"
        status = self.wait_status("INVALID", 3.0)
        self.assertIn("ODOMETRY position is not finite", status.reason)
        self.assertGreater(status.invalid, 0)
        self.stops_commanding("no fresh estimate")
        self.assertLessEqual(len(self.odoms), published + 5)
        self.assertTrue(all(math.isfinite(m.pose.pose.position.x) for _, m in self.odoms))

        # fit again: it may fly
        peer.estimate_mode = "ok"
        self.wait_status("OK", 5.0)
        self.fly()

        # a NaN pose on the watched topic itself (any other odometry source could send one): it stops at once
        bad = Odometry()
        bad.header.stamp = rospy.Time.now()
        bad.pose.pose.position.x = math.nan
        bad.pose.pose.orientation.w = 1.0
        pub = rospy.Publisher(ODOM, Odometry, queue_size=1)
        wait_until(pub.get_num_connections, lambda n: n > 0, timeout_s=5.0, describe="controller subscribed")
        time.sleep(0.3)
        pub.publish(bad)
        self.stops_commanding("a message with NaN/inf", still_bad=False)  # one NaN is enough to stop
        self.fly()  # the estimates that followed are fine: it may fly again when asked

        # silence: STALE, the controller stops
        peer.estimate_mode = "paused"
        status = self.wait_status("STALE", 5.0)
        self.assertIn("no fresh estimate", status.reason)
        self.stops_commanding("no fresh estimate")

        # an autopilot without ODOMETRY: LOCAL_POSITION_NED + ATTITUDE_QUATERNION after odometry_fallback_s
        peer.estimate_mode = "no_odometry"
        status = self.wait_status("OK", 10.0, source="LOCAL_POSITION_NED+ATTITUDE_QUATERNION")
        self.assertFalse(status.covariance_from_autopilot)
        _, odom = self.odoms[-1]
        self.assertEqual(odom.pose.covariance[0], 1.0)  # the assumed 1 m (config/autonomy.yaml)
        for proc in (self.odometry, self.controller, self.robot):
            self.assertTrue(proc.alive(), proc.tail())


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "autonomy_autopilot_estimate", AutopilotEstimate)
