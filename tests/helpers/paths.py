"""Where the checkout's files are, for tests and benchmarks (found once, not with ``parents[N]`` per file)."""

from __future__ import annotations

from pathlib import Path

from uav_common.paths import repo_root

__all__ = ["CONFIG", "DEVEL_LIB", "REPO", "WORKSPACE"]

_root = repo_root(Path(__file__))
if _root is None:  # pragma: no cover - the tests always run from a checkout
    msg = f"{__file__} is not inside a checkout of the project (no config/README.md above it)"
    raise RuntimeError(msg)

#: The repository checkout the tests run from.
REPO: Path = _root
#: ``config/``.
CONFIG: Path = REPO / "config"
#: The catkin workspace.
WORKSPACE: Path = REPO / "catkin_ws"
#: Where catkin puts the packages' executables (``DEVEL_LIB / "uav_mapping" / "map_server"``).
DEVEL_LIB: Path = WORKSPACE / "devel" / "lib"
