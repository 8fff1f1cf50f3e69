"""The camera-effects child process: ``python -m uav_sim_bridge.cli.effects_worker FD``.

Started by :class:`uav_sim_bridge.shell.effects_process.EffectsProcess` (the bridge node's engine) with one end of
a socket pair as ``FD``; not meant to be run by hand. It serves that socket until the parent closes it.
"""

from __future__ import annotations

import sys

from uav_sim_bridge.shell.effects_process import serve_fd


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1 or not args[0].isdigit():
        sys.stderr.write(
            "usage: python -m uav_sim_bridge.cli.effects_worker FD\n"
            "(the bridge starts it itself for its camera effects, with one end of a socket pair as FD)\n"
        )
        return 2
    return serve_fd(int(args[0]))


if __name__ == "__main__":
    sys.exit(main())
