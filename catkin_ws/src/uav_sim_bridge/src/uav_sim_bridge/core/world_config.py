"""Configuration of the world generator: ``config/worlds/<name>.yaml``.

Every field has a default, so an empty file gives the default ~1 km² valley.  Units
are in the field names.  Relative file paths (``heightmap_image``, ``mesh``) are
resolved against the YAML file's folder by :func:`load_world_config`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace
from pathlib import Path

from uav_common.config import config_errors_as, load_config
from uav_common.validate import require_non_negative, require_positive
from uav_sim_bridge.errors import SimBridgeConfigError

__all__ = [
    "BuildingsConfig",
    "CustomObjectConfig",
    "ForestConfig",
    "ObjectClass",
    "PeopleConfig",
    "RoadsConfig",
    "TerrainConfig",
    "VehiclesConfig",
    "WorldConfig",
    "load_world_config",
]


class ObjectClass(enum.IntEnum):
    """Semantic class of a world surface; the value is the class id in images (0 = sky)."""

    SKY = 0
    TERRAIN = 1
    ROAD = 2
    BUILDING = 3
    TREE = 4
    PERSON = 5
    VEHICLE = 6

    @property
    def label(self) -> str:
        return self.name.lower()

    @staticmethod
    def from_label(label: str) -> ObjectClass:
        try:
            return ObjectClass[label.upper()]
        except KeyError as err:
            known = ", ".join(c.label for c in ObjectClass if c is not ObjectClass.SKY)
            msg = f"unknown object class {label!r}; known: {known}"
            raise ValueError(msg) from err


@dataclass(frozen=True)
class TerrainConfig:
    """Heightfield: generated valley-and-hills, or a user heightmap image.

    The square terrain spans ``center_m ± size_m / 2``; home (the map origin) must lie
    inside it.  With ``heightmap_image`` set, the image's pixel grid is stretched over
    that square (row 0 = north edge), black = ``heightmap_min_m``, white =
    ``heightmap_max_m``, and the generator fields below it are ignored.
    """

    size_m: float = 1000.0
    resolution_m: float = 4.0
    center_m: tuple[float, float] = (0.0, 0.0)
    heightmap_image: Path | None = None
    heightmap_min_m: float = 0.0
    heightmap_max_m: float = 100.0
    hill_height_m: float = 85.0
    valley_width_m: float = 300.0
    valley_meander_m: float = 120.0
    valley_heading_deg: float = 20.0
    roughness_m: float = 9.0
    valley_grade: float = 0.012
    home_pad_radius_m: float = 20.0

    def __post_init__(self) -> None:
        require_positive("size_m", self.size_m)
        require_positive("resolution_m", self.resolution_m)
        if self.size_m / self.resolution_m > 4096:
            msg = f"size_m / resolution_m = {self.size_m / self.resolution_m:.0f} cells per side; the limit is 4096"
            raise ValueError(msg)
        if max(abs(self.center_m[0]), abs(self.center_m[1])) >= self.size_m / 2 - self.home_pad_radius_m:
            msg = f"center_m {self.center_m} puts home (0, 0) outside the terrain or too close to its edge"
            raise ValueError(msg)
        if self.heightmap_max_m < self.heightmap_min_m:
            msg = "heightmap_max_m must be >= heightmap_min_m"
            raise ValueError(msg)
        for name in ("hill_height_m", "valley_meander_m", "roughness_m", "home_pad_radius_m"):
            require_non_negative(name, getattr(self, name))
        require_positive("valley_width_m", self.valley_width_m)


@dataclass(frozen=True)
class RoadsConfig:
    """Villages (building clusters) and the irregular road network linking them."""

    villages: int = 5
    width_m: float = 6.0
    extra_links: int = 2
    exits: int = 2
    min_village_spacing_m: float = 220.0
    grid_m: float = 10.0

    def __post_init__(self) -> None:
        require_non_negative("villages", self.villages)
        require_positive("width_m", self.width_m)
        require_non_negative("extra_links", self.extra_links)
        require_non_negative("exits", self.exits)
        require_positive("min_village_spacing_m", self.min_village_spacing_m)
        require_positive("grid_m", self.grid_m)


@dataclass(frozen=True)
class BuildingsConfig:
    per_village_min: int = 8
    per_village_max: int = 16
    village_radius_m: float = 90.0
    flat_roof_fraction: float = 0.2

    def __post_init__(self) -> None:
        require_non_negative("per_village_min", self.per_village_min)
        if self.per_village_max < self.per_village_min:
            msg = "per_village_max must be >= per_village_min"
            raise ValueError(msg)
        require_positive("village_radius_m", self.village_radius_m)
        if not 0.0 <= self.flat_roof_fraction <= 1.0:
            msg = "flat_roof_fraction must be in [0, 1]"
            raise ValueError(msg)


@dataclass(frozen=True)
class ForestConfig:
    """Forest patches from a low-frequency noise mask; ``coverage`` is the target area fraction."""

    coverage: float = 0.3
    spacing_m: float = 7.5
    conifer_fraction: float = 0.6
    max_trees: int = 6000

    def __post_init__(self) -> None:
        if not 0.0 <= self.coverage <= 1.0:
            msg = "coverage must be in [0, 1]"
            raise ValueError(msg)
        require_positive("spacing_m", self.spacing_m)
        if not 0.0 <= self.conifer_fraction <= 1.0:
            msg = "conifer_fraction must be in [0, 1]"
            raise ValueError(msg)
        require_non_negative("max_trees", self.max_trees)


@dataclass(frozen=True)
class PeopleConfig:
    count: int = 30

    def __post_init__(self) -> None:
        require_non_negative("count", self.count)


@dataclass(frozen=True)
class VehiclesConfig:
    count: int = 20

    def __post_init__(self) -> None:
        require_non_negative("count", self.count)


@dataclass(frozen=True)
class CustomObjectConfig:
    """A user mesh (any format trimesh reads: PLY, OBJ, STL, glTF...) placed in the world.

    ``position_m`` is the (x, y) of the mesh origin in ``map``; the mesh's z = 0 is put
    on the ground there (plus ``z_offset_m``).  The mesh is in metres, z up, and is
    scaled by ``scale`` and turned by ``yaw_deg`` (counter-clockwise from east).
    """

    mesh: Path
    object_class: str = "building"
    position_m: tuple[float, float] = (0.0, 0.0)
    yaw_deg: float = 0.0
    scale: float = 1.0
    z_offset_m: float = 0.0
    color_rgb: tuple[float, float, float] = (0.7, 0.7, 0.7)
    name: str = ""

    def __post_init__(self) -> None:
        ObjectClass.from_label(self.object_class)
        if self.object_class in ("terrain", "sky"):
            msg = "custom objects cannot have class terrain or sky"
            raise ValueError(msg)
        require_positive("scale", self.scale)
        if not all(0.0 <= c <= 1.0 for c in self.color_rgb):
            msg = "color_rgb components must be in [0, 1]"
            raise ValueError(msg)


@dataclass(frozen=True)
class WorldConfig:
    """The whole world.  The same config (and the same input files) gives the same world."""

    name: str = "default"
    seed: int = 0
    home_clear_radius_m: float = 15.0
    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    roads: RoadsConfig = field(default_factory=RoadsConfig)
    buildings: BuildingsConfig = field(default_factory=BuildingsConfig)
    forest: ForestConfig = field(default_factory=ForestConfig)
    people: PeopleConfig = field(default_factory=PeopleConfig)
    vehicles: VehiclesConfig = field(default_factory=VehiclesConfig)
    custom_objects: tuple[CustomObjectConfig, ...] = ()

    def __post_init__(self) -> None:
        if self.seed < 0:
            msg = f"seed must be >= 0, got {self.seed}"
            raise ValueError(msg)
        if self.home_clear_radius_m < 15.0:
            msg = f"home_clear_radius_m must be >= 15 (architecture contract), got {self.home_clear_radius_m}"
            raise ValueError(msg)


def load_world_config(path: Path) -> WorldConfig:
    """Load a world YAML; relative file paths in it are made relative to its folder.

    Raises:
        SimBridgeConfigError: missing file, bad YAML, unknown key or invalid value.
    """
    with config_errors_as(SimBridgeConfigError):
        cfg = load_config(WorldConfig, path)
    base = path.resolve().parent
    terrain = cfg.terrain
    if terrain.heightmap_image is not None and not terrain.heightmap_image.is_absolute():
        terrain = replace(terrain, heightmap_image=base / terrain.heightmap_image)
    customs = tuple(c if c.mesh.is_absolute() else replace(c, mesh=base / c.mesh) for c in cfg.custom_objects)
    return replace(cfg, terrain=terrain, custom_objects=customs)
