"""The one exception hierarchy of :mod:`uav_campaigns`.

Every error raised on purpose by the package derives from :class:`CampaignError`. A wrong
campaign file, arm override or command-line argument is a :class:`CampaignConfigError` (also a
:class:`uav_common.errors.ConfigError`, exit code 2); a scheduler that cannot be reached or
workers without the project are a :class:`CampaignResourceError` (also a
:class:`uav_common.errors.ResourceError`, exit code 3). Every message says what was wrong and
what to do.
"""

from __future__ import annotations

from uav_common.errors import ConfigError, ResourceError

__all__ = ["CampaignConfigError", "CampaignDirError", "CampaignError", "CampaignResourceError", "StatisticsError"]


class CampaignError(Exception):
    """Root of every error raised on purpose by :mod:`uav_campaigns`."""


class CampaignConfigError(CampaignError, ConfigError):
    """A campaign file, an arm's scenario override or a command-line argument is wrong."""


class CampaignDirError(CampaignConfigError):
    """The campaign directory cannot be used: made by another campaign file, or not a campaign directory."""


class CampaignResourceError(CampaignError, ResourceError):
    """The Dask scheduler cannot be reached, or its workers cannot run the project's runs."""


class StatisticsError(CampaignError):
    """Inputs to the statistics are inconsistent (unpaired samples, a confidence level outside (0, 1))."""
