"""Scoring records and results -> ROS messages (the scenario layer's only message builders)."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import rospy
from geometry_msgs.msg import Point, Vector3
from std_msgs.msg import Header

from uav_autonomy.ros.conversions import NumpyGridLayers
from uav_msgs.msg import GridLayers, RunMetrics, ScenarioStatus, Track, TrackArray
from uav_scenarios.core.scoring.metrics import downsample_grid
from uav_scenarios.core.scoring.types import Track as TrackRecord
from uav_scenarios.ros.records import grid_from_msg

__all__ = ["downsampled_layers_msg", "json_safe", "metrics_msg", "status_msg", "tracks_msg"]


def json_safe(data: Any) -> Any:
    """NaN/inf -> None, recursively, so the JSON is standard."""
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {str(k): json_safe(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [json_safe(v) for v in data]
    return data


def _f(value: Any) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def _u(value: Any) -> int:
    v = _f(value)
    return int(v) if math.isfinite(v) and v >= 0 else 0


def metrics_msg(stamp: rospy.Time, row: dict[str, Any], summary: dict[str, Any]) -> RunMetrics:
    msg = RunMetrics(header=Header(stamp=stamp, frame_id="map"))
    msg.sim_time_s = stamp.to_sec()
    for name in ("mapped_pct", "mapped_m2", "mean_cell_age_s", "map_iou", "distance_m", "agl_m", "battery_pct"):
        setattr(msg, name, _f(row.get(name)))
    msg.battery_used_mah = _f(row.get("battery_used_mah"))
    msg.observed_cells = _u(row.get("observed_cells"))
    occupied = _f(row.get("occupied_voxels"))
    msg.occupied_voxels = int(occupied) if math.isfinite(occupied) else -1
    for name in ("collisions", "det_tp", "det_fp", "det_fn"):
        setattr(msg, name, _u(row.get(name)))
    msg.summary_json = json.dumps(json_safe(summary))
    return msg


def tracks_msg(
    stamp: rospy.Time,
    camera: str,
    tracks: tuple[TrackRecord, ...],
    *,
    received: int = 0,
    unplaced: int = 0,
    below_threshold: int = 0,
) -> TrackArray:
    """A frame's confirmed tracks, with the tracker's running counts of what it was given and could not use."""
    return TrackArray(
        header=Header(stamp=stamp, frame_id="map"),
        camera=camera,
        detections_received=received,
        detections_unplaced=unplaced,
        detections_below_threshold=below_threshold,
        tracks=[
            Track(
                track_id=t.track_id,
                class_name=t.class_name,
                position=Point(*t.position_m),
                velocity=Vector3(*t.velocity_mps),
                hits=t.hits,
            )
            for t in tracks
        ],
    )


def _point(xyz: tuple[float, float, float] | None) -> Point:
    return Point(*(xyz if xyz is not None else (math.nan, math.nan, math.nan)))


def status_msg(stamp: rospy.Time, fields: dict[str, Any]) -> ScenarioStatus:
    msg = ScenarioStatus(header=Header(stamp=stamp, frame_id="map"))
    for name in ("scenario", "mission", "strategy", "phase", "controller_state", "autopilot_mode", "stop_reason"):
        setattr(msg, name, str(fields.get(name, "")))
    for name in ("sim_time_s", "real_time_factor", "mapped_pct", "battery_pct", "complete_time_s"):
        setattr(msg, name, _f(fields.get(name)))
    msg.goal = _point(fields.get("goal"))
    msg.target_found = bool(fields.get("target_found", False))
    msg.target_position = _point(fields.get("target_position"))
    msg.detections_unplaced = _u(fields.get("detections_unplaced", 0))
    msg.candidates_rejected = _u(fields.get("candidates_rejected", 0))
    msg.stop = bool(fields.get("stop", False))
    return msg


def downsampled_layers_msg(msg: GridLayers, max_cells: int) -> GridLayers:
    """A GridLayers message reduced to at most ``max_cells`` per side (same header and layer names).

    Always a new ``numpy_msg(GridLayers)`` (``data`` a float32 array; the input may be either kind).
    """
    grid = downsample_grid(grid_from_msg(msg), max_cells)
    rows, cols = grid.shape
    out = NumpyGridLayers(header=msg.header, resolution_m=grid.resolution_m)
    out.origin_x_m, out.origin_y_m = grid.origin_x_m, grid.origin_y_m
    out.width, out.height = cols, rows
    out.names = list(grid.layers)
    out.data = (
        np.concatenate([grid.layers[n].astype(np.float32).ravel() for n in out.names])
        if out.names
        else np.zeros(0, np.float32)
    )
    return out
