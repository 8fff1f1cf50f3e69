#!/usr/bin/env python3
"""loiter.launch for 30 simulated seconds: it takes off, the map grows, the goal changes, nothing collides; the
scenario's camera faults (nadir off for 4 s, forward stuck for 5 s) are applied by the real bridge (no nadir
frames, the same forward picture over new stamps) and recorded by the scorer with the bridge's answer.

The launch file runs on rostest's master with every port free (SITL TCP and sim link, router
endpoints), the small scenario world and 160x120 cameras in lockstep. The run ends on its own
(the mission manager's time limit); the check then reads metrics.json too.
"""

from __future__ import annotations

import csv
import itertools
import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import unittest
import zlib
from pathlib import Path

import rospy
import rostest
from sensor_msgs.msg import Image

from uav_msgs.msg import Collision, ControllerState, RunMetrics, ScenarioStatus

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # tests/: the shared helpers
from helpers.procs import Proc, artifacts_dir, free_port  # noqa: E402

SCENARIO = HERE / "ros_loiter.yaml"


class LoiterCheck(unittest.TestCase):
    def setUp(self) -> None:
        rospy.init_node("scenario_loiter_check")  # before the launch sets /use_sim_time: wall-clock timeouts here
        self.lock = threading.Lock()
        self.status: list[ScenarioStatus] = []
        self.metrics: list[RunMetrics] = []
        self.goals: set[tuple[float, float]] = set()
        self.collisions: list[Collision] = []
        self.states: set[str] = set()
        self.frames: dict[str, list[tuple[float, int]]] = {"nadir": [], "forward": []}
        self.subs = [
            *[
                rospy.Subscriber(f"/cameras/{cam}/color/image_raw", Image, self._frame(cam), queue_size=50)
                for cam in self.frames
            ],
            rospy.Subscriber("/scenario/status", ScenarioStatus, self._add(self.status), queue_size=50),
            rospy.Subscriber("/scenario/metrics", RunMetrics, self._add(self.metrics), queue_size=50),
            rospy.Subscriber("/sim/collision", Collision, self._add(self.collisions), queue_size=10),
            rospy.Subscriber("/uav/controller/state", ControllerState, self._state, queue_size=50),
        ]
        self.run_dir = artifacts_dir() / "scenario_ros" / "loiter"
        for name in ("metrics.json", "timeseries.csv"):
            (self.run_dir / name).unlink(missing_ok=True)
        udp = socket.SOCK_DGRAM
        ports = {
            "sitl_tcp_port": free_port(), "sim_port": free_port(udp), "router_tcp_port": free_port(),
            "gcs_port": free_port(udp), "controller_port": free_port(udp), "mavsdk_port": free_port(udp),
            "adhoc_port": free_port(udp),
        }  # fmt: skip
        argv = [
            "roslaunch", "uav_scenarios", "loiter.launch", f"scenario:={SCENARIO}", f"run_dir:={self.run_dir}",
            "record:=false", *[f"{k}:={v}" for k, v in ports.items()],
        ]  # fmt: skip
        self.launch = Proc("scenario_ros_loiter_roslaunch", argv)
        self.proc = self.launch.popen
        self.log = self.launch.log_path

    def tearDown(self) -> None:
        self.launch.stop(5.0, int_timeout_s=30.0)
        for sub in self.subs:
            sub.unregister()

    def _add(self, store: list) -> object:  # type: ignore[type-arg]
        def cb(msg: object) -> None:
            with self.lock:
                store.append(msg)
                if isinstance(msg, ScenarioStatus) and math.isfinite(msg.goal.x):
                    self.goals.add((round(msg.goal.x, 1), round(msg.goal.y, 1)))

        return cb

    def _frame(self, camera: str) -> object:
        def cb(msg: Image) -> None:
            with self.lock:
                self.frames[camera].append((msg.header.stamp.to_sec(), zlib.crc32(msg.data)))

        return cb

    def _state(self, msg: ControllerState) -> None:
        with self.lock:
            self.states.add(msg.state)

    def _tail(self) -> str:
        return "\n".join(self.log.read_text(errors="replace").splitlines()[-30:])

    def test_loiter_takes_off_maps_changes_goal_without_collision(self) -> None:
        deadline = time.monotonic() + 170.0
        while time.monotonic() < deadline:
            with self.lock:
                done = bool(self.status) and self.status[-1].stop
            if done or self.proc.poll() is not None:
                break
            time.sleep(0.5)
        with self.lock:
            status, metrics = list(self.status), list(self.metrics)
            goals, collisions, states = set(self.goals), list(self.collisions), set(self.states)
        self.assertTrue(status, f"no /scenario/status from the run:\n{self._tail()}")
        self.assertTrue(status[-1].stop, f"the run did not reach a stop criterion in time:\n{self._tail()}")
        self.assertEqual(status[-1].stop_reason, "time_limit")
        self.assertIn("AUTONOMOUS", states, f"controller states seen: {states}")
        self.assertIn("LOITERING", {s.phase for s in status})
        airborne = [m for m in metrics if math.isfinite(m.agl_m) and m.agl_m > 15.0]
        self.assertTrue(airborne, "never 15 m above ground")
        mapped = [m.mapped_pct for m in metrics if math.isfinite(m.mapped_pct)]
        self.assertGreater(len(mapped), 5)
        self.assertGreater(mapped[-1], 2.0 * max(mapped[len(mapped) // 3], 0.05), f"the map did not grow: {mapped}")
        self.assertTrue(all(b >= a - 1e-6 for a, b in itertools.pairwise(mapped)), "mapped area shrank")
        self.assertGreaterEqual(len(goals), 2, f"the goal never changed: {goals}")
        self.assertEqual(collisions, [])
        self.assertEqual(metrics[-1].collisions, 0)
        # the run ends by itself once the scorer has written its final summary
        self.proc.wait(timeout=60)
        self.assertEqual(self.proc.returncode, 0, self._tail())
        summary = json.loads((self.run_dir / "metrics.json").read_text())
        self.assertTrue(summary["final"])
        self.assertEqual(summary["stop_reason"], "time_limit")
        self.assertEqual(summary["world"]["name"], "scenario_test")
        self.assertGreater(summary["map_accuracy"]["precision"], 0.8)
        self.assertGreater(summary["flight"]["distance_m"], 20.0)
        self.assertAlmostEqual(summary["time"]["duration_s"], 30.0, delta=1.0)
        self._check_camera_faults(summary)

    def _check_camera_faults(self, summary: dict) -> None:  # type: ignore[type-arg]
        """The scripted camera faults: the bridge's answers in the faults section, the frames as they went out."""
        faults = {(f["unit"], f["type"]): f for f in summary["faults"]}
        self.assertEqual(
            sorted(faults), [("camera_forward", "ok"), ("camera_forward", "stuck"), ("camera_nadir", "off"),
                             ("camera_nadir", "ok")], summary["faults"],
        )  # fmt: skip
        for f in faults.values():
            self.assertEqual(f["result"], "ACCEPTED", f)
            self.assertTrue(math.isfinite(f["answered_s"]), f)
            self.assertLess(abs(f["run_t_s"] - f["at_s"]), 1.0, f)  # sent at its run time
        events = [e["what"] for e in summary["events"]]
        self.assertIn("fault camera_nadir off: ACCEPTED", events)
        with self.lock:
            nadir, forward = list(self.frames["nadir"]), list(self.frames["forward"])
        # nadir off: no frame captured while it was off, frames before and after
        off, on = faults[("camera_nadir", "off")], faults[("camera_nadir", "ok")]
        t0, t1 = off["answered_s"], on["answered_s"]
        self.assertGreater(t1 - t0, 3.0, (off, on))
        during = [t for t, _ in nadir if t0 + 1e-6 < t <= t1]
        self.assertEqual(during, [], f"nadir frames while off ({t0:.2f}-{t1:.2f} s)")
        self.assertTrue(any(t <= t0 for t, _ in nadir) and any(t > t1 for t, _ in nadir), "nadir frames")
        followed = [c["what"] for c in off["followed"]]
        self.assertIn("camera nadir: frames stopped", followed, off)
        self.assertEqual(off["camera"]["frames"], 0, off)
        self.assertTrue(any(w.startswith("camera nadir: frames resumed") for w in (c["what"] for c in on["followed"])))
        # forward stuck: the last good picture again and again, each with a new stamp; live again after
        stuck, ok = faults[("camera_forward", "stuck")], faults[("camera_forward", "ok")]
        t0, t1 = stuck["answered_s"], ok["answered_s"]
        before = [c for t, c in forward if t <= t0]
        during = [(t, c) for t, c in forward if t0 + 1e-6 < t <= t1]
        after = [c for t, c in forward if t > t1 + 1e-6]
        self.assertGreater(len(during), 20, f"forward frames while stuck: {len(during)}")  # 10 Hz for 5 s
        self.assertEqual({c for _, c in during}, {before[-1]}, "the stuck camera showed other pictures")
        stamps = [t for t, _ in during]
        self.assertTrue(all(b > a for a, b in itertools.pairwise(stamps)), "stuck frames must carry new stamps")
        self.assertGreater(len(set(before[-20:])), 10, "the forward pictures were not changing before the fault")
        self.assertGreater(len(set(after)), 10, "the forward camera did not come back to life")
        self.assertIn(
            "camera forward: image frozen (the same picture 3 frames in a row)", [c["what"] for c in stuck["followed"]]
        )
        self.assertEqual(stuck["camera"]["distinct_images"], 1, stuck)

    def test_a_crashed_bridge_ends_the_run_and_keeps_the_metrics(self) -> None:
        deadline = time.monotonic() + 120.0
        while time.monotonic() < deadline:
            with self.lock:
                t = self.status[-1].sim_time_s if self.status else 0.0
            if t > 12.0 or self.proc.poll() is not None:
                break
            time.sleep(0.2)
        self.assertGreater(t, 12.0, f"the run did not get going:\n{self._tail()}")
        bridge = subprocess.run(
            ["pgrep", "-P", str(self.proc.pid), "-f", "__name:=sim_bridge"], capture_output=True, text=True, check=False
        )
        pids = [int(p) for p in bridge.stdout.split()]
        self.assertEqual(len(pids), 1, f"bridge process: {bridge.stdout!r}")
        os.kill(pids[0], signal.SIGKILL)
        self.proc.wait(timeout=90)  # the bridge is required: roslaunch stops the run
        summary = json.loads((self.run_dir / "metrics.json").read_text())
        self.assertTrue(summary["final"], "the scorer wrote no final summary at shutdown")
        self.assertGreater(summary["time"]["duration_s"], 10.0)
        self.assertGreater(summary["flight"]["distance_m"], 1.0)
        # the time series survives too, up to the crash (the scorer's 1 Hz sim-time timer may skip a tick when
        # the loop runs fast, so count coverage, not rows)
        rows = list(csv.DictReader((self.run_dir / "timeseries.csv").read_text().splitlines()))
        self.assertGreater(len(rows), 5)
        self.assertGreaterEqual(float(rows[-1]["t_s"]), summary["time"]["end_s"] - 2.0, rows[-1])
        self.assertGreater(float(rows[-1]["t_s"]), 10.0)


if __name__ == "__main__":
    rostest.rosrun("uav_rostests", "scenario_loiter_check", LoiterCheck)
