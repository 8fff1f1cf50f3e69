"""The run report's figures (matplotlib, Agg backend, PNG files).

Each function draws one figure from a :class:`RunData` into a PNG and returns
its path, or ``None`` when the run has no data for it (the HTML then says so).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib as mpl

mpl.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import MaxNLocator

from uav_scenarios.core.scoring.types import GridSnapshot
from uav_scenarios.report.data import CameraImage, RunData

__all__ = [
    "FIGURES",
    "battery_altitude_figure",
    "camera_figure",
    "detection_figure",
    "gallery_figure",
    "map_snapshots_figure",
    "pr_curves_figure",
    "snapshot_columns",
    "topdown_figure",
    "voxel_figure",
]

_DPI = 100
_STATE_COLORS = {
    "IDLE": "#bbbbbb",
    "TAKEOFF": "#8fbfe0",
    "AUTONOMOUS": "#9fd49f",
    "SCRIPTED": "#c7b3e5",
    "MANUAL": "#f2c48d",
    "HOLD": "#f29d9d",
    "RTL": "#e6d37a",
    "LAND": "#a0a0a0",
}


def _save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=_DPI, bbox_inches="tight")
    plt.close(fig)
    return path


def _extent(g: GridSnapshot) -> tuple[float, float, float, float]:
    rows, cols = g.shape
    return (g.origin_x_m, g.origin_x_m + cols * g.resolution_m, g.origin_y_m, g.origin_y_m + rows * g.resolution_m)


def _instance_colors(ids: npt.NDArray[Any]) -> npt.NDArray[np.uint8]:
    """A stable pseudo-random colour per instance id; id 0 (sky) is black."""
    ids64 = ids.astype(np.uint64)
    h = (ids64 * np.uint64(2654435761)) & np.uint64(0xFFFFFF)
    rgb = np.stack([(h >> np.uint64(s)) & np.uint64(0xFF) for s in (16, 8, 0)], axis=-1).astype(np.uint8)
    rgb[ids == 0] = 0
    return np.asarray(rgb, dtype=np.uint8)


def camera_figure(run: RunData, path: Path) -> Path | None:
    """Color, depth and segmentation of each camera at the latest snapshot time."""
    if not run.images:
        return None
    latest: dict[tuple[str, str], CameraImage] = {}
    for img in run.images:
        latest[(img.camera, img.kind)] = img
    cameras = sorted({c for c, _ in latest})
    kinds = ("color", "depth", "instance")
    fig, axes = plt.subplots(len(cameras), 3, figsize=(12, 3.2 * len(cameras)), squeeze=False, layout="constrained")
    for r, cam in enumerate(cameras):
        for c, kind in enumerate(kinds):
            ax = axes[r][c]
            ax.set_axis_off()
            found = latest.get((cam, kind))
            if found is None:
                ax.text(0.5, 0.5, f"no {kind} snapshot", ha="center", va="center", transform=ax.transAxes)
                continue
            img = found
            if kind == "depth":
                finite = img.image[np.isfinite(img.image)]
                vmax = float(np.percentile(finite, 99)) if finite.size else 1.0
                im = ax.imshow(img.image, cmap="viridis", vmin=0.0, vmax=vmax)
                fig.colorbar(im, ax=ax, fraction=0.035, label="depth (m)")
            elif kind == "instance":
                ax.imshow(_instance_colors(img.image))
            else:
                ax.imshow(img.image)
            ax.set_title(f"{cam} {kind}  (t = {img.t_s:.0f} s)", fontsize=10)
    fig.suptitle("Camera snapshots", fontsize=12)
    return _save(fig, path)


def snapshot_columns(
    layer_times_s: list[float], feature_times_s: list[float], tolerance_s: float = 1.0
) -> list[tuple[float, int | None, int | None]]:
    """Pair layer and feature snapshots taken at (nearly) the same time into figure columns.

    The scorer snapshots the map layers and the feature maps when each arrives after a snapshot
    time, so the two stamps of one snapshot differ by up to a feature period. Returns
    ``(t_s, layer index or None, feature index or None)`` in time order; a snapshot without a
    partner within ``tolerance_s`` gets a column of its own.
    """
    used: set[int] = set()
    out: list[tuple[float, int | None, int | None]] = []
    for i, t in enumerate(layer_times_s):
        best = min(
            (j for j in range(len(feature_times_s)) if j not in used),
            key=lambda j: abs(feature_times_s[j] - t),
            default=None,
        )
        if best is not None and abs(feature_times_s[best] - t) <= tolerance_s:
            used.add(best)
            out.append((t, i, best))
        else:
            out.append((t, i, None))
    out.extend((t, None, j) for j, t in enumerate(feature_times_s) if j not in used)
    return sorted(out, key=lambda c: c[0])


def map_snapshots_figure(run: RunData, path: Path) -> Path | None:
    """Elevation (top row) and combined score (bottom row) at each snapshot time."""
    columns = snapshot_columns([g.t_s for g in run.layers], [g.t_s for g in run.features])
    if not columns:
        return None
    times = [t for t, _, _ in columns]
    layers = {t: run.layers[i] for t, i, _ in columns if i is not None}
    features = {t: run.features[j] for t, _, j in columns if j is not None}
    all_elev = [g.layers["elevation_m"] for g in run.layers if "elevation_m" in g.layers]
    finite = np.concatenate([e[np.isfinite(e)] for e in all_elev]) if all_elev else np.zeros(0)
    vmin, vmax = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    fig, axes = plt.subplots(2, len(times), figsize=(3.6 * len(times) + 1, 7), squeeze=False, layout="constrained")
    for c, t in enumerate(times):
        for r, (source, layer, cmap, label) in enumerate(
            ((layers, "elevation_m", "terrain", "elevation (m)"), (features, "score", "magma", "score"))
        ):
            ax = axes[r][c]
            g = source.get(t)
            if g is None or layer not in g.layers:
                ax.set_axis_off()
                ax.text(0.5, 0.5, f"no {label}", ha="center", va="center", transform=ax.transAxes)
                continue
            kw = {"vmin": vmin, "vmax": vmax} if layer == "elevation_m" else {}
            im = ax.imshow(g.layers[layer], origin="lower", extent=_extent(g), cmap=cmap, **kw)
            ax.set_title(f"t = {t:.0f} s", fontsize=10)
            ax.set_xlabel("x east (m)", fontsize=8)
            if c == 0:
                ax.set_ylabel(f"{label}\ny north (m)", fontsize=9)
            ax.tick_params(labelsize=7)
            fig.colorbar(im, ax=ax, fraction=0.04)
    fig.suptitle("Elevation map and combined MCDM score over time", fontsize=12)
    return _save(fig, path)


def topdown_figure(run: RunData, path: Path) -> Path | None:
    """Trajectory and goals over the latest known DEM."""
    if run.trajectory.shape[0] == 0 and not run.layers:
        return None
    fig, ax = plt.subplots(figsize=(8, 8), layout="constrained")
    if run.layers and "elevation_m" in run.layers[-1].layers:
        g = run.layers[-1]
        im = ax.imshow(g.layers["elevation_m"], origin="lower", extent=_extent(g), cmap="terrain", alpha=0.9)
        fig.colorbar(im, ax=ax, fraction=0.04, label="known elevation (m)")
    traj = run.trajectory
    if traj.shape[0]:
        sc = ax.scatter(traj[:, 1], traj[:, 2], c=traj[:, 0], s=2, cmap="cool", label="trajectory")
        fig.colorbar(sc, ax=ax, location="bottom", fraction=0.04, label="simulation time since start (s)")
        ax.plot(traj[0, 1], traj[0, 2], "k^", ms=9, label="start")
        ax.plot(traj[-1, 1], traj[-1, 2], "ks", ms=8, label="end")
    distinct = [g.goal_m[:2] for k, g in enumerate(run.goals) if k == 0 or g.goal_m != run.goals[k - 1].goal_m]
    if distinct:
        goals = np.array(distinct)
        ax.plot(goals[:, 0], goals[:, 1], "o", mfc="none", mec="red", ms=7, label=f"goals ({len(goals)})")
        ax.plot(goals[:, 0], goals[:, 1], "r:", lw=0.8)
    if run.target_position_m is not None:
        ax.plot(*run.target_position_m, "*", color="gold", mec="k", ms=16, label="person (confirmed)")
    ax.set_xlabel("x east (m)")
    ax.set_ylabel("y north (m)")
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("Top-down: trajectory and goals over the map's DEM")
    return _save(fig, path)


def _state_bands(ax: Any, run: RunData, t_end: float) -> None:
    for k, (t, state) in enumerate(run.controller):
        t1 = run.controller[k + 1][0] if k + 1 < len(run.controller) else t_end
        ax.axvspan(t, t1, color=_STATE_COLORS.get(state, "#eeeeee"), alpha=0.25, lw=0)


def voxel_figure(run: RunData, path: Path) -> Path | None:
    """Mean voxel (column) age, voxel count and % mapped over time."""
    ts = run.timeseries
    if "t_s" not in ts or ts["t_s"].size == 0:
        return None
    t = ts["t_s"]
    fig, (ax1, ax3) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, layout="constrained")
    ax1.plot(t, ts["mean_cell_age_s"], color="tab:red", label="mean voxel age")
    ax1.set_ylabel("mean voxel age (s)", color="tab:red")
    ax2 = ax1.twinx()
    count = ts["occupied_voxels"] if np.any(ts["occupied_voxels"] >= 0) else ts["observed_cells"]
    label = "occupied voxels" if np.any(ts["occupied_voxels"] >= 0) else "observed map columns"
    ax2.plot(t, count, color="tab:blue", label=label)
    ax2.set_ylabel(label, color="tab:blue")
    ax1.set_title("Map freshness and size")
    ax3.plot(t, ts["mapped_pct"], color="tab:green")
    ax3.set_ylabel("scene mapped (%)")
    ax3.set_xlabel("simulation time since start (s)")
    _state_bands(ax3, run, float(t[-1]))
    ax1.grid(alpha=0.3)
    ax3.grid(alpha=0.3)
    return _save(fig, path)


def battery_altitude_figure(run: RunData, path: Path) -> Path | None:
    """Battery (remaining %, voltage) and altitude above ground over time."""
    has_bat = run.battery.shape[0] > 0
    has_alt = "agl_m" in run.timeseries or run.trajectory.shape[0] > 0
    if not (has_bat or has_alt):
        return None
    fig, (ax1, ax3) = plt.subplots(2, 1, figsize=(10, 6.5), sharex=True, layout="constrained")
    if has_bat:
        ax1.plot(run.battery[:, 0], run.battery[:, 1], color="tab:orange")
        ax1.set_ylabel("battery remaining (%)", color="tab:orange")
        ax2 = ax1.twinx()
        ax2.plot(run.battery[:, 0], run.battery[:, 2], color="tab:gray", lw=0.8)
        ax2.set_ylabel("voltage (V)", color="tab:gray")
    else:
        ax1.text(0.5, 0.5, "no battery data", ha="center", transform=ax1.transAxes)
    ax1.set_title("Battery and altitude")
    if run.trajectory.shape[0]:
        ax3.plot(run.trajectory[:, 0], run.trajectory[:, 3], color="tab:purple", lw=0.8, label="z above home")
    if "agl_m" in run.timeseries:
        ax3.plot(run.timeseries["t_s"], run.timeseries["agl_m"], color="tab:blue", label="above ground")
    floor = run.summary.get("flight", {}).get("altitude_floor_m")
    if floor is not None:
        ax3.axhline(floor, color="red", ls="--", lw=0.8, label=f"floor {floor:g} m")
    ax3.set_ylabel("altitude (m)")
    ax3.set_xlabel("simulation time since start (s)")
    ax3.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    ax3.grid(alpha=0.3)
    return _save(fig, path)


def detection_figure(run: RunData, path: Path) -> Path | None:
    """Objects detected per frame over time, per source and class, with controller states."""
    if not run.detections and not run.controller:
        return None
    fig, ax = plt.subplots(figsize=(10, 3.8), layout="constrained")
    t_end = max([d.t_s for d in run.detections] + [c[0] for c in run.controller] + [1.0])
    _state_bands(ax, run, t_end)
    series: dict[str, list[tuple[float, int]]] = {}
    for frame in run.detections:
        by_class: dict[str, int] = {}
        for d in frame.detections:
            by_class[d.class_name] = by_class.get(d.class_name, 0) + 1
        for cls in by_class | {"person": 0}:
            series.setdefault(f"{frame.source}/{frame.camera}: {cls}", []).append((frame.t_s, by_class.get(cls, 0)))
    for label, points in sorted(series.items()):
        arr = np.array(points)
        if arr[:, 1].max() > 0:
            ax.step(arr[:, 0], arr[:, 1], where="post", label=label, lw=1)
    det = run.summary.get("detection", {})
    for key, style in (("person_first_in_view", "g--"), ("person_first_detected", "r-")):
        t = (det.get(key) or {}).get("t_s")
        if t is not None:
            ax.axvline(t, color=style[0], ls=style[1:], lw=1.2, label=key.replace("_", " "))
    ax.set_xlabel("simulation time since start (s)")
    ax.set_ylabel("objects detected per frame")
    ax.set_ylim(bottom=0)
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    handles = [Rectangle((0, 0), 1, 1, color=_STATE_COLORS.get(s, "#eee"), alpha=0.4) for _, s in run.controller]
    states = [s for _, s in run.controller]
    uniq = dict(zip(states, handles, strict=True))
    lines, labels = ax.get_legend_handles_labels()
    ax.legend(lines + list(uniq.values()), labels + list(uniq), fontsize=7, loc="upper left", ncol=2)
    ax.set_title("Detection timeline (background: controller state)")
    if not series:
        ax.text(0.5, 0.5, "no detections", ha="center", transform=ax.transAxes)
    ax.grid(alpha=0.3)
    return _save(fig, path)


def moving_objects_figure(run: RunData, path: Path) -> Path | None:
    """Where the people and vehicles moved (over the drone's path), and what the map did with what they left."""
    ts = run.timeseries
    has_trails = "trail_mapped_voxels" in ts and bool(np.isfinite(ts["trail_mapped_voxels"]).any())
    if not run.object_tracks and not has_trails:
        return None
    fig, (ax_map, ax_t) = plt.subplots(1, 2, figsize=(12, 4.8), layout="constrained")
    if len(run.trajectory):
        ax_map.plot(run.trajectory[:, 1], run.trajectory[:, 2], color="0.35", lw=1.0, label="drone")
    labelled: set[bool] = set()
    for name, track in sorted(run.object_tracks.items()):
        arr = np.array(track)
        person = name.startswith("person")
        label = None if person in labelled else ("people (dot: last position)" if person else "vehicles")
        labelled.add(person)
        color = "tab:red" if person else "tab:blue"
        ax_map.plot(arr[:, 1], arr[:, 2], lw=1.4, color=color, alpha=0.8, label=label)
        ax_map.plot(arr[-1, 1], arr[-1, 2], "o", ms=3, color=color)
    handles, labels = ax_map.get_legend_handles_labels()
    uniq = dict(zip(labels, handles, strict=False))
    ax_map.legend(uniq.values(), uniq.keys(), fontsize=8, loc="best")
    ax_map.set_aspect("equal", adjustable="datalim")
    ax_map.set_xlabel("x east (m)")
    ax_map.set_ylabel("y north (m)")
    ax_map.set_title("Ground-truth tracks of the moving people and vehicles")
    ax_map.grid(alpha=0.3)
    if has_trails:
        t = ts["t_s"]
        for key, label, color in (
            ("trail_mapped_voxels", "mapped occupied while an object was there", "0.5"),
            ("trail_seen_again_voxels", "... left, and the map looked there again", "tab:orange"),
            ("trail_cleared_voxels", "... of those, cleared by the map", "tab:green"),
            ("trail_ghost_voxels", "... of those, still occupied (ghosts)", "tab:red"),
        ):
            if key not in ts:
                continue
            ok = np.isfinite(ts[key])
            ax_t.step(t[ok], ts[key][ok], where="post", label=label, color=color)
        ax_t.legend(fontsize=8, loc="upper left")
    else:
        ax_t.text(0.5, 0.5, "no map evaluation yet", ha="center", transform=ax_t.transAxes)
    ax_t.set_xlabel("simulation time since start (s)")
    ax_t.set_ylabel("voxels")
    ax_t.set_title("Voxels the moving objects occupied: what the map kept")
    ax_t.grid(alpha=0.3)
    return _save(fig, path)


_CONTEXT_TITLES = {
    "pixel_size": "pixel size (TinyPerson bins)",
    "range": "range",
    "view_angle": "view angle (off nadir)",
    "visible_fraction": "visible fraction (occlusion)",
    "altitude": "altitude above ground",
    "clutter": "clutter (objects in frame)",
}


def pr_curves_figure(run: RunData, path: Path) -> Path | None:
    """Precision-recall curves (IoU 0.5, mean over classes) of the detector: overall and per class, then one
    panel per context with a curve per band (AP50 and the number of truth objects in the legend)."""
    coco = (run.summary.get("detection") or {}).get("coco") or {}
    if not coco.get("pr_curve") and not coco.get("by_context"):
        return None
    recall = np.linspace(0.0, 1.0, 101)
    contexts = [c for c in _CONTEXT_TITLES if c in (coco.get("by_context") or {})]
    panels = 1 + len(contexts)
    cols = min(3, panels)
    rows = (panels + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.6 * rows), squeeze=False, layout="constrained")

    def curve(ax: Any, values: list[Any], label: str, **kw: Any) -> None:
        if values and len(values) == recall.size:
            prec = np.array([np.nan if v is None else v for v in values], dtype=np.float64)
            # COCO gives precision 0 beyond the highest recall reached: end the line there instead.
            reached = np.flatnonzero(prec > 0)
            prec[reached[-1] + 1 if reached.size else 0 :] = np.nan
            ax.plot(recall, prec, label=label, lw=1.3, **kw)

    def ap(v: Any) -> str:
        return "n/a" if v is None or (isinstance(v, float) and np.isnan(v)) else f"{v:.2f}"

    ax0 = axes[0][0]
    curve(ax0, coco.get("pr_curve") or [], f"all: AP50 {ap(coco.get('AP50'))}, AP {ap(coco.get('AP'))}", color="k")
    for name, per in (coco.get("per_class") or {}).items():
        curve(ax0, per.get("pr_curve") or [], f"{name}: AP50 {ap(per.get('AP50'))} (n={per.get('truths', 0)})", ls="--")
    ax0.set_title(f"{(run.summary.get('detection') or {}).get('source', 'detector')}: overall", fontsize=10)
    for k, name in enumerate(contexts, start=1):
        ax = axes[k // cols][k % cols]
        for label, band in coco["by_context"][name].items():
            n = band.get("truths", 0)
            if band.get("pr_curve"):
                curve(ax, band["pr_curve"], f"{label}: AP50 {ap(band.get('AP50'))} (n={n})")
            else:
                ax.plot([], [], " ", label=f"{label}: no AP (n={n}, {band.get('detections', 0)} det.)")
        ax.set_title(f"by {_CONTEXT_TITLES[name]}", fontsize=10)
    for k in range(panels, rows * cols):
        axes[k // cols][k % cols].axis("off")
    for k in range(panels):
        ax = axes[k // cols][k % cols]
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("recall")
        ax.set_ylabel("precision (IoU 0.5)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6.5, loc="lower left")
    return _save(fig, path)


def gallery_figure(run: RunData, path: Path) -> Path | None:
    """The detector's worst false positives (top row, highest score first) and worst misses (largest and least
    occluded first), cut from the camera images with the box drawn."""
    det = run.summary.get("detection") or {}
    if run.gallery is None:
        frames = int(det.get("frames") or 0)
        if not frames or "gallery" not in det:
            return None  # no detector frame was scored
        items = det.get("gallery") or []
        fig, ax = plt.subplots(figsize=(8, 1.2), layout="constrained")
        ax.set_axis_off()
        text = (
            f"no false positive and no miss at the operating threshold in {frames} scored frames"
            if not items
            else f"{len(items)} mistakes kept, but no image crops (the detector camera's images were not kept)"
        )
        ax.text(0.5, 0.5, f"{det.get('source', 'detector')}: {text}", ha="center", va="center", fontsize=10)
        return _save(fig, path)
    img = np.asarray(run.gallery)
    fig, ax = plt.subplots(figsize=(min(14.0, img.shape[1] / 60.0), img.shape[0] / 60.0 + 0.6), layout="constrained")
    ax.imshow(img, interpolation="nearest")
    ax.set_axis_off()
    ax.set_title(
        "worst false positives (red, score) and misses (blue); range from the geolocation or the truth", fontsize=9
    )
    return _save(fig, path)


#: Figure id -> (title, drawing function), in report order.
FIGURES = {
    "cameras": ("Camera snapshots: color, depth, segmentation", camera_figure),
    "maps": ("Elevation and combined score maps over time", map_snapshots_figure),
    "topdown": ("Top-down map: trajectory and goals over the DEM", topdown_figure),
    "voxels": ("Mean voxel age and voxel count over time", voxel_figure),
    "battery_altitude": ("Battery and altitude over time", battery_altitude_figure),
    "detections": ("Detection timeline", detection_figure),
    "moving_objects": ("Moving people and vehicles, and the map's clearing of what they left", moving_objects_figure),
    "pr_curves": ("Detector precision-recall curves, overall and by context (COCO, IoU 0.5)", pr_curves_figure),
    "gallery": ("Detector gallery: worst false positives and misses", gallery_figure),
}
