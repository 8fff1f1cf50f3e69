"""Where the project's configuration and run folders are, found the same way from every component.

No module computes the repository root from ``Path(__file__).parents[N]``: that breaks as
soon as the code runs from a catkin *install* space (a companion computer), a wheel or a
different checkout layout. The configuration folder (the repository's ``config/``,
recognised by its ``README.md``) is looked up, in this order:

1. ``$UAV_CONFIG_DIR``, when set (it must then hold the configuration);
2. the ROS package ``uav_config``: ``<prefix>/share/uav_config/config`` for each prefix of
   ``$CMAKE_PREFIX_PATH`` (an install space) and ``<dir>/uav_config/config`` for each entry of
   ``$ROS_PACKAGE_PATH`` (a devel space: a symlink to the checkout's ``config/``);
3. the source checkout this module was loaded from: the nearest ancestor folder with
   ``config/README.md``.

The environment and the starting file are parameters, so the lookup is a pure function
of its inputs and is unit-tested without touching the process environment.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from pathlib import Path

from uav_common.errors import ConfigError

__all__ = ["CONFIG_MARKER", "config_dir", "config_file", "repo_root", "runs_dir"]

#: The file that marks a folder as the project's configuration folder.
CONFIG_MARKER = "README.md"
_CONFIG_PACKAGE = "uav_config"


def _is_config_dir(path: Path) -> bool:
    return (path / CONFIG_MARKER).is_file() and (path / "scenarios").is_dir()


def _candidates(environ: Mapping[str, str], start: Path) -> Iterator[tuple[str, Path]]:
    for prefix in filter(None, environ.get("CMAKE_PREFIX_PATH", "").split(os.pathsep)):
        yield f"$CMAKE_PREFIX_PATH entry {prefix}", Path(prefix) / "share" / _CONFIG_PACKAGE / "config"
    for entry in filter(None, environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep)):
        yield f"$ROS_PACKAGE_PATH entry {entry}", Path(entry) / _CONFIG_PACKAGE / "config"
    root = repo_root(start)
    if root is not None:
        yield f"the source checkout {root}", root / "config"


def config_dir(environ: Mapping[str, str] | None = None, start: Path | None = None) -> Path:
    """The configuration folder (see the module docstring for the search order).

    Args:
        environ: the environment to read (default: the process's).
        start: the file to search upwards from (default: this module).

    Raises:
        ConfigError: ``$UAV_CONFIG_DIR`` names a folder without the configuration, or none was found;
            the message lists every place looked at.
    """
    env = os.environ if environ is None else environ
    explicit = env.get("UAV_CONFIG_DIR")
    if explicit:
        path = Path(explicit).expanduser()
        if _is_config_dir(path):
            return path.resolve()
        msg = (
            f"$UAV_CONFIG_DIR={explicit} is not the project's configuration folder (no {CONFIG_MARKER} and scenarios/ "
            "there); point it at a copy of the repository's config/ or unset it"
        )
        raise ConfigError(msg)
    looked: list[str] = []
    for where, path in _candidates(env, start or Path(__file__)):
        if _is_config_dir(path):
            return path.resolve()
        looked.append(f"{path} ({where})")
    msg = (
        "cannot find the project's configuration folder (config/); looked in: "
        + ("; ".join(looked) or "nothing (no ROS environment and no source checkout)")
        + ". Source catkin_ws/devel/setup.bash (or the install space's setup.bash), or set UAV_CONFIG_DIR"
    )
    raise ConfigError(msg)


def config_file(*parts: str, environ: Mapping[str, str] | None = None, start: Path | None = None) -> Path:
    """``config_dir() / parts``, which must exist (e.g. ``config_file("scenarios", "loiter.yaml")``).

    Raises:
        ConfigError: no configuration folder, or no such file in it.
    """
    base = config_dir(environ, start)
    path = base.joinpath(*parts)
    if not path.exists():
        msg = f"{path}: no such configuration file in {base}"
        raise ConfigError(msg)
    return path


def repo_root(start: Path | None = None) -> Path | None:
    """The source checkout ``start`` (default: this module) lies in, or ``None`` outside one.

    A checkout is the nearest ancestor folder holding ``config/README.md`` and ``config/scenarios/``.
    """
    here = (start or Path(__file__)).resolve()
    for folder in here.parents:
        if _is_config_dir(folder / "config"):
            return folder
    return None


def runs_dir(environ: Mapping[str, str] | None = None, start: Path | None = None) -> Path:
    """Where run folders go by default: ``$UAV_RUNS_DIR``, else ``<checkout>/runs``, else ``~/.ros/uav_runs``."""
    env = os.environ if environ is None else environ
    if env.get("UAV_RUNS_DIR"):
        return Path(env["UAV_RUNS_DIR"]).expanduser()
    root = repo_root(start)
    if root is not None:
        return root / "runs"
    return Path(env.get("HOME", "~")).expanduser() / ".ros" / "uav_runs"
