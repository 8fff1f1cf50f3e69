"""A dataset folder's identity and progress: ``dataset.json``, the workers' journals, resuming.

* ``dataset.json`` is written first, with ``"complete": false`` and the dataset's *fingerprint* (a
  digest of the effective config, the frame count, the sampling seed and the worlds' hashes), and
  rewritten with ``"complete": true`` as the very last file of a generation.
* Each worker appends one JSON line per finished frame to its journal in ``.progress/`` after the
  frame's files are in place. A killed worker leaves at most a partial last line, which is ignored.
* Generating into a folder resumes it when the fingerprints match (frames in the journals whose files
  exist are kept), and refuses with :class:`~uav_datasets.errors.DatasetFolderError` when the folder
  holds another dataset or files that are not a dataset.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from uav_datasets.core.records import FrameRecord
from uav_datasets.errors import DatasetFolderError, IncompleteDatasetError
from uav_datasets.shell.writers import atomic_write

__all__ = [
    "ENGINE_VERSION",
    "MANIFEST",
    "PROGRESS",
    "RECORDS",
    "clear_progress",
    "config_differences",
    "fingerprint",
    "journal_records",
    "prepare_folder",
    "read_manifest",
    "read_records",
    "remove_temporaries",
    "write_manifest",
]

#: Bump when the same config would give different files (label definitions, layout).
ENGINE_VERSION = 1
MANIFEST = "dataset.json"
PROGRESS = ".progress"
RECORDS = "frames.jsonl"


def fingerprint(identity: dict[str, Any]) -> str:
    """sha256 of the canonical JSON of what makes a dataset (config, frames, seed, world hashes, version)."""
    blob = json.dumps({"engine_version": ENGINE_VERSION, **identity}, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()


def _flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, dict):
        out: dict[str, Any] = {}
        for k, v in data.items():
            out.update(_flatten(v, f"{prefix}.{k}" if prefix else str(k)))
        return out
    return {prefix: data}


def config_differences(a: dict[str, Any], b: dict[str, Any]) -> list[str]:
    """Dotted keys whose values differ between two identities (``key: old -> new``)."""
    fa, fb = _flatten(a), _flatten(b)
    out = []
    for key in sorted(set(fa) | set(fb)):
        if fa.get(key) != fb.get(key):
            out.append(f"{key}: {fa.get(key)!r} -> {fb.get(key)!r}")
    return out


def read_manifest(folder: Path) -> dict[str, Any]:
    """``dataset.json`` of a dataset folder.

    Raises:
        DatasetFolderError: no such file, or not valid JSON.
    """
    path = folder / MANIFEST
    if not path.is_file():
        msg = f"{folder}: not a dataset folder (no {MANIFEST}); generate one with uav-dataset generate"
        raise DatasetFolderError(msg)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        msg = f"{path}: unreadable dataset manifest ({err}); delete {folder} and generate it again"
        raise DatasetFolderError(msg) from err
    if not isinstance(data, dict) or data.get("format") != "uav-dataset":
        msg = f"{path}: not a uav-dataset manifest"
        raise DatasetFolderError(msg)
    return data


def write_manifest(folder: Path, manifest: dict[str, Any]) -> None:
    atomic_write(folder / MANIFEST, json.dumps(manifest, indent=1, sort_keys=True) + "\n", sync=True)


def prepare_folder(folder: Path, manifest: dict[str, Any]) -> bool:
    """Make ``folder`` ready for the dataset ``manifest`` describes; returns whether it is already complete.

    A missing or empty folder gets a new manifest. A folder with the same fingerprint is resumed (or is
    complete already).

    Raises:
        DatasetFolderError: the folder holds a different dataset (the message lists what differs) or
            files that are not a dataset.
    """
    if folder.exists() and not folder.is_dir():
        msg = f"{folder} is a file, not a folder; choose another --out"
        raise DatasetFolderError(msg)
    existing = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    if existing:
        if MANIFEST not in existing:
            shown = ", ".join(existing[:5]) + (" ..." if len(existing) > 5 else "")
            msg = (
                f"{folder} is not empty ({shown}) and holds no {MANIFEST}: it is not a dataset folder. "
                "Choose an empty or new --out folder"
            )
            raise DatasetFolderError(msg)
        old = read_manifest(folder)
        if old.get("fingerprint") != manifest["fingerprint"]:
            diffs = config_differences(old.get("identity", {}), manifest["identity"])
            shown = "; ".join(diffs[:6]) + (f"; and {len(diffs) - 6} more" if len(diffs) > 6 else "")
            msg = (
                f"{folder} already holds a different dataset ({old.get('name')!r}, "
                f"{'complete' if old.get('complete') else 'incomplete'}): {shown or 'engine version differs'}. "
                f"Use another --out folder, or delete {folder} to replace it"
            )
            raise DatasetFolderError(msg)
        return bool(old.get("complete"))
    folder.mkdir(parents=True, exist_ok=True)
    write_manifest(folder, manifest)
    return False


def _journal_lines(path: Path) -> Iterator[dict[str, Any]]:
    with path.open(encoding="utf-8") as fh:
        for line in fh:
            if not line.endswith("\n"):
                return  # a partial last line: the worker died while writing it
            try:
                yield json.loads(line)
            except json.JSONDecodeError:
                return


def journal_records(folder: Path) -> dict[int, FrameRecord]:
    """Frames finished by earlier or current workers whose files are all in place, by index."""
    out: dict[int, FrameRecord] = {}
    progress = folder / PROGRESS
    if not progress.is_dir():
        return out
    for path in sorted(progress.glob("*.jsonl")):
        for data in _journal_lines(path):
            rec = FrameRecord.from_json(data)
            if all((folder / rel).is_file() for rel in rec.files.values()):
                out[rec.index] = rec
    return out


def remove_temporaries(folder: Path) -> int:
    """Delete the temporary files an interrupted run left (``.<name>.<pid>.tmp`` / ``.lnk``); returns how many."""
    n = 0
    for pattern in (".*.tmp", ".*.lnk"):
        for path in folder.rglob(pattern):
            if path.is_file() or path.is_symlink():
                path.unlink(missing_ok=True)
                n += 1
    return n


def clear_progress(folder: Path) -> None:
    shutil.rmtree(folder / PROGRESS, ignore_errors=True)


def read_records(folder: Path) -> list[FrameRecord]:
    """The frames of a finished dataset (``frames.jsonl``), in index order.

    Raises:
        DatasetFolderError: not a dataset folder.
        IncompleteDatasetError: its generation has not finished.
    """
    manifest = read_manifest(folder)
    if not manifest.get("complete"):
        done = len(journal_records(folder))
        msg = (
            f"{folder}: generation has not finished ({done} of {manifest.get('frames_planned')} frames made); "
            "run the same uav-dataset generate command again to resume it"
        )
        raise IncompleteDatasetError(msg)
    path = folder / RECORDS
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
        return [FrameRecord.from_json(json.loads(line)) for line in lines if line.strip()]
    except (OSError, json.JSONDecodeError, KeyError, ValueError, TypeError) as err:
        msg = f"{path}: unreadable ({err}); generate the dataset again"
        raise DatasetFolderError(msg) from err
