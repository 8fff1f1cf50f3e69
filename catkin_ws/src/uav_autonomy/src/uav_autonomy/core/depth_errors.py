"""Exceptions of the motion-stereo depth estimator and its evaluator.

They derive from the package root :class:`uav_autonomy.errors.UavAutonomyError`;
:class:`DepthError` lets callers catch everything this component raises at once.
"""

from __future__ import annotations

from uav_autonomy.errors import UavAutonomyError

__all__ = ["DepthError", "DepthGeometryError", "DepthInputError"]


class DepthError(UavAutonomyError):
    """Root of every error raised by the depth estimation and evaluation code."""


class DepthInputError(DepthError):
    """An input is malformed: wrong image shape or dtype, mismatched sizes, bad intrinsics."""


class DepthGeometryError(DepthError):
    """A camera pose or a stereo geometry is unusable (NaN pose, degenerate baseline)."""
