"""Exceptions of the scenario layer (scenario files, scoring, tracking, reports, bags).

They hang under the package root :class:`uav_autonomy.errors.UavAutonomyError`, so
callers can catch every autonomy error with one ``except``.
Every message says what was wrong and what to do about it.
"""

from __future__ import annotations

from uav_autonomy.errors import UavAutonomyError

__all__ = ["BagReadError", "ReportError", "ScenarioError", "ScoringError", "WorldDataError"]


class ScenarioError(UavAutonomyError):
    """Root of the scenario layer's errors."""


class WorldDataError(ScenarioError):
    """The world's ground truth (object list, surface voxels, bounds) is missing or malformed."""


class ScoringError(ScenarioError):
    """Inputs to the scoring core are inconsistent (shapes, units, time going backwards)."""


class BagReadError(ScenarioError):
    """A run's bag cannot be read (missing, truncated, or without the needed topics)."""


class ReportError(ScenarioError):
    """The run report cannot be built (no data, unwritable output folder)."""
