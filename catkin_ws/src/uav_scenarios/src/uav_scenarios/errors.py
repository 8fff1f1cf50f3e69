"""The one exception hierarchy of :mod:`uav_scenarios` (scenario files, scoring, tracking, reports, bags).

Every error raised on purpose by the package derives from :class:`ScenarioError`.
Configuration mistakes (a scenario file, a node's ``~params``, a command-line argument)
are :class:`ScenarioConfigError`, also a :class:`uav_common.errors.ConfigError`.
Every message says what was wrong and what to do about it.
"""

from __future__ import annotations

from uav_common.errors import ConfigError

__all__ = [
    "BagReadError",
    "ReportError",
    "ScenarioConfigError",
    "ScenarioError",
    "ScoringError",
    "WorldDataError",
]


class ScenarioError(Exception):
    """Root of every error raised on purpose by :mod:`uav_scenarios`."""


class ScenarioConfigError(ScenarioError, ConfigError):
    """A scenario file, a key of it, a node's private parameter or a command-line argument is wrong."""


class WorldDataError(ScenarioError):
    """The world's ground truth (object list, surface voxels, bounds) is missing or malformed."""


class ScoringError(ScenarioError):
    """Inputs to the scoring core are inconsistent (shapes, units, time going backwards)."""


class BagReadError(ScenarioError):
    """A run's bag cannot be read (missing, truncated, or without the needed topics)."""


class ReportError(ScenarioError):
    """The run report cannot be built (no data, unwritable output folder)."""
