"""Telemetry log (``.tlog``) files: every routed frame with its arrival time.

Format (mavlink-router ``tlog.cpp``, MAVProxy, QGroundControl, pymavlink's
``mavlogfile``): for each frame, an 8-byte big-endian UNIX timestamp in
microseconds, then the raw MAVLink frame, unchanged.

Files are named like mavlink-router's, ``NNNNN-YYYY-MM-DD_HH-MM-SS.tlog``, with
``NNNNN`` one more than the highest number already in the directory. Before a
new file is opened, the oldest of these files are deleted while there are
``MaxLogFiles`` or more of them, or while free space is below ``MinFreeSpace``.
"""

from __future__ import annotations

import logging
import re
import shutil
import struct
import time
from pathlib import Path
from typing import BinaryIO

from mavlink_router.errors import RouterError

__all__ = ["TelemetryLog", "next_log_path"]

_LOG = logging.getLogger("mavlink_router.shell.tlog")
_NAME = re.compile(r"^(\d{5})-.*\.tlog$")
_STAMP = struct.Struct(">Q")
_BUFFER_BYTES = 256 * 1024


def _numbered(directory: Path) -> list[tuple[int, Path]]:
    found = []
    for path in directory.iterdir():
        match = _NAME.match(path.name)
        if match and path.is_file():
            found.append((int(match.group(1)), path))
    return sorted(found)


def next_log_path(directory: Path, now_unix_s: float) -> Path:
    """The name of the next log file in ``directory`` (which must exist)."""
    existing = _numbered(directory)
    index = existing[-1][0] + 1 if existing else 1
    stamp = time.strftime("%Y-%m-%d_%H-%M-%S", time.localtime(now_unix_s))
    return directory / f"{index % 100000:05d}-{stamp}.tlog"


class TelemetryLog:
    """One log directory; :meth:`start` opens a new file, :meth:`stop` closes it."""

    def __init__(self, directory: Path, *, max_files: int = 0, min_free_space_bytes: int = 0) -> None:
        self.directory = directory
        self._max_files = max_files
        self._min_free = min_free_space_bytes
        self._file: BinaryIO | None = None
        self.path: Path | None = None
        self.frames = 0
        self.bytes = 0

    @property
    def active(self) -> bool:
        return self._file is not None

    def start(self, now_unix_s: float) -> Path:
        """Open a new ``.tlog`` file (closing any open one) and return its path."""
        self.stop()
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._prune()
            path = next_log_path(self.directory, now_unix_s)
            self._file = path.open("xb", buffering=_BUFFER_BYTES)
        except OSError as err:
            msg = f"cannot open a telemetry log in {self.directory}: {err}; check the Log directory (-l)"
            raise RouterError(msg) from err
        self.path = path
        _LOG.info("telemetry log: %s", path)
        return path

    def write(self, frame: bytes, now_unix_s: float) -> None:
        """Append one frame (no-op when no file is open)."""
        fh = self._file
        if fh is None:
            return
        fh.write(_STAMP.pack(int(now_unix_s * 1_000_000)) + frame)
        self.frames += 1
        self.bytes += 8 + len(frame)

    def flush(self) -> None:
        if self._file is not None:
            try:
                self._file.flush()
            except OSError as err:
                _LOG.error("telemetry log %s: flush failed (%s); logging stops", self.path, err)
                self._close_quietly()

    def stop(self) -> None:
        """Flush and close the current file, if any."""
        if self._file is None:
            return
        self.flush()
        self._close_quietly()
        _LOG.info("telemetry log closed: %s (%d frames)", self.path, self.frames)

    def _close_quietly(self) -> None:
        fh, self._file = self._file, None
        if fh is not None:
            try:
                fh.close()
            except OSError as err:
                _LOG.error("telemetry log %s: close failed (%s)", self.path, err)

    def _prune(self) -> None:
        files = _numbered(self.directory)
        while files and (
            (self._max_files and len(files) >= self._max_files)
            or (self._min_free and shutil.disk_usage(self.directory).free < self._min_free)
        ):
            _, oldest = files.pop(0)
            _LOG.info("deleting old telemetry log %s (MaxLogFiles/MinFreeSpace)", oldest)
            oldest.unlink(missing_ok=True)
