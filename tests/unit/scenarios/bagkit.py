"""A synthetic search-and-rescue run written as a bag, for the report tests (builders: helpers.bags)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from helpers.bags import BagKit
from helpers.paths import REPO

__all__ = ["REPO", "BagKit", "write_synthetic_run"]


#: The synthetic run's objects: the person of interest and a parked car (instance id, class, box, range, position).
_PERSON = (42, "person", (300, 200, 320, 240), 60.0, (30.0, -80.0, 0.0))
_CAR = (57, "vehicle", (100, 300, 160, 330), 45.0, (-20.0, -60.0, 0.0))


def _detector_frame(k: int) -> tuple[list[Any], list[float]]:
    """The synthetic detector's boxes in frame ``k``: the person (shifted a pixel, missed every 5th frame), the car
    (every 3rd frame, a loose box), a false positive in every 4th frame (placed) and an unplaced one every 7th."""
    dets: list[Any] = []
    scores: list[float] = []
    if k % 10 != 0:
        dets.append((0, "person", (301, 201, 321, 241), 59.0, (30.5, -80.3, 0.0)))
        scores.append(0.9 - 0.001 * (k % 50))
    if k % 6 == 0:
        dets.append((0, "vehicle", (96, 296, 166, 336), 44.0, (-19.0, -61.5, 0.0)))
        scores.append(0.7)
    if k % 8 == 0:
        dets.append((0, "person", (500, 100, 508, 120), 90.0, (60.0, -140.0, 0.0)))
        scores.append(0.8)
    if k % 14 == 0:
        dets.append((0, "person", (40, 20, 44, 30), math.nan, (math.nan, math.nan, math.nan)))
        scores.append(0.6)
    return dets, scores


def write_synthetic_run(path: Path, *, duration_s: float = 60.0, with_snapshots: bool = True) -> dict[str, Any]:
    """A small SAR-like run: climb, fly south, see and confirm a person. Returns the final summary.

    Its detection and tracking metrics are a real :class:`RunScorer`'s over the frames written (the truth on
    ``/detections/ground_truth``, a synthetic detector's placed boxes on ``/geolocator/detections``), with the COCO
    scores; with snapshots it also writes a gallery mosaic cut from a synthetic camera image.
    """
    from uav_scenarios.core.config import GEOLOCATED_TOPIC, ScoringSpec  # noqa: PLC0415
    from uav_scenarios.core.scoring.gallery import crop_tile, mosaic  # noqa: PLC0415
    from uav_scenarios.core.scoring.run import RunScorer  # noqa: PLC0415
    from uav_scenarios.core.scoring.types import (  # noqa: PLC0415
        Detection,
        DetectionFrame,
        PoseSample,
        SceneTruth,
        Track,
        TrackFrame,
    )

    kit = BagKit(path)
    start = 100.0  # sim time when the run starts (SITL boot time is not 0)
    scenario = (REPO / "config/scenarios/search_and_rescue.yaml").read_text()
    kit.write("/scenario/config", start, kit.string(scenario))
    summary: dict[str, Any] = {}
    scorer = RunScorer(
        ScoringSpec(), SceneTruth((-100.0, -100.0, 100.0, 100.0)), detection_source="degraded_truth", person_id=42
    )
    scorer.score_threshold = 0.5
    scorer.start_t_s = start

    def record(frame_msg: Any, t: float) -> DetectionFrame:
        return DetectionFrame(
            t,
            "forward",
            str(frame_msg.source),
            tuple(
                Detection(
                    int(d.instance_id),
                    str(d.class_name),
                    float(d.score),
                    (d.x_min, d.y_min, d.x_max, d.y_max),
                    float(d.range_m),
                    float(d.visible_fraction),
                    (d.position.x, d.position.y, d.position.z),
                    tuple(float(c) for c in d.position_covariance),
                    str(d.position_source),
                )
                for d in frame_msg.detections
            ),
            tuple(zip(frame_msg.discarded_reasons, (int(c) for c in frame_msg.discarded_counts), strict=True)),
        )

    res, n = 4.0, 50
    yy, xx = np.mgrid[0:n, 0:n]
    elevation = 10.0 * np.sin(xx / 8.0) + 5.0 * np.cos(yy / 6.0)
    for k in range(int(duration_s * 10) + 1):
        t = start + 0.1 * k
        rel = t - start
        z = min(30.0, 3.0 * rel)
        y = -max(0.0, 4.0 * (rel - 10.0))
        if k % 5 == 0:
            kit.write("/scenario/status", t, kit.status(t, "SEARCHING" if rel > 10 else "TAKEOFF", found=rel > 50))
        kit.write("/uav/ground_truth/odom", t, kit.odom(t, 0.0, y, z))
        scorer.add_pose(PoseSample(t, (0.0, y, z)))
        if k % 2 == 0:
            movers = [(7, "person_0003", 20.0 + 1.2 * rel, -30.0, 0.0), (9, "vehicle_0001", -50.0, 8.0 * rel, 1.57)]
            kit.write("/sim/object_states", t, kit.object_states(t, movers))
        if k % 10 == 0:
            kit.write("/uav/battery", t, kit.battery(t, 100.0 - 0.2 * rel, 16.8 - 0.01 * rel))
            kit.write("/autonomy/goal_reason", t, kit.goal_reason(t, 0.0, y - 50.0))
            seen = np.clip((np.hypot(xx - n / 2, yy - n / 2 - y / res) < 4 + rel / 4), 0, 1).astype(float)
            summary = {
                "time": {"duration_s": rel, "complete_s": 50.0 if rel > 50 else None},
                "coverage": {"mapped_pct": rel / 2},
                "flight": {"distance_m": 4.0 * rel, "altitude_floor_m": 10.0},
                "detection": {"person_first_in_view": {"t_s": 40.0}, "person_first_detected": {"t_s": 40.0}},
                "events": [{"t_s": 40.0, "what": "person in view"}],
                "moving_objects": {
                    "movers": 2,
                    "distance_m": 5.0 * rel,
                    "mapped_voxels": 10.0 * rel,
                    "seen_again_voxels": 8.0 * rel,
                    "ghost_voxels": 2.0 * rel,
                    "cleared_voxels": 6.0 * rel,
                    "cleared_fraction": 0.75,
                },
            }
            kit.write(
                "/scenario/metrics",
                t,
                kit.metrics(
                    t,
                    {
                        "mapped_pct": rel / 2,
                        "mean_cell_age_s": min(rel, 20.0),
                        "observed_cells": int(seen.sum()),
                        "distance_m": 4.0 * rel,
                        "agl_m": z,
                        "battery_pct": 100.0 - 0.2 * rel,
                    },
                    summary,
                ),
            )
        if k % 100 == 0:
            kit.write(
                "/uav/controller/state",
                t,
                kit.controller(t, "TAKEOFF" if rel < 10 else ("HOLD" if rel > 50 else "AUTONOMOUS")),
            )
        if k % 2 == 0 and rel > 40:
            truth_msg = kit.detections(t, "forward", "ground_truth", [_PERSON, _CAR])
            kit.write("/detections/ground_truth", t, truth_msg)
            dets, scores = _detector_frame(k)
            discarded = {"nan_box": 1} if k % 20 == 0 else {}
            hyp_msg = kit.detections(
                t, "forward", "degraded_truth", dets, scores=scores, position_source="terrain", sigma_m=1.5,
                discarded=discarded,
            )  # fmt: skip
            kit.write(GEOLOCATED_TOPIC, t, hyp_msg)
            scorer.add_detections(record(truth_msg, t), is_truth=True)
            scorer.add_detections(record(hyp_msg, t), is_truth=False)
            tracks = (Track(7, "person", (30.4, -80.2, 0.0)),) if k % 10 != 0 else ()
            scorer.add_tracks(TrackFrame(t, "forward", tracks, detections_received=k, detections_unplaced=k // 14))
        if with_snapshots and k in (150, 450):
            obs = (np.hypot(xx - n / 2, yy - n / 2) < 5 + k / 20).astype(float)
            layers = {
                "elevation_m": np.where(obs > 0, elevation, np.nan),
                "last_seen_s": np.where(obs > 0, t, np.nan),
                "observed": obs,
            }
            kit.write("/scenario/snapshot/layers", t, kit.grid(t, layers, res, -100.0, -100.0))
            kit.write(
                "/scenario/snapshot/features",
                t,
                kit.grid(
                    t,
                    {"score": np.where(obs > 0, np.random.default_rng(k).random((n, n)), np.nan)},
                    res,
                    -100.0,
                    -100.0,
                ),
            )
            for cam in ("nadir", "forward"):
                color = np.zeros((48, 64, 3), np.uint8)
                color[..., 1] = 120
                color[10:20, 10:30] = (200, 50, 50)
                kit.write(f"/scenario/snapshot/{cam}/color", t, kit.image(t, color, "rgb8"))
                kit.write(
                    f"/scenario/snapshot/{cam}/depth",
                    t,
                    kit.image(t, np.linspace(5, 80, 48 * 64, dtype=np.float32).reshape(48, 64), "32FC1"),
                )
                inst = np.zeros((48, 64), np.uint16)
                inst[24:, :] = 1
                inst[10:20, 10:30] = 42
                kit.write(f"/scenario/snapshot/{cam}/instance", t, kit.image(t, inst, "16UC1"))
    end = start + duration_s
    scored = scorer.summary(end, coco=True)
    summary = {**summary, "detection": scored["detection"], "tracking": scored["tracking"]}
    summary["detection"]["person_first_in_view"] = {"t_s": 40.0}
    kit.write("/scenario/metrics", end, kit.metrics(end, {"mapped_pct": duration_s / 2}, summary))
    if with_snapshots:
        color = np.full((480, 640, 3), 90, np.uint8)
        color[200:241, 300:321] = (200, 60, 60)
        color[100:121, 500:509] = (60, 60, 200)
        tiles: dict[str, list[Any]] = {}
        for item in scorer.gallery_items():
            tiles.setdefault(item.kind, []).append(crop_tile(color, item))
        gallery = mosaic(tiles, scorer.spec.gallery_size)
        if gallery is not None:  # short runs end before the detector starts: nothing to show
            kit.write("/scenario/snapshot/gallery", end, kit.image(end, gallery, "rgb8"))
    kit.write("/scenario/status", end, kit.status(end, "DONE", found=True, stop_reason="target_found"))
    kit.close()
    return summary
