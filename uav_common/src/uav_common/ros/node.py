"""How every Python ROS node of the project starts and stops: one error policy, one exit-code convention.

``run_node(name, body)`` initialises the node, runs ``body()`` (which parses its ``~params``,
builds the node and spins) and turns the errors that stop it into one fatal log line and an
exit status of :class:`uav_common.exit_codes.ExitCode`: 2 for configuration and parameters,
3 for an unavailable resource, 1 for any other error of the project's packages. A
programming error (any other exception) is not caught: its traceback is the report.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NoReturn

from uav_common.exit_codes import ExitCode, exit_code_for

__all__ = ["run_node"]


def run_node(
    name: str,
    body: Callable[[], None],
    *,
    errors: tuple[type[BaseException], ...] = (),
    anonymous: bool = False,
) -> NoReturn:
    """``rospy.init_node(name)``, then ``body()``; exit with the convention's status.

    Args:
        name: the node's default name (roslaunch's ``name=`` wins).
        body: parses parameters, builds the node and spins until shutdown.
        errors: the package's root error classes (and any other expected failure) to report
            as one line; :class:`uav_common.errors.ConfigError` and ``ResourceError`` always are.
        anonymous: passed to ``rospy.init_node``.
    """
    import rospy  # noqa: PLC0415

    from uav_common.errors import UavCommonError  # noqa: PLC0415

    rospy.init_node(name, anonymous=anonymous)
    expected: tuple[type[BaseException], ...] = (UavCommonError, *errors)
    try:
        body()
    except expected as err:
        code = exit_code_for(err)
        rospy.logfatal(f"{rospy.get_name().lstrip('/')}: {err}")
        raise SystemExit(int(code)) from err
    except rospy.ROSInterruptException:
        pass
    raise SystemExit(int(ExitCode.OK))
