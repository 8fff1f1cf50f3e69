"""Terrain model (DEM) files: the prior ground heights the geolocator falls back to.

Format (``.npz``, numpy's zip of arrays; written by :func:`save_dem`):

* ``heights_m``: float32 ``(rows, cols)``, metres in ``map`` z; row 0 is the southern-most row, column 0
  the western-most; NaN where unknown;
* ``origin_x_m``, ``origin_y_m``: the south-west corner of cell ``(0, 0)`` in ``map``;
* ``resolution_m``: cell size; heights are samples at cell centres (``origin + (k + 0.5) res``),
  interpolated bilinearly between them;
* ``frame_id``: ``map``; ``format``: ``uav_dem_v1``.

A scenario run writes its world's terrain in this format (``uav_scenarios.shell.world_store.terrain_dem``),
as a ground station keeps an SRTM tile; for a real flight, resample any DEM into it.
"""

from __future__ import annotations

import math
import os
import zipfile
from pathlib import Path

import numpy as np

from uav_perception.core.detection.heightfield import HeightGrid
from uav_perception.errors import DetectionInputError, TerrainFileError

__all__ = ["DEM_FORMAT", "load_dem", "save_dem"]

DEM_FORMAT = "uav_dem_v1"
_KEYS = ("heights_m", "origin_x_m", "origin_y_m", "resolution_m", "frame_id", "format")


def save_dem(path: Path, grid: HeightGrid) -> None:
    """Write ``grid`` to ``path`` atomically (a reader never sees half a file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with tmp.open("wb") as fh:
        np.savez_compressed(
            fh,
            heights_m=np.asarray(grid.heights_m, dtype=np.float32),
            origin_x_m=np.float64(grid.origin_x_m),
            origin_y_m=np.float64(grid.origin_y_m),
            resolution_m=np.float64(grid.resolution_m),
            frame_id=np.str_("map"),
            format=np.str_(DEM_FORMAT),
        )
    os.replace(tmp, path)


def load_dem(path: Path) -> HeightGrid:
    """Read a DEM file as a bilinear :class:`HeightGrid` named ``terrain``.

    Raises:
        TerrainFileError: the file is missing, not an ``.npz`` of this format, or its values are unusable
            (the message names the file and what was expected).
    """
    expected = f"a {DEM_FORMAT} .npz with {', '.join(_KEYS)} (uav_perception.shell.dem)"
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [k for k in _KEYS if k not in data.files]
            if missing:
                msg = f"{path}: terrain model lacks {', '.join(missing)}; expected {expected}"
                raise TerrainFileError(msg)
            if str(data["format"]) != DEM_FORMAT:
                msg = f"{path}: terrain model format {str(data['format'])!r}; expected {expected}"
                raise TerrainFileError(msg)
            if str(data["frame_id"]) != "map":
                msg = f"{path}: terrain model is in frame {str(data['frame_id'])!r}; the geolocator works in 'map'"
                raise TerrainFileError(msg)
            heights = np.asarray(data["heights_m"], dtype=np.float64)
            origin = (float(data["origin_x_m"]), float(data["origin_y_m"]))
            resolution = float(data["resolution_m"])
    except FileNotFoundError as err:
        msg = f"{path}: no such terrain model file; expected {expected}"
        raise TerrainFileError(msg) from err
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as err:
        msg = f"{path}: cannot read the terrain model ({err}); expected {expected}"
        raise TerrainFileError(msg) from err
    if not np.isfinite(heights).any():
        msg = f"{path}: terrain model has no finite height"
        raise TerrainFileError(msg)
    if not all(math.isfinite(v) for v in (*origin, resolution)):
        msg = f"{path}: terrain model origin/resolution are not finite: {origin}, {resolution}"
        raise TerrainFileError(msg)
    try:
        return HeightGrid(heights, origin[0], origin[1], resolution, "bilinear", "terrain")
    except DetectionInputError as err:
        msg = f"{path}: {err}"
        raise TerrainFileError(msg) from err
