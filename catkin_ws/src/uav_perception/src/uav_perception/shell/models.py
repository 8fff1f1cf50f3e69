"""Where the shipped detector model is: ``uav_perception/models/uav_detector.onnx`` in the install or devel space.

Searched like the configuration folder (``uav_common.paths``): each ``$CMAKE_PREFIX_PATH`` prefix's
``share/uav_perception/models``, then each ``$ROS_PACKAGE_PATH`` entry's ``uav_perception/models``.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from uav_perception.errors import ModelFileError

__all__ = ["SHIPPED_MODEL", "resolve_model", "shipped_model"]

#: The model ``uav-train-detector`` trained here (docs/detector_model_card.md).
SHIPPED_MODEL = "uav_detector.onnx"
_PACKAGE = "uav_perception"


def shipped_model(environ: Mapping[str, str] | None = None) -> Path:
    """The shipped model file.

    Raises:
        ModelFileError: not found; the message lists where it looked.
    """
    env = os.environ if environ is None else environ
    looked = []
    for prefix in filter(None, env.get("CMAKE_PREFIX_PATH", "").split(os.pathsep)):
        looked.append(Path(prefix) / "share" / _PACKAGE / "models" / SHIPPED_MODEL)
    for entry in filter(None, env.get("ROS_PACKAGE_PATH", "").split(os.pathsep)):
        looked.append(Path(entry) / _PACKAGE / "models" / SHIPPED_MODEL)
    for path in looked:
        if path.is_file():
            return path
    where = ", ".join(str(p) for p in looked) or "nowhere: neither $CMAKE_PREFIX_PATH nor $ROS_PACKAGE_PATH is set"
    msg = f"the shipped detector model {SHIPPED_MODEL} is not installed (looked at {where}); run make build"
    raise ModelFileError(msg)


def resolve_model(model: str, base: Path | None = None, environ: Mapping[str, str] | None = None) -> Path:
    """``model`` as a path: "" = the shipped model; a relative path is relative to ``base`` (a scenario's
    folder) if given. Existence is not checked here (the detector checks the file when it loads it)."""
    if not model:
        return shipped_model(environ)
    path = Path(model).expanduser()
    if not path.is_absolute() and base is not None:
        path = base / path
    return path
