"""What a camera's frames show a user, for the faults section: they stop, resume, freeze, turn to noise (pure).

The scorer watches the colour images of each camera a scenario scripts a fault for (``camera_<name>``); per
frame it keeps only the capture stamp, a digest of the pixels and how noisy they are (:func:`noise_level`).
:class:`CameraWatch` turns those into changes, the "what followed" of the faults:

* ``camera <name>: frames stopped``: no frame for ``stale_after_s`` of simulation time (stamped then), seen when
  the next frame comes (with ``camera <name>: frames resumed after a <gap> s gap``) or, for a camera still
  silent, by :meth:`CameraWatch.open_gaps` at the time of a summary. Gaps are judged on the camera's own
  stamps only: images reach the scorer later than the small messages, so another topic's time says nothing;
* ``camera <name>: image frozen (the same picture <n> frames in a row)`` and ``... image moving again``;
* ``camera <name>: image is noise (<level>)`` and ``... image is a picture again``.

:meth:`CameraWatch.window` counts the frames of a stretch of the run (a fault's window): how many, their rate,
how many distinct pictures, how many noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

__all__ = ["NOISE_LEVEL", "CameraFrameSample", "CameraWatch", "noise_level"]

#: :func:`noise_level` above which a frame is noise: uniform noise scores ~85, rendered scenes ~5-30.
NOISE_LEVEL = 60.0

#: Stamps this close are the same simulation instant: a frame's stamp goes through ROS time (integer
#: nanoseconds) and a fault's ``answered_s`` through float arithmetic, so the frame of the very state after which
#: a fault applies can read a hair later (6.7 against 6.699999999999999).
SAME_INSTANT_S = 1e-6


def noise_level(rgb: npt.NDArray[np.uint8]) -> float:
    """Mean absolute difference of horizontally neighbouring pixel values (0-255) over every 4th row: ~85 for
    uniform noise, tens at most for a picture of the world."""
    a = np.asarray(rgb)
    if a.ndim < 2 or a.shape[0] == 0 or a.shape[1] < 2:
        return math.nan
    rows = a[::4].astype(np.int16)
    return float(np.abs(np.diff(rows, axis=1)).mean())


@dataclass(frozen=True)
class CameraFrameSample:
    """One colour frame of a watched camera: stamp, a digest of its pixels, :func:`noise_level`."""

    t_s: float
    camera: str
    digest: int
    noise: float


@dataclass
class _Camera:
    times: list[float] = field(default_factory=list)
    digests: list[int] = field(default_factory=list)
    noise: list[float] = field(default_factory=list)
    frozen: bool = False
    noisy: bool = False
    repeats: int = 0


class CameraWatch:
    """Per camera: the changes its frames show (see module docstring).

    Args:
        stale_after_s: simulation seconds without a frame before the frames count as stopped.
        frozen_after: that many identical frames in a row are a frozen image.
        noise_above: :func:`noise_level` above which a frame is noise.
    """

    def __init__(self, *, stale_after_s: float = 1.0, frozen_after: int = 3, noise_above: float = NOISE_LEVEL) -> None:
        if not stale_after_s > 0.0 or frozen_after < 2:
            msg = f"stale_after_s must be > 0 and frozen_after >= 2, got {stale_after_s}, {frozen_after}"
            raise ValueError(msg)
        self.stale_after_s = stale_after_s
        self.frozen_after = frozen_after
        self.noise_above = noise_above
        self._cams: dict[str, _Camera] = {}

    @property
    def cameras(self) -> tuple[str, ...]:
        return tuple(self._cams)

    def add(self, frame: CameraFrameSample) -> list[tuple[float, str]]:
        """One frame (in time order; an older one is ignored) -> the changes it shows."""
        cam = self._cams.setdefault(frame.camera, _Camera())
        if cam.times and frame.t_s < cam.times[-1]:
            return []
        out: list[tuple[float, str]] = []
        name, t = frame.camera, frame.t_s
        if cam.times and t - cam.times[-1] >= self.stale_after_s:
            out.append((cam.times[-1] + self.stale_after_s, f"camera {name}: frames stopped"))
            out.append((t, f"camera {name}: frames resumed after a {t - cam.times[-1]:.1f} s gap"))
        cam.repeats = cam.repeats + 1 if cam.digests and cam.digests[-1] == frame.digest else 1
        if not cam.frozen and cam.repeats >= self.frozen_after:
            cam.frozen = True
            out.append((t, f"camera {name}: image frozen (the same picture {cam.repeats} frames in a row)"))
        elif cam.frozen and cam.repeats == 1:
            cam.frozen = False
            out.append((t, f"camera {name}: image moving again"))
        noisy = math.isfinite(frame.noise) and frame.noise > self.noise_above
        if noisy != cam.noisy:
            cam.noisy = noisy
            what = f"image is noise ({frame.noise:.0f})" if noisy else "image is a picture again"
            out.append((t, f"camera {name}: {what}"))
        cam.times.append(t)
        cam.digests.append(frame.digest)
        cam.noise.append(frame.noise)
        return out

    def open_gaps(self, t_s: float) -> list[tuple[float, str]]:
        """The cameras silent for ``stale_after_s`` or more at ``t_s`` (their frames stopped and have not come
        back yet); changes nothing."""
        return [
            (cam.times[-1] + self.stale_after_s, f"camera {name}: frames stopped")
            for name, cam in self._cams.items()
            if cam.times and t_s - cam.times[-1] >= self.stale_after_s
        ]

    def window(self, camera: str, start_s: float, end_s: float) -> dict[str, float | int | str]:
        """The frames of ``camera`` captured in ``(start_s, end_s)``: ``frames``, ``rate_hz``, ``rate_before_hz``
        (over the same length of time before, at most 10 s), ``distinct_images``, ``noise_frames``.

        A frame stamped within :data:`SAME_INSTANT_S` of ``start_s`` is of that instant, so before the window
        (a fault applies after the state it was taken at)."""
        cam = self._cams.get(camera, _Camera())
        t = np.asarray(cam.times, dtype=np.float64)
        inside = (t > start_s + SAME_INSTANT_S) & (t < end_s)
        span = max(end_s - start_s, 0.0)
        before_span = min(span, 10.0) if span > 0 else 10.0
        before = (t > start_s - before_span) & (t <= start_s + SAME_INSTANT_S)
        digests = {d for d, k in zip(cam.digests, inside, strict=True) if k}
        noise = np.asarray(cam.noise, dtype=np.float64)[inside] if cam.noise else np.zeros(0)
        return {
            "camera": camera,
            "frames": int(inside.sum()),
            "rate_hz": float(inside.sum() / span) if span > 0 else math.nan,
            "rate_before_hz": float(before.sum() / before_span),
            "distinct_images": len(digests),
            "noise_frames": int((noise > self.noise_above).sum()),
        }
