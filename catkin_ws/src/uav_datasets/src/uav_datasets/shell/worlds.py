"""The worlds of a dataset: the base world config with each split's seeds, generated once and cached."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from uav_common.config import ConfigError
from uav_datasets.core.config import DatasetConfig
from uav_datasets.errors import DatasetConfigError
from uav_sim_bridge.config import resolve_world_path
from uav_sim_bridge.core.world import World
from uav_sim_bridge.core.world_config import WorldConfig, load_world_config
from uav_sim_bridge.errors import SimBridgeError
from uav_sim_bridge.shell.world_store import load_or_generate

__all__ = ["DEFAULT_CACHE_DIR", "base_world_config", "load_world", "with_seed", "world_configs"]

DEFAULT_CACHE_DIR = Path("~/.cache/uav_test_range/worlds").expanduser()


def base_world_config(cfg: DatasetConfig) -> WorldConfig:
    """The world config the dataset's ``world`` key names (a name under ``config/worlds`` or a YAML path).

    Raises:
        DatasetConfigError: the world file is missing or invalid (the message names it).
    """
    try:
        path = resolve_world_path(cfg.world)
        return load_world_config(path)
    except (ConfigError, SimBridgeError) as err:
        msg = f"dataset {cfg.name}: world {cfg.world!r}: {err}"
        raise DatasetConfigError(msg) from err


def with_seed(base: WorldConfig, seed: int) -> WorldConfig:
    """``base`` with another seed (and a name that says so, as scenario worlds are named)."""
    if seed == base.seed:
        return base
    return replace(base, seed=seed, name=f"{base.name}-seed{seed}")


def world_configs(cfg: DatasetConfig) -> dict[int, WorldConfig]:
    """World seed -> world config of every split of a sampled-viewpoint dataset."""
    base = base_world_config(cfg)
    return {seed: with_seed(base, seed) for split in cfg.splits.values() for seed in split.world_seeds}


def load_world(world_cfg: WorldConfig, cache_dir: Path) -> World:
    """Load the world from the cache, or generate and cache it.

    Raises:
        DatasetConfigError: the world cannot be generated from its config.
    """
    try:
        return load_or_generate(world_cfg, cache_dir)
    except SimBridgeError as err:
        msg = f"world {world_cfg.name} (seed {world_cfg.seed}): {err}"
        raise DatasetConfigError(msg) from err
