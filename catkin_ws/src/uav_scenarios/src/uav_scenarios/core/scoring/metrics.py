"""Pure metric functions: coverage, voxel-set accuracy, flight statistics, detection matching.

Everything is vectorised numpy on already-read data; no clocks, no I/O.
Positions are metres in ``map`` (ENU); times are simulation seconds.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from uav_common.voxel_keys import VoxelKeyError, key_columns, keys_from_points, pack_keys, sorted_unique
from uav_scenarios.core.scoring.types import BatterySample, Detection, GridSnapshot
from uav_scenarios.errors import ScoringError

__all__ = [
    "AltitudeStats",
    "BatteryUse",
    "PoseError",
    "VoxelAccuracy",
    "altitude_stats",
    "band_label",
    "band_of",
    "battery_use",
    "bbox_iou",
    "coverage_efficiency",
    "downsample_grid",
    "mapped_area_m2",
    "match_detections",
    "path_length_m",
    "pose_error",
    "view_angle_deg",
    "voxel_accuracy",
    "voxel_keys",
    "voxel_keys_from_indices",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def voxel_keys_from_indices(ijk: npt.ArrayLike) -> IntArray:
    """Integer voxel indices ``(N, 3)`` -> unique sorted int64 keys ``(M,)`` (:mod:`uav_common.voxel_keys`).

    Raises:
        ScoringError: wrong shape, or an index out of the ±2^20 range.
    """
    try:
        # the map server's export is already sorted and unique: sorted_unique does not sort it again
        return sorted_unique(pack_keys(ijk))
    except VoxelKeyError as err:
        raise ScoringError(str(err)) from err


def voxel_keys(points_m: npt.ArrayLike, resolution_m: float) -> IntArray:
    """Points ``(N, 3)`` metres -> unique int64 keys of the voxels containing them.

    Voxel ``i`` covers ``[i*res, (i+1)*res)`` on each axis, as OctoMap and OpenVDB
    index space, so keys from the map server and from the world's ground truth align.
    Non-finite points are dropped.

    Raises:
        ScoringError: a resolution that is not positive, or a point beyond the keys' range.
    """
    try:
        return keys_from_points(points_m, resolution_m)
    except VoxelKeyError as err:
        raise ScoringError(str(err)) from err


@dataclass(frozen=True)
class VoxelAccuracy:
    """Occupied voxel set E of the map against ground-truth surface voxels G."""

    iou: float
    precision: float
    recall: float
    #: Recall against the G voxels in columns the map has any voxel in (what could be seen).
    recall_observed: float
    n_map: int
    n_truth: int
    n_common: int
    #: IoU against the G voxels in columns the map has any voxel in.
    iou_observed: float = math.nan


def voxel_accuracy(map_keys: IntArray, truth_keys: IntArray, truth_columns: IntArray | None = None) -> VoxelAccuracy:
    """IoU ``|E∩G|/|E∪G|``, precision ``|E∩G|/|E|``, recall ``|E∩G|/|G|`` (NaN when undefined).

    Both sets are compared by binary search in the sorted truth (``O(|E| log |G|)``), so a map
    of a few 100 k voxels against a world of millions takes milliseconds. Keys sort by
    column (x, y) first, so the truth voxels of the map's columns are contiguous runs.
    ``truth_columns``: ``key_columns`` of the sorted, unique truth keys if already known
    (:attr:`SceneTruth.surface_columns`; the truth does not change during a run).
    """
    e = sorted_unique(map_keys)
    g = sorted_unique(truth_keys)
    if g.size:
        pos = np.minimum(np.searchsorted(g, e), g.size - 1)
        common = int(np.count_nonzero(g[pos] == e)) if e.size else 0
    else:
        common = 0
    union = e.size + g.size - common
    seen = 0
    if e.size and g.size:
        c = key_columns(e)  # sorted, since e is
        cols = c[np.concatenate(([True], c[1:] != c[:-1]))]
        g_cols = key_columns(g) if truth_columns is None else truth_columns  # sorted, since g is
        seen = int(np.sum(np.searchsorted(g_cols, cols, side="right") - np.searchsorted(g_cols, cols, side="left")))
    union_seen = e.size + seen - common
    return VoxelAccuracy(
        iou=common / union if union else math.nan,
        precision=common / e.size if e.size else math.nan,
        recall=common / g.size if g.size else math.nan,
        recall_observed=common / seen if seen else math.nan,
        n_map=int(e.size),
        n_truth=int(g.size),
        n_common=common,
        iou_observed=common / union_seen if union_seen else math.nan,
    )


@dataclass(frozen=True)
class Coverage:
    swath_m: float
    speed_mps: float
    limit_m2_per_s: float
    efficiency: float


def coverage_efficiency(
    mapped_m2: float, airborne_s: float, *, swath_m: float, along_m: float, speed_mps: float
) -> Coverage:
    """Coverage rate against the physical limit of a nadir camera sweeping the ground.

    The limit is ``swath width x cruise speed`` (m²/s). What the camera sees without moving
    (one footprint, ``swath_m x along_m``) is not coverage *rate*, so it is taken out:
    ``efficiency = max(0, mapped - footprint) / airborne_s / limit``; a straight pass at
    the cruise speed scores about 1, overlapping tracks, turns and hovering less.
    NaN when a term is unknown.
    """
    limit = swath_m * speed_mps
    if not (math.isfinite(limit) and limit > 0 and airborne_s > 0):
        return Coverage(swath_m, speed_mps, limit if math.isfinite(limit) else math.nan, math.nan)
    swept = max(0.0, mapped_m2 - swath_m * along_m)
    return Coverage(swath_m, speed_mps, limit, swept / airborne_s / limit)


def mapped_area_m2(layers: GridSnapshot, bounds_m: tuple[float, float, float, float]) -> float:
    """Area of observed cells (layer ``observed`` > 0.5) whose centres lie within the scene bounds."""
    observed = layers.layers.get("observed")
    if observed is None or observed.size == 0:
        return 0.0
    xs, ys = layers.cell_centers_m()
    x0, y0, x1, y1 = bounds_m
    in_x = (xs >= x0) & (xs < x1)
    in_y = (ys >= y0) & (ys < y1)
    mask = (observed > 0.5) & in_y[:, None] & in_x[None, :]
    return float(np.count_nonzero(mask)) * layers.resolution_m**2


def mean_cell_age_s(layers: GridSnapshot, now_s: float) -> float:
    """Mean of ``now - last_seen`` over observed cells; NaN with no observed cell."""
    last = layers.layers.get("last_seen_s")
    if last is None:
        return math.nan
    seen = np.isfinite(last)
    observed = layers.layers.get("observed")
    if observed is not None:
        seen &= observed > 0.5
    if not seen.any():
        return math.nan
    return float(np.mean(np.maximum(0.0, now_s - last[seen])))


def path_length_m(times_s: npt.ArrayLike, positions_m: npt.ArrayLike) -> float:
    """3D length of a sampled path ``(N, 3)``; samples must be time-ordered.

    Raises:
        ScoringError: times go backwards or shapes disagree.
    """
    t = np.asarray(times_s, dtype=np.float64)
    p = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
    if t.shape[0] != p.shape[0]:
        msg = f"{t.shape[0]} times but {p.shape[0]} positions"
        raise ScoringError(msg)
    if t.size < 2:
        return 0.0
    if np.any(np.diff(t) < 0):
        msg = "pose samples go back in time; pass them in time order"
        raise ScoringError(msg)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


@dataclass(frozen=True)
class PoseError:
    """An estimated trajectory against the true one (see :func:`pose_error`); NaN without samples."""

    samples: int
    position_mean_m: float
    position_rms_m: float
    position_p95_m: float
    position_max_m: float
    horizontal_rms_m: float
    vertical_rms_m: float
    #: Mean of the signed errors (estimate - truth), ENU: a bias shows here.
    bias_enu_m: tuple[float, float, float]
    yaw_mean_abs_deg: float
    yaw_rms_deg: float
    yaw_p95_deg: float
    yaw_max_deg: float

    def as_dict(self) -> dict[str, object]:
        return {
            "samples": self.samples,
            "position_mean_m": self.position_mean_m,
            "position_rms_m": self.position_rms_m,
            "position_p95_m": self.position_p95_m,
            "position_max_m": self.position_max_m,
            "horizontal_rms_m": self.horizontal_rms_m,
            "vertical_rms_m": self.vertical_rms_m,
            "bias_enu_m": list(self.bias_enu_m),
            "yaw_mean_abs_deg": self.yaw_mean_abs_deg,
            "yaw_rms_deg": self.yaw_rms_deg,
            "yaw_p95_deg": self.yaw_p95_deg,
            "yaw_max_deg": self.yaw_max_deg,
        }


def pose_error(
    truth_t_s: npt.ArrayLike,
    truth_xyz_m: npt.ArrayLike,
    truth_yaw_rad: npt.ArrayLike,
    *,
    est_t_s: npt.ArrayLike,
    est_xyz_m: npt.ArrayLike,
    est_yaw_rad: npt.ArrayLike,
    max_gap_s: float = 0.2,
) -> PoseError:
    """Error of an estimated trajectory against the true one, at the estimate's own stamps.

    The truth is interpolated linearly (yaw unwrapped) at each estimate stamp; an estimate is scored only
    where two truth samples at most ``max_gap_s`` apart bracket its stamp (the truth comes at 50 Hz). So a
    stamp that is off (a bad clock mapping) shows as an error, as it would in the map.
    """
    tt = np.asarray(truth_t_s, dtype=np.float64).reshape(-1)
    tp = np.asarray(truth_xyz_m, dtype=np.float64).reshape(-1, 3)
    ty = np.unwrap(np.asarray(truth_yaw_rad, dtype=np.float64).reshape(-1)) if tt.size else np.zeros(0)
    et = np.asarray(est_t_s, dtype=np.float64).reshape(-1)
    ep = np.asarray(est_xyz_m, dtype=np.float64).reshape(-1, 3)
    ey = np.asarray(est_yaw_rad, dtype=np.float64).reshape(-1)
    nan = math.nan
    empty = PoseError(0, nan, nan, nan, nan, nan, nan, (nan, nan, nan), nan, nan, nan, nan)
    if tt.size < 2 or et.size == 0:
        return empty
    order = np.argsort(tt, kind="stable")
    tt, tp, ty = tt[order], tp[order], ty[order]
    k = np.searchsorted(tt, et, side="right")
    ok = (k > 0) & (k < tt.size)
    k = np.clip(k, 1, tt.size - 1)
    t0, t1 = tt[k - 1], tt[k]
    ok &= (t1 - t0 <= max_gap_s) & (t1 > t0)
    if not ok.any():
        return empty
    k, t0, t1, et, ep, ey = k[ok], t0[ok], t1[ok], et[ok], ep[ok], ey[ok]
    w = ((et - t0) / (t1 - t0))[:, None]
    truth_p = tp[k - 1] * (1.0 - w) + tp[k] * w
    truth_y = ty[k - 1] * (1.0 - w[:, 0]) + ty[k] * w[:, 0]
    d = ep - truth_p
    dist = np.linalg.norm(d, axis=1)
    yaw = np.degrees(np.abs((ey - truth_y + math.pi) % (2.0 * math.pi) - math.pi))
    return PoseError(
        samples=int(dist.size),
        position_mean_m=float(dist.mean()),
        position_rms_m=float(np.sqrt(np.mean(dist**2))),
        position_p95_m=float(np.percentile(dist, 95)),
        position_max_m=float(dist.max()),
        horizontal_rms_m=float(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2))),
        vertical_rms_m=float(np.sqrt(np.mean(d[:, 2] ** 2))),
        bias_enu_m=(float(d[:, 0].mean()), float(d[:, 1].mean()), float(d[:, 2].mean())),
        yaw_mean_abs_deg=float(yaw.mean()),
        yaw_rms_deg=float(np.sqrt(np.mean(yaw**2))),
        yaw_p95_deg=float(np.percentile(yaw, 95)),
        yaw_max_deg=float(yaw.max()),
    )


@dataclass(frozen=True)
class AltitudeStats:
    min_m: float
    mean_m: float
    #: Time spent below the floor after first climbing above it (takeoff excluded).
    time_below_floor_s: float
    airborne_s: float


def altitude_stats(times_s: npt.ArrayLike, agl_m: npt.ArrayLike, floor_m: float) -> AltitudeStats:
    """Statistics of altitude above ground from the first sample at or above ``floor_m`` on.

    The mean is time-weighted (each sample holds until the next). Before the vehicle
    first reaches the floor (takeoff) nothing counts; with no such sample every field
    is NaN except the times, which are 0.
    """
    t = np.asarray(times_s, dtype=np.float64)
    h = np.asarray(agl_m, dtype=np.float64)
    valid = np.isfinite(h)
    t, h = t[valid], h[valid]
    above = np.flatnonzero(h >= floor_m)
    if above.size == 0:
        return AltitudeStats(math.nan, math.nan, 0.0, 0.0)
    t, h = t[above[0] :], h[above[0] :]
    if t.size == 1:
        return AltitudeStats(float(h[0]), float(h[0]), 0.0, 0.0)
    dt = np.diff(t)
    weights = np.append(dt, 0.0)
    span = float(t[-1] - t[0])
    mean = float(np.sum(h * weights) / span) if span > 0 else float(h.mean())
    below = float(np.sum(dt[h[:-1] < floor_m]))
    return AltitudeStats(float(h.min()), mean, below, span)


@dataclass(frozen=True)
class BatteryUse:
    used_mah: float
    used_pct: float
    start_pct: float
    end_pct: float
    min_voltage_v: float


def battery_use(samples: Sequence[BatterySample]) -> BatteryUse:
    """Charge used between the first and last sample.

    mAh comes from the autopilot's consumed counter when it reports one, otherwise
    from integrating the current (trapezoid). NaN when neither is known.
    """
    if not samples:
        return BatteryUse(math.nan, math.nan, math.nan, math.nan, math.nan)
    first, last = samples[0], samples[-1]
    if math.isfinite(first.consumed_mah) and math.isfinite(last.consumed_mah):
        used_mah = last.consumed_mah - first.consumed_mah
    else:
        t = np.array([s.t_s for s in samples])
        i = np.array([s.current_a for s in samples])
        ok = np.isfinite(i)
        used_mah = float(np.trapz(i[ok], t[ok]) / 3.6) if ok.sum() >= 2 else math.nan
    volts = [s.voltage_v for s in samples if math.isfinite(s.voltage_v)]
    return BatteryUse(
        used_mah=used_mah,
        used_pct=first.remaining_pct - last.remaining_pct,
        start_pct=first.remaining_pct,
        end_pct=last.remaining_pct,
        min_voltage_v=min(volts) if volts else math.nan,
    )


def bbox_iou(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """IoU of two inclusive pixel boxes ``(x_min, y_min, x_max, y_max)``."""
    ix = min(a[2], b[2]) - max(a[0], b[0]) + 1
    iy = min(a[3], b[3]) - max(a[1], b[1]) + 1
    if ix <= 0 or iy <= 0:
        return 0.0
    inter = ix * iy
    area_a = (a[2] - a[0] + 1) * (a[3] - a[1] + 1)
    area_b = (b[2] - b[0] + 1) * (b[3] - b[1] + 1)
    return inter / float(area_a + area_b - inter)


def match_detections(
    truth: Sequence[Detection], hypotheses: Sequence[Detection], *, min_iou: float = 0.5
) -> tuple[list[tuple[int, int]], list[int], list[int]]:
    """Optimal one-to-one matching of boxes of the same class by IoU (Hungarian).

    Returns:
        ``(matches, unmatched_truth, unmatched_hypotheses)``: index pairs ``(i_truth,
        i_hyp)`` with IoU >= ``min_iou``, and the leftover indices of each side (the
        false negatives and false positives).
    """
    if not truth or not hypotheses:
        return [], list(range(len(truth))), list(range(len(hypotheses)))
    iou = np.zeros((len(truth), len(hypotheses)))
    for i, t in enumerate(truth):
        for j, h in enumerate(hypotheses):
            if t.class_name == h.class_name:
                iou[i, j] = bbox_iou(t.bbox_px, h.bbox_px)
    rows, cols = linear_sum_assignment(-iou)
    matches = [(int(r), int(c)) for r, c in zip(rows, cols, strict=True) if iou[r, c] >= min_iou]
    matched_t = {m[0] for m in matches}
    matched_h = {m[1] for m in matches}
    return (
        matches,
        [i for i in range(len(truth)) if i not in matched_t],
        [j for j in range(len(hypotheses)) if j not in matched_h],
    )


def view_angle_deg(camera_m: tuple[float, float, float], target_m: tuple[float, float, float]) -> float:
    """Off-nadir angle of the line of sight: 0° looking straight down, 90° at the horizon."""
    dx = target_m[0] - camera_m[0]
    dy = target_m[1] - camera_m[1]
    dz = camera_m[2] - target_m[2]
    if not all(math.isfinite(v) for v in (dx, dy, dz)):
        return math.nan
    return math.degrees(math.atan2(math.hypot(dx, dy), dz))


def band_of(value: float, edges: Sequence[float]) -> int:
    """Index of the band ``[edges[k], edges[k+1])`` holding ``value``; -1 if outside or NaN.

    The last band is closed on the right.
    """
    if not math.isfinite(value) or value < edges[0] or value > edges[-1]:
        return -1
    k = int(np.searchsorted(np.asarray(edges), value, side="right")) - 1
    return min(k, len(edges) - 2)


#: A last band edge at or above this stands for "no upper limit" in labels (``">=32 px"``, not ``"32-10000 px"``).
OPEN_EDGE = 1000.0


def band_label(k: int, edges: Sequence[float], unit: str = "") -> str:
    """Human label of band ``k``, e.g. ``"20-40 m"``, or ``">=100 m"`` for an open last band; ``"unknown"`` for -1."""
    if k < 0:
        return "unknown"
    suffix = " " + unit if unit else ""
    if k == len(edges) - 2 and edges[k + 1] >= OPEN_EDGE:
        return f">={edges[k]:g}{suffix}"
    return f"{edges[k]:g}-{edges[k + 1]:g}{suffix}"


#: Layers reduced by their maximum when a snapshot is downsampled (heights, times, masks); others by their mean.
_MAX_LAYERS = ("elevation_m", "last_seen_s", "observed")


def downsample_grid(grid: GridSnapshot, max_cells: int) -> GridSnapshot:
    """The grid reduced by an integer factor so that no side exceeds ``max_cells`` (NaN-aware).

    Blocks of ``k x k`` cells become one: elevation, last-seen time and the observed mask
    take the block maximum (the highest surface, the freshest view, seen at all), other
    layers the block mean. Blocks with no finite value stay NaN.
    """
    rows, cols = grid.shape
    k = max(1, math.ceil(max(rows, cols) / max_cells))
    if k == 1:
        return grid
    out_rows, out_cols = math.ceil(rows / k), math.ceil(cols / k)
    layers: dict[str, FloatArray] = {}
    for name, arr in grid.layers.items():
        pad = np.full((out_rows * k, out_cols * k), np.nan)
        pad[:rows, :cols] = arr
        blocks = pad.reshape(out_rows, k, out_cols, k).transpose(0, 2, 1, 3).reshape(out_rows, out_cols, k * k)
        finite = np.isfinite(blocks)
        any_finite = finite.any(axis=2)
        if name in _MAX_LAYERS:
            reduced = np.where(finite, blocks, -np.inf).max(axis=2)
        else:
            total = np.where(finite, blocks, 0.0).sum(axis=2)
            reduced = total / np.maximum(finite.sum(axis=2), 1)
        layers[name] = np.where(any_finite, reduced, np.nan)
    return GridSnapshot(grid.t_s, grid.resolution_m * k, grid.origin_x_m, grid.origin_y_m, layers)
