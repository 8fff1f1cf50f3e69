"""The one exit-status convention of every program and ROS node of the project.

=====  ==========  ===========================================================================
code   name        meaning and what the user does
=====  ==========  ===========================================================================
0      OK          finished, or stopped on request (SIGINT, ``rosnode kill``, the run ended)
1      FAILURE     a runtime failure the program cannot recover from; read its log
2      CONFIG      bad configuration, parameter or argument (file, key, ``~param``); fix the input
3      RESOURCE    something it needs is unavailable (port in use, no GL, missing build); fix the machine
=====  ==========  ===========================================================================

Programs print one message saying what was wrong and what to do, then exit with the code.
``roslaunch`` shows the code in "process has died [exit code N]".
"""

from __future__ import annotations

import enum

from uav_common.errors import ConfigError, ResourceError

__all__ = ["ExitCode", "exit_code_for"]


class ExitCode(enum.IntEnum):
    OK = 0
    FAILURE = 1
    CONFIG = 2
    RESOURCE = 3


def exit_code_for(err: BaseException) -> ExitCode:
    """The exit code a program ends with when ``err`` stops it."""
    if isinstance(err, ConfigError):
        return ExitCode.CONFIG
    if isinstance(err, ResourceError):
        return ExitCode.RESOURCE
    return ExitCode.FAILURE
