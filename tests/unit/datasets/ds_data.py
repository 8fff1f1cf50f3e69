"""Small worlds and dataset configs shared by the data engine's tests (unique module name)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

#: A small world with every kind of content (generates in well under a second).
SMALL_WORLD = """name: ds_small
seed: 21
terrain: {size_m: 400.0, resolution_m: 4.0, hill_height_m: 25.0, valley_width_m: 160.0}
roads: {villages: 2, min_village_spacing_m: 150.0, exits: 1, extra_links: 0}
forest: {coverage: 0.25, max_trees: 500}
people: {count: 16}
vehicles: {count: 8}
"""


def small_dataset(tmp: Path, **overrides: Any) -> Path:
    """A dataset config (tens of frames, two train worlds, one test world) in ``tmp``; returns its path."""
    (tmp / "ds_world.yaml").write_text(SMALL_WORLD)
    data: dict[str, Any] = {
        "name": "unit_small",
        "description": "unit test dataset",
        "world": "ds_world.yaml",
        "seed": 4,
        "frames": 24,
        "splits": {
            "train": {"world_seeds": [21, 22], "fraction": 0.75},
            "test": {"world_seeds": [23], "fraction": 0.25},
        },
        "camera": {"width": 320, "height": 240, "hfov_deg": 80.0},
        "viewpoints": {
            "margin_m": 30.0,
            "positions": [
                {"kind": "near_objects", "classes": ["person"], "max_offset_m": 8.0, "weight": 2.0},
                {"kind": "near_objects", "classes": ["vehicle"], "max_offset_m": 8.0},
                {"kind": "roads", "max_offset_m": 5.0},
                {"kind": "uniform"},
            ],
            "altitude_agl_m": [12.0, 60.0],
            "pitch_deg": [25.0, 90.0],
        },
        "labels": {"classes": ["person", "vehicle"], "min_visible_pixels": 4},
    }
    for key, value in overrides.items():
        node = data
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    path = tmp / "dataset.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path
