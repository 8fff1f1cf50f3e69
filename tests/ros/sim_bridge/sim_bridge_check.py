#!/usr/bin/env python3
"""rostest: the sim_bridge node (sim_bridge.launch) against a fake SITL in lockstep, through a real roscore.

The test node owns the fake SITL (a free UDP port) and starts the bridge's launch file
with that port, so the bridge is the lockstep master of a scripted flight: 30 m over
home, drifting east at 2 m/s.  It checks /clock, tf, odometry, every camera topic,
detections, collisions, the terrain reports, the set_object_pose service and camera faults (set_camera_fault).
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import Point
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # tests/: the shared helpers
from helpers.paths import REPO  # noqa: E402
from helpers.procs import Proc  # noqa: E402

sys.path.insert(0, str(HERE))

from fake_sitl_peer import HOME, FakeSitl, hover_east  # noqa: E402

from uav_common.geo import LocalProjection  # noqa: E402
from uav_common.ros.arrays import cloud_to_xyzrgb, image_to_array  # noqa: E402
from uav_msgs.msg import Collision, DetectionArray, ObjectStateArray, SimState  # noqa: E402
from uav_msgs.srv import SetCameraFault, SetObjectPose, SetObjectPoseRequest  # noqa: E402
from uav_sim_bridge.core.world_config import ObjectClass, load_world_config  # noqa: E402
from uav_sim_bridge.shell.world_store import load_or_generate  # noqa: E402

ALT_M = 30.0
SPEED_MPS = 2.0
WORLD_YAML = HERE / "test_world.yaml"
ARTIFACTS = Path(os.environ.get("UAV_ARTIFACTS", REPO / "artifacts"))
CACHE = ARTIFACTS / "world_cache"


class Inbox:
    """Latest message and count per topic, filled by subscriber threads."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.last: dict[str, object] = {}
        self.count: dict[str, int] = {}
        self.clock: list[float] = []
        self.detections: list[DetectionArray] = []
        self.history: dict[str, list[object]] = {}

    def cb(self, topic: str):
        def on(msg: object) -> None:
            with self.lock:
                self.last[topic] = msg
                self.count[topic] = self.count.get(topic, 0) + 1
                self.history[topic] = [*self.history.get(topic, [])[-9:], msg]
                if topic == "/clock":
                    self.clock.append(msg.clock.to_sec())  # type: ignore[attr-defined]
                if topic == "/detections/ground_truth":
                    self.detections.append(msg)  # type: ignore[arg-type]

        return on

    def same_stamp(self, a: str, b: str) -> tuple[object, object]:
        """Messages of topics ``a`` and ``b`` from the same instant (images of one frame)."""
        self.wait(a, 2)
        self.wait(b, 2)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            with self.lock:
                by_stamp = {m.header.stamp: m for m in self.history[b]}  # type: ignore[attr-defined]
                for m in reversed(self.history[a]):
                    if m.header.stamp in by_stamp:  # type: ignore[attr-defined]
                        return m, by_stamp[m.header.stamp]  # type: ignore[attr-defined]
            time.sleep(0.02)
        raise AssertionError(f"no {a} and {b} with the same stamp")

    def wait(self, topic: str, n: int = 1, timeout_s: float = 30.0) -> object:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if self.count.get(topic, 0) >= n:
                    return self.last[topic]
            time.sleep(0.02)
        raise AssertionError(f"fewer than {n} messages on {topic} within {timeout_s} s")


class SimBridgeCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("sim_bridge_check")
        cls.world = load_or_generate(load_world_config(WORLD_YAML), CACHE)
        cls.sitl = FakeSitl(lockstep=True, trajectory=hover_east(ALT_M, SPEED_MPS)).start()
        cls.bridge = Proc(
            "rostest_sim_bridge_node",
            [
                "roslaunch",
                "uav_sim_bridge",
                "sim_bridge.launch",
                f"sim_port:={cls.sitl.port}",
                f"world:={WORLD_YAML}",
                f"world_cache_dir:={CACHE}",
                "lockstep_role:=master",
                "output:=screen",
            ],
        )
        cls.inbox = Inbox()
        topics = {
            "/clock": Clock,
            "/uav/ground_truth/odom": Odometry,
            "/uav/sim_state": SimState,
            "/detections/ground_truth": DetectionArray,
            "/sim/collision": Collision,
            "/sim/object_states": ObjectStateArray,
        }
        for cam in ("nadir", "forward"):
            ns = f"/cameras/{cam}"
            topics |= {
                f"{ns}/color/image_raw": Image,
                f"{ns}/color/camera_info": CameraInfo,
                f"{ns}/depth/image_raw": Image,
                f"{ns}/depth/camera_info": CameraInfo,
                f"{ns}/instance/image_raw": Image,
                f"{ns}/class/image_color": Image,
                f"{ns}/points": PointCloud2,
            }
        cls.subs = [rospy.Subscriber(t, ty, cls.inbox.cb(t), queue_size=5) for t, ty in topics.items()]
        cls.tf_buffer = tf2_ros.Buffer(cache_time=rospy.Duration(600))
        cls.tf_listener = tf2_ros.TransformListener(cls.tf_buffer)
        cls.inbox.wait("/uav/sim_state", 5, timeout_s=60.0)

    @classmethod
    def tearDownClass(cls) -> None:
        cls.bridge.stop(5.0, int_timeout_s=15.0)
        cls.sitl.stop()

    # ------------------------------------------------------------------ tests
    def test_1_clock_advances_by_grants(self) -> None:
        self.inbox.wait("/clock", 50)
        with self.inbox.lock:
            clock = list(self.inbox.clock)
        steps = np.round(np.diff(clock), 6)
        self.assertTrue(np.all(steps > 0), "clock must increase")
        self.assertTrue(np.all(steps == 0.02), f"lockstep grants of 5 x 4 ms: {set(steps.tolist())}")
        state = self.inbox.wait("/uav/sim_state")
        self.assertTrue(state.lockstep)
        self.assertTrue(state.armed)
        self.assertEqual(len(state.motor_outputs), 4)
        grants = self.sitl.of_kind("COMMAND_LONG")
        self.assertGreater(len(grants), 40)
        self.assertTrue(all(g.fields["param1"] == 5 for g in grants))

    def test_2_odometry_and_tf_follow_the_sitl(self) -> None:
        # The tf listener may have subscribed after the first odometry went out: make sure
        # the buffer holds transforms, then check an odometry message published after that.
        self.tf_buffer.lookup_transform("map", "base_link", rospy.Time(0), rospy.Duration(10.0))
        with self.inbox.lock:
            seen = self.inbox.count.get("/uav/ground_truth/odom", 0)
        odom = self.inbox.wait("/uav/ground_truth/odom", seen + 2)
        t = odom.header.stamp.to_sec()
        self.assertEqual(odom.header.frame_id, "map")
        self.assertEqual(odom.child_frame_id, "base_link")
        p = odom.pose.pose.position
        # NED (0, 2t, -30) -> ENU (2t, 0, 30); heading north -> ENU yaw +90 deg
        self.assertAlmostEqual(p.x, SPEED_MPS * t, places=3)
        self.assertAlmostEqual(p.y, 0.0, places=6)
        self.assertAlmostEqual(p.z, ALT_M, places=6)
        q = odom.pose.pose.orientation
        yaw = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        self.assertAlmostEqual(yaw, math.pi / 2, places=6)
        tf = self.tf_buffer.lookup_transform("map", "base_link", odom.header.stamp, rospy.Duration(5.0))
        self.assertAlmostEqual(tf.transform.translation.x, p.x, places=6)
        self.assertAlmostEqual(tf.transform.translation.z, p.z, places=6)
        opt = self.tf_buffer.lookup_transform("base_link", "camera_nadir_optical", rospy.Time(0), rospy.Duration(5.0))
        # nadir optical z axis = base_link -z: rotate (0, 0, 1) by the quaternion
        r = opt.transform.rotation
        z_axis = np.array([2 * (r.x * r.z + r.w * r.y), 2 * (r.y * r.z - r.w * r.x), 1 - 2 * (r.x * r.x + r.y * r.y)])
        np.testing.assert_allclose(z_axis, [0, 0, -1], atol=1e-6)
        self.tf_buffer.lookup_transform("camera_forward", "camera_forward_optical", rospy.Time(0), rospy.Duration(5.0))

    def test_3_camera_topics(self) -> None:
        for cam in ("nadir", "forward"):
            ns = f"/cameras/{cam}"
            color = self.inbox.wait(f"{ns}/color/image_raw", 2)
            depth = self.inbox.wait(f"{ns}/depth/image_raw", 2)
            inst = self.inbox.wait(f"{ns}/instance/image_raw", 2)
            klass = self.inbox.wait(f"{ns}/class/image_color", 2)
            info = self.inbox.wait(f"{ns}/depth/camera_info", 2)
            self.inbox.wait(f"{ns}/color/camera_info", 2)
            cloud = self.inbox.wait(f"{ns}/points", 2)
            self.assertEqual((color.encoding, color.width, color.height), ("rgb8", 640, 480))
            self.assertEqual(depth.encoding, "32FC1")
            self.assertEqual(inst.encoding, "16UC1")
            self.assertEqual(klass.encoding, "rgb8")
            for m in (color, depth, inst, klass, cloud, info):
                self.assertEqual(m.header.frame_id, f"camera_{cam}_optical")
            self.assertAlmostEqual(info.K[0], 320.0)
            self.assertAlmostEqual(info.K[2], 319.5)
            depth, inst = self.inbox.same_stamp(f"{ns}/depth/image_raw", f"{ns}/instance/image_raw")
            d = image_to_array(depth)
            ids = image_to_array(inst)
            self.assertTrue(set(np.unique(ids)) <= set(range(len(self.world.objects) + 1)))
            self.assertTrue(np.array_equal(np.isnan(d), ids == 0))
            xyz, _ = cloud_to_xyzrgb(cloud)
            self.assertTrue(np.all(np.isfinite(xyz)))
            self.assertEqual(cloud.point_step, 16)
            self.assertGreater(len(xyz), 1000)
        # nadir centre depth = height above the ground under the camera (within 1 cm + the mount offset)
        depth = self.inbox.wait("/cameras/nadir/depth/image_raw")
        t = depth.header.stamp.to_sec()
        d = image_to_array(depth)
        x = SPEED_MPS * t
        ground = self.world.ground_height_at(x, 0.0, ALT_M)[0]
        centre = float(np.mean(d[239:241, 319:321]))
        self.assertAlmostEqual(centre, ALT_M - 0.08 - ground, delta=0.05)

    def test_4_terrain_reports_precede_grants(self) -> None:
        self.inbox.wait("/uav/sim_state", 20)
        with self.sitl.lock:
            kinds = [r.kind for r in self.sitl.received if r.kind in ("TERRAIN_REPORT", "COMMAND_LONG")]
        grants_after_first = [i for i, k in enumerate(kinds) if k == "COMMAND_LONG" and i > 2]
        self.assertGreater(len(grants_after_first), 10)
        self.assertTrue(all(kinds[i - 1] == "TERRAIN_REPORT" for i in grants_after_first))
        report = self.sitl.of_kind("TERRAIN_REPORT")[-1]
        n, e, _ = LocalProjection(HOME).to_ned(type(HOME)(report.fields["lat"], report.fields["lon"], 0.0))
        surface = self.world.ground_height_at(e, n, ALT_M)[0]
        self.assertAlmostEqual(report.fields["terrain_height"], HOME.alt_amsl_m + surface, delta=0.05)
        self.assertAlmostEqual(report.fields["current_height"], ALT_M - surface, delta=0.1)

    def test_5_person_detected_when_moved_under_the_drone(self) -> None:
        rospy.wait_for_service("/sim_bridge/set_object_pose", 10.0)
        move = rospy.ServiceProxy("/sim_bridge/set_object_pose", SetObjectPose)
        person = self.world.objects_of_class(ObjectClass.PERSON)[0]
        odom = self.inbox.wait("/uav/ground_truth/odom")
        x_ahead = odom.pose.pose.position.x + 6.0
        resp = move(SetObjectPoseRequest(name=person.name, position=_point(x_ahead, 2.0, math.nan), yaw_rad=0.0))
        self.assertTrue(resp.success, resp.message)
        self.assertEqual(resp.instance_id, person.instance_id)
        with self.inbox.lock:
            start = len(self.inbox.detections)
        seen = self._wait_detection(person.instance_id, "nadir", start, present=True)
        d = next(d for d in seen.detections if d.instance_id == person.instance_id)
        self.assertEqual(d.class_name, "person")
        self.assertLess(d.x_min, d.x_max)
        self.assertGreater(d.visible_fraction, 0.5)
        self.assertAlmostEqual(d.range_m, ALT_M - 0.86, delta=8.0)
        # far away: out of frame -> gone
        resp = move(SetObjectPoseRequest(instance_id=person.instance_id, position=_point(-150.0, -150.0, math.nan)))
        self.assertTrue(resp.success, resp.message)
        with self.inbox.lock:
            start = len(self.inbox.detections)
        self._wait_detection(person.instance_id, "nadir", start, present=False)
        bad = move(SetObjectPoseRequest(name="terrain", position=_point(0.0, 0.0, 0.0)))
        self.assertFalse(bad.success)
        self.assertIn("cannot be moved", bad.message)
        unknown = move(SetObjectPoseRequest(name="nobody", position=_point(0.0, 0.0, 0.0)))
        self.assertFalse(unknown.success)

    def test_6_collision_reported_to_sitl_and_ros(self) -> None:
        move = rospy.ServiceProxy("/sim_bridge/set_object_pose", SetObjectPose)
        vehicle = self.world.objects_of_class(ObjectClass.VEHICLE)[0]
        odom = self.inbox.wait("/uav/ground_truth/odom")
        x_ahead = odom.pose.pose.position.x + 3.0
        # a car hanging in the air across the drone's path
        resp = move(
            SetObjectPoseRequest(name=vehicle.name, position=_point(x_ahead, 0.0, ALT_M - 1.0), yaw_rad=math.pi / 2)
        )
        self.assertTrue(resp.success, resp.message)
        msg = self.inbox.wait("/sim/collision", 1, timeout_s=30.0)
        self.assertEqual(msg.instance_id, vehicle.instance_id)
        self.assertEqual(msg.class_name, "vehicle")
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not self.sitl.of_kind("COLLISION"):
            time.sleep(0.05)
        col = self.sitl.of_kind("COLLISION")
        self.assertEqual(len(col), 1, "one report per contact")
        self.assertEqual(col[0].fields["id"], vehicle.instance_id)
        self.assertEqual(col[0].fields["threat_level"], 2)  # MAV_COLLISION_THREAT_LEVEL_HIGH
        self.assertEqual(col[0].fields["action"], 1)  # MAV_COLLISION_ACTION_REPORT

    def test_7_bridge_survives_garbage_on_the_sim_link(self) -> None:
        before = self.inbox.count.get("/uav/sim_state", 0)
        for junk in (b"\xfd\x09garbage", b"\x00" * 300, bytes(range(256))):
            self.sitl.send_raw(junk)
        self.inbox.wait("/uav/sim_state", before + 20, timeout_s=20.0)
        self.assertTrue(self.bridge.alive(), self.bridge.tail())

    def test_8_moving_objects_publish_their_ground_truth(self) -> None:
        first = self.inbox.wait("/sim/object_states", 1)
        n = self.inbox.count["/sim/object_states"]
        last = self.inbox.wait("/sim/object_states", n + 3)
        moving = [o for o in last.objects if o.moving]  # type: ignore[attr-defined]
        self.assertEqual(len(moving), 3, [(o.name, o.moving) for o in last.objects])  # type: ignore[attr-defined]
        self.assertEqual(last.header.frame_id, "map")  # type: ignore[attr-defined]
        dt = (last.header.stamp - first.header.stamp).to_sec()  # type: ignore[attr-defined]
        self.assertGreater(dt, 0.0)
        before = {o.instance_id: o for o in first.objects}  # type: ignore[attr-defined]
        for o in moving:
            self.assertIn(o.class_name, ("person", "vehicle"))
            self.assertIn(o.kind, ("walking", "car", "van", "truck"))
            self.assertGreater(o.size.z, 0.3)
            speed = math.hypot(o.velocity.x, o.velocity.y)
            moved = math.hypot(o.pose.position.x - before[o.instance_id].pose.position.x,
                               o.pose.position.y - before[o.instance_id].pose.position.y)  # fmt: skip
            # it moved as far as its speed says (paths turn: a little less, never more)
            self.assertLessEqual(moved, speed * dt + 0.05)
            self.assertGreater(moved, 0.5 * speed * dt)

    def test_9_camera_faults_through_the_service(self) -> None:
        rospy.wait_for_service("/sim_bridge/set_camera_fault", 10.0)
        fault = rospy.ServiceProxy("/sim_bridge/set_camera_fault", SetCameraFault)
        bad = fault(camera="down", type="off")
        self.assertEqual(bad.result, "DENIED")
        self.assertIn("unknown camera 'down'; this bridge runs forward, nadir", bad.detail)
        self.assertEqual(fault(camera="nadir", type="melted").result, "DENIED")
        color, depth = "/cameras/nadir/color/image_raw", "/cameras/nadir/depth/image_raw"

        def after(topic: str, t_s: float) -> Image:  # the first message of a frame captured after t_s
            deadline = time.monotonic() + 20.0
            while time.monotonic() < deadline:
                with self.inbox.lock:
                    later = [m for m in self.inbox.history.get(topic, []) if m.header.stamp.to_sec() > t_s + 1e-6]
                if later:
                    return later[0]  # type: ignore[return-value]
                time.sleep(0.02)
            raise AssertionError(f"no {topic} captured after {t_s}")

        def noise(msg: Image) -> float:
            rgb = image_to_array(msg).astype(np.int16)
            return float(np.abs(np.diff(rgb[::4], axis=1)).mean())

        live = after(color, 0.0)
        self.assertLess(noise(live), 40.0)
        # garbage: noise of the right size and encoding, finite depth
        g = fault(camera="nadir", type="garbage")
        self.assertEqual((g.result, g.detail), ("ACCEPTED", ""))
        img, d = after(color, g.applied_s), after(depth, g.applied_s)
        self.assertEqual((img.encoding, img.width, img.height), ("rgb8", 640, 480))
        self.assertGreater(noise(img), 70.0)
        self.assertEqual(d.encoding, "32FC1")
        self.assertTrue(np.all(np.isfinite(image_to_array(d))))
        # off: the nadir camera goes quiet (no image, no camera_info), the forward camera goes on
        off = fault(camera="nadir", type="off")
        self.assertEqual(off.result, "ACCEPTED")
        with self.inbox.lock:
            fwd = self.inbox.count["/cameras/forward/color/image_raw"]
        self.inbox.wait("/cameras/forward/color/image_raw", fwd + 15)
        for topic in (color, depth, "/cameras/nadir/color/camera_info", "/cameras/nadir/points"):
            with self.inbox.lock:
                stamps = [m.header.stamp.to_sec() for m in self.inbox.history.get(topic, [])]
            self.assertTrue(stamps)
            self.assertLessEqual(max(stamps), off.applied_s + 1e-6, f"{topic} while the camera was off")
        # ok: live pictures again
        ok = fault(camera="nadir", type="ok")
        self.assertEqual(ok.result, "ACCEPTED")
        self.assertLess(noise(after(color, ok.applied_s)), 40.0)

    def _wait_detection(self, iid: int, camera: str, start: int, *, present: bool) -> DetectionArray:
        deadline = time.monotonic() + 30.0
        while time.monotonic() < deadline:
            with self.inbox.lock:
                batch = self.inbox.detections[start:]
            for arr in batch:
                if arr.camera != camera:
                    continue
                has = any(d.instance_id == iid for d in arr.detections)
                if has == present:
                    return arr
            time.sleep(0.05)
        raise AssertionError(f"instance {iid} never {'appeared' if present else 'disappeared'} in {camera}")


def _point(x: float, y: float, z: float) -> Point:
    return Point(x=x, y=y, z=z)


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "sim_bridge_node", SimBridgeCheck)
