"""A run's summary as the few lines a shell prints after it (``uav-run``, ``uav-report``)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

__all__ = ["headline"]


def _get(data: Mapping[str, Any], dotted: str) -> Any:
    cur: Any = data
    for part in dotted.split("."):
        if not isinstance(cur, Mapping):
            return None
        cur = cur.get(part)
    return cur


def headline(summary: Mapping[str, Any]) -> list[str]:
    """The few lines a shell prints after a run."""

    def f(key: str, unit: str = "", digits: int = 1) -> str:
        value = _get(summary, key)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return "n/a"
        return f"{value:.{digits}f}{unit}" if isinstance(value, float | int) else str(value)

    return [
        (
            f"  simulated {f('time.duration_s', ' s')}, airborne {f('time.airborne_s', ' s')}, "
            f"complete at {f('time.complete_s', ' s')}"
        ),
        (
            f"  mapped {f('coverage.mapped_pct', ' %', 2)} of the scene ({f('coverage.mapped_m2', ' m²', 0)}), "
            f"coverage efficiency {f('coverage.efficiency', '', 3)}; map server inserted "
            f"{f('map_input.clouds_inserted', '', 0)} of {f('map_input.clouds_received', '', 0)} clouds "
            f"({f('map_input.dropped_queue_full', '', 0)} dropped: insertion too slow; "
            f"{f('map_input.dropped_unsynchronized', '', 0)} incomplete)"
        ),
        (
            f"  map vs ground truth: IoU {f('map_accuracy.iou', '', 3)} over the scene, "
            f"{f('map_accuracy.iou_observed', '', 3)} where mapped; precision {f('map_accuracy.precision', '', 3)}"
        ),
        (
            f"  flew {f('flight.distance_m', ' m', 0)}, min AGL {f('flight.agl_min_m', ' m')}, "
            f"below floor {f('flight.time_below_floor_s', ' s')}, collisions {f('collisions.count', '', 0)}"
        ),
        f"  battery used {f('battery.used_mah', ' mAh', 0)} ({f('battery.used_pct', ' %')})",
        (
            f"  detection ({f('detection.source')}) TP/FP/FN {f('detection.tp', '', 0)}/{f('detection.fp', '', 0)}/"
            f"{f('detection.fn', '', 0)} at score >= {f('detection.score_threshold', '', 2)}, "
            f"AP50 {f('detection.coco.AP50', '', 3)}, AP {f('detection.coco.AP', '', 3)}; "
            f"person first detected {f('detection.person_first_detected.t_s', ' s')} at "
            f"{f('detection.person_first_detected.range_m', ' m', 0)}"
        ),
        (
            f"  geolocation: median error {f('detection.geolocation.error.median_m', ' m', 2)}, "
            f"{f('detection.geolocation.error.within_95', '', 2)} inside the stated 95 % ellipse; "
            f"unplaced {f('detection.geolocation.unplaced_share', '', 3)} of the detections"
        ),
        (
            f"  tracking MOTA {f('tracking.mota', '', 3)}, IDF1 {f('tracking.idf1', '', 3)}, "
            f"HOTA {f('tracking.hota', '', 3)}"
        ),
        (
            f"  moving objects {f('moving_objects.movers', '', 0)}, {f('moving_objects.distance_m', ' m', 0)} "
            "travelled; of the voxels they left that the map had marked occupied and looked at again, "
            f"{f('moving_objects.cleared_voxels', '', 0)} cleared, {f('moving_objects.ghost_voxels', '', 0)} "
            f"still occupied ({f('moving_objects.cleared_fraction', '', 2)} cleared; "
            f"{f('moving_objects.unseen_voxels', '', 0)} not looked at since)"
        ),
    ]
