"""The one exception hierarchy of :mod:`uav_datasets`.

Every error raised on purpose by the package derives from :class:`DatasetError`. A dataset config
that is wrong (unknown key or class, impossible altitude range...) is :class:`DatasetConfigError`, also
a :class:`uav_common.errors.ConfigError`; an output folder that holds something else is
:class:`DatasetFolderError` (also a ``ConfigError``: the user picks another folder). Messages say what
was wrong, where (file and key, or folder) and what to do.
"""

from __future__ import annotations

from uav_common.errors import ConfigError, ResourceError

__all__ = [
    "DatasetConfigError",
    "DatasetError",
    "DatasetFolderError",
    "FlightError",
    "IncompleteDatasetError",
    "SamplingError",
    "WorkerError",
]


class DatasetError(Exception):
    """Root of every error raised on purpose by :mod:`uav_datasets`."""


class DatasetConfigError(DatasetError, ConfigError):
    """A dataset config file, one of its keys or a command-line argument is wrong."""


class DatasetFolderError(DatasetError, ConfigError):
    """The output folder holds a different dataset, or files that are not a dataset."""


class IncompleteDatasetError(DatasetError):
    """A dataset folder whose generation has not finished (resume it with the same command)."""


class SamplingError(DatasetError, ConfigError):
    """No valid viewpoint could be drawn: the config's area, altitudes and classes leave none in a world."""


class FlightError(DatasetError):
    """A recorded run cannot be turned into a sequence (missing bag or topics, unreadable scenario)."""


class WorkerError(DatasetError, ResourceError):
    """A generation worker process died; the frames it finished are kept and the run can be resumed."""
