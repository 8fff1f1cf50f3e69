"""The detector contract's class ids: ``config/detection_classes.yaml`` as a frozen class map.

A detector publishes ``vision_msgs/Detection2DArray``; each hypothesis carries a numeric class id
(``ObjectHypothesisWithPose.id``). This map says which id is which class of the range, so the
ground truth, the stand-in detectors, a learned detector and any existing ROS detector agree.

The ids this range publishes are the COCO-80 indices as YOLO-family models number them (person 0,
car 2), so a COCO-trained ROS detector plugs in unchanged; ``accept_ids`` lists the other ids read
as the same class (COCO motorcycle 3, bus 5, truck 7 are vehicles). Any other id is not a class of
the range: consumers count such hypotheses (``unknown_class``) and drop them.

Pure: the file is read once by :func:`load_detection_classes` (strict, errors name the file and key).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

from uav_common.config import load_config

__all__ = ["DetectionClass", "DetectionClasses", "load_detection_classes"]


@dataclass(frozen=True)
class DetectionClass:
    """One class of the range."""

    #: The id this range's detectors publish for the class.
    id: int
    #: Further ids read as this class (other detectors' numbering); ``id`` is always accepted.
    accept_ids: tuple[int, ...] = ()
    #: Half the object's typical ground footprint along the line of sight (geolocation places the
    #: box's ground-contact point, the near edge of the footprint, this far beyond it).
    footprint_radius_m: float = 0.0

    def __post_init__(self) -> None:
        if self.id < 0:
            msg = f"id must be >= 0, got {self.id}"
            raise ValueError(msg)
        if any(i < 0 for i in self.accept_ids):
            msg = f"accept_ids must be >= 0, got {list(self.accept_ids)}"
            raise ValueError(msg)
        if not (math.isfinite(self.footprint_radius_m) and self.footprint_radius_m >= 0):
            msg = f"footprint_radius_m must be finite and >= 0, got {self.footprint_radius_m}"
            raise ValueError(msg)


def _default_classes() -> dict[str, DetectionClass]:
    return {
        "person": DetectionClass(0, (0,), 0.2),
        "vehicle": DetectionClass(2, (2, 3, 5, 7), 1.5),
    }


@dataclass(frozen=True)
class DetectionClasses:
    """Class name -> :class:`DetectionClass`; the ids of different classes never overlap."""

    classes: dict[str, DetectionClass] = field(default_factory=_default_classes)

    def __post_init__(self) -> None:
        if not self.classes:
            msg = "classes must name at least one class"
            raise ValueError(msg)
        owner: dict[int, str] = {}
        for name, cls in self.classes.items():
            if not name or not name.replace("_", "").isalnum():
                msg = f"class name {name!r} must be a non-empty word (letters, digits, _)"
                raise ValueError(msg)
            for i in (cls.id, *cls.accept_ids):
                if owner.get(i, name) != name:
                    msg = f"id {i} is claimed by both {owner[i]!r} and {name!r}"
                    raise ValueError(msg)
                owner[i] = name

    @cached_property
    def _by_id(self) -> dict[int, str]:
        return {i: name for name, cls in self.classes.items() for i in (cls.id, *cls.accept_ids)}

    def name_of(self, class_id: int) -> str | None:
        """The class a hypothesis id stands for, ``None`` if the range has no such class."""
        return self._by_id.get(int(class_id))

    def id_of(self, name: str) -> int:
        """The id this range publishes for ``name``.

        Raises:
            KeyError: no such class (the message lists the known ones).
        """
        cls = self.classes.get(name)
        if cls is None:
            msg = f"no detection class {name!r}; known: {', '.join(sorted(self.classes))}"
            raise KeyError(msg)
        return cls.id

    def footprint_radius_m(self, name: str) -> float:
        cls = self.classes.get(name)
        return cls.footprint_radius_m if cls is not None else 0.0

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(sorted(self.classes, key=lambda n: self.classes[n].id))


def load_detection_classes(path: Path) -> DetectionClasses:
    """Read a class map file (``config/detection_classes.yaml``).

    Raises:
        ConfigError: missing file, bad YAML, unknown key, negative or shared id (the message names
            the file and key).
    """
    return load_config(DetectionClasses, path)
