"""Faults of the simulated cameras, injected in flight: off, stuck, garbage, intermittent (and ok, which clears).

MAVLink has no ``FAILURE_UNIT`` for a payload camera, so these are the range's own: a scenario scripts them
(``faults: [{unit: camera_nadir, type: stuck, ...}]``), the mission manager asks the bridge to apply them
(``/sim_bridge/set_camera_fault``) and the bridge passes every frame of a camera through this model.

What each type does to a camera's frames (one call of :meth:`CameraFaults.apply` per captured frame):

* ``ok``: frames go out as captured (clears any fault).
* ``off``: nothing goes out (the camera is dead).
* ``stuck``: the last frame delivered before the fault goes out again with every new capture (the caller
  stamps it with the new capture time); with no earlier frame, the first frame captured under the fault
  is the one that stays.
* ``garbage``: a frame of the right size and encoding goes out, its pixels seeded noise (the caller builds it
  with :func:`garbage_color` and :func:`garbage_depth` from :meth:`CameraFaults.rng`).
* ``intermittent``: each frame is lost with probability ``intermittent_drop_probability`` (default
  :data:`INTERMITTENT_DROP_PROBABILITY`), drawn from the camera's seeded generator, one draw per frame.

The model is generic over the frame record (the bridge's ``CameraOutput``; tests use plain arrays): it only
decides, remembers the last frame delivered and holds each camera's generator. Pure: randomness comes from the
generators passed in (one per camera, so one camera's draws never shift another's).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from typing import Generic, TypeVar

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.errors import CameraFaultError

__all__ = [
    "CAMERA_FAULT_TYPES",
    "INTERMITTENT_DROP_PROBABILITY",
    "CameraFaults",
    "CameraFaultsConfig",
    "Faulted",
    "Verdict",
    "garbage_color",
    "garbage_depth",
]

#: The fault types a camera takes (the scenario's ``type`` names, as MAVLink's FAILURE_TYPE names them).
CAMERA_FAULT_TYPES = ("ok", "off", "stuck", "garbage", "intermittent")
#: Chance that an ``intermittent`` camera loses a frame.
INTERMITTENT_DROP_PROBABILITY = 0.5

F = TypeVar("F")


@dataclass(frozen=True)
class CameraFaultsConfig:
    """``camera_faults`` in the bridge's configuration: the seed of the faults' generators and how often an
    intermittent camera loses a frame."""

    seed: int = 0
    intermittent_drop_probability: float = INTERMITTENT_DROP_PROBABILITY

    def __post_init__(self) -> None:
        p = self.intermittent_drop_probability
        if not 0.0 < p < 1.0:
            msg = f"intermittent_drop_probability must be in (0, 1) (0 never drops, 1 is off), got {p}"
            raise ValueError(msg)


class Verdict(Enum):
    """What became of one captured frame."""

    DELIVERED = "ok"
    OFF = "off"
    DROPPED = "dropped"
    STUCK = "stuck"
    GARBAGE = "garbage"


@dataclass(frozen=True)
class Faulted(Generic[F]):
    """One frame through the model.

    Attributes:
        verdict: what the fault did.
        frame: what the camera delivers: the frame itself (``DELIVERED``; ``GARBAGE``: the caller replaces its
            pixels), the frozen frame (``STUCK``), None (``OFF``, ``DROPPED``).
    """

    verdict: Verdict
    frame: F | None


class CameraFaults(Generic[F]):
    """The fault state of each camera.

    Args:
        rngs: one seeded generator per camera name (the cameras this model knows).
        intermittent_drop_probability: chance an ``intermittent`` camera loses a frame, in (0, 1).

    Raises:
        CameraFaultError: no camera, or a probability out of range.
    """

    def __init__(
        self,
        rngs: Mapping[str, np.random.Generator],
        *,
        intermittent_drop_probability: float = INTERMITTENT_DROP_PROBABILITY,
    ) -> None:
        if not rngs:
            msg = "camera faults need at least one camera"
            raise CameraFaultError(msg)
        if not 0.0 < intermittent_drop_probability < 1.0:
            msg = f"intermittent_drop_probability must be in (0, 1), got {intermittent_drop_probability}"
            raise CameraFaultError(msg)
        self._rngs = dict(rngs)
        self.drop_probability = float(intermittent_drop_probability)
        self._fault: dict[str, str] = dict.fromkeys(self._rngs, "ok")
        self._last: dict[str, F] = {}
        self._frozen: dict[str, F] = {}

    @property
    def cameras(self) -> tuple[str, ...]:
        return tuple(self._rngs)

    def fault(self, camera: str) -> str:
        """The camera's current fault type (``ok``: none).

        Raises:
            CameraFaultError: an unknown camera.
        """
        self._check_camera(camera)
        return self._fault[camera]

    def set(self, camera: str, failure_type: str) -> None:
        """Inject ``failure_type`` into ``camera`` (``ok`` clears it); it applies from the next frame on.

        Raises:
            CameraFaultError: an unknown camera or type (the message lists the known ones).
        """
        self._check_camera(camera)
        if failure_type not in CAMERA_FAULT_TYPES:
            msg = f"unknown camera fault type {failure_type!r}; known: {', '.join(CAMERA_FAULT_TYPES)}"
            raise CameraFaultError(msg)
        if failure_type != "stuck":
            self._frozen.pop(camera, None)
        elif self._fault[camera] != "stuck" and camera in self._last:
            self._frozen[camera] = self._last[camera]
        self._fault[camera] = failure_type

    def rng(self, camera: str) -> np.random.Generator:
        """The camera's generator (the intermittent drops and the garbage pixels both draw from it)."""
        self._check_camera(camera)
        return self._rngs[camera]

    def apply(self, camera: str, frame: F, *, complete: bool = True) -> Faulted[F]:
        """Pass one captured frame of ``camera`` through its fault.

        Args:
            camera: the camera's name.
            frame: the frame as captured.
            complete: whether the frame has its images (a frame with detections only is never the one a stuck
                camera keeps showing, and is not remembered as the last good one).

        Raises:
            CameraFaultError: an unknown camera.
        """
        kind = self.fault(camera)
        if kind == "off":
            return Faulted(Verdict.OFF, None)
        if kind == "intermittent" and float(self._rngs[camera].random()) < self.drop_probability:
            return Faulted(Verdict.DROPPED, None)
        if kind == "stuck":
            frozen = self._frozen.get(camera)
            if frozen is None:
                if not complete:
                    return Faulted(Verdict.STUCK, None)
                self._frozen[camera] = frozen = frame
            return Faulted(Verdict.STUCK, frozen)
        if kind == "garbage":
            return Faulted(Verdict.GARBAGE, frame)
        if complete:
            self._last[camera] = frame
        return Faulted(Verdict.DELIVERED, frame)

    def _check_camera(self, camera: str) -> None:
        if camera not in self._rngs:
            msg = f"unknown camera {camera!r}; this bridge runs {', '.join(sorted(self._rngs))}"
            raise CameraFaultError(msg)


def garbage_color(rng: np.random.Generator, height: int, width: int) -> npt.NDArray[np.uint8]:
    """A colour image of uniform noise, ``(height, width, 3)`` uint8 (rgb8)."""
    _check_size(height, width)
    return rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)


def garbage_depth(
    rng: np.random.Generator, height: int, width: int, near_m: float, far_m: float
) -> npt.NDArray[np.float32]:
    """A depth image of noise, ``(height, width)`` float32 metres, uniform in ``[near_m, far_m)``: finite values a
    consumer cannot tell from returns by their encoding."""
    _check_size(height, width)
    if not (np.isfinite(near_m) and np.isfinite(far_m) and 0.0 <= near_m < far_m):
        msg = f"garbage depth needs 0 <= near_m < far_m, finite; got {near_m}, {far_m}"
        raise CameraFaultError(msg)
    return rng.uniform(near_m, far_m, size=(height, width)).astype(np.float32)


def _check_size(height: int, width: int) -> None:
    if height < 1 or width < 1:
        msg = f"an image needs a positive size, got {height} x {width}"
        raise CameraFaultError(msg)
