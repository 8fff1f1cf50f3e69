"""End to end: the real uav-sitl in lockstep, the sim_bridge (step master) and a real roscore.

A GCS arms the SITL and takes off to 20 m; the bridge must follow the real flight in
simulation time (clock, odometry, nadir depth = height above ground), tell the SITL
the ground height, and crash it with a COLLISION when a vehicle is put in its way.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rospy
from e2e.sitl.harness import Gcs, run_sitl
from helpers.procs import REPO, Proc, artifacts_dir, roscore
from nav_msgs.msg import Odometry
from pymavlink import mavutil
from sensor_msgs.msg import Image

from uav_common.ros.arrays import image_to_array
from uav_msgs.msg import Collision, SimState
from uav_msgs.srv import SetObjectPose, SetObjectPoseRequest
from uav_sim_bridge.core.world_config import ObjectClass, load_world_config
from uav_sim_bridge.shell.world_store import load_or_generate

pytestmark = pytest.mark.slow

M = mavutil.mavlink
WORLD = REPO / "tests" / "ros" / "sim_bridge" / "test_world.yaml"
LAUNCH = REPO / "catkin_ws" / "src" / "uav_sim_bridge" / "launch" / "sim_bridge.launch"
HOME_ALT_M = 488.0  # config/sitl.yaml home altitude
NADIR_MOUNT_Z_M = -0.08


class Topics:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.odom: list[Odometry] = []
        self.state: SimState | None = None
        self.depth: Image | None = None
        self.collisions: list[Collision] = []
        rospy.init_node("sim_bridge_e2e", anonymous=True, disable_signals=True)
        self.subs = [
            rospy.Subscriber("/uav/ground_truth/odom", Odometry, self._odom, queue_size=50),
            rospy.Subscriber("/uav/sim_state", SimState, self._state, queue_size=5),
            rospy.Subscriber("/cameras/nadir/depth/image_raw", Image, self._depth, queue_size=2),
            rospy.Subscriber("/sim/collision", Collision, self._collision, queue_size=5),
        ]

    def _odom(self, m: object) -> None:
        with self.lock:
            self.odom.append(m)  # type: ignore[arg-type]

    def _state(self, m: object) -> None:
        with self.lock:
            self.state = m  # type: ignore[assignment]

    def _depth(self, m: object) -> None:
        with self.lock:
            self.depth = m  # type: ignore[assignment]

    def _collision(self, m: object) -> None:
        with self.lock:
            self.collisions.append(m)  # type: ignore[arg-type]

    def wait(self, what: str, pred: object, timeout_s: float) -> object:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                value = getattr(self, what)
            if value is not None and pred(value):  # type: ignore[operator]
                return value
            time.sleep(0.05)
        with self.lock:
            last = getattr(self, what)
        raise AssertionError(f"{what} never satisfied the condition; last: {str(last)[:400]}")


def test_bridge_follows_the_real_sitl_in_lockstep(tmp_path: Path) -> None:
    cache = artifacts_dir() / "world_cache"
    world = load_or_generate(load_world_config(WORLD), cache)
    with (
        roscore("roscore_sim_bridge_e2e") as env,
        run_sitl("sitl_sim_bridge_e2e", tmp_path, extra=["--lockstep"]) as sitl,
    ):
        bridge = Proc(
            "sim_bridge_e2e",
            [
                "roslaunch", str(LAUNCH), f"sim_port:={sitl.ports.sim}", f"world:={WORLD}",
                f"world_cache_dir:={cache}", "lockstep_role:=master", "cameras:=nadir",
            ],
            env=env,
        )  # fmt: skip
        try:
            topics = Topics()
            state = topics.wait("state", lambda s: s.sim_time_s > 1.0, 60.0)
            assert state.lockstep  # type: ignore[attr-defined]
            assert "the SITL accepted our SIM_STEP grants" in bridge.log_text()
            gcs = Gcs.listen(sitl.ports.gcs)
            assert gcs.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout_s=20) == M.MAV_RESULT_ACCEPTED
            result = gcs.cmd(
                M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, HOME_ALT_M + 20.0, timeout_s=20
            )
            assert result == M.MAV_RESULT_ACCEPTED
            topics.wait("odom", lambda o: o and o[-1].pose.pose.position.z > 18.0, 90.0)
            with topics.lock:
                odom = list(topics.odom)
            stamps = np.array([o.header.stamp.to_sec() for o in odom])
            steps = np.diff(stamps)
            assert np.all(steps > 0)
            # a state per 5-step grant: stamps on the 20 ms grid (the subscriber may drop a few)
            np.testing.assert_allclose(np.round(steps / 0.02) * 0.02, steps, atol=1e-6)
            assert np.median(steps) == pytest.approx(0.02)
            # hover near home: nadir depth = height above the (flat) home pad
            topics.wait("depth", lambda d: d.header.stamp.to_sec() > stamps[-1] - 0.1, 30.0)
            with topics.lock:
                depth_msg = topics.depth
                odom = list(topics.odom)
            assert depth_msg is not None
            t_img = depth_msg.header.stamp.to_sec()
            # the subscriber may drop a few in a row under load; hovering, 0.1 s moves the vehicle by millimetres
            nearest = min(odom, key=lambda o: abs(o.header.stamp.to_sec() - t_img))
            assert abs(nearest.header.stamp.to_sec() - t_img) <= 0.1
            pose = nearest.pose.pose.position
            d = image_to_array(depth_msg)
            centre = float(np.mean(d[239:241, 319:321]))
            assert abs(pose.x) < 10.0
            assert abs(pose.y) < 10.0
            assert centre == pytest.approx(pose.z + NADIR_MOUNT_Z_M - float(world.height_at(pose.x, pose.y)), abs=0.1)
            # a car in the air where the drone is: the bridge reports the collision, the SITL crashes
            rospy.wait_for_service("/sim_bridge/set_object_pose", 10.0)
            move = rospy.ServiceProxy("/sim_bridge/set_object_pose", SetObjectPose)
            car = world.objects_of_class(ObjectClass.VEHICLE)[0]
            req = SetObjectPoseRequest(name=car.name, yaw_rad=0.0)
            req.position.x, req.position.y, req.position.z = pose.x, pose.y, pose.z - 0.9
            assert move(req).success
            topics.wait("collisions", lambda c: len(c) >= 1, 30.0)
            assert topics.collisions[0].instance_id == car.instance_id
            topics.wait("state", lambda s: s.crashed, 30.0)  # the SITL's heartbeat says FLIGHT_TERMINATION
            gcs.close()
        finally:
            bridge.stop()
        sitl_log = sitl.proc.log_path.read_text(errors="replace")
        assert "collision reported by" in sitl_log
        assert f"world id {car.instance_id}" in sitl_log
        log = bridge.log_path.read_text(errors="replace")
        assert "Traceback" not in log, log[-3000:]
        assert "collision with vehicle_0000" in log
