"""Exceptions of the motion-stereo depth estimator and its evaluator.

The package-wide hierarchy (``uav_autonomy.errors``) belongs to the autonomy
component; these depth-specific errors have their own root, :class:`DepthError`,
so callers can catch everything this component raises in one place.
"""

from __future__ import annotations

__all__ = ["DepthError", "DepthGeometryError", "DepthInputError"]


class DepthError(Exception):
    """Root of every error raised by the depth estimation and evaluation code."""


class DepthInputError(DepthError):
    """An input is malformed: wrong image shape or dtype, mismatched sizes, bad intrinsics."""


class DepthGeometryError(DepthError):
    """A camera pose or a stereo geometry is unusable (NaN pose, degenerate baseline)."""
