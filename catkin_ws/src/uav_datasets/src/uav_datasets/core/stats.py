"""The dataset card's statistics and tables (pure): what ``README.md`` and ``uav-dataset stats`` show.

:func:`dataset_stats` counts the frames and labels; :func:`stats_markdown` renders the tables. Bands
are half-open ``[low, high)`` with the last one open-ended; a frame's altitude and pitch are its
camera's (``altitude_agl_m``, ``pitch_deg``), an instance's size is ``sqrt(w * h)`` of its tight box.
"""

from __future__ import annotations

import itertools
import statistics
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from uav_datasets.core.records import SIZE_BINS, FrameRecord

__all__ = ["VISIBILITY_BANDS", "DatasetStats", "band_labels", "band_of", "dataset_stats", "stats_markdown"]

#: Visible-fraction bands of the card (the last, exactly 1, is "nothing in front"; 0.95-<1 is mostly a vehicle
#: whose wheel dips below the terrain on a slope, which counts as hidden).
VISIBILITY_BANDS: tuple[tuple[float, float, str], ...] = (
    (0.0, 0.25, "<0.25"),
    (0.25, 0.5, "0.25-0.5"),
    (0.5, 0.75, "0.5-0.75"),
    (0.75, 0.95, "0.75-0.95"),
    (0.95, 1.0, "0.95-<1"),
    (1.0, 1.0, "1 (unoccluded)"),
)


def band_labels(edges: Sequence[float], unit: str) -> list[str]:
    out = [f"{a:g}-{b:g} {unit}" for a, b in itertools.pairwise(edges)]
    out.append(f">={edges[-1]:g} {unit}")
    return out


def band_of(value: float, edges: Sequence[float]) -> int:
    """Index of the band ``value`` falls in (below the first edge: the first band)."""
    for k in range(len(edges) - 1, -1, -1):
        if value >= edges[k]:
            return k
    return 0


def _visibility_band(v: float) -> str:
    if v >= 1.0:
        return VISIBILITY_BANDS[-1][2]
    for lo, hi, label in VISIBILITY_BANDS[:-1]:
        if lo <= v < hi:
            return label
    return VISIBILITY_BANDS[0][2]


@dataclass(frozen=True)
class DatasetStats:
    """Counts of a dataset, as plain data (``to_json`` goes into ``dataset.json``)."""

    frames: int
    instances: int
    classes: list[str]
    per_class: dict[str, dict[str, Any]]
    per_split: dict[str, dict[str, Any]]
    size_bins: dict[str, dict[str, int]]
    altitude: dict[str, dict[str, int]]
    pitch: dict[str, dict[str, int]]
    visibility: dict[str, dict[str, int]]
    sampling: dict[str, Any]

    def to_json(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "instances": self.instances,
            "classes": self.classes,
            "per_class": self.per_class,
            "per_split": self.per_split,
            "size_bins": self.size_bins,
            "altitude_bands": self.altitude,
            "pitch_bands": self.pitch,
            "visibility_bands": self.visibility,
            "sampling": self.sampling,
        }


def dataset_stats(
    frames: Sequence[FrameRecord],
    classes: Sequence[str],
    altitude_edges_m: Sequence[float],
    pitch_edges_deg: Sequence[float],
) -> DatasetStats:
    """Count ``frames`` by class, split, size bin, altitude band, pitch band and visible fraction."""
    cls = list(classes)
    per_class: dict[str, dict[str, Any]] = {}
    sizes: dict[str, list[float]] = {c: [] for c in cls}
    vis: dict[str, list[float]] = {c: [] for c in cls}
    frames_with: dict[str, int] = dict.fromkeys(cls, 0)
    truncated: dict[str, int] = dict.fromkeys(cls, 0)
    size_bins = {c: {label: 0 for _, _, label in SIZE_BINS} for c in cls}
    alt_labels = band_labels(altitude_edges_m, "m")
    pitch_labels = band_labels(pitch_edges_deg, "deg")
    altitude = {label: {"frames": 0, **dict.fromkeys(cls, 0)} for label in alt_labels}
    pitch = {label: {"frames": 0, **dict.fromkeys(cls, 0)} for label in pitch_labels}
    visibility = {c: {label: 0 for _, _, label in VISIBILITY_BANDS} for c in cls}
    per_split: dict[str, dict[str, Any]] = {}
    attempts = 0
    for rec in frames:
        attempts += rec.attempts
        a = alt_labels[band_of(rec.altitude_agl_m, altitude_edges_m)]
        p = pitch_labels[band_of(rec.pitch_deg, pitch_edges_deg)]
        altitude[a]["frames"] += 1
        pitch[p]["frames"] += 1
        split = per_split.setdefault(
            rec.split, {"frames": 0, "instances": 0, "worlds": {}, **{f"{c}_instances": 0 for c in cls}}
        )
        split["frames"] += 1
        split["worlds"][str(rec.world_seed)] = rec.world_hash
        seen: set[str] = set()
        for lab in rec.labels:
            c = lab.class_name
            if c not in sizes:
                continue
            seen.add(c)
            sizes[c].append(lab.size_px)
            vis[c].append(lab.visible_fraction)
            size_bins[c][lab.size_bin] += 1
            visibility[c][_visibility_band(lab.visible_fraction)] += 1
            altitude[a][c] += 1
            pitch[p][c] += 1
            split["instances"] += 1
            split[f"{c}_instances"] += 1
            if lab.truncation > 0:
                truncated[c] += 1
        for c in seen:
            frames_with[c] += 1
    for c in cls:
        per_class[c] = {
            "instances": len(sizes[c]),
            "frames_with": frames_with[c],
            "median_size_px": round(statistics.median(sizes[c]), 2) if sizes[c] else None,
            "mean_visible_fraction": round(statistics.fmean(vis[c]), 4) if vis[c] else None,
            "truncated": truncated[c],
        }
    for split in per_split.values():
        split["worlds"] = dict(sorted(split["worlds"].items(), key=lambda kv: int(kv[0])))
    sampling = {
        "draws": attempts,
        "rejected": attempts - len(frames),
        "rejected_pct": round(100.0 * (attempts - len(frames)) / attempts, 2) if attempts else 0.0,
    }
    return DatasetStats(
        frames=len(frames),
        instances=sum(len(s) for s in sizes.values()),
        classes=cls,
        per_class=per_class,
        per_split=per_split,
        size_bins=size_bins,
        altitude=altitude,
        pitch=pitch,
        visibility=visibility,
        sampling=sampling,
    )


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    def cell(v: Any) -> str:
        return "-" if v is None else str(v)

    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return out


def stats_markdown(stats: DatasetStats) -> str:
    """The card's tables as Markdown (splits, classes, size bins, altitude, pitch, visibility, sampling)."""
    cls = stats.classes
    lines = [f"{stats.frames} frames, {stats.instances} labelled instances.", "", "### Splits (held-out worlds)", ""]
    rows = []
    for name, s in stats.per_split.items():
        worlds = ", ".join(f"{seed} (`{h[:12]}`)" for seed, h in s["worlds"].items())
        rows.append([name, worlds, s["frames"], s["instances"], *(s[f"{c}_instances"] for c in cls)])
    lines += _table(["split", "world seeds (hash)", "frames", "instances", *cls], rows)
    lines += ["", "### Classes", ""]
    rows = [
        [
            c,
            p["instances"],
            p["frames_with"],
            p["median_size_px"],
            p["mean_visible_fraction"],
            p["truncated"],
        ]
        for c, p in stats.per_class.items()
    ]
    lines += _table(
        ["class", "instances", "frames with one", "median size (px)", "mean visible fraction", "truncated"], rows
    )
    lines += ["", "### Size (TinyPerson bins of sqrt(w h) of the tight box, px)", ""]
    bins = [label for _, _, label in SIZE_BINS]
    lines += _table(["class", *bins], [[c, *(stats.size_bins[c][b] for b in bins)] for c in cls])
    lines += ["", "### Camera altitude above ground", ""]
    lines += _table(
        ["altitude", "frames", *cls], [[k, v["frames"], *(v[c] for c in cls)] for k, v in stats.altitude.items()]
    )
    lines += ["", "### Camera pitch (90 = nadir)", ""]
    lines += _table(["pitch", "frames", *cls], [[k, v["frames"], *(v[c] for c in cls)] for k, v in stats.pitch.items()])
    lines += ["", "### Visible fraction (occlusion)", ""]
    vb = [label for _, _, label in VISIBILITY_BANDS]
    lines += _table(["class", *vb], [[c, *(stats.visibility[c][b] for b in vb)] for c in cls])
    s = stats.sampling
    lines += [
        "",
        (
            f"Viewpoint draws: {s['draws']}, rejected {s['rejected']} ({s['rejected_pct']} %: camera inside the "
            "terrain or an object, outside the world, or too few objects in view)."
        ),
    ]
    return "\n".join(lines) + "\n"
