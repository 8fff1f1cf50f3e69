"""End to end: estimated depth feeds the map in a real closed loop.

The real ``uav-sitl`` in lockstep, the real sim bridge (step master, nadir camera
640x480 at 10 Hz, small test world) and ``perception.launch depth_source:=estimated``
(depth_estimator, depth_evaluator, the C++ map server) on a real roscore. A GCS
takes off to 50 m (a vertical climb: the pairing gate must refuse those pairs) and
flies towards a village; the estimated depth must agree with the bridge's ground
truth, and the map server must build its map from ``/depth_estimator/points``.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

import cv2
import numpy as np
import pytest
import rospy
from e2e.sitl.harness import Gcs, run_sitl
from helpers.procs import REPO, Proc, artifacts_dir, roscore
from pymavlink import mavutil
from sensor_msgs.msg import Image

from uav_common.geo import GeoPoint, LocalProjection
from uav_common.ros.arrays import image_to_depth_m, image_to_rgb
from uav_msgs.msg import DepthEstimatorStatus, DepthMetrics, MapInsertStats, SimState

pytestmark = pytest.mark.slow
T = TypeVar("T")

M = mavutil.mavlink
WORLD = REPO / "tests" / "ros" / "sim_bridge" / "test_world.yaml"
BRIDGE_LAUNCH = REPO / "catkin_ws" / "src" / "uav_sim_bridge" / "launch" / "sim_bridge.launch"
PERCEPTION_LAUNCH = REPO / "catkin_ws" / "src" / "uav_perception" / "launch" / "perception.launch"
HOME = GeoPoint(47.397742, 8.545594, 488.0)  # config/sitl.yaml
ALT_M = 50.0
TARGET_EN_M = (80.0, 110.0)  # a village of the test world (roofs below 35 m)
# roslaunch escalates SIGINT -> SIGTERM -> SIGKILL on its nodes within ~17 s; it must live that
# long, or a node stuck in rospy's shutdown (a SIGINT during its start-up can deadlock it) is orphaned.
ROSLAUNCH_STOP_S = 20.0


class Topics:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.metrics: list[DepthMetrics] = []
        self.status: DepthEstimatorStatus | None = None
        self.inserts: list[MapInsertStats] = []
        self.state: SimState | None = None
        self.images: dict[str, dict[int, Image]] = {"estimate": {}, "color": {}, "truth": {}}
        rospy.init_node("depth_e2e", anonymous=True, disable_signals=True)
        self.subs = [
            rospy.Subscriber("/depth_evaluator/metrics", DepthMetrics, self._add("metrics"), queue_size=50),
            rospy.Subscriber("/depth_estimator/status", DepthEstimatorStatus, self._status, queue_size=5),
            rospy.Subscriber("/map_server/insert_stats", MapInsertStats, self._add("inserts"), queue_size=50),
            rospy.Subscriber("/uav/sim_state", SimState, self._state, queue_size=5),
            rospy.Subscriber("/depth_estimator/depth/image_raw", Image, self._image("estimate"), queue_size=5),
            rospy.Subscriber("/cameras/nadir/color/image_raw", Image, self._image("color"), queue_size=5),
            rospy.Subscriber("/cameras/nadir/depth/image_raw", Image, self._image("truth"), queue_size=5),
        ]

    def _image(self, kind: str) -> Callable[[Image], None]:
        def cb(msg: Image) -> None:
            with self.lock:
                store = self.images[kind]
                store[msg.header.stamp.to_nsec()] = msg
                while len(store) > 40:
                    del store[min(store)]

        return cb

    def save_example(self, path: Path) -> bool:
        """color | ground truth | estimate of the newest estimate whose inputs were kept."""
        with self.lock:
            stamps = sorted(set(self.images["estimate"]) & set(self.images["color"]) & set(self.images["truth"]))
            if not stamps:
                return False
            msgs = [self.images[k][stamps[-1]] for k in ("color", "truth", "estimate")]
        rgb = image_to_rgb(msgs[0])
        truth, est = image_to_depth_m(msgs[1]), image_to_depth_m(msgs[2])
        lo, hi = float(np.nanmin(truth)) - 2.0, float(np.nanmax(truth)) + 2.0

        def color(d: np.ndarray) -> np.ndarray:
            vis = cv2.applyColorMap(
                np.clip(255 * (hi - np.nan_to_num(d, nan=hi)) / (hi - lo), 0, 255).astype(np.uint8), cv2.COLORMAP_TURBO
            )
            vis[~np.isfinite(d)] = 0
            return vis

        cv2.imwrite(str(path), np.hstack([cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), color(truth), color(est)]))
        return True

    def _state(self, msg: SimState) -> None:
        with self.lock:
            self.state = msg

    def sim_time_s(self) -> float:
        with self.lock:
            return self.state.sim_time_s if self.state is not None else 0.0

    def _add(self, name: str) -> Callable[[object], None]:
        def cb(msg: object) -> None:
            with self.lock:
                getattr(self, name).append(msg)

        return cb

    def _status(self, msg: DepthEstimatorStatus) -> None:
        with self.lock:
            self.status = msg

    def snapshot(self) -> tuple[list[DepthMetrics], DepthEstimatorStatus | None, list[MapInsertStats]]:
        with self.lock:
            return list(self.metrics), self.status, list(self.inserts)


def wait_for(what: str, probe: Callable[[], T], pred: Callable[[T], bool], timeout_s: float, procs: list[Proc]) -> T:
    deadline = time.monotonic() + timeout_s
    value = probe()
    while time.monotonic() < deadline:
        value = probe()
        if pred(value):
            return value
        for p in procs:
            assert p.alive(), f"{p.name} died:\n{p.tail()}"
        time.sleep(0.2)
    raise AssertionError(f"timed out waiting for {what}; last: {str(value)[:300]}")


def rejections(status: DepthEstimatorStatus) -> dict[str, int]:
    return dict(zip(status.pair_rejection_reasons, status.pair_rejection_counts, strict=True))


def test_estimated_depth_feeds_the_map_in_closed_loop(tmp_path: Path) -> None:
    cache = artifacts_dir() / "world_cache"
    run_dir = artifacts_dir() / "depth_e2e_run"
    for name in ("depth_metrics.jsonl", "depth_summary.json"):
        (run_dir / name).unlink(missing_ok=True)
    with (
        roscore("roscore_depth_e2e") as env,
        run_sitl("sitl_depth_e2e", tmp_path, extra=["--lockstep"]) as sitl,
    ):
        bridge = Proc(
            "sim_bridge_depth_e2e",
            [
                "roslaunch", str(BRIDGE_LAUNCH), f"sim_port:={sitl.ports.sim}", f"world:={WORLD}",
                f"world_cache_dir:={cache}", "lockstep_role:=master", "cameras:=nadir",
            ],
            env=env,
        )  # fmt: skip
        perception = Proc(
            "perception_depth_e2e",
            [
                "roslaunch", str(PERCEPTION_LAUNCH), "depth_source:=estimated", f"run_dir:={run_dir}",
                f"autosave_path:={tmp_path / 'map_autosave.bt'}",
            ],
            env=env,
        )  # fmt: skip
        procs = [bridge, perception]
        try:
            topics = Topics()
            wait_for("simulation time", topics.sim_time_s, lambda t: t > 2.0, 60.0, procs)
            gcs = Gcs.listen(sitl.ports.gcs)
            wait_for(
                "arming",
                lambda: gcs.cmd(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout_s=10),
                lambda r: r == 0,
                40.0,
                procs,
            )
            result = gcs.cmd(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, HOME.alt_amsl_m + ALT_M)
            assert result == M.MAV_RESULT_ACCEPTED
            # The climb: the nadir camera moves along its optical axis, the gate refuses the pairs.
            status = wait_for(
                "axial-motion rejections during the climb",
                lambda: topics.snapshot()[1],
                lambda s: s is not None and rejections(s).get("axial_motion", 0) > 5,
                40.0,
                procs,
            )  # fmt: skip
            wait_for("the climb", gcs.relative_alt_m, lambda a: a > ALT_M - 3.0, 60.0, procs)
            n_before = len(topics.snapshot()[0])
            target = LocalProjection(HOME).to_geo(TARGET_EN_M[1], TARGET_EN_M[0], -ALT_M)
            result = gcs.cmd(
                M.MAV_CMD_DO_REPOSITION, 6.0, M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0, math.nan,
                target.lat_deg, target.lon_deg, HOME.alt_amsl_m + ALT_M,
            )  # fmt: skip
            assert result == M.MAV_RESULT_ACCEPTED
            metrics = wait_for(
                "12 depth evaluations in level flight",
                lambda: topics.snapshot()[0][n_before:],
                lambda m: len(m) >= 12,
                60.0,
                procs,
            )
            # The status of the last of them can come a message later than its metrics.
            wait_for(
                "the estimator's status to count them",
                lambda: topics.snapshot()[1],
                lambda s: s is not None and s.estimates >= 12,
                20.0,
                procs,
            )
            _, status, inserts = topics.snapshot()
            saved = topics.save_example(run_dir / "example_color_truth_estimate.png")
            gcs.close()
        finally:
            perception.stop(timeout_s=ROSLAUNCH_STOP_S)
            bridge.stop(timeout_s=ROSLAUNCH_STOP_S)
    # Depth agrees with ground truth, frame by frame, in level flight.
    within = np.array([m.overall.within_abs for m in metrics])
    coverage = np.array([m.overall.coverage for m in metrics])
    assert np.median(within) > 0.9, within
    assert np.median(coverage) > 0.5, coverage
    assert all(m.stamp_diff_s < 1e-3 for m in metrics)
    classes = {c.label: c.n_evaluated for m in metrics for c in m.classes if c.n_evaluated}
    assert "terrain" in classes, classes  # the object list came from the bridge's world folder
    # The estimator said why it skipped, and kept estimating.
    assert status is not None
    assert status.estimates >= 12
    assert status.refine_applied
    # The map was built from the estimated clouds.
    inserted = [s for s in inserts if s.inserted]
    assert len(inserted) >= 5, [s.drop_reason for s in inserts]
    assert max(s.points_inserted for s in inserted) > 1000
    assert saved, "no estimate with its color and ground-truth images was kept"
    # The run log for the report.
    lines = (run_dir / "depth_metrics.jsonl").read_text().splitlines()
    assert len(lines) >= len(metrics)
    summary = json.loads((run_dir / "depth_summary.json").read_text())
    assert summary["frames"] >= len(metrics)
    for proc in (bridge, perception):
        log = proc.log_path.read_text(errors="replace")
        assert "Traceback" not in log, log[-3000:]
