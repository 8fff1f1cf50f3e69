"""Run-folder log of the depth evaluator: one JSON line per frame and a summary.

Files in the run folder (created if missing):

* ``depth_metrics.jsonl``: one object per evaluated frame (``stamp_s``, ``camera``,
  ``stamp_diff_s``, ``abs_tol_m``, ``rel_tol``, ``overall``, ``range_bands``,
  ``classes``, ``n_spurious``, ``n_pixels``); NaN is written as ``null``.
* ``depth_summary.json``: the pixel-weighted aggregate over all frames, rewritten
  by :meth:`DepthRunLog.write_summary` (the node calls it periodically and at shutdown).

The node's callbacks and its shutdown hook run in different threads, so every method takes one lock; a frame
added after :meth:`DepthRunLog.close` (a callback still running while the node shuts down) is still appended,
and the summary rewritten with it.
"""

from __future__ import annotations

import json
import math
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from uav_perception.core.depth.config import EvaluatorConfig
from uav_perception.core.depth.metrics import DepthAccumulator, DepthEvaluation

__all__ = ["DepthRunLog", "json_safe"]

METRICS_FILE = "depth_metrics.jsonl"
SUMMARY_FILE = "depth_summary.json"


def json_safe(value: Any) -> Any:
    """Replace NaN/inf floats by None, recursively (strict JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    return value


class DepthRunLog:
    """Appends per-frame records and keeps the aggregate."""

    def __init__(self, run_dir: Path, camera: str, config: EvaluatorConfig) -> None:
        run_dir.mkdir(parents=True, exist_ok=True)
        self.run_dir = run_dir
        self.camera = camera
        self.config = config
        self.accumulator = DepthAccumulator()
        self._lock = threading.Lock()
        self._extra: dict[str, Any] = {}
        self._fh = (run_dir / METRICS_FILE).open("a", encoding="utf-8")

    def add(self, stamp_s: float, stamp_diff_s: float, evaluation: DepthEvaluation) -> None:
        """Log one frame and add it to the aggregate (after :meth:`close` too: see the module docstring)."""
        record = {
            "stamp_s": stamp_s,
            "camera": self.camera,
            "stamp_diff_s": stamp_diff_s,
            "abs_tol_m": self.config.abs_tol_m,
            "rel_tol": self.config.rel_tol,
            **evaluation.as_dict(),
        }
        line = json.dumps(json_safe(record), allow_nan=False) + "\n"
        with self._lock:
            self.accumulator.add(evaluation)
            if not self._fh.closed:
                self._fh.write(line)
                self._fh.flush()
                return
            with (self.run_dir / METRICS_FILE).open("a", encoding="utf-8") as fh:
                fh.write(line)
            self._write_summary_locked()

    def write_summary(self, extra: Mapping[str, Any] | None = None) -> Path:
        """(Re)write ``depth_summary.json`` (``extra``: more keys, kept for later rewrites); returns its path."""
        with self._lock:
            self._extra = dict(extra or {})
            return self._write_summary_locked()

    def _write_summary_locked(self) -> Path:
        summary = {
            "camera": self.camera,
            "frames": self.accumulator.frames,
            "abs_tol_m": self.config.abs_tol_m,
            "rel_tol": self.config.rel_tol,
            "aggregate": self.accumulator.result().as_dict(),
            **self._extra,
        }
        path = self.run_dir / SUMMARY_FILE
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(json_safe(summary), indent=1, allow_nan=False))
        tmp.replace(path)
        return path

    def close(self) -> None:
        """Close the per-frame file (a later :meth:`add` opens it again for its line)."""
        with self._lock:
            self._fh.close()
