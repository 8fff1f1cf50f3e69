"""Dataset configuration: ``config/datasets/<name>.yaml`` parsed once into validated frozen dataclasses.

Every key is documented in ``docs/datasets.md``. Unknown keys, wrong types and impossible values
(an unknown class, an altitude range whose minimum exceeds its maximum, a world seed in two splits)
are :class:`~uav_datasets.errors.DatasetConfigError` naming the file and the key.

Units are in the names: ``altitude_agl_m`` is metres above the terrain under the camera,
``pitch_deg`` the camera's depression below the horizon (0 = looking at the horizon, 90 = nadir),
``yaw_deg`` the heading of the view, counter-clockwise from east (``map`` x).
"""

from __future__ import annotations

import itertools
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from uav_common.config import config_errors_as, from_mapping, load_yaml_mapping, to_mapping
from uav_common.validate import require_non_negative, require_positive
from uav_datasets.errors import DatasetConfigError
from uav_sim_bridge.core.camera import CameraConfig, CameraModel
from uav_sim_bridge.core.world_config import ObjectClass

__all__ = [
    "LABEL_CLASSES",
    "CameraSpec",
    "CardSpec",
    "DatasetConfig",
    "FlightSpec",
    "LabelSpec",
    "OutputSpec",
    "PositionMode",
    "SplitSpec",
    "ViewpointSpec",
    "dataset_config_from_mapping",
    "load_dataset_config",
]

#: Classes that can be labelled: every object class of the world except the sky and the terrain.
LABEL_CLASSES = tuple(c.label for c in ObjectClass if c not in (ObjectClass.SKY, ObjectClass.TERRAIN))
_SLUG = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]*$")
#: Highest altitude above ground a viewpoint may ask for (the world's hills reach ~100 m; a camera 5 km up sees
#: people as less than a pixel).
MAX_ALTITUDE_M = 5000.0


def _label_class(label: str, key: str) -> ObjectClass:
    try:
        cls = ObjectClass.from_label(label)
    except ValueError:
        msg = f"{key}: unknown class {label!r}; classes that can be labelled: {', '.join(LABEL_CLASSES)}"
        raise ValueError(msg) from None
    if cls.label not in LABEL_CLASSES:
        msg = f"{key}: class {label!r} cannot be labelled (no instances); use one of {', '.join(LABEL_CLASSES)}"
        raise ValueError(msg)
    return cls


def _range(name: str, values: tuple[float, float], lo: float, hi: float, unit: str) -> None:
    a, b = values
    if not (math.isfinite(a) and math.isfinite(b)):
        msg = f"{name} {list(values)} must be finite"
        raise ValueError(msg)
    if a > b:
        msg = f"{name} {list(values)} is impossible: the minimum {a:g} {unit} is above the maximum {b:g} {unit}"
        raise ValueError(msg)
    if a < lo or b > hi:
        msg = f"{name} {list(values)} is impossible: both ends must lie within [{lo:g}, {hi:g}] {unit}"
        raise ValueError(msg)


@dataclass(frozen=True)
class CameraSpec:
    """The pinhole camera every frame is rendered with.

    Give ``hfov_deg`` (square pixels, principal point at the centre) or ``fx`` and ``fy`` (and
    optionally ``cx``, ``cy``); with neither, the field of view is 90 degrees.
    """

    width: int = 640
    height: int = 480
    hfov_deg: float | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    near_m: float = 0.5
    far_m: float = 2000.0

    def __post_init__(self) -> None:
        self.model()  # validates (CameraError is a ValueError)

    def model(self, name: str = "dataset") -> CameraModel:
        hfov = self.hfov_deg if self.hfov_deg is not None or self.fx is not None or self.fy is not None else 90.0
        cfg = CameraConfig(
            width=self.width,
            height=self.height,
            hfov_deg=hfov,
            fx=self.fx,
            fy=self.fy,
            cx=self.cx,
            cy=self.cy,
            near_m=self.near_m,
            far_m=self.far_m,
        )
        return CameraModel.from_config(name, cfg)


@dataclass(frozen=True)
class PositionMode:
    """One way of choosing where a viewpoint looks (the *target*, a point on the ground).

    * ``uniform``: uniform over the area;
    * ``near_objects``: an object of ``classes`` in the area, chosen uniformly, moved by up to
      ``max_offset_m`` (uniform over a disc) so it is not always in the image centre;
    * ``roads``: a point on a road centreline (uniform by length) moved by up to ``max_offset_m``.

    ``weight`` is the mode's share of the frames (relative to the other modes).
    """

    kind: Literal["uniform", "near_objects", "roads"] = "uniform"
    weight: float = 1.0
    classes: tuple[str, ...] = ()
    max_offset_m: float = 10.0

    def __post_init__(self) -> None:
        require_positive("weight", self.weight)
        require_non_negative("max_offset_m", self.max_offset_m)
        if self.kind == "near_objects" and not self.classes:
            msg = f"kind near_objects needs 'classes' (one or more of {', '.join(LABEL_CLASSES)})"
            raise ValueError(msg)
        if self.kind != "near_objects" and self.classes:
            msg = f"'classes' only applies to kind near_objects, not {self.kind}"
            raise ValueError(msg)
        for c in self.classes:
            _label_class(c, "classes")

    @property
    def class_ids(self) -> frozenset[ObjectClass]:
        return frozenset(ObjectClass.from_label(c) for c in self.classes)


@dataclass(frozen=True)
class ViewpointSpec:
    """How viewpoints are sampled over a world (``source: viewpoints``).

    Each frame draws a mode from ``positions``, a target point by that mode, an altitude above the
    terrain, a pitch and a yaw, all uniform in their ranges; the camera is put ``altitude_agl_m``
    above the terrain at the point from which its optical axis, at that pitch and yaw, meets the
    target's height (no farther than ``max_standoff_m`` horizontally). A draw whose camera lies
    within ``clearance_m`` of an object's 3D box, or less than ``clearance_m`` above the terrain
    within ``clearance_m`` of it, or that sees fewer than ``min_objects_in_view`` labelled objects,
    is rejected and drawn again (at most ``max_attempts`` times per frame).
    """

    area_m: tuple[float, float, float, float] | None = None
    margin_m: float = 50.0
    positions: tuple[PositionMode, ...] = (PositionMode(),)
    altitude_agl_m: tuple[float, float] = (20.0, 120.0)
    pitch_deg: tuple[float, float] = (30.0, 90.0)
    yaw_deg: tuple[float, float] = (0.0, 360.0)
    max_standoff_m: float = 300.0
    clearance_m: float = 1.0
    min_objects_in_view: int = 0
    max_attempts: int = 500

    def __post_init__(self) -> None:
        if self.area_m is not None:
            x0, y0, x1, y1 = self.area_m
            if not all(math.isfinite(v) for v in self.area_m) or x0 >= x1 or y0 >= y1:
                msg = (
                    f"area_m {list(self.area_m)} must be [x_min, y_min, x_max, y_max] with x_min < x_max, y_min < y_max"
                )
                raise ValueError(msg)
        require_non_negative("margin_m", self.margin_m)
        if not self.positions:
            msg = "positions must name at least one mode"
            raise ValueError(msg)
        if not (self.altitude_agl_m[0] > 0):
            msg = (
                f"altitude_agl_m {list(self.altitude_agl_m)} is impossible: the camera must be above the terrain "
                "(minimum > 0 m)"
            )
            raise ValueError(msg)
        _range("altitude_agl_m", self.altitude_agl_m, 0.0, MAX_ALTITUDE_M, "m")
        _range("pitch_deg", self.pitch_deg, 0.0, 90.0, "deg (0 = horizon, 90 = nadir)")
        _range("yaw_deg", self.yaw_deg, -360.0, 720.0, "deg")
        require_positive("max_standoff_m", self.max_standoff_m)
        require_non_negative("clearance_m", self.clearance_m)
        if self.min_objects_in_view < 0 or self.max_attempts < 1:
            msg = "min_objects_in_view must be >= 0 and max_attempts >= 1"
            raise ValueError(msg)


@dataclass(frozen=True)
class SplitSpec:
    """One split: its worlds (seeds of the base world config) and its share of the frames."""

    world_seeds: tuple[int, ...]
    fraction: float = 1.0

    def __post_init__(self) -> None:
        if not self.world_seeds:
            msg = "world_seeds must list at least one seed"
            raise ValueError(msg)
        if len(set(self.world_seeds)) != len(self.world_seeds):
            msg = f"world_seeds {list(self.world_seeds)} repeats a seed"
            raise ValueError(msg)
        require_positive("fraction", self.fraction)


def _default_splits() -> dict[str, SplitSpec]:
    return {
        "train": SplitSpec((1, 2, 3), 0.8),
        "val": SplitSpec((4,), 0.1),
        "test": SplitSpec((5,), 0.1),
    }


@dataclass(frozen=True)
class FlightSpec:
    """A sequence along a flight (``source: flight``): a recorded run, or a scenario flown now.

    ``run`` is a run folder (``runs/<name>-<time>/``) or its ``run.bag``, recorded with the ``replay``
    preset (or any preset: only ``/uav/ground_truth/odom`` and ``/scenario/config`` are read).
    ``scenario`` instead flies that scenario first (``uav-run --lockstep --record replay --time-limit
    time_limit_s``) and converts the new run. ``camera`` is one of the run's bridge cameras (its
    intrinsics, mount and rate); frames fall where the bridge rendered them, on the grid of
    ``rate_hz`` (default: the camera's rate) from ``start_s`` to ``end_s`` (simulation seconds since
    the first state), skipping frames whose camera is less than ``min_altitude_agl_m`` above the terrain
    (the vehicle on the ground: its near plane clips the ground in front of it).
    """

    run: Path | None = None
    scenario: Path | None = None
    time_limit_s: float = 60.0
    camera: str = "forward"
    rate_hz: float | None = None
    start_s: float = 0.0
    end_s: float | None = None
    min_altitude_agl_m: float = 2.0
    split: str = "test"
    sequence: str = ""

    def __post_init__(self) -> None:
        if (self.run is None) == (self.scenario is None):
            msg = "give exactly one of 'run' (a recorded run folder or bag) and 'scenario' (fly it now)"
            raise ValueError(msg)
        require_positive("time_limit_s", self.time_limit_s)
        if self.rate_hz is not None:
            require_positive("rate_hz", self.rate_hz)
        require_non_negative("min_altitude_agl_m", self.min_altitude_agl_m)
        if self.start_s < 0 or (self.end_s is not None and self.end_s <= self.start_s):
            msg = f"need 0 <= start_s < end_s, got start_s={self.start_s}, end_s={self.end_s}"
            raise ValueError(msg)
        if not _SLUG.match(self.split):
            msg = f"split {self.split!r} must be a slug (letters, digits, - and _)"
            raise ValueError(msg)
        if self.sequence and not _SLUG.match(self.sequence):
            msg = f"sequence {self.sequence!r} must be a slug (letters, digits, - and _)"
            raise ValueError(msg)


@dataclass(frozen=True)
class LabelSpec:
    """Which instances get labels (filters) and the size of the smallest one.

    An instance is labelled when its class is in ``classes``, at least ``min_visible_pixels`` of its
    pixels are visible, its visible fraction is at least ``min_visible_fraction`` and (if set) its
    range is at most ``max_range_m``. A fully occluded object has no visible pixel, so never a label.
    """

    classes: tuple[str, ...] = ("person", "vehicle")
    min_visible_pixels: int = 4
    min_visible_fraction: float = 0.0
    max_range_m: float | None = None

    def __post_init__(self) -> None:
        if not self.classes:
            msg = f"classes must list at least one of {', '.join(LABEL_CLASSES)}"
            raise ValueError(msg)
        for c in self.classes:
            _label_class(c, "classes")
        if len(set(self.classes)) != len(self.classes):
            msg = f"classes {list(self.classes)} repeats a class"
            raise ValueError(msg)
        if self.min_visible_pixels < 1:
            msg = (
                "min_visible_pixels must be >= 1 (an object with no visible pixel has no box), "
                f"got {self.min_visible_pixels}"
            )
            raise ValueError(msg)
        if not 0.0 <= self.min_visible_fraction <= 1.0:
            msg = f"min_visible_fraction must be within [0, 1], got {self.min_visible_fraction}"
            raise ValueError(msg)
        if self.max_range_m is not None:
            require_positive("max_range_m", self.max_range_m)

    @property
    def class_list(self) -> tuple[ObjectClass, ...]:
        """The labelled classes in the config's order (YOLO class index = position)."""
        return tuple(ObjectClass.from_label(c) for c in self.classes)


@dataclass(frozen=True)
class OutputSpec:
    """What is written for every frame (all from the same render)."""

    images: Literal["png", "jpg", "none"] = "png"
    jpeg_quality: int = 95
    #: Colour and depth PNGs: ``fast`` (zlib-ng level 1, ~670 KB for a 640x480 frame's four PNGs) or ``none``
    #: (stored, ~900 + ~600 KB). Id masks are always compressed (they shrink to ~20-30 KB).
    png_compression: Literal["fast", "none"] = "fast"
    coco: bool = True
    yolo: bool = True
    #: MOTChallenge files for sequences; None = when the source is a flight.
    mot: bool | None = None
    kitti: bool = True
    depth: Literal["uint16_mm", "float32", "none"] = "uint16_mm"
    instance_masks: bool = True
    class_masks: bool = True

    def __post_init__(self) -> None:
        if not 1 <= self.jpeg_quality <= 100:
            msg = f"jpeg_quality must be within [1, 100], got {self.jpeg_quality}"
            raise ValueError(msg)
        if self.images == "none" and (self.yolo or self.mot):
            msg = "images: none leaves YOLO and MOT labels without images; set yolo: false and mot: false"
            raise ValueError(msg)


@dataclass(frozen=True)
class CardSpec:
    """Bands of the dataset card's tables (edges, ascending; the last band is open-ended)."""

    altitude_bands_m: tuple[float, ...] = (0.0, 30.0, 60.0, 90.0, 120.0)
    pitch_bands_deg: tuple[float, ...] = (0.0, 30.0, 60.0, 80.0)

    def __post_init__(self) -> None:
        for name in ("altitude_bands_m", "pitch_bands_deg"):
            edges = getattr(self, name)
            if len(edges) < 2 or any(b <= a for a, b in itertools.pairwise(edges)):
                msg = f"{name} must be at least 2 strictly ascending edges, got {list(edges)}"
                raise ValueError(msg)


@dataclass(frozen=True)
class DatasetConfig:
    """A whole dataset config (``config/datasets/<name>.yaml``); see ``docs/datasets.md``."""

    name: str
    description: str = ""
    licence: str = "CC-BY-4.0"
    source: Literal["viewpoints", "flight"] = "viewpoints"
    world: str = "default"
    seed: int = 0
    #: Frames to generate; None: 100 sampled viewpoints, or every frame of a flight.
    frames: int | None = None
    splits: dict[str, SplitSpec] = field(default_factory=_default_splits)
    viewpoints: ViewpointSpec = field(default_factory=ViewpointSpec)
    camera: CameraSpec = field(default_factory=CameraSpec)
    flight: FlightSpec | None = None
    labels: LabelSpec = field(default_factory=LabelSpec)
    outputs: OutputSpec = field(default_factory=OutputSpec)
    card: CardSpec = field(default_factory=CardSpec)

    def __post_init__(self) -> None:
        if not _SLUG.match(self.name):
            msg = f"name {self.name!r} must be a slug (letters, digits, - and _)"
            raise ValueError(msg)
        if self.frames is not None and self.frames < 1:
            msg = f"frames must be >= 1, got {self.frames}"
            raise ValueError(msg)
        if not self.splits:
            msg = "splits must name at least one split"
            raise ValueError(msg)
        seen: dict[int, str] = {}
        for split, spec in self.splits.items():
            if not _SLUG.match(split):
                msg = f"splits: split name {split!r} must be a slug (letters, digits, - and _)"
                raise ValueError(msg)
            for seed in spec.world_seeds:
                if seed in seen:
                    msg = (
                        f"splits: world seed {seed} is in both {seen[seed]!r} and {split!r}; held-out splits "
                        "need different worlds"
                    )
                    raise ValueError(msg)
                seen[seed] = split
        if self.source == "flight" and self.flight is None:
            msg = "source: flight needs a 'flight' section (run: <run folder> or scenario: <scenario file>)"
            raise ValueError(msg)
        if self.source == "viewpoints" and self.flight is not None:
            msg = "a 'flight' section needs source: flight"
            raise ValueError(msg)
        if self.source == "viewpoints" and self.outputs.mot:
            msg = "outputs.mot needs sequences (source: flight); sampled viewpoints are independent frames"
            raise ValueError(msg)

    @property
    def frame_limit(self) -> int | None:
        """Frames to generate: ``frames``, else 100 sampled viewpoints, else (None) every frame of the flight."""
        if self.frames is not None:
            return self.frames
        return 100 if self.source == "viewpoints" else None

    @property
    def writes_mot(self) -> bool:
        return self.outputs.mot if self.outputs.mot is not None else self.source == "flight"

    def with_overrides(self, *, frames: int | None = None, seed: int | None = None) -> DatasetConfig:
        """The config with the command line's ``--frames`` and ``--seed`` applied."""
        out = self
        if frames is not None:
            if frames < 1:
                msg = f"--frames must be >= 1, got {frames}"
                raise DatasetConfigError(msg)
            out = replace(out, frames=frames)
        if seed is not None:
            out = replace(out, seed=seed)
        return out

    def to_mapping(self) -> dict[str, Any]:
        data: dict[str, Any] = to_mapping(self)
        return data


def dataset_config_from_mapping(data: Any, *, source: str, base_dir: Path | None = None) -> DatasetConfig:
    """Parse a mapping (e.g. a ``dataset.json``'s config) into a :class:`DatasetConfig`.

    ``base_dir`` resolves the relative paths of ``flight.run`` and ``flight.scenario`` and a ``world``
    given as a relative YAML path.

    Raises:
        DatasetConfigError: unknown key, wrong type or impossible value (the message names the key).
    """
    with config_errors_as(DatasetConfigError):
        cfg = from_mapping(DatasetConfig, data, source=source)
    if base_dir is not None:
        cfg = _resolve_paths(cfg, base_dir)
    return cfg


def load_dataset_config(path: Path) -> DatasetConfig:
    """Read and validate ``config/datasets/<name>.yaml``; relative paths are relative to the file.

    Raises:
        DatasetConfigError: missing file, bad YAML, unknown key, wrong type or impossible value,
            with the file and the key in the message.
    """
    with config_errors_as(DatasetConfigError):
        data = load_yaml_mapping(path)
    return dataset_config_from_mapping(data, source=str(path), base_dir=path.resolve().parent)


def _resolve_paths(cfg: DatasetConfig, base: Path) -> DatasetConfig:
    world = cfg.world
    if world.endswith((".yaml", ".yml")) and not Path(world).is_absolute() and (base / world).is_file():
        world = str((base / world).resolve())
    flight = cfg.flight
    if flight is not None:
        run = flight.run if flight.run is None or flight.run.is_absolute() else (base / flight.run)
        scen = flight.scenario if flight.scenario is None or flight.scenario.is_absolute() else (base / flight.scenario)
        flight = replace(flight, run=run, scenario=scen)
    return replace(cfg, world=world, flight=flight)
