"""World configurations shared by the sim_bridge tests (unique module name: no clash with other conftests)."""

from __future__ import annotations

from dataclasses import replace

from helpers.paths import REPO

from uav_sim_bridge.core.world_config import (
    ForestConfig,
    PeopleConfig,
    RoadsConfig,
    TerrainConfig,
    VehiclesConfig,
    WorldConfig,
)

DEFAULT_WORLD_YAML = REPO / "config" / "worlds" / "default.yaml"


def flat_config(**overrides: object) -> WorldConfig:
    """A 400 m flat, empty world (terrain only)."""
    cfg = WorldConfig(
        name="flat",
        seed=1,
        terrain=TerrainConfig(size_m=400.0, resolution_m=4.0, hill_height_m=0.0, roughness_m=0.0, valley_grade=0.0),
        roads=RoadsConfig(villages=0),
        forest=ForestConfig(coverage=0.0),
        people=PeopleConfig(count=0),
        vehicles=VehiclesConfig(count=0),
    )
    return replace(cfg, **overrides)  # type: ignore[arg-type]


def small_config(seed: int = 3) -> WorldConfig:
    """A 400 m world with every kind of content, fast to generate."""
    return WorldConfig(
        name="small",
        seed=seed,
        terrain=TerrainConfig(size_m=400.0, resolution_m=4.0, hill_height_m=30.0, valley_width_m=150.0),
        roads=RoadsConfig(villages=2, min_village_spacing_m=150.0, exits=1, extra_links=0),
        forest=ForestConfig(coverage=0.3, max_trees=800),
        people=PeopleConfig(count=12),
        vehicles=VehiclesConfig(count=6),
    )
