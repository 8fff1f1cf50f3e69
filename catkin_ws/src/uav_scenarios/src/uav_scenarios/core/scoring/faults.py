"""Scripted faults and what followed them; setpoint tracking error (pure).

A fault's "what followed" is every change the run's own topics show between the fault and the next fault
(or the end of the run): the autopilot's mode, the controller's state and its ``last_event``, the pose
estimate's state, and the frames of the cameras with scripted faults (:mod:`uav_scenarios.core.scoring.cameras`:
stopped, resumed, frozen, noise); a camera fault also counts its camera's frames over its window. The tracking
error is the distance between the vehicle (ground truth) and the path the autonomy commanded (``/autonomy/path``,
a polyline in map ENU), while the controller follows it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from uav_scenarios.core.faults import camera_name
from uav_scenarios.core.scoring.cameras import CameraWatch
from uav_scenarios.core.scoring.types import FaultSample

__all__ = ["distance_to_polyline_m", "fault_summary", "target_tracking_stats", "tracking_stats"]

FloatArray = npt.NDArray[np.float64]


def fault_summary(
    faults: Sequence[FaultSample],
    changes: Sequence[tuple[float, str]],
    *,
    start_s: float,
    end_s: float,
    cameras: CameraWatch | None = None,
) -> list[dict[str, Any]]:
    """Each fault with what followed it.

    Args:
        faults: the faults sent, in any order.
        changes: ``(t_s, what)`` of every mode/state/event change of the run.
        start_s: the run's start (``run_t_s`` = ``t_s - start_s``).
        end_s: the run's end (the last fault's window ends there).
        cameras: the watched cameras' frames: a camera fault gets ``camera``, :meth:`CameraWatch.window` of its
            camera from the time the bridge applied it (``answered_s``; else when it was sent) to the next fault,
            if any frame of that camera was seen at all.

    Returns:
        One entry per fault, in time order: ``t_s``, ``run_t_s``, ``at_s`` (when it was due), unit, type,
        instance, ``clear``, the autopilot's ``result`` and ``detail``, ``answered_s``, and ``followed``: the
        changes in ``[t_s, next fault's t_s)`` as ``{t_s, after_s, what}``.
    """
    ordered = sorted(faults, key=lambda f: (f.t_s, f.index))
    out = []
    for i, f in enumerate(ordered):
        until = ordered[i + 1].t_s if i + 1 < len(ordered) else max(end_s, f.t_s)
        last = i + 1 == len(ordered)
        followed = [
            {"t_s": t, "after_s": t - f.t_s, "what": what}
            for t, what in sorted(changes, key=lambda c: c[0])
            if f.t_s <= t and (t < until or (last and t <= until))
        ]
        entry: dict[str, Any] = {}
        cam = camera_name(f.unit)
        if cam and cameras is not None and cam in cameras.cameras:  # (a replay without its images: no counts)
            applied = f.answered_s if math.isfinite(f.answered_s) and f.answered_s >= f.t_s else f.t_s
            entry["camera"] = cameras.window(cam, applied, until)
        out.append(
            {
                "t_s": f.t_s,
                "run_t_s": f.t_s - start_s if math.isfinite(start_s) else math.nan,
                "at_s": f.at_s,
                "index": f.index,
                "unit": f.unit,
                "type": f.failure_type,
                "instance": f.instance,
                "clear": f.clear,
                "result": f.result,
                "detail": f.detail,
                "answered_s": f.answered_s,
                "followed": followed,
                **entry,
            }
        )
    return out


def distance_to_polyline_m(point_m: npt.ArrayLike, path_m: npt.ArrayLike) -> float:
    """Shortest 3D distance from a point to a polyline ``(N, 3)`` (one point: the distance to it)."""
    p = np.asarray(point_m, dtype=np.float64).reshape(3)
    path = np.asarray(path_m, dtype=np.float64).reshape(-1, 3)
    if path.shape[0] == 0:
        return math.nan
    if path.shape[0] == 1:
        return float(np.linalg.norm(p - path[0]))
    a, b = path[:-1], path[1:]
    ab = b - a
    len2 = np.einsum("ij,ij->i", ab, ab)
    t = np.where(len2 > 0, np.einsum("ij,ij->i", p - a, ab) / np.where(len2 > 0, len2, 1.0), 0.0)
    closest = a + np.clip(t, 0.0, 1.0)[:, None] * ab
    return float(np.min(np.linalg.norm(closest - p, axis=1)))


def tracking_stats(errors_m: Sequence[float]) -> dict[str, float]:
    """``samples``, ``rms_m``, ``p95_m``, ``max_m`` of tracking errors (NaN without samples)."""
    e = np.asarray([v for v in errors_m if math.isfinite(v)], dtype=np.float64)
    if e.size == 0:
        return {"samples": 0, "rms_m": math.nan, "p95_m": math.nan, "max_m": math.nan}
    return {
        "samples": int(e.size),
        "rms_m": float(np.sqrt(np.mean(e**2))),
        "p95_m": float(np.percentile(e, 95)),
        "max_m": float(e.max()),
    }


def target_tracking_stats(errors_m: Sequence[tuple[float, float]]) -> dict[str, float]:
    """:func:`tracking_stats` of ``(error_3d_m, horizontal_error_m)`` pairs, plus ``horizontal_rms_m`` and
    ``horizontal_max_m`` (the part wind pushes)."""
    out = tracking_stats([e for e, _ in errors_m])
    h = np.asarray([v for _, v in errors_m if math.isfinite(v)], dtype=np.float64)
    out["horizontal_rms_m"] = float(np.sqrt(np.mean(h**2))) if h.size else math.nan
    out["horizontal_max_m"] = float(h.max()) if h.size else math.nan
    return out
