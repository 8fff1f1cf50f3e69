"""Geometry of the regular 2D grids exchanged as ``uav_msgs/GridLayers``.

Cell ``(row, col)`` covers ``x`` in ``[origin_x_m + col*res, origin_x_m + (col+1)*res)``
and ``y`` in ``[origin_y_m + row*res, ...)`` in the ``map`` frame (ENU, metres);
row 0 is the southern-most row. Arrays of layers are indexed ``[row, col]``,
shape ``(height, width)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from uav_autonomy.errors import InvalidInputError

__all__ = ["FloatGrid", "GridSpec"]

FloatGrid = npt.NDArray[np.float32]


@dataclass(frozen=True)
class GridSpec:
    """Size and placement of a grid: ``height`` rows (y) by ``width`` columns (x)."""

    resolution_m: float
    origin_x_m: float
    origin_y_m: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if not (math.isfinite(self.resolution_m) and self.resolution_m > 0.0):
            msg = f"grid resolution_m must be a finite number > 0, got {self.resolution_m}"
            raise InvalidInputError(msg)
        if not (math.isfinite(self.origin_x_m) and math.isfinite(self.origin_y_m)):
            msg = f"grid origin must be finite, got ({self.origin_x_m}, {self.origin_y_m})"
            raise InvalidInputError(msg)
        if self.width <= 0 or self.height <= 0:
            msg = f"grid must have at least one cell, got width={self.width} height={self.height}"
            raise InvalidInputError(msg)

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``: the shape of every layer array."""
        return (self.height, self.width)

    def cell_centers_x_m(self) -> npt.NDArray[np.float64]:
        """``(width,)`` x of each column's centre, metres ENU."""
        return self.origin_x_m + (np.arange(self.width, dtype=np.float64) + 0.5) * self.resolution_m

    def cell_centers_y_m(self) -> npt.NDArray[np.float64]:
        """``(height,)`` y of each row's centre, metres ENU."""
        return self.origin_y_m + (np.arange(self.height, dtype=np.float64) + 0.5) * self.resolution_m

    def cell_center_m(self, row: int, col: int) -> tuple[float, float]:
        """Centre ``(x_m, y_m)`` of cell ``(row, col)``."""
        return (
            self.origin_x_m + (col + 0.5) * self.resolution_m,
            self.origin_y_m + (row + 0.5) * self.resolution_m,
        )

    def cell_of(self, x_m: float, y_m: float) -> tuple[int, int] | None:
        """``(row, col)`` of the cell containing ``(x_m, y_m)``, or None outside the grid."""
        col = math.floor((x_m - self.origin_x_m) / self.resolution_m)
        row = math.floor((y_m - self.origin_y_m) / self.resolution_m)
        if 0 <= row < self.height and 0 <= col < self.width:
            return (row, col)
        return None

    def cells_of(
        self, xy_m: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        """Rows, columns and an inside-the-grid mask for ``(N, 2)`` points (metres ENU)."""
        pts = np.asarray(xy_m, dtype=np.float64).reshape(-1, 2)
        cols = np.floor((pts[:, 0] - self.origin_x_m) / self.resolution_m).astype(np.int64)
        rows = np.floor((pts[:, 1] - self.origin_y_m) / self.resolution_m).astype(np.int64)
        inside = (rows >= 0) & (rows < self.height) & (cols >= 0) & (cols < self.width)
        return rows, cols, inside

    def extent_m(self) -> tuple[float, float, float, float]:
        """``(x_min, x_max, y_min, y_max)`` of the grid's outer edges."""
        return (
            self.origin_x_m,
            self.origin_x_m + self.width * self.resolution_m,
            self.origin_y_m,
            self.origin_y_m + self.height * self.resolution_m,
        )

    def check_layer(self, name: str, layer: npt.NDArray[np.generic]) -> None:
        """Raise :class:`InvalidInputError` unless ``layer`` has this grid's 2D shape."""
        if layer.shape[:2] != self.shape:
            msg = f"layer '{name}' has shape {layer.shape}, expected {self.shape} (height, width) for this grid"
            raise InvalidInputError(msg)
