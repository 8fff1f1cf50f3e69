"""What produced a run or a report: the checkout's commit, Python, ROS and the libraries behind the numbers."""

from __future__ import annotations

import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

from uav_common.paths import repo_root

__all__ = ["run_versions", "tool_versions"]

_RUN_DISTS = ("numpy", "scipy", "opencv-python-headless", "motmetrics", "pymavlink", "jsbsim", "moderngl")


def _with_versions(out: dict[str, str], dists: tuple[str, ...]) -> dict[str, str]:
    for dist in dists:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            continue
    return out


def run_versions() -> dict[str, str]:
    """What produced a run: the checkout's commit, Python, ROS and the libraries behind the numbers."""
    out = {"python": platform.python_version(), "ros": os.environ.get("ROS_DISTRO", "unknown")}
    repo = repo_root(Path(__file__))
    if repo is None:
        out["commit"] = "installed (no checkout)"
        return _with_versions(out, _RUN_DISTS)
    try:
        commit = subprocess.run(
            ["git", "-C", str(repo), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            check=False,
            text=True,
            timeout=5,
        ).stdout.strip()
        out["commit"] = (commit or "unknown") + (" (modified)" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        out["commit"] = "unknown"
    return _with_versions(out, _RUN_DISTS)


def tool_versions() -> dict[str, str]:
    """Versions of the libraries that shape a report's numbers and figures."""
    out = {"python": platform.python_version()}
    for dist in ("numpy", "scipy", "matplotlib", "motmetrics", "rosbags", "pandas"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "not installed"
    return out
