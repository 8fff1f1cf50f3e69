"""How every Python ROS node of the project starts and stops: one error policy, one exit-code convention.

``run_node(name, body)`` initialises the node, runs ``body()`` (which parses its ``~params``,
builds the node and spins) and turns the errors that stop it into one fatal log line and an
exit status of :class:`uav_common.exit_codes.ExitCode`: 2 for configuration and parameters,
3 for an unavailable resource, 1 for any other error of the project's packages. A
programming error (any other exception) is not caught: its traceback is the report.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, NoReturn

if TYPE_CHECKING:
    from uav_common.ros.lockstep import Participant

from uav_common.exit_codes import ExitCode, exit_code_for

__all__ = ["run_node", "run_participant"]


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


def run_participant(
    name: str,
    build: Callable[[Participant], None],
    *,
    lookahead_steps: int,
    errors: tuple[type[BaseException], ...] = (),
) -> NoReturn:
    """:func:`run_node` for an in-loop node (docs/lockstep.md): ``rospy.init_node(name)``, its
    :class:`~uav_common.ros.lockstep.Participant` (``lookahead_steps`` is its default lookahead), ``build(ls)``
    (parses the ``~params``, builds and starts the node through ``ls``), then ``ls.spin()``; the same error
    policy and exit codes. Every in-loop Python node's ``main`` is this one line.
    """

    def body() -> None:
        from uav_common.ros.lockstep import Participant  # noqa: PLC0415 - rospy is imported by run_node first

        ls = Participant(lookahead_steps=lookahead_steps)
        build(ls)
        ls.spin()

    run_node(name, body, errors=errors)
