#!/usr/bin/env python3

"""rostest node: the map server in the causal lockstep (docs/lockstep.md), this node playing the step master.

The master (``uav_common.ros.lockstep.StepMaster``, as the sim bridge uses it) publishes, per step, a synthetic nadir
cloud and the camera's transform through its counted publishers, then the tick, as fast as the map server's
lookahead (3 steps) lets it. Each step's cloud sees its own 2 m x 2 m patch of flat ground (z = 0.1) 2 m east of
the previous one, from a camera 20 m above the patch's centre, so every inserted frame adds exactly 16 occupied
0.5 m voxels and 16 observed columns: what the map holds after any step is known in advance.

With ``~input: rgbd`` the frames are a depth image, a colour image and the camera info of the same patch (equal
stamps, three counted topics), which the map server synchronises and back-projects.

Steps are 0.125 s of simulated time (exact in binary and in nanoseconds), from 1000 s; ``tf_wait_s`` is 0.5 s
(four steps), the layers timer 2 Hz and the map timer 1 Hz (the test launch file sets them). ``/use_sim_time`` is
true and nobody publishes ``/clock``: a stamp taken from ROS time instead of the step's would read 0.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import threading
import time
import unittest
from collections.abc import Callable
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parents[1])]

import numpy as np  # noqa: E402
import roslib.packages  # noqa: E402
import rospy  # noqa: E402
import rostest  # noqa: E402
from geometry_msgs.msg import TransformStamped  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, PointCloud2, PointField  # noqa: E402

from uav_autonomy.core.octree_reader import load_occupied_cells  # noqa: E402
from uav_common.lockstep.protocol import LockstepError  # noqa: E402
from uav_common.lockstep.timers import SimTimer  # noqa: E402
from uav_common.ros.lockstep import APPLY_AFTER_HEADER, StepMaster  # noqa: E402
from uav_common.waiting import wait_until  # noqa: E402
from uav_msgs.msg import GridLayers, LockstepDone, MapInsertStats  # noqa: E402
from uav_msgs.srv import ExportVoxels, GetGridLayers  # noqa: E402

NODE = "/map_server"
CLOUD_TOPIC = "/test/points"
DEPTH_TOPIC, COLOR_TOPIC, INFO_TOPIC = "/test/depth", "/test/color", "/test/depth_info"
STATS_TOPIC = "/map_server/insert_stats"
LAYERS_TOPIC = "/map_server/layers"
LOOKAHEAD = 3  # the map server's default (the launch file overrides another node's only)
STEP_S = 0.125
T0_S = 1000.0
TF_WAIT_S = 0.5  # = 4 steps
CAM_Z = 20.0
PATCH_VOXELS = 16  # a 2 m x 2 m patch of ground at 0.5 m


def step_time(k: int) -> float:
    return T0_S + STEP_S * k


def patch_cloud(patch: int, frame: str, stamp: rospy.Time) -> PointCloud2:
    """Patch ``patch``: ground at z = 0.1 over x in [2 patch, 2 patch + 2), y in [0, 2), points every 0.1 m, in the
    optical frame of a nadir camera 20 m above the patch's centre (x east, y south, z down)."""
    off = np.arange(20) * 0.1 + 0.05
    x, y = np.meshgrid(2.0 * patch + off, off, indexing="xy")
    cx, cy = 2.0 * patch + 1.0, 1.0
    pts = np.zeros(x.size, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
    pts["x"], pts["y"], pts["z"] = x.ravel() - cx, cy - y.ravel(), CAM_Z - 0.1
    pts["rgb"] = 0x808080
    msg = PointCloud2()
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    msg.height, msg.width = 1, x.size
    msg.fields = [
        PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1) for i, n in enumerate("xyz")
    ] + [PointField(name="rgb", offset=12, datatype=PointField.FLOAT32, count=1)]
    msg.is_bigendian = False
    msg.point_step = 16
    msg.row_step = 16 * x.size
    msg.is_dense = True
    msg.data = pts.tobytes()
    return msg


def patch_images(frame: str, stamp: rospy.Time) -> tuple[Image, Image, CameraInfo]:
    """The same patch as a 20 x 20 z-depth image (19.9 m everywhere; fx = fy = 199: a pixel is 0.1 m of ground),
    its colour image and the camera info, all stamped alike."""
    side, f = 20, 199.0
    c = (side - 1) / 2.0

    def image(data: np.ndarray, encoding: str) -> Image:
        msg = Image()
        msg.header.stamp = stamp
        msg.header.frame_id = frame
        msg.height, msg.width = data.shape[:2]
        msg.encoding = encoding
        msg.is_bigendian = 0
        msg.step = data.strides[0]
        msg.data = np.ascontiguousarray(data).tobytes()
        return msg

    info = CameraInfo()
    info.header.stamp = stamp
    info.header.frame_id = frame
    info.width = info.height = side
    info.K = [f, 0.0, c, 0.0, f, c, 0.0, 0.0, 1.0]
    depth = np.full((side, side), CAM_Z - 0.1, dtype=np.float32)
    color = np.full((side, side, 3), 128, dtype=np.uint8)
    return image(depth, "32FC1"), image(color, "rgb8"), info


def camera_tf(patch: int, frame: str, stamp: rospy.Time) -> TransformStamped:
    t = TransformStamped()
    t.header.stamp = stamp
    t.header.frame_id = "map"
    t.child_frame_id = frame
    t.transform.translation.x = 2.0 * patch + 1.0
    t.transform.translation.y = 1.0
    t.transform.translation.z = CAM_Z
    t.transform.rotation.x = 1.0  # optical z down, y south
    return t


class Frame:
    """What one step publishes: its own cloud (with the transform at once, later, or never) and late transforms."""

    def __init__(self, frame: str = "cam", tf_now: bool = True, late_tfs: tuple[tuple[int, str], ...] = ()) -> None:
        self.frame = frame
        self.tf_now = tf_now
        self.late_tfs = late_tfs  # (step of the frame, its frame id): transforms at that step's stamp, sent now


class MapServerLockstepCheck(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("map_server_lockstep_check")
        cls.tmp = Path(tempfile.mkdtemp(prefix="map_server_lockstep_"))
        cls.exit_file = Path(rospy.get_param("~exit_file"))
        cls.lock = threading.Lock()
        cls.dones: list[LockstepDone] = []
        cls.latest_done = 0
        cls.stats: list[MapInsertStats] = []
        cls.layers: list[GridLayers] = []
        cls.tick_lag: dict[int, int] = {}  # step -> the map server's latest done when the master ticked it
        # Registered before the master's own /lockstep/done subscription: rospy calls them in this order, so a done
        # is recorded here before the master can grant on it.
        rospy.Subscriber("/lockstep/done", LockstepDone, cls._on_done, queue_size=None)
        rospy.Subscriber(STATS_TOPIC, MapInsertStats, cls._on_stats, queue_size=None)
        rospy.Subscriber(LAYERS_TOPIC, GridLayers, cls._on_layers, queue_size=None, buff_size=2**24)
        cls.master = StepMaster(step_s=STEP_S, expected=[NODE])
        cls.rgbd = rospy.get_param("~input", "cloud") == "rgbd"
        if cls.rgbd:
            cls.frame_topics = (DEPTH_TOPIC, COLOR_TOPIC, INFO_TOPIC)
            cls.pub_frame = [
                cls.master.publisher(DEPTH_TOPIC, Image),
                cls.master.publisher(COLOR_TOPIC, Image),
                cls.master.publisher(INFO_TOPIC, CameraInfo),
            ]
        else:
            cls.frame_topics = (CLOUD_TOPIC,)
            cls.pub_frame = [cls.master.publisher(CLOUD_TOPIC, PointCloud2)]
        cls.tf = cls.master.tf_broadcaster()
        # /lockstep/observers lists this node: the master starts once these subscriptions are connected too.
        wait_until(cls.master.try_start, bool, timeout_s=45.0, describe="the map server joined and connected")

    @classmethod
    def tearDownClass(cls) -> None:
        shutil.rmtree(cls.tmp, ignore_errors=True)
        cls.exit_file.unlink(missing_ok=True)

    @classmethod
    def _on_done(cls, msg: LockstepDone) -> None:
        if msg.node != NODE:
            return
        with cls.lock:
            cls.dones.append(msg)
            if not msg.error:
                cls.latest_done = max(cls.latest_done, int(msg.step))

    @classmethod
    def _on_stats(cls, msg: MapInsertStats) -> None:
        with cls.lock:
            cls.stats.append(msg)

    @classmethod
    def _on_layers(cls, msg: GridLayers) -> None:
        with cls.lock:
            cls.layers.append(msg)

    # ------------------------------------------------------------------------------------------ the master

    def step(self, frame: Frame | None = None) -> int:
        """Grant and publish the next step as soon as the lookahead allows: its frame, transforms, then the tick."""
        while not self.master.can_grant():
            self.master.check_watchdog()
            time.sleep(0.0005)
        k = self.master.step + 1
        stamp = rospy.Time.from_sec(step_time(k))
        with self.lock:
            self.tick_lag[k] = self.latest_done
        if frame is not None:
            transforms = [camera_tf(k, frame.frame, stamp)] if frame.tf_now else []
            transforms += [camera_tf(j, f, rospy.Time.from_sec(step_time(j))) for j, f in frame.late_tfs]
            if transforms:
                self.tf.sendTransform(transforms)
            parts = patch_images(frame.frame, stamp) if self.rgbd else (patch_cloud(k, frame.frame, stamp),)
            for pub, msg in zip(self.pub_frame, parts, strict=True):
                pub.publish(msg)
        self.master.publish_tick(step_time(k))
        return k

    def run_steps(self, frames: list[Frame]) -> list[int]:
        return [self.step(f) for f in frames]

    def wait_done(self, step: int) -> None:
        """Until the map server is done with ``step`` and everything it counted by then has arrived here (a done may
        overtake the messages it counts: they come on other connections)."""
        wait_until(lambda: self.latest_done, lambda d: d >= step, timeout_s=30.0, describe=f"{NODE} done({step})")
        want = (self.count_at(step, STATS_TOPIC), self.count_at(step, LAYERS_TOPIC))

        def have() -> tuple[int, int]:
            with self.lock:
                return len(self.stats), len(self.layers)

        wait_until(
            have,
            lambda n: n[0] >= want[0] and n[1] >= want[1],
            timeout_s=10.0,
            describe=f"the messages counted by done({step})",
        )

    def done_of(self, step: int) -> LockstepDone:
        with self.lock:
            return next(d for d in self.dones if d.step == step and not d.error)

    def count_at(self, step: int, topic: str) -> int:
        done = self.done_of(step)
        counts = dict(zip(done.topics.split("\n") if done.topics else [], done.published, strict=True))
        return int(counts.get(topic, 0))

    def export(self, apply_after: int | None) -> Any:
        headers = None if apply_after is None else {APPLY_AFTER_HEADER: str(apply_after)}
        path = self.tmp / f"occupied_{apply_after}_{time.monotonic_ns()}.npy"
        res = rospy.ServiceProxy("/map_server/export_occupied", ExportVoxels, headers=headers)(str(path), 0.0)
        self.assertTrue(res.success, res.message)
        self.assertEqual(len(load_occupied_cells(path).cells), res.count)
        return res

    def in_thread(self, call: Callable[[], Any]) -> tuple[threading.Thread, list[Any]]:
        out: list[Any] = []

        def run() -> None:
            try:
                out.append(call())
            except Exception as err:  # handed to the test thread
                out.append(err)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        return thread, out

    # ------------------------------------------------------------------------------------------ tests

    def test_1_every_frame_inserted_timers_in_simulated_time_and_the_lookahead(self) -> None:
        manifest = self.master.barrier.manifest(NODE)
        self.assertEqual(manifest.lookahead_steps, LOOKAHEAD)
        self.assertEqual(manifest.inputs, (*self.frame_topics, "/tf", "/tf_static"))
        self.assertEqual(manifest.timers, ("layers 0.5", "map 1"))
        self.assertIn(STATS_TOPIC, manifest.outputs)
        self.assertIn("/octomap_binary", manifest.outputs)

        started = time.monotonic()
        steps = self.run_steps([Frame() for _ in range(24)])
        self.wait_done(steps[-1])
        wall = time.monotonic() - started
        n = len(steps)
        self.assertEqual(steps, list(range(1, n + 1)))

        # Every frame inserted, in order, however fast the master ran: no drops of any kind.
        with self.lock:
            stats = list(self.stats)
            layers = list(self.layers)
            dones = [d for d in self.dones if not d.error]
        self.assertEqual(len(stats), n)
        self.assertTrue(all(s.inserted for s in stats), [s.drop_reason for s in stats])
        self.assertEqual({s.points_in for s in stats}, {400})
        self.assertEqual([s.header.stamp.to_sec() for s in stats], [step_time(k) for k in steps])
        last = stats[-1]
        self.assertEqual(last.clouds_inserted, n)
        drops = (
            last.clouds_dropped_empty,
            last.clouds_dropped_bad_layout,
            last.clouds_dropped_too_large,
            last.clouds_dropped_no_transform,
            last.clouds_dropped_queue_full,
            last.clouds_dropped_unsynchronized,
        )
        self.assertEqual(drops, (0, 0, 0, 0, 0, 0))

        # One done per step, in order; its counts are what was published (and received here).
        self.assertEqual([int(d.step) for d in dones], steps)
        self.assertEqual(self.count_at(n, STATS_TOPIC), len(stats))
        self.assertEqual(self.count_at(n, LAYERS_TOPIC), len(layers))

        # Layers at exactly the steps the 2 Hz timer gives in simulated time, stamped with the step's time, holding
        # the frames inserted before that step (timers fire before the step's insertions).
        timer = SimTimer(0.5)
        fired = [k for k in steps if timer.due(rospy.Time.from_sec(step_time(k)).to_sec())]
        self.assertEqual(fired, [1, 4, 8, 12, 16, 20, 24])
        self.assertEqual([m.header.stamp.to_sec() for m in layers], [step_time(k) for k in fired])
        for k, m in zip(fired, layers, strict=True):
            self.assertEqual(list(m.names), ["elevation_m", "last_seen_s", "observed"])
            grids = np.asarray(m.data, dtype=np.float32).reshape(len(m.names), m.height, m.width)
            self.assertEqual(int(np.sum(grids[2] == 1.0)), PATCH_VOXELS * (k - 1), f"layers of step {k}")
        # The map outputs at 1 Hz of simulated time (latch: every output each time).
        map_timer = SimTimer(1.0)
        map_fired = [k for k in steps if map_timer.due(step_time(k))]
        self.assertEqual(map_fired, [1, 8, 16, 24])
        self.assertEqual(self.count_at(n, "/octomap_binary"), len(map_fired))
        self.assertEqual(self.count_at(n, "/projected_map"), len(map_fired))

        # The lookahead: no step was granted before the map server was done with the step L before it.
        lags = {k: k - done for k, done in self.tick_lag.items()}
        self.assertLessEqual(max(lags.values()), LOOKAHEAD, lags)
        rospy.loginfo(f"{n} steps in {wall:.2f} s, the master up to {max(lags.values())} steps ahead")

    def test_2_late_transforms_wait_missing_ones_are_dropped_at_tf_wait_s(self) -> None:
        with self.lock:
            n0 = len(self.stats)
        # A frame whose transform comes two steps later: it waits (and the frame behind it too), then both go in.
        s0 = self.step(Frame("cam_late2", tf_now=False))
        self.step(Frame())
        s2 = self.step(Frame(late_tfs=((s0, "cam_late2"),)))
        # A frame whose transform comes exactly tf_wait_s later: still in time.
        s3 = self.step(Frame("cam_late4", tf_now=False))
        for _ in range(3):
            self.step(Frame())
        s7 = self.step(Frame(late_tfs=((s3, "cam_late4"),)))
        self.assertEqual(s7 - s3, 4)
        # A frame whose transform never comes: dropped at the first step more than tf_wait_s past its stamp.
        s8 = self.step(Frame("cam_never", tf_now=False))
        last = [self.step(Frame()) for _ in range(5)][-1]
        self.wait_done(last)

        counts = {k: self.count_at(k, STATS_TOPIC) for k in range(s0, last + 1)}
        self.assertEqual(counts[s0], n0)
        self.assertEqual(counts[s0 + 1], n0, "the frame behind the waiting one waits too")
        self.assertEqual(counts[s2], n0 + 3)
        self.assertEqual(counts[s7 - 1], n0 + 3)
        self.assertEqual(counts[s7], n0 + 3 + 5)
        self.assertEqual(counts[s8 + 4], n0 + 8, "4 steps = tf_wait_s after its stamp: still waiting")
        self.assertEqual(counts[s8 + 5], n0 + 8 + 6, "dropped, then the 5 frames behind it inserted")
        with self.lock:
            stats = self.stats[n0:]
        self.assertEqual(len(stats), 14)
        reasons = ["" if s.inserted else s.drop_reason for s in stats]
        self.assertEqual(reasons, [""] * 8 + ["no_transform"] + [""] * 5)
        self.assertEqual([s.header.stamp.to_sec() for s in stats], [step_time(k) for k in range(s0, last + 1)])
        self.assertEqual(stats[-1].clouds_dropped_no_transform, 1)
        self.assertEqual(stats[-1].clouds_inserted, n0 + 13)

    def test_3_export_sees_the_map_of_its_boundary(self) -> None:
        # Every frame so far is in but test_2's cam_never one: 16 voxels each.
        inserted = self.master.step - 1
        n = self.master.step
        # The request names the boundary after the last granted step; the map server may still be steps behind.
        res = self.export(n)
        self.assertEqual(res.count, PATCH_VOXELS * inserted)
        # Boundaries still ahead of the map server while the master keeps stepping (it holds back past the
        # boundary until the answer, as it would for a participant that waits for it).
        for ahead, pause in ((1, 0.0), (3, 0.3), (2, 0.3)):
            target = self.master.step + ahead
            thread, out = self.in_thread(lambda target=target: self.export(target))
            if pause:  # the request is at the map server (idle at an earlier boundary) long before its boundary
                thread.join(timeout=pause)
                self.assertTrue(thread.is_alive(), f"export for the boundary after step {target} answered early")
            while self.master.step < target:
                self.step(Frame())
                inserted += 1
            thread.join(timeout=30.0)
            self.assertFalse(thread.is_alive(), f"export at the boundary after step {target} never answered")
            self.assertNotIsInstance(out[0], Exception)
            self.assertEqual(out[0].count, PATCH_VOXELS * inserted, f"export at the boundary after step {target}")
        # A boundary the map server has passed: an error, never a map of another step.
        self.wait_done(self.master.step)
        with self.assertRaises(rospy.ServiceException) as err:
            self.export(self.master.step - 5)
        self.assertIn("too late", str(err.exception))
        # Without the header: applied at the next boundary (now: the map server is idle), stamped with its step.
        layers = rospy.ServiceProxy("/map_server/get_layers", GetGridLayers)().layers
        self.assertEqual(layers.header.stamp.to_sec(), step_time(self.master.step))

    def test_4_a_participant_that_joins_after_the_start_is_refused(self) -> None:
        binary = roslib.packages.find_node("uav_mapping", "map_server")[0]
        proc = subprocess.run(
            [binary, "__name:=late_map_server", f"cloud_in:={self.frame_topics[0]}"],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        out = proc.stdout + proc.stderr
        self.assertEqual(proc.returncode, 1, out[-2000:])
        self.assertIn("/late_map_server: the step master refused the join: /late_map_server asked to join", out)

    def test_9_an_input_that_never_comes_stops_the_run(self) -> None:
        self.wait_done(self.master.step)
        # The tick counts one more frame than was sent (a message lost on the way): every step so far sent one.
        k = self.master.step + 1
        lost = self.frame_topics[0]
        self.master.count(lost)
        self.assertEqual(self.step(None), k)
        started = time.monotonic()
        error = wait_until(
            lambda: next((d.error for d in list(self.dones) if d.error), ""),
            bool,
            timeout_s=20.0,
            describe="a done with an error from the map server",
        )
        waited = time.monotonic() - started
        self.assertGreaterEqual(waited, 2.5, f"it reported before /lockstep/watchdog_s (3 s): {error}")
        self.assertIn(f"step {k}", error)
        self.assertIn(f"{lost} from {rospy.get_name()} ({k - 1} of {k})", error)
        with self.assertRaises(LockstepError) as err:
            self.master.can_grant()
        self.assertIn(NODE, str(err.exception))
        code = wait_until(
            lambda: self.exit_file.read_text().strip() if self.exit_file.exists() else "",
            bool,
            timeout_s=15.0,
            describe=f"the map server's exit code in {self.exit_file}",
        )
        self.assertNotEqual(code, "0", f"the map server exited with {code} after the error")


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "map_server_lockstep_check", MapServerLockstepCheck)
