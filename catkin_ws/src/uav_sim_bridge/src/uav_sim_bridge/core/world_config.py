"""Configuration of the world generator: ``config/worlds/<name>.yaml``.

Every field has a default, so an empty file gives the default ~1 km² valley.  Units
are in the field names.  Relative file paths (``heightmap_image``, ``mesh``) are
resolved against the YAML file's folder by :func:`load_world_config`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal

from uav_common.config import config_errors_as, load_config
from uav_common.validate import require_non_negative, require_positive
from uav_sim_bridge.errors import SimBridgeConfigError

__all__ = [
    "PERSON_POSES",
    "VEHICLE_TYPES",
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


PERSON_POSES = ("standing", "walking", "sitting", "lying")
VEHICLE_TYPES = ("car", "van", "truck")


def _weights(name: str, weights: dict[str, float], known: tuple[str, ...]) -> None:
    unknown = sorted(set(weights) - set(known))
    if unknown:
        msg = f"{name} has unknown entries {unknown}; known: {', '.join(known)}"
        raise ValueError(msg)
    if any(not w >= 0 for w in weights.values()) or not sum(weights.values()) > 0:
        msg = f"{name} weights must be >= 0 with a positive sum, got {weights}"
        raise ValueError(msg)


def _speed_range(name: str, speeds: tuple[float, float], limit: float) -> None:
    lo, hi = speeds
    if not 0 < lo <= hi <= limit:
        msg = f"{name} must be [min, max] with 0 < min <= max <= {limit:g} m/s, got {list(speeds)}"
        raise ValueError(msg)


@dataclass(frozen=True)
class PeopleConfig:
    """People: articulated figures in seeded poses, sizes and clothes; ``moving`` of them walk.

    ``poses`` weighs the poses of the people who do not walk. Walkers follow ``motion``:
    ``road`` (along a road's shoulder), ``random`` (a seeded loop of random waypoints within
    ``wander_radius_m`` of where they stand, around buildings and trees) or ``mixed`` (road
    walkers near a road, the rest random), at a seeded speed in ``speed_mps``. Which people walk,
    and their paths, are chosen when the simulation starts (``uav_sim_bridge.core.motion``).
    """

    count: int = 30
    poses: dict[str, float] = field(default_factory=lambda: {"standing": 0.6, "sitting": 0.2, "lying": 0.2})
    height_m: tuple[float, float] = (1.55, 1.95)
    moving: int = 0
    speed_mps: tuple[float, float] = (1.0, 1.6)
    motion: Literal["mixed", "road", "random"] = "mixed"
    wander_radius_m: float = 40.0

    def __post_init__(self) -> None:
        require_non_negative("count", self.count)
        _weights("poses", self.poses, PERSON_POSES)
        if not 1.0 <= self.height_m[0] <= self.height_m[1] <= 2.3:
            msg = f"height_m must be [min, max] within [1.0, 2.3] m, got {list(self.height_m)}"
            raise ValueError(msg)
        if not 0 <= self.moving <= self.count:
            msg = f"moving must be in [0, count = {self.count}], got {self.moving}"
            raise ValueError(msg)
        _speed_range("speed_mps", self.speed_mps, 4.0)
        require_positive("wander_radius_m", self.wander_radius_m)


@dataclass(frozen=True)
class VehiclesConfig:
    """Vehicles: cars, vans and trucks (``types`` weighs them) in seeded colours, parked at the kerb of a
    road or in a village; ``moving`` of them drive along the roads at a seeded speed in ``speed_mps``."""

    count: int = 20
    types: dict[str, float] = field(default_factory=lambda: {"car": 0.6, "van": 0.25, "truck": 0.15})
    moving: int = 0
    speed_mps: tuple[float, float] = (7.0, 13.0)

    def __post_init__(self) -> None:
        require_non_negative("count", self.count)
        _weights("types", self.types, VEHICLE_TYPES)
        if not 0 <= self.moving <= self.count:
            msg = f"moving must be in [0, count = {self.count}], got {self.moving}"
            raise ValueError(msg)
        _speed_range("speed_mps", self.speed_mps, 40.0)


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
    #: Where on Earth the world lies (for the sun; the SITL's home latitude, ``config/sitl.yaml``, by default).
    latitude_deg: float = 47.397742
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
        if not -90.0 <= self.latitude_deg <= 90.0:
            msg = f"latitude_deg must be in [-90, 90], got {self.latitude_deg}"
            raise ValueError(msg)
        if self.roads.villages == 0 and self.vehicles.moving > 0:
            msg = (
                f"vehicles.moving is {self.vehicles.moving} but the world has no roads to drive on "
                "(roads.villages is 0): set vehicles.moving to 0 or add villages"
            )
            raise ValueError(msg)
        if self.roads.villages == 0 and self.people.moving > 0 and self.people.motion == "road":
            msg = (
                f"people.motion is road and people.moving is {self.people.moving}, but the world has no roads "
                "(roads.villages is 0): use people.motion random or mixed, or add villages"
            )
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
