"""Everything a run report shows, read from a run's bag with ``rosbags`` (no ROS needed).

:func:`read_run_bag` turns the topics the scenario records (``RECORDING_PRESETS``)
into a :class:`RunData`. Times in a ``RunData`` are simulation seconds since the
run started (the first ``/scenario/status``; without one, the first message).
A bag that is missing, still being written or truncated raises
:class:`BagReadError` with what to do; a bag without some topics gives a report
without those figures and a note saying why.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_scenarios.core.config import GEOLOCATED_TOPIC
from uav_scenarios.core.scoring.types import DetectionFrame, GoalSample, GridSnapshot
from uav_scenarios.errors import BagReadError, ScoringError
from uav_scenarios.ros.records import (
    battery_from_msg,
    controller_from_msg,
    detections_from_msg,
    goal_from_msg,
    grid_from_msg,
    image_from_msg,
    object_states_from_msg,
    pose_from_odometry,
    stamp_s,
)

__all__ = ["METRIC_COLUMNS", "TRAIL_COLUMNS", "CameraImage", "RunData", "read_run_bag"]

#: ``moving_objects`` metrics that become ``trail_<name>`` time-series columns (from each summary).
TRAIL_COLUMNS = ("mapped_voxels", "seen_again_voxels", "ghost_voxels", "cleared_voxels")

FloatArray = npt.NDArray[np.float64]

#: ``uav_msgs/RunMetrics`` fields that become time-series columns.
METRIC_COLUMNS = (
    "mapped_pct",
    "mapped_m2",
    "mean_cell_age_s",
    "observed_cells",
    "occupied_voxels",
    "map_iou",
    "distance_m",
    "agl_m",
    "battery_pct",
    "battery_used_mah",
    "collisions",
    "det_tp",
    "det_fp",
    "det_fn",
)


@dataclass(frozen=True)
class CameraImage:
    t_s: float
    camera: str
    kind: str  # color | depth | instance
    image: npt.NDArray[Any]


@dataclass
class RunData:
    """One run, ready to plot. Empty arrays/lists where the bag had no such data."""

    name: str = "run"
    scenario_yaml: str = ""
    summary: dict[str, Any] = field(default_factory=dict)
    #: Time series: ``t_s`` plus :data:`METRIC_COLUMNS`, one row per metrics message.
    timeseries: dict[str, FloatArray] = field(default_factory=dict)
    #: ``(N, 4)``: t, x, y, z (map, ENU).
    trajectory: FloatArray = field(default_factory=lambda: np.zeros((0, 4)))
    #: ``(N, 3)``: t, remaining %, voltage.
    battery: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    goals: list[GoalSample] = field(default_factory=list)
    detections: list[DetectionFrame] = field(default_factory=list)
    controller: list[tuple[float, str]] = field(default_factory=list)
    phases: list[tuple[float, str]] = field(default_factory=list)
    layers: list[GridSnapshot] = field(default_factory=list)
    features: list[GridSnapshot] = field(default_factory=list)
    images: list[CameraImage] = field(default_factory=list)
    #: The scorer's gallery of the detector's worst false positives and misses (RGB mosaic), if any.
    gallery: npt.NDArray[Any] | None = None
    target_position_m: tuple[float, float] | None = None
    #: Moving people and vehicles: name -> ``[(t, x, y), ...]`` (``/sim/object_states``).
    object_tracks: dict[str, list[tuple[float, float, float]]] = field(default_factory=dict)
    stop_reason: str = ""
    notes: list[str] = field(default_factory=list)
    start_stamp_s: float = 0.0
    bag_path: str = ""


_SNAPSHOT_PREFIX = "/scenario/snapshot/"


def _open_reader(path: Path) -> Any:
    from rosbags.highlevel import AnyReader  # noqa: PLC0415 - keep the report's import light

    if not path.exists():
        msg = f"{path}: no such bag; pass the run folder's .bag file (runs/<name>-<time>/run.bag)"
        raise BagReadError(msg)
    if path.suffix != ".bag":
        hint = (
            " (rosbag record is still writing it, or was killed: run `rosbag reindex`)"
            if path.suffix == ".active"
            else ""
        )
        msg = f"{path}: not a finished ROS 1 bag{hint}"
        raise BagReadError(msg)
    return AnyReader([path])


def read_run_bag(path: Path, *, snapshot_topics: bool = True) -> RunData:  # noqa: PLR0912, PLR0915
    """Read a run's bag into a :class:`RunData`.

    Raises:
        BagReadError: missing, unfinished, unindexed or corrupt bag (the message says what to do).
    """
    run = RunData(bag_path=str(path))
    reader = _open_reader(path)
    try:
        reader.open()
    except Exception as err:  # rosbags raises its own error types per format
        msg = (
            f"{path}: cannot open bag ({err}). If the recording was interrupted, run "
            "`rosbag reindex` on it (needs ROS) and retry"
        )
        raise BagReadError(msg) from err
    metrics_rows: list[dict[str, float]] = []
    odom: list[tuple[float, float, float, float]] = []
    battery: list[tuple[float, float, float]] = []
    first_status: float | None = None
    first_any = math.inf
    detection_topic = ""
    try:
        by_topic: dict[str, list[Any]] = {}
        for conn in reader.connections:
            by_topic.setdefault(conn.topic, []).append(conn)
        if "/scenario/config" in by_topic:
            for conn, _, raw in reader.messages(connections=by_topic["/scenario/config"]):
                run.scenario_yaml = str(reader.deserialize(raw, conn.msgtype).data)
        detection_topic = _detection_topic(run.scenario_yaml)
        wanted: dict[str, Callable[[Any, Any], None]] = {}

        def on_metrics(m: Any, _conn: Any) -> None:
            row = {"t_s": stamp_s(m.header.stamp)}
            row.update({c: float(getattr(m, c)) for c in METRIC_COLUMNS})
            summary = json.loads(m.summary_json) if m.summary_json else {}
            moving = summary.get("moving_objects") or {}
            for key in TRAIL_COLUMNS:
                value = moving.get(key)
                row[f"trail_{key}"] = float(value) if isinstance(value, int | float) else math.nan
            metrics_rows.append(row)
            if summary:
                run.summary = summary

        def on_objects(m: Any, _conn: Any) -> None:
            rec = object_states_from_msg(m)
            for row, name, moving in zip(rec.rows, rec.names, rec.moving, strict=True):
                if moving:
                    run.object_tracks.setdefault(name, []).append((rec.t_s, float(row[1]), float(row[2])))

        def on_status(m: Any, _conn: Any) -> None:
            nonlocal first_status
            t = stamp_s(m.header.stamp)
            if first_status is None:
                first_status = t
                run.name = str(m.scenario) or run.name
            if not run.phases or run.phases[-1][1] != m.phase:
                run.phases.append((t, str(m.phase)))
            if m.target_found:
                run.target_position_m = (float(m.target_position.x), float(m.target_position.y))
            if m.stop_reason:
                run.stop_reason = str(m.stop_reason)

        def on_odom(m: Any, _conn: Any) -> None:
            p = pose_from_odometry(m)
            odom.append((p.t_s, *p.position_m))

        def on_battery(m: Any, _conn: Any) -> None:
            b = battery_from_msg(m)
            battery.append((b.t_s, b.remaining_pct, b.voltage_v))

        def on_controller(m: Any, _conn: Any) -> None:
            c = controller_from_msg(m)
            if not run.controller or run.controller[-1][1] != c.state:
                run.controller.append((c.t_s, c.state))

        wanted = {
            "/scenario/metrics": on_metrics,
            "/scenario/status": on_status,
            "/uav/ground_truth/odom": on_odom,
            "/uav/battery": on_battery,
            "/uav/controller/state": on_controller,
            "/autonomy/goal_reason": lambda m, _c: run.goals.append(goal_from_msg(m)),
            "/detections/ground_truth": lambda m, _c: run.detections.append(detections_from_msg(m)),
            "/sim/object_states": on_objects,
            GEOLOCATED_TOPIC: lambda m, _c: run.detections.append(detections_from_msg(m)),
        }
        if detection_topic and detection_topic not in wanted:
            wanted[detection_topic] = lambda m, _c: run.detections.append(detections_from_msg(m))
        if snapshot_topics:
            wanted["/scenario/snapshot/gallery"] = lambda m, _c: setattr(run, "gallery", image_from_msg(m))
            wanted["/scenario/snapshot/layers"] = lambda m, _c: run.layers.append(grid_from_msg(m))
            wanted["/scenario/snapshot/features"] = lambda m, _c: run.features.append(grid_from_msg(m))
        conns = [c for c in reader.connections if c.topic in wanted or _is_image_snapshot(c.topic, snapshot_topics)]
        for conn, timestamp_ns, raw in reader.messages(connections=conns):
            first_any = min(first_any, timestamp_ns * 1e-9)
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic in wanted:
                wanted[conn.topic](msg, conn)
            else:
                camera, kind = conn.topic[len(_SNAPSHOT_PREFIX) :].split("/", 1)
                run.images.append(CameraImage(stamp_s(msg.header.stamp), camera, kind, image_from_msg(msg)))
    except BagReadError:
        raise
    except ScoringError as err:
        msg = f"{path}: a message could not be interpreted: {err}"
        raise BagReadError(msg) from err
    except Exception as err:  # truncated chunks, bad connection records
        msg = f"{path}: the bag is damaged or truncated ({type(err).__name__}: {err}); run `rosbag reindex` and retry"
        raise BagReadError(msg) from err
    finally:
        reader.close()
    start = first_status if first_status is not None else (odom[0][0] if odom else 0.0)
    run.start_stamp_s = start
    _finish(run, start, metrics_rows, odom, battery)
    return run


def _is_image_snapshot(topic: str, enabled: bool) -> bool:
    if not enabled or not topic.startswith(_SNAPSHOT_PREFIX):
        return False
    return topic.count("/") == 4 and topic.rsplit("/", 1)[1] in ("color", "depth", "instance")


def _detection_topic(scenario_yaml: str) -> str:
    if not scenario_yaml:
        return ""
    import yaml  # noqa: PLC0415

    try:
        data = yaml.safe_load(scenario_yaml)
    except yaml.YAMLError:
        return ""
    search = data.get("search") if isinstance(data, dict) else None
    # Bags from before the detector contract: the detector's uav_msgs/DetectionArray topic was search.detection_topic.
    return str(search.get("detection_topic") or "") if isinstance(search, dict) else ""


def _finish(
    run: RunData,
    start: float,
    metrics_rows: list[dict[str, float]],
    odom: list[tuple[float, float, float, float]],
    battery: list[tuple[float, float, float]],
) -> None:
    """Shift every time to 'since start' and note what is missing."""
    if metrics_rows:
        run.timeseries = {k: np.array([r[k] for r in metrics_rows], dtype=np.float64) for k in metrics_rows[0]}
        run.timeseries["t_s"] = run.timeseries["t_s"] - start
    else:
        run.notes.append("no /scenario/metrics in the bag: the scorer did not run or was not recorded")
    run.trajectory = np.array(odom, dtype=np.float64).reshape(-1, 4)
    run.trajectory[:, 0] -= start
    if not odom:
        run.notes.append("no /uav/ground_truth/odom in the bag: no trajectory")
    run.battery = np.array(battery, dtype=np.float64).reshape(-1, 3)
    run.battery[:, 0] -= start
    if not battery:
        run.notes.append("no /uav/battery in the bag: no battery plot")
    run.goals = [GoalSample(g.t_s - start, g.goal_m, g.reason) for g in run.goals]
    run.detections = [DetectionFrame(d.t_s - start, d.camera, d.source, d.detections) for d in run.detections]
    run.controller = [(t - start, s) for t, s in run.controller]
    run.phases = [(t - start, s) for t, s in run.phases]
    run.layers = [_shift(g, start) for g in run.layers]
    run.features = [_shift(g, start) for g in run.features]
    run.images = [CameraImage(i.t_s - start, i.camera, i.kind, i.image) for i in run.images]
    run.object_tracks = {k: [(t - start, x, y) for t, x, y in v] for k, v in run.object_tracks.items()}
    if not run.summary:
        run.notes.append("no final metrics summary in the bag (the run may have been cut short)")


def _shift(g: GridSnapshot, start: float) -> GridSnapshot:
    return GridSnapshot(g.t_s - start, g.resolution_m, g.origin_x_m, g.origin_y_m, g.layers)
