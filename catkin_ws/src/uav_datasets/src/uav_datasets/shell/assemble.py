"""The files written once every frame is made: annotation files, the dataset card, the manifest.

Each is written whole through :func:`~uav_datasets.shell.writers.atomic_write`; ``dataset.json`` is
marked complete last, so a folder whose manifest says complete has every file.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from uav_datasets.core.config import DatasetConfig
from uav_datasets.core.formats import coco_document, data_yaml, mot_lines, seqinfo_ini
from uav_datasets.core.records import FrameRecord
from uav_datasets.core.stats import dataset_stats, stats_markdown
from uav_datasets.shell.folder import RECORDS, clear_progress, write_manifest
from uav_datasets.shell.writers import atomic_write

__all__ = ["assemble", "card_markdown", "split_order"]


def split_order(frames: Sequence[FrameRecord]) -> list[str]:
    seen: list[str] = []
    for rec in frames:
        if rec.split not in seen:
            seen.append(rec.split)
    return seen


def _image_name(rec: FrameRecord) -> str:
    path = rec.files.get("image", f"images/{rec.split}/{rec.name}.png")
    return path.removeprefix("images/")


def _symlink(link: Path, target: str) -> None:
    """A relative symlink ``link -> target`` (replaced if present)."""
    link.parent.mkdir(parents=True, exist_ok=True)
    tmp = link.with_name(f".{link.name}.{os.getpid()}.lnk")
    if tmp.is_symlink() or tmp.exists():
        tmp.unlink()
    tmp.symlink_to(target)
    os.replace(tmp, link)


def _write_coco(out: Path, cfg: DatasetConfig, frames: Sequence[FrameRecord], manifest: dict[str, Any]) -> None:
    classes = [(int(c), c.label) for c in cfg.labels.class_list]
    info = {
        "description": cfg.description or f"uav-dataset {cfg.name}",
        "version": "1.0",
        "contributor": "UAV autonomy test range data engine (uav-dataset)",
        "dataset": cfg.name,
        "fingerprint": manifest["fingerprint"],
        "licence": cfg.licence,
    }
    for name, subset in [("instances", list(frames))] + [
        (f"instances_{s}", [f for f in frames if f.split == s]) for s in split_order(frames)
    ]:
        doc = coco_document(
            subset, classes=classes, info={**info, "subset": name}, licence=cfg.licence, file_name=_image_name
        )
        atomic_write(out / "annotations" / f"{name}.json", json.dumps(doc, separators=(",", ":")), sync=True)


def _write_mot(out: Path, frames: Sequence[FrameRecord], rate_hz: float) -> list[str]:
    by_seq: dict[str, list[FrameRecord]] = {}
    for rec in frames:
        if rec.sequence:
            by_seq.setdefault(rec.sequence, []).append(rec)
    lines: dict[str, list[str]] = {}
    for seq, recs in by_seq.items():
        recs.sort(key=lambda r: r.sequence_frame)
        base = out / "mot" / seq
        ext = Path(recs[0].files.get("image", ".png")).suffix
        for rec in recs:
            if "image" in rec.files:
                _symlink(base / "img1" / f"{rec.sequence_frame:06d}{ext}", f"../../../{rec.files['image']}")
        atomic_write(base / "gt" / "gt.txt", mot_lines(recs), sync=True)
        first = recs[0]
        ini = seqinfo_ini(seq, frames=len(recs), rate_hz=rate_hz, width=first.width, height=first.height, ext=ext)
        atomic_write(base / "seqinfo.ini", ini)
        lines.setdefault(first.split, []).append(seq)
    for split, seqs in lines.items():
        atomic_write(out / "mot" / "seqmaps" / f"uav-{split}.txt", "name\n" + "".join(s + "\n" for s in seqs))
    return sorted(by_seq)


def card_markdown(cfg: DatasetConfig, manifest: dict[str, Any], frames: Sequence[FrameRecord]) -> str:
    """The dataset card (``README.md``): what it is, how it was made, its tables, its files and licence."""
    stats = dataset_stats(frames, cfg.labels.classes, cfg.card.altitude_bands_m, cfg.card.pitch_bands_deg)
    worlds = manifest["identity"]["worlds"]
    source = (
        "sampled viewpoints over procedurally generated worlds"
        if cfg.source == "viewpoints"
        else f"a sequence along a recorded flight ({manifest['identity'].get('flight', {}).get('run', '')})"
    )
    outputs = [
        ("COCO instances", "annotations/instances.json, annotations/instances_<split>.json", cfg.outputs.coco),
        ("YOLO labels", "labels/<split>/<frame>.txt, data.yaml", cfg.outputs.yolo),
        ("MOTChallenge", "mot/<sequence>/gt/gt.txt, seqinfo.ini, img1/, mot/seqmaps/", cfg.writes_mot),
        ("KITTI labels and calibration", "kitti/<split>/label_2, calib, image_2", cfg.outputs.kitti),
        (f"depth ({cfg.outputs.depth})", "depth/<split>/<frame>.png|tiff", cfg.outputs.depth != "none"),
        ("instance-id masks (uint16)", "masks/instance/<split>/<frame>.png", cfg.outputs.instance_masks),
        ("class-id masks (uint16)", "masks/class/<split>/<frame>.png", cfg.outputs.class_masks),
        ("per-frame metadata and labels", "frames.jsonl (and the COCO images entries)", True),
    ]
    lines = [
        f"# Dataset card: {cfg.name}",
        "",
        cfg.description or "Labelled aerial images rendered from the UAV autonomy test range's simulated world.",
        "",
        f"* Source: {source}; generated by `uav-dataset` (engine v{manifest['engine_version']}).",
        f"* Fingerprint: `{manifest['fingerprint']}` (config, frames, sampling seed, world hashes).",
        f"* Sampling seed: {cfg.seed}. Worlds: "
        + ", ".join(f"seed {seed} ({w['split']}, `{w['hash'][:12]}`)" for seed, w in worlds.items())
        + ".",
        f"* Camera: {frames[0].width}x{frames[0].height} px, fx {frames[0].fx:.2f}, fy {frames[0].fy:.2f}."
        if frames
        else "* Camera: no frames.",
        (
            f"* Labelled classes: {', '.join(cfg.labels.classes)} (COCO category id = world class id; YOLO "
            "index = position in this list)."
        ),
        f"* Filters: at least {cfg.labels.min_visible_pixels} visible pixels, visible fraction at least "
        f"{cfg.labels.min_visible_fraction:g}"
        + (f", range at most {cfg.labels.max_range_m:g} m" if cfg.labels.max_range_m is not None else "")
        + ". A fully occluded object has no label.",
        f"* Licence of the data: **{cfg.licence}**. The software that made it is BSD-3-Clause.",
        "",
        "Splits hold out whole worlds (different world seeds), so a test split never shows a training world.",
        "Every attribute is defined in the project's docs/datasets.md.",
        "",
        "## Contents",
        "",
    ]
    lines += [f"* {what}: `{where}`" for what, where, on in outputs if on]
    lines += ["", "## Statistics", "", stats_markdown(stats).rstrip(), "", "## Configuration", "", "```yaml"]
    lines.append(yaml.safe_dump(cfg.to_mapping(), sort_keys=False).rstrip())
    lines += ["```", ""]
    return "\n".join(lines)


def assemble(
    out: Path, cfg: DatasetConfig, frames: Sequence[FrameRecord], manifest: dict[str, Any], *, rate_hz: float
) -> dict[str, Any]:
    """Write every annotation file, the card and the records, then mark the manifest complete; returns it."""
    frames = sorted(frames, key=lambda r: r.index)
    atomic_write(out / RECORDS, "".join(json.dumps(r.to_json(), sort_keys=True) + "\n" for r in frames), sync=True)
    splits = split_order(frames)
    if cfg.outputs.coco:
        _write_coco(out, cfg, frames, manifest)
    if cfg.outputs.yolo:
        atomic_write(out / "data.yaml", data_yaml(splits, cfg.labels.classes))
    if cfg.outputs.kitti and cfg.outputs.images != "none":
        for split in splits:
            _symlink(out / "kitti" / split / "image_2", f"../../images/{split}")
    sequences = _write_mot(out, frames, rate_hz) if cfg.writes_mot else []
    atomic_write(out / "README.md", card_markdown(cfg, manifest, frames))
    stats = dataset_stats(frames, cfg.labels.classes, cfg.card.altitude_bands_m, cfg.card.pitch_bands_deg)
    done = {**manifest, "complete": True, "frames": len(frames), "sequences": sequences, "stats": stats.to_json()}
    write_manifest(out, done)
    clear_progress(out)
    return done
