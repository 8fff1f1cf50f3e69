#!/usr/bin/env python3

"""rostest node: the real waypoint_controller node flies a fake PX4 (fake_px4.py) through every state."""

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
from fake_px4 import FakePx4  # noqa: E402
from geometry_msgs.msg import Point, PoseStamped  # noqa: E402
from helpers.paths import REPO  # noqa: E402
from helpers.procs import Proc, free_udp_port  # noqa: E402
from nav_msgs.msg import Path as PathMsg  # noqa: E402
from sensor_msgs.msg import BatteryState  # noqa: E402

from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import ControllerState  # noqa: E402
from uav_msgs.srv import SetControllerState, SetControllerStateRequest  # noqa: E402


class ControllerAgainstFakePx4(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("controller_check")
        cls.port = free_udp_port()
        cls.proc = Proc(
            "autonomy_waypoint_controller_fake_peer",
            [
                "rosrun", "uav_autonomy", "waypoint_controller",
                f"_config:={REPO / 'config/autonomy.yaml'}",
                f"_connection_url:=udpin:127.0.0.1:{cls.port}",
                "_overrides:={link_timeout_s: 1.0, reconnect_after_s: 2.0, mode_retry_s: 0.5, takeoff_height_m: 10.0}",
            ],
        )  # fmt: skip
        cls.peer = FakePx4(cls.port).start()
        cls.state: ControllerState | None = None
        cls.states: list[ControllerState] = []
        cls.battery: BatteryState | None = None
        rospy.Subscriber("/uav/controller/state", ControllerState, cls._on_state)
        rospy.Subscriber("/uav/battery", BatteryState, cls._on_battery)
        cls.pub_path = rospy.Publisher("/autonomy/path", PathMsg, queue_size=1, latch=True)
        cls.pub_manual = rospy.Publisher("/waypoint_controller/manual_setpoint", PoseStamped, queue_size=1)
        rospy.wait_for_service("/waypoint_controller/set_state", timeout=30.0)
        cls.set_state = rospy.ServiceProxy("/waypoint_controller/set_state", SetControllerState)

    @classmethod
    def tearDownClass(cls) -> None:
        cls.peer.stop()
        cls.proc.stop()

    @classmethod
    def _on_state(cls, msg: ControllerState) -> None:
        cls.state = msg
        cls.states.append(msg)

    @classmethod
    def _on_battery(cls, msg: BatteryState) -> None:
        cls.battery = msg

    def wait_state(self, name: str, timeout_s: float) -> ControllerState:
        return wait_until(lambda: self.state, lambda s: s is not None and s.state == name, timeout_s=timeout_s,
                          describe=f"controller state {name}")  # fmt: skip

    def near(self, enu: tuple[float, float, float], tol: float, timeout_s: float) -> None:
        wait_until(self.peer.pos_enu, lambda p: math.dist(p, enu) < tol, timeout_s=timeout_s,
                   describe=f"vehicle near {enu}")  # fmt: skip

    def request(self, state: str, **kw: object) -> None:
        resp = self.set_state(SetControllerStateRequest(state=state, **kw))
        self.assertTrue(resp.success, resp.message)

    def test_flight(self) -> None:
        peer = self.peer
        # Link up, IDLE sends nothing.
        wait_until(lambda: self.state, lambda s: s is not None and s.link_ok, timeout_s=20.0, describe="link_ok")
        time.sleep(0.5)
        self.assertEqual(peer.setpoints, [])
        self.assertEqual(self.state.state, "IDLE")
        self.assertGreater(peer.controller_heartbeats, 0)

        # TAKEOFF: stream >= 1 s at >= 10 Hz, OFFBOARD rejected once and retried, then arm and climb.
        peer.reject_offboard = 1
        self.request("TAKEOFF")
        self.wait_state("HOLD", 30.0)
        first_sp = peer.setpoints[0].t
        offboard = [r for r in peer.mode_requests if r[1] == "OFFBOARD"]
        self.assertGreaterEqual(len(offboard), 2, offboard)
        self.assertFalse(offboard[0][2])
        self.assertTrue(offboard[-1][2])
        self.assertGreaterEqual(offboard[0][0] - first_sp, 1.0)
        streamed = peer.setpoints_between(first_sp, offboard[0][0])
        self.assertGreaterEqual(len(streamed) / (offboard[0][0] - first_sp), 10.0)
        self.assertGreater(peer.arm_requests[0], offboard[-1][0])
        sp = peer.setpoints[-1]
        self.assertEqual(sp.type_mask, 2552)
        self.assertEqual(sp.frame, 1)
        self.assertEqual(sp.target, (1, 1))
        self.assertAlmostEqual(sp.ned[2], -10.0, delta=0.01)  # 10 m up is NED z = -10
        self.assertAlmostEqual(peer.pos_enu()[2], 10.0, delta=1.5)

        # AUTONOMOUS: follow a planner path (ENU); the peer receives NED.
        path = PathMsg()
        path.header.frame_id = "map"
        for x, y, z in [(0, 0, 10), (0, 0, 20), (30, 10, 20), (30, 10, 15)]:
            pose = PoseStamped()
            pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = x, y, z
            pose.pose.orientation.w = 1.0
            path.poses.append(pose)
        self.pub_path.publish(path)
        self.request("AUTONOMOUS")
        self.near((30.0, 10.0, 15.0), 1.0, 20.0)
        n, e, d = peer.setpoints[-1].ned
        self.assertAlmostEqual(n, 10.0, delta=0.01)
        self.assertAlmostEqual(e, 30.0, delta=0.01)
        self.assertAlmostEqual(d, -15.0, delta=0.01)

        # MANUAL: the operator's setpoint takes effect at once.
        manual = PoseStamped()
        manual.pose.position = Point(25.0, 5.0, 18.0)
        manual.pose.orientation.w = 1.0
        t_manual = time.monotonic()
        self.pub_manual.publish(manual)
        wait_until(lambda: peer.setpoints[-1].ned, lambda ned: math.dist(ned, (5.0, 25.0, -18.0)) < 0.01,
                   timeout_s=1.0, describe="manual setpoint at the peer")  # fmt: skip
        self.assertLess(time.monotonic() - t_manual, 0.5)
        self.wait_state("MANUAL", 2.0)
        self.near((25.0, 5.0, 18.0), 1.0, 10.0)

        # NaN manual setpoint: rejected, nothing non-finite reaches the autopilot.
        bad = PoseStamped()
        bad.pose.position = Point(math.nan, 0.0, 10.0)
        self.pub_manual.publish(bad)
        time.sleep(0.5)
        self.assertTrue(all(all(math.isfinite(v) for v in s.ned) for s in peer.setpoints))
        self.assertEqual(self.state.state, "MANUAL")

        # HOLD and stare at a point west of the vehicle: yaw (NED) faces west = -pi/2.
        self.request("HOLD", points=[Point(-100.0, 5.0, 0.0)])
        time.sleep(0.5)
        self.assertAlmostEqual(abs(peer.setpoints[-1].yaw), math.pi / 2, delta=0.05)
        self.assertLess(peer.setpoints[-1].yaw, 0.0)

        # Autopilot failsafe: mode changes under the controller; it yields at once.
        # The controller sees it with the next heartbeat (2 Hz here) and stops within one timer tick.
        peer.force_mode("AUTO.RTL")
        self.wait_state("RTL", 2.0)
        t_rtl = time.monotonic()
        self.assertIn("yielded", self.state.last_event)
        time.sleep(0.5)
        self.assertEqual(peer.setpoints_between(t_rtl + 0.1, time.monotonic()), [])
        self.wait_state("IDLE", 30.0)
        self.assertIn("landed and disarmed", self.state.last_event)

        # Link drop while flying: setpoints stop, no stale setpoints after the link returns.
        self.request("TAKEOFF")
        self.wait_state("HOLD", 30.0)
        peer.paused = True
        t_drop = time.monotonic()
        wait_until(lambda: self.state, lambda s: not s.link_ok, timeout_s=3.0, describe="link lost")
        time.sleep(2.5)  # past reconnect_after_s: the controller reopens its socket
        self.assertEqual(self.state.state, "IDLE")
        self.assertEqual(peer.setpoints_between(t_drop + 1.3, time.monotonic()), [])
        peer.paused = False
        wait_until(lambda: self.state, lambda s: s.link_ok, timeout_s=5.0, describe="link back")
        t_back = time.monotonic()
        time.sleep(1.0)
        self.assertEqual(peer.setpoints_between(t_back, time.monotonic()), [])
        self.assertEqual(self.state.state, "IDLE")

        # Re-engage (the peer fell back to AUTO.LOITER on offboard loss), then RTL on request.
        self.request("HOLD")
        self.wait_state("HOLD", 10.0)
        self.wait_until_offboard()
        self.request("RTL")
        self.wait_state("IDLE", 30.0)
        self.assertFalse(peer.armed)
        self.assertLess(peer.pos_enu()[2], 0.1)
        self.assertIsNotNone(self.battery)
        self.assertAlmostEqual(self.battery.voltage, 16.0, delta=0.01)
        self.assertAlmostEqual(self.battery.percentage, 0.87, delta=0.01)

        # Bad requests are refused with a reason.
        resp = self.set_state(SetControllerStateRequest(state="FLY"))
        self.assertFalse(resp.success)
        resp = self.set_state(SetControllerStateRequest(state="SCRIPTED", pattern="lawnmower", spacing_m=0.0))
        self.assertFalse(resp.success)
        self.assertTrue(self.proc.alive(), self.proc.tail())

    def wait_until_offboard(self) -> None:
        wait_until(lambda: self.peer.mode, lambda m: m == "OFFBOARD", timeout_s=10.0, describe="peer in OFFBOARD")


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "autonomy_controller_fake_peer", ControllerAgainstFakePx4)
