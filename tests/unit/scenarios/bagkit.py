"""A synthetic search-and-rescue run written as a bag, for the report tests (builders: helpers.bags)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from helpers.bags import BagKit
from helpers.paths import REPO

__all__ = ["REPO", "BagKit", "write_synthetic_run"]


def write_synthetic_run(path: Path, *, duration_s: float = 60.0, with_snapshots: bool = True) -> dict[str, Any]:
    """A small SAR-like run: climb, fly south, see and confirm a person. Returns the final summary."""
    kit = BagKit(path)
    start = 100.0  # sim time when the run starts (SITL boot time is not 0)
    scenario = (REPO / "config/scenarios/search_and_rescue.yaml").read_text()
    kit.write("/scenario/config", start, kit.string(scenario))
    summary: dict[str, Any] = {}
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
            kit.write(
                "/detections/ground_truth",
                t,
                kit.detections(
                    t, "forward", "ground_truth", [(42, "person", (300, 200, 320, 240), 60.0, (30.0, -80.0, 0.0))]
                ),
            )
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
    kit.write(
        "/scenario/status",
        start + duration_s,
        kit.status(start + duration_s, "DONE", found=True, stop_reason="target_found"),
    )
    kit.close()
    return summary
